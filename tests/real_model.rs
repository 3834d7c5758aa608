//! The embedded default model, for real: a fixed ChatML prompt under the demo action grammar gives a
//! parseable action list, and the same one twice (greedy decoding is deterministic). Skips with a note
//! when the model is not installed, unless STEP_REQUIRE_MODELS=1.

use std::path::PathBuf;

use step::grammar::parse_actions;
use step::scene_grammar::demo_kitchen_grammar;
use step::llm::chat::Message;
use step::llm::engine::{Engine, GenOptions, Generate, Prompt, StopReason, WarmSource};

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

/// The quantised kernels, for real: the planner's system message read back from a prefix snapshot
/// scores a continuation exactly as computing it does (the first 200-odd tokens of it, so that the
/// prefix spans more than one 128-token batch and the test stays short in a debug build).
#[test]
fn smollm2_prefix_snapshot_scores_bit_for_bit() {
    let Some(path) = smollm2() else { return };
    let text: String = step::planner::prompt::system_message().chars().take(900).collect();
    let system = vec![Message::system(text)];
    let prompt = Prompt::Chat(vec![system[0].clone(), Message::user("Task: put the apple in the fridge\nNext step?")]);
    let conts = ["action: [WALK] <apple> (12)".to_string(), "done".to_string()];
    let want = Engine::load(&path).unwrap().score(&prompt, &conts).unwrap();
    let store = tempfile::tempdir().unwrap();
    for expected in [WarmSource::Computed, WarmSource::Loaded] {
        let mut e = Engine::load(&path).unwrap();
        e.set_prefix_dir(Some(store.path().to_path_buf()));
        let w = e.warm(&system).unwrap();
        assert_eq!(w.source, expected, "{w:?}");
        assert!(w.tokens > 128, "{w:?}");
        let got = e.score(&prompt, &conts).unwrap();
        assert_eq!(got.reused_tokens, w.tokens);
        assert_eq!(got.scores, want.scores);
    }
}

#[test]
fn bench_at_a_depth_times_only_the_prompt_after_the_cached_tokens() {
    use step::bench::{run_llm_bench, LlmBenchConfig};
    let Some(path) = smollm2() else { return };
    let mut engine = Engine::load_with_slices(&path, &[step::grammar::TEXT_SLICE.to_string()]).unwrap();
    let flat = run_llm_bench(&mut engine, &LlmBenchConfig { runs: 1, decode_tokens: 4, depth: 0 }).unwrap();
    assert_eq!(flat.depth, 0);
    let deep = run_llm_bench(&mut engine, &LlmBenchConfig { runs: 1, decode_tokens: 4, depth: 300 }).unwrap();
    // The filler is cut at 300 tokens; re-tokenizing the cut may merge or split a token or two.
    assert!((297..=303).contains(&deep.depth), "reused {} tokens, asked for 300", deep.depth);
    // The timed prefill is the same prompt, after the filler (a token either side at the seam).
    assert!(deep.prompt_tokens.abs_diff(flat.prompt_tokens) <= 3, "{} new tokens at depth, {} at 0", deep.prompt_tokens, flat.prompt_tokens);
    assert!(deep.prefill_tok_per_s > 0.0 && deep.decode_tok_per_s > 0.0);
}
