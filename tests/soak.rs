//! Soak run (ignored; outside the default test command):
//! `cargo test --release --test soak -- --ignored soak --nocapture`.
//!
//! Many constrained generations from random-weight tiny models of both architectures, over random
//! grammars of the planner's family (verbs × objects, optional verdict/reason header, optional
//! free-text subgoal lines, bounded line counts) and random sampling parameters and seeds. Counts
//! outputs the independent checker (`ActionGrammar::parse`) rejects, panics, and generations that hit
//! the token budget; the first two must be zero. `STEP_SOAK_N` sets the number of generations
//! (default 10,000).

use std::collections::BTreeMap;
use std::panic::AssertUnwindSafe;
use std::path::Path;
use std::time::Instant;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use step::action::{ObjRef, Verb};
use step::grammar::{ActionGrammar, VerbSpec};
use step::llm::chat::Message;
use step::llm::engine::{Engine, GenOptions, Generate, Prompt};
use step::llm::sample::Sampling;
use step::llm::tiny::{write_tiny_gguf, TinySpec};
use step::llm::LlmError;

const NAMES: &[&str] = &[
    "apple",
    "fridge",
    "kitchen_counter",
    "microwave",
    "mug",
    "sofa",
    "tv",
    "light_switch",
    "plate",
    "book",
    "o'clock",
    "a.b",
    "x_9",
    "door",
];

/// A random grammar of the planner's family.
fn random_grammar(rng: &mut StdRng) -> ActionGrammar {
    let n_obj = rng.random_range(1..=8);
    let objects: Vec<ObjRef> = (0..n_obj)
        .map(|i| {
            let name = NAMES[rng.random_range(0..NAMES.len())];
            ObjRef::new(
                format!("{name}{}", if rng.random_bool(0.3) { i.to_string() } else { String::new() }),
                rng.random_range(1..3000),
            )
        })
        .collect();
    let n_verbs = rng.random_range(1..=8);
    let mut verbs: Vec<VerbSpec> = Vec::new();
    for _ in 0..n_verbs {
        let v = Verb::ALL[rng.random_range(0..Verb::ALL.len())];
        if !verbs.iter().any(|s| s.name == v.name()) {
            verbs.push(VerbSpec::from(v));
        }
    }
    let mut g = ActionGrammar::new(verbs, objects);
    if rng.random_bool(0.5) {
        g = g.header_choice("verdict", ["decompose", "primitive", "inconsistent"]);
    }
    if rng.random_bool(0.4) {
        g = g.header_text("reason", rng.random_range(5..=60));
    }
    if rng.random_bool(0.5) {
        g = g.subgoals("subgoal", rng.random_range(5..=60));
    }
    let min = rng.random_range(0..=2);
    let max = rng.random_range(min.max(1)..=6);
    g.lines(min, max)
}

fn sampling(rng: &mut StdRng) -> Sampling {
    if rng.random_bool(0.2) {
        Sampling::Greedy
    } else {
        Sampling::Sample {
            temperature: rng.random_range(0.2..2.5),
            top_p: if rng.random_bool(0.5) { 1.0 } else { rng.random_range(0.3..1.0) },
            seed: rng.random(),
        }
    }
}

fn load(dir: &Path, spec: TinySpec) -> Engine {
    let p = dir.join(format!("tiny-{}-{}.gguf", spec.arch, spec.seed));
    write_tiny_gguf(&spec, &p).unwrap();
    Engine::load_with_slices(&p, &[step::grammar::TEXT_SLICE.to_string()]).unwrap()
}

#[test]
#[ignore = "soak run: cargo test --release --test soak -- --ignored soak --nocapture"]
fn soak_constrained_generations_never_fail_the_checker_or_panic() {
    let n: usize = std::env::var("STEP_SOAK_N").ok().and_then(|s| s.parse().ok()).unwrap_or(10_000);
    let dir = tempfile::tempdir().unwrap();
    let specs: Vec<TinySpec> =
        (0..3).flat_map(|s| [TinySpec::llama().with_seed(s), TinySpec::qwen2().with_seed(s)]).collect();
    let mut engines: Vec<(String, Engine)> =
        specs.iter().map(|s| (format!("{}#{}", s.arch, s.seed), load(dir.path(), s.clone()))).collect();
    let mut rng = StdRng::seed_from_u64(0x5eed);
    let (mut checker_failures, mut panics, mut budget_hits, mut other_errors) = (0usize, 0usize, 0usize, 0usize);
    let mut stops: BTreeMap<String, usize> = BTreeMap::new();
    let mut tokens = 0usize;
    let mut grammar = random_grammar(&mut rng);
    let mut lark = grammar.to_lark().unwrap();
    let t0 = Instant::now();
    for i in 0..n {
        // A new grammar every 8 generations (compiles are cached, as in the planner).
        if i % 8 == 0 {
            grammar = random_grammar(&mut rng);
            lark = match grammar.to_lark() {
                Ok(l) => l,
                Err(e) => panic!("generated spec does not build: {e}\n{grammar:?}"),
            };
        }
        let which = rng.random_range(0..engines.len());
        let opts = GenOptions {
            max_tokens: rng.random_range(24..=160),
            sampling: sampling(&mut rng),
            reuse_prefix: rng.random_bool(0.7),
        };
        let prompt = Prompt::Chat(vec![
            Message::system("You are a household robot planner. Answer in the required format."),
            Message::user(format!("Task {i}: put the {} away.", NAMES[i % NAMES.len()])),
        ]);
        let (name, engine) = &mut engines[which];
        let r = std::panic::catch_unwind(AssertUnwindSafe(|| engine.generate(&prompt, Some(&lark), &opts)));
        match r {
            Err(_) => {
                panics += 1;
                eprintln!("PANIC on {name}, generation {i}, grammar:\n{lark}");
                let spec = specs[which].clone();
                engines[which].1 = load(dir.path(), spec);
            }
            Ok(Err(LlmError::TokenBudget { .. })) => budget_hits += 1,
            Ok(Err(e)) => {
                other_errors += 1;
                eprintln!("error on {name}, generation {i}: {e}");
            }
            Ok(Ok(g)) => {
                tokens += g.tokens.len();
                *stops.entry(format!("{:?}", g.stop)).or_default() += 1;
                if let Err(e) = grammar.parse(&g.text) {
                    checker_failures += 1;
                    eprintln!("CHECKER REJECTS output of {name}, generation {i}: {e}\n{:?}\ngrammar:\n{lark}", g.text);
                }
            }
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    eprintln!(
        "soak: {n} generations on {} models ({} architectures) in {secs:.1} s, {tokens} tokens; \
         checker failures {checker_failures}, panics {panics}, token-budget hits {budget_hits}, other errors \
         {other_errors}; stops {stops:?}",
        engines.len(),
        2
    );
    assert_eq!(checker_failures, 0, "outputs the checker rejects");
    assert_eq!(panics, 0, "panics");
    assert_eq!(other_errors, 0, "errors other than the token budget");
}
