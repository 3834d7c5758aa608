//! Zero grammar errors through the real decode loop: for random grammars of the planner's family
//! (verbs of arity 0–2 over an enumerated object list, optional header fields, subgoal lines), tiny
//! random-weight models of both architectures, and random sampling seeds, every output is accepted by
//! the grammar's independent checker. (`grammar`'s own property tests walk the masks directly, with
//! many more cases; this one proves the engine applies them.)

use proptest::prelude::*;
use step::action::{ObjRef, Verb};
use step::grammar::{ActionGrammar, VerbSpec};
use step::llm::engine::{Engine, GenOptions, Generate, Prompt};
use step::llm::sample::Sampling;
use step::llm::tiny::{write_tiny_gguf, TinySpec};

const NAMES: &[&str] = &["apple", "fridge", "kitchen_counter", "tv", "mug2", "light", "sofa", "book"];

#[derive(Debug, Clone)]
struct Family {
    verbs: Vec<usize>,
    objects: Vec<(usize, u32)>,
    max_lines: usize,
    reason: Option<usize>,
    verdict: bool,
    subgoals: Option<usize>,
}

fn family() -> impl Strategy<Value = Family> {
    (
        prop::sample::subsequence((0..Verb::ALL.len()).collect::<Vec<_>>(), 1..6),
        prop::collection::vec((0..NAMES.len(), 1u32..2000), 1..6),
        1usize..4,
        prop::option::of(1usize..30),
        any::<bool>(),
        prop::option::of(5usize..40),
    )
        .prop_map(|(verbs, objects, max_lines, reason, verdict, subgoals)| Family {
            verbs,
            objects,
            max_lines,
            reason,
            verdict,
            subgoals,
        })
}

fn build(f: &Family) -> ActionGrammar {
    let verbs = f.verbs.iter().map(|&i| VerbSpec::from(Verb::ALL[i]));
    let objects = f.objects.iter().map(|&(n, id)| ObjRef::new(NAMES[n], id));
    let mut g = ActionGrammar::new(verbs, objects).lines(1, f.max_lines);
    if f.verdict {
        g = g.header_choice("verdict", ["execute", "decompose", "replan"]);
    }
    if let Some(k) = f.reason {
        g = g.header_text("reason", k);
    }
    if let Some(k) = f.subgoals {
        g = g.subgoals("subgoal", k);
    }
    g
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn every_sampled_output_parses(f in family(), seed in any::<u64>(), qwen in any::<bool>()) {
        let dir = tempfile::tempdir().unwrap();
        let spec = if qwen { TinySpec::qwen2() } else { TinySpec::llama() }.with_seed(seed % 7);
        let path = dir.path().join("m.gguf");
        write_tiny_gguf(&spec, &path).unwrap();
        let mut engine = Engine::load(&path).unwrap();
        let grammar = build(&f);
        let lark = grammar.to_lark().unwrap();
        let opts = GenOptions {
            max_tokens: 400,
            sampling: Sampling::Sample { temperature: 1.3, top_p: 1.0, seed },
            reuse_prefix: true,
        };
        let g = engine.generate(&Prompt::Text("plan:".into()), Some(&lark), &opts).unwrap();
        prop_assert!(grammar.parse(&g.text).is_ok(), "{:?} does not parse under\n{}", g.text, lark);
    }
}
