//! Zero grammar errors for the planner's decision grammars through the real decode loop: random
//! decomposition, verdict and plan grammars of all three strengths, over random states of the demo
//! scene and random focus lists, decoded by tiny random-weight models of both architectures with
//! random sampling seeds; every output is accepted by the grammar's independent checker. Also: a
//! whole scene's action set (hundreds of objects, thousands of exact actions) compiles and decodes
//! within llguidance's limits.

use proptest::prelude::*;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use step::action::{Action, ObjRef, Verb};
use step::grammar::{ActionSet, Cause, DecomposeGrammar, PlanGrammar, Proposal, Strength, Verdict, VerdictGrammar};
use step::llm::engine::{Engine, GenOptions, Generate, Prompt};
use step::llm::sample::Sampling;
use step::llm::tiny::{write_tiny_gguf, TinySpec};
use step::world::World;

/// The demo kitchen after `steps` random feasible actions (so sets see held objects, open doors,
/// a seated robot), and a random focus list of its objects.
fn random_scene(seed: u64, steps: usize, focus: usize) -> (World, Vec<u32>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut w = World::demo();
    for _ in 0..steps {
        let f = w.feasible_actions();
        if f.is_empty() {
            break;
        }
        let a = f[rng.random_range(0..f.len())].clone();
        w.execute(&a).unwrap();
    }
    let mut ids: Vec<u32> = w.nodes().map(|n| n.id).collect();
    // A random subset of `focus` objects (the character may be among them; sets leave it out).
    for i in (1..ids.len()).rev() {
        ids.swap(i, rng.random_range(0..=i));
    }
    ids.truncate(focus.max(1));
    (w, ids)
}

const MENU: [&str; 3] = ["apple is INSIDE to fridge", "say \"done\" \\ twice", "WATCH or LOOKAT"];

#[derive(Debug, Clone, Copy)]
enum Kind {
    Decompose { subgoal: bool, done: bool, menu: bool },
    Verdict { decompose: bool },
    Plan { max_lines: usize },
}

fn kind() -> impl Strategy<Value = Kind> {
    prop_oneof![
        (any::<bool>(), any::<bool>(), any::<bool>()).prop_map(|(subgoal, done, menu)| Kind::Decompose { subgoal, done, menu }),
        any::<bool>().prop_map(|decompose| Kind::Verdict { decompose }),
        (1usize..4).prop_map(|max_lines| Kind::Plan { max_lines }),
    ]
}

/// A decision grammar: its Lark, and its checker as a closure returning the actions the text writes
/// (the three types parse to different outputs).
struct Decision {
    lark: String,
    check: Box<Checker>,
}

type Checker = dyn Fn(&str) -> Result<Vec<Action>, String>;

fn decision(kind: Kind, set: ActionSet, chars: usize) -> Result<Decision, String> {
    let err = |e: step::grammar::GrammarError| e.to_string();
    Ok(match kind {
        Kind::Decompose { subgoal, done, menu } => {
            // Offered subgoal lines, quotes and backslashes included, must reach the grammar unchanged.
            let subgoal_menu = if menu { MENU.iter().map(|s| s.to_string()).collect() } else { Vec::new() };
            let g = DecomposeGrammar { actions: set, subgoal_chars: chars, allow_subgoal: subgoal, allow_done: done, subgoal_menu };
            Decision {
                lark: g.to_lark().map_err(err)?,
                check: Box::new(move |t| {
                    g.parse(t).map_err(|e| e.to_string()).map(|p| match p {
                        Proposal::Action(a) => vec![a],
                        _ => vec![],
                    })
                }),
            }
        }
        Kind::Verdict { decompose } => {
            let g = VerdictGrammar { actions: set, reason_chars: chars, allow_decompose: decompose, causes: Cause::ALL.to_vec() };
            Decision {
                lark: g.to_lark().map_err(err)?,
                check: Box::new(move |t| {
                    g.parse(t).map_err(|e| e.to_string()).map(|v| match v {
                        Verdict::Execute(a) => vec![a],
                        _ => vec![],
                    })
                }),
            }
        }
        Kind::Plan { max_lines } => {
            let g = PlanGrammar { actions: set, max_lines };
            Decision {
                lark: g.to_lark().map_err(err)?,
                check: Box::new(move |t| g.parse(t).map_err(|e| e.to_string())),
            }
        }
    })
}

/// Under `feasible`, the first action written succeeds in the world as it is (later plan lines are
/// decided against the same state, so only the first is guaranteed); under `typed`, none is refused
/// for want of an affordance.
fn check_world(world: &World, strength: Strength, actions: &[Action]) -> Result<(), String> {
    for (i, a) in actions.iter().enumerate() {
        match (strength, world.why_not(a)) {
            (Strength::Feasible, Some(f)) if i == 0 => {
                return Err(format!("feasible grammar wrote {a}: {}", f.message))
            }
            (Strength::Typed | Strength::Feasible, Some(f))
                if f.kind == step::world::FailureKind::Affordance && !f.message.contains("is not in any room") =>
            {
                return Err(format!("{strength} grammar wrote the affordance error {a}: {}", f.message))
            }
            _ => {}
        }
    }
    Ok(())
}

