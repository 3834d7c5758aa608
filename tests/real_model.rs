//! The embedded default model, for real: a fixed ChatML prompt under the demo action grammar gives a
//! parseable action list, and the same one twice (greedy decoding is deterministic). Skips with a note
//! when the model is not installed, unless STEP_REQUIRE_MODELS=1.

use std::path::PathBuf;

use step::grammar::parse_actions;
use step::scene_grammar::demo_kitchen_grammar;
use step::llm::engine::{Engine, GenOptions, Generate, Prompt, StopReason};

fn smollm2() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models/SmolLM2-135M-Instruct.Q4_1.gguf");
    if p.exists() {
        return Some(p);
    }
    assert!(
        std::env::var("STEP_REQUIRE_MODELS").map_or(true, |v| v != "1"),
        "{} is missing and STEP_REQUIRE_MODELS=1: run models/install.sh",
        p.display()
    );
    eprintln!("skipped: {} not installed (models/install.sh)", p.display());
    None
}

/// ChatML written out by hand, so the test does not depend on the template renderer.
const PROMPT: &str = "<|im_start|>system\nYou are a household robot. Write the robot's actions, one per line, \
as [VERB] <object> (id).<|im_end|>\n<|im_start|>user\nPut the apple (12) in the fridge (10).<|im_end|>\n\
<|im_start|>assistant\n";

#[test]
fn smollm2_writes_a_parseable_action_list_and_the_same_one_twice() {
    let Some(path) = smollm2() else { return };
    let lark = demo_kitchen_grammar().to_lark().unwrap();
    let opts = GenOptions { max_tokens: 160, ..Default::default() };
    let mut engine = Engine::load(&path).unwrap();
    let first = engine.generate(&Prompt::Text(PROMPT.into()), Some(&lark), &opts).unwrap();
    // A second engine, so the first call's cache cannot be what makes them agree.
    let mut other = Engine::load(&path).unwrap();
    let second = other.generate(&Prompt::Text(PROMPT.into()), Some(&lark), &opts).unwrap();
    assert_eq!(first.text, second.text);
    assert_ne!(first.stop, StopReason::MaxTokens);
    let actions = parse_actions(&first.text).unwrap_or_else(|e| panic!("{e:?}\n{}", first.text));
    assert!(!actions.is_empty() && actions.len() <= 8, "{}", first.text);
    // And the first engine again, now reusing its cached prompt: still the same.
    let third = engine.generate(&Prompt::Text(PROMPT.into()), Some(&lark), &opts).unwrap();
    assert_eq!(third.text, first.text);
    assert_eq!(third.reused_tokens, third.prompt_tokens - 1);
}
