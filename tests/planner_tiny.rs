//! The STEP planner end to end on tiny random-weight models of each architecture: whatever the model
//! writes parses (the planner stops with an error on any output its grammar's checker rejects), the
//! loop always ends, the trace is complete, and a replay with a fresh engine is identical.

use std::path::PathBuf;

use serde_json::Value;
use step::llm::engine::Engine;
use step::llm::tiny::{write_tiny_gguf, TinySpec};
use step::planner::replay::{compare, read_trace};
use step::planner::{plan, ActionChoice, Budgets, PlanRequest, PlannerConfig, PlannerKind, SimEnv, StopCause, Strength, TraceWriter};
use step::world::World;

fn tiny(mut spec: TinySpec, dir: &tempfile::TempDir) -> PathBuf {
    // The planner's prompts (system message with examples, state, node; a goal-setting root's
    // lines and examples) need more than the default: SmolLM2's 8192, in the tiny vocabulary's
    // many short tokens.
    spec.context_length = 8192;
    let path = dir.path().join(format!("tiny-{}-{}.gguf", spec.arch, spec.seed));
    write_tiny_gguf(&spec, &path).unwrap();
    path
}

fn small_budgets() -> Budgets {
    Budgets { max_depth: 2, max_children: 4, max_replans: 2, max_llm_calls: 14, max_actions: 6, deadline: None }
}

#[test]
fn random_weight_models_always_end_with_parsed_outputs_and_replay_identically() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (TinySpec::llama(), PlannerKind::Step, Strength::Feasible),
        (TinySpec::qwen2(), PlannerKind::Step, Strength::Feasible),
        (TinySpec::llama().with_seed(7), PlannerKind::NoTree, Strength::Format),
        (TinySpec::qwen2().with_seed(5), PlannerKind::NoSubgoalTree, Strength::Typed),
        // Actions chosen by likelihood over the feasible set (the trace holds the score calls).
        (TinySpec::llama().with_seed(4), PlannerKind::Step, Strength::Feasible),
        // The main job's settings: the root sets its own goal lines (scored whole).
        (TinySpec::qwen2().with_seed(3), PlannerKind::Step, Strength::Feasible),
    ];
    for (i, (spec, kind, strength)) in cases.into_iter().enumerate() {
        let model = tiny(spec, &dir);
        let choose = if i == 4 { ActionChoice::Score } else { ActionChoice::Generate };
        let infer_goals = i == 5;
        let cfg = PlannerConfig { kind, strength, budgets: small_budgets(), choose, infer_goals, ..PlannerConfig::default() };
        let req = PlanRequest::new("put the apple in the fridge", vec![]);
        let trace_path = dir.path().join(format!("{i}-{kind}-{strength:?}.jsonl"));
        let mut trace = TraceWriter::create(&trace_path).unwrap();
        let mut engine = Engine::load(&model).unwrap();
        let mut env = SimEnv::new(World::demo(), vec![]);
        let out = plan(&mut engine, &mut env, &req, &cfg, &mut trace);
        let label = format!("{} {kind} {strength:?}", model.display());
        assert!(!matches!(out.stop, StopCause::Error(_)), "{label}: {:?}", out.stop);
        assert!(out.stats.llm_calls <= 14, "{label}");
        if choose == ActionChoice::Score {
            assert!(out.stats.calls.iter().any(|c| c.role == "score"), "{label}: no action was scored");
        }
        assert_eq!(out.tree.plan(), out.executed, "{label}");

        // The trace: header first, end last, every call, every node, every executed action.
        let rec = read_trace(&trace_path).unwrap();
        assert!(rec.end.is_some(), "{label}");
        assert_eq!(rec.calls.len(), out.stats.calls.len(), "{label}");
        let text = std::fs::read_to_string(&trace_path).unwrap();
        let events: Vec<Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        let count = |k: &str| events.iter().filter(|e| e["event"] == k).count();
        assert_eq!(count("node"), out.tree.len(), "{label}");
        assert_eq!(count("exec"), out.stats.actions, "{label}");
        assert_eq!(events[0]["event"], "header");
        if infer_goals {
            assert_eq!(count("goal_candidates"), 1, "{label}");
            let first = (out.tree.len() > 1).then(|| out.tree.node(1).text.clone()).unwrap_or_default();
            assert!(first.contains("apple") || first.contains("fridge"),
                "{label}: the root's first child is one of the lines about the apple and the fridge: {:?}", out.tree.to_json());
        }

        // Replay with a fresh engine (nothing cached): the same calls, outputs, actions and stop.
        let mut engine = Engine::load(&model).unwrap();
        let mut env = SimEnv::new(World::demo(), vec![]);
        let again = plan(&mut engine, &mut env, &req, &cfg, &mut TraceWriter::sink());
        let diffs = compare(&rec, &again);
        assert!(diffs.is_empty(), "{label}: {diffs:?}");

        // A run killed half way leaves a trace that replays as far as it goes; a replay that
        // makes fewer calls than a complete trace differs.
        let lines: Vec<&str> = text.lines().collect();
        let cut = dir.path().join(format!("{i}-cut.jsonl"));
        std::fs::write(&cut, lines[..lines.len() / 2].join("\n") + "\n").unwrap();
        let rec_cut = read_trace(&cut).unwrap();
        assert!(rec_cut.end.is_none() && rec_cut.calls.len() <= rec.calls.len(), "{label}");
        let diffs = compare(&rec_cut, &again);
        assert!(diffs.is_empty(), "{label}: a trace cut short: {diffs:?}");
        if !again.stats.calls.is_empty() {
            let mut fewer = again.clone();
            fewer.stats.calls.pop();
            assert!(!compare(&rec, &fewer).is_empty(), "{label}: a missing call went unnoticed");
        }
    }
}