fn engine(qwen: bool, seed: u64, dir: &tempfile::TempDir) -> Engine {
    let spec = if qwen { TinySpec::qwen2() } else { TinySpec::llama() }.with_seed(seed);
    let path = dir.path().join(format!("m{}{seed}.gguf", if qwen { "q" } else { "l" }));
    write_tiny_gguf(&spec, &path).unwrap();
    Engine::load(&path).unwrap()
}

fn opts(seed: u64) -> GenOptions {
    GenOptions {
        max_tokens: 2000,
        sampling: Sampling::Sample { temperature: 1.3, top_p: 1.0, seed },
        reuse_prefix: true,
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 30, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn every_sampled_decision_parses(
        scene_seed in any::<u64>(),
        steps in 0usize..12,
        focus in 1usize..30,
        strength in prop::sample::select(Strength::ALL.to_vec()),
        kind in kind(),
        chars in 1usize..40,
        seed in any::<u64>(),
        qwen in any::<bool>(),
    ) {
        let (world, ids) = random_scene(scene_seed, steps, focus);
        let set = step::scene_grammar::action_set(strength, &world, &ids);
        let empty = set.is_empty();
        let d = match decision(kind, set, chars) {
            Ok(d) => d,
            Err(e) => {
                // The only grammars that may not exist: a plan, or a verdict that may not decompose,
                // over an empty set; and a decomposition with everything switched off.
                let expected = match kind {
                    Kind::Plan { .. } | Kind::Verdict { decompose: false } => empty,
                    Kind::Decompose { subgoal, done, .. } => empty && !subgoal && !done,
                    Kind::Verdict { decompose: true } => false,
                };
                prop_assert!(expected, "{kind:?} {strength}: unexpected grammar error {e}");
                return Ok(());
            }
        };
        let dir = tempfile::tempdir().unwrap();
        let mut engine = engine(qwen, seed % 5, &dir);
        let g = engine.generate(&Prompt::Text("decide:".into()), Some(&d.lark), &opts(seed)).unwrap();
        let actions = (d.check)(&g.text);
        prop_assert!(actions.is_ok(), "{:?} rejected: {:?}\n{}", g.text, actions, d.lark);
        let r = check_world(&world, strength, &actions.unwrap());
        prop_assert!(r.is_ok(), "{:?}", r);
    }
}

/// A uniformly random walk through llguidance's masks (no model): pick any allowed token, EOS
/// included where the grammar may end, until the grammar ends. Returns the text written.
fn mask_walk(engine: &Engine, lark: &str, seed: u64) -> String {
    let mut rng = StdRng::seed_from_u64(seed);
    let tok = engine.tokenizer();
    let mut k = engine.grammars().compile(lark).unwrap();
    let mut bytes = Vec::new();
    for _ in 0..5000 {
        for t in k.forced_tokens().unwrap() {
            bytes.extend(tok.token_bytes(t).unwrap());
        }
        if k.is_finished() {
            break;
        }
        let allowed: Vec<u32> = k.mask().unwrap().iter().collect();
        assert!(!allowed.is_empty(), "empty mask after {:?}", String::from_utf8_lossy(&bytes));
        let t = allowed[rng.random_range(0..allowed.len())];
        if tok.is_eos(t) {
            break;
        }
        k.commit(t).unwrap();
        bytes.extend(tok.token_bytes(t).unwrap());
    }
    assert!(k.is_accepting() || k.is_finished(), "walk did not end: {:?}", String::from_utf8_lossy(&bytes));
    String::from_utf8(bytes).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, failure_persistence: None, ..ProptestConfig::default() })]

    /// Many more cases than the decode loop, without forward passes: every walk through the masks
    /// writes a sentence the independent checker accepts.
    #[test]
    fn random_mask_walks_write_only_accepted_decisions(
        scene_seed in any::<u64>(),
        steps in 0usize..15,
        focus in 1usize..30,
        strength in prop::sample::select(Strength::ALL.to_vec()),
        kind in kind(),
        chars in 1usize..30,
        seed in any::<u64>(),
        qwen in any::<bool>(),
    ) {
        let (world, ids) = random_scene(scene_seed, steps, focus);
        let Ok(d) = decision(kind, step::scene_grammar::action_set(strength, &world, &ids), chars) else { return Ok(()) };
        let engine = walk_engine(qwen);
        let text = mask_walk(engine, &d.lark, seed);
        let actions = (d.check)(&text);
        prop_assert!(actions.is_ok(), "{:?} rejected: {:?}\n{}", text, actions, d.lark);
        let r = check_world(&world, strength, &actions.unwrap());
        prop_assert!(r.is_ok(), "{:?}", r);
    }
}

/// One tiny engine per architecture for the mask walks (only its tokenizer and grammar compiler
/// are used), leaked so that proptest cases can share it.
fn walk_engine(qwen: bool) -> &'static Engine {
    thread_local! {
        static ENGINES: std::cell::RefCell<[Option<&'static Engine>; 2]> = const { std::cell::RefCell::new([None, None]) };
    }
    ENGINES.with(|e| {
        *e.borrow_mut()[qwen as usize].get_or_insert_with(|| {
            let dir = Box::leak(Box::new(tempfile::tempdir().unwrap()));
            Box::leak(Box::new(engine(qwen, 3, dir)))
        })
    })
}

/// A synthetic scene far larger than any EAI scene: thousands of objects in one slot and thousands of
/// exact pairs still compile and decode (no llguidance row limit is hit), for both architectures.
#[test]
fn very_large_action_sets_compile_and_decode() {
    let objs: Vec<ObjRef> = (0..2500u32).map(|i| ObjRef::new(format!("thing_{}", i % 97), 1000 + i)).collect();
    let mut exact: Vec<Action> = objs.iter().map(|o| Action::new(Verb::Walk, vec![o.clone()]).unwrap()).collect();
    // 40 held objects, each with its own 60 destinations: 2400 pairs in 40 groups.
    for (k, a) in objs.iter().take(40).enumerate() {
        for b in objs.iter().skip(100 + k * 50).take(60) {
            exact.push(Action::new(Verb::PutIn, vec![a.clone(), b.clone()]).unwrap());
        }
    }
    let sets = [ActionSet::format(&objs), ActionSet::Exact(exact)];
    let dir = tempfile::tempdir().unwrap();
    for qwen in [false, true] {
        let mut engine = engine(qwen, 1, &dir);
        for (i, set) in sets.iter().enumerate() {
            for seed in 0..3u64 {
                let g = PlanGrammar { actions: set.clone(), max_lines: 3 };
                let lark = g.to_lark().unwrap();
                let out = engine.generate(&Prompt::Text("plan:".into()), Some(&lark), &opts(seed)).unwrap();
                assert!(g.parse(&out.text).is_ok(), "set {i}: {:?}: {:?}", out.text, g.parse(&out.text));
                let d = VerdictGrammar::new(set.clone(), 30);
                let out = engine
                    .generate(&Prompt::Text("verdict:".into()), Some(&d.to_lark().unwrap()), &opts(seed))
                    .unwrap();
                assert!(d.parse(&out.text).is_ok(), "set {i}: {:?}", out.text);
            }
        }
    }
}

/// A whole EAI scene (every object) under each strength. Needs the benchmark data; skipped
/// with a note when it is absent, unless STEP_REQUIRE_DATA=1.
#[test]
fn a_whole_eai_scene_compiles_and_decodes() {
    use step::eval::EaiData;
    let data = match EaiData::open(None) {
        Ok(d) => d,
        Err(e) => {
            assert!(
                std::env::var("STEP_REQUIRE_DATA").map_or(true, |v| v != "1"),
                "STEP_REQUIRE_DATA=1 but the data is missing: {e}"
            );
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "note: skipping the whole-EAI-scene grammar test: {e}");
            return;
        }
    };
    let meta = data.tasks_meta().unwrap();
    let wanted = std::iter::once(meta[0].id.clone()).collect();
    let (_, world) = data
        .scenes(Some(&wanted), |id, s| World::from_graph(&s.init, id).map_err(step::eval::EvalError::from))
        .unwrap()
        .remove(0);
    let ids: Vec<u32> = world.nodes().map(|n| n.id).collect();
    let dir = tempfile::tempdir().unwrap();
    let mut engine = engine(true, 2, &dir);
    for strength in Strength::ALL {
        let set = step::scene_grammar::action_set(strength, &world, &ids);
        assert!(set.len() > 300, "{strength}: {} actions", set.len());
        eprintln!("task {} scene: {} objects, {strength}: {} actions", meta[0].id, ids.len(), set.len());
        let g = DecomposeGrammar::new(set.clone(), 40);
        let p = PlanGrammar { actions: set, max_lines: 4 };
        // Reported, never asserted: what rebuilding a grammar before a decision costs.
        let t = std::time::Instant::now();
        let lark = g.to_lark().unwrap();
        let render_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = std::time::Instant::now();
        let mut k = engine.grammars().compile(&lark).unwrap();
        k.mask().unwrap();
        eprintln!(
            "  {strength} decompose grammar: {} bytes, render {render_ms:.1} ms, compile + first mask {:.1} ms",
            lark.len(),
            t.elapsed().as_secs_f64() * 1e3
        );
        for seed in 0..3u64 {
            let out = engine.generate(&Prompt::Text("next:".into()), Some(&g.to_lark().unwrap()), &opts(seed)).unwrap();
            assert!(g.parse(&out.text).is_ok(), "{strength}: {:?}", out.text);
            let out = engine.generate(&Prompt::Text("plan:".into()), Some(&p.to_lark().unwrap()), &opts(seed)).unwrap();
            assert!(p.parse(&out.text).is_ok(), "{strength}: {:?}", out.text);
            eprintln!("  {strength} plan: {:?}", out.text);
        }
    }
}
