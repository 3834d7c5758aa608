//! `step eval plan` and its library: planners on the demo task file and on two EAI tasks, scored by the
//! same scorer as the gold programs; the random planner's determinism; the flat planner with a scripted
//! model and with a random-weight tiny model (its output always parses); the EAI export; the
//! relevant-object rule. EAI parts are skipped with a note when the data is absent.

use std::path::PathBuf;
use std::process::Command;

use step::eval::plans::{self, EvalEnv, NoModel, PlanEvalConfig, PlanEvalReport};
use step::eval::protocol::Seen;
use step::eval::{EaiData, RelevantRule, Task, TaskSource};
use step::llm::engine::{GenOptions, Generate, Generation, Prompt, StopReason, Timings};
use step::planner::Strength;
use step::planner::{Budgets, PlannerConfig, PlannerKind};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn demo_tasks() -> Vec<Task> {
    TaskSource { tasks_file: Some(repo().join("tests/data/demo_tasks.json")), data: None }.load(None).unwrap()
}

fn cfg(kind: PlannerKind, strength: Strength, seed: u64, n: usize) -> PlanEvalConfig {
    PlanEvalConfig {
        planner: PlannerConfig {
            kind,
            strength,
            random_seed: seed,
            random_actions: n,
            budgets: Budgets { max_actions: 60, ..Budgets::default() },
            // The flat random walk of N actions; `random_walks_the_goal_lines` tests the tree one.
            goal_subgoals: false,
            ..PlannerConfig::default()
        },
        seen: Seen::Goals,
        env: EvalEnv::Sim,
        trace_dir: None,
    }
}

/// A model that answers every call with the same text.
struct Scripted(String);

impl Generate for Scripted {
    fn generate(&mut self, _: &Prompt, _: Option<&str>, _: &GenOptions) -> step::llm::Result<Generation> {
        Ok(Generation {
            text: self.0.clone(),
            tokens: vec![1; 5],
            prompt_tokens: 100,
            reused_tokens: 0,
            forced_tokens: 0,
            stop: StopReason::GrammarComplete,
            timings: Timings::default(),
        })
    }
}

#[test]
fn relevant_objects_follow_eai_rule_on_gold_programs() {
    let tasks = demo_tasks();
    let apple = tasks.iter().find(|t| t.id == "apple_in_fridge").unwrap();
    assert_eq!(apple.relevance.rule, RelevantRule::GoldRun);
    // The gold's own objects, the character and the counter the apple leaves, and the objects the apple
    // was close to (distractors on the robot's way), which the goal alone would not list.
    for id in [3, 10, 11, 12] {
        assert!(apple.relevant.contains(&id), "{id} missing from {:?}", apple.relevant);
    }
    assert!(apple.relevant.len() > 4, "the diff adds distractors: {:?}", apple.relevant);
    let milk = tasks.iter().find(|t| t.id == "heat_milk").unwrap();
    assert_eq!(milk.relevance.rule, RelevantRule::Goal, "no gold, no final graph: the goal's objects");
}

#[test]
fn an_explicit_relevant_list_wins_and_a_bad_id_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let scene = repo().join("src/world/demo_kitchen.json");
    let write = |relevant: &str| {
        let p = dir.path().join("t.json");
        std::fs::write(
            &p,
            format!(
                r#"[{{"id": "t", "scene": "{}", "title": "T", "vh_goal": {{"goal": [{{"id": 10, "class_name": "fridge", "state": "OPEN"}}]}},
                    "gold": ["[WALK] <fridge> (10)", "[OPEN] <fridge> (10)"], "relevant": {relevant}}}]"#,
                scene.display()
            ),
        )
        .unwrap();
        TaskSource { tasks_file: Some(p), data: None }.load(None)
    };
    let t = write("[10, 3, 1, 10]").unwrap();
    assert_eq!(t[0].relevant, [1, 3, 10]);
    assert_eq!(t[0].relevance.rule, RelevantRule::Explicit);
    let e = write("[10, 999]").unwrap_err().to_string();
    assert!(e.contains("999") && e.contains("relevant"), "{e}");
}

#[test]
fn random_planner_is_deterministic_per_seed_and_scored_by_the_scorer() {
    let tasks = demo_tasks();
    let run = |seed| -> Vec<_> {
        tasks
            .iter()
            .map(|t| plans::run_task(&mut NoModel, t, &cfg(PlannerKind::Random, Strength::Feasible, seed, 20)))
            .collect()
    };
    let a = run(1);
    let b = run(1);
    let c = run(2);
    let plans_of = |r: &[plans::TaskPlanReport]| r.iter().map(|t| t.plan.clone()).collect::<Vec<_>>();
    assert_eq!(plans_of(&a), plans_of(&b));
    assert_ne!(plans_of(&a), plans_of(&c));
    for r in &a {
        assert_eq!(r.actions_sent, 20, "{}: stops after N actions", r.score.id);
        assert_eq!(r.failed_attempts, 0, "feasible + symbolic check: nothing fails");
        assert_eq!(r.grammar_errors, 0);
        assert!(r.replay_agrees, "{}: the scorer's replay reaches the planner's state", r.score.id);
        assert_eq!(r.llm_calls, 0);
    }
    let report = PlanEvalReport::new(&cfg(PlannerKind::Random, Strength::Feasible, 1, 20), "demo".into(), a, 0.0);
    assert!(report.protocol.closed_loop && !report.comparable_with_eai_table);
    let table = report.table();
    assert!(table.contains("closed-loop") && table.contains("grammar errors: 0"), "{table}");
    // Stops are counted by kind, a budget by its name: `done` was cut at the colon inside its
    // explanation ("stops: done (the root is complete=3").
    let stops = table.lines().find(|l| l.starts_with("stops: ")).unwrap();
    assert!(!stops.contains('('), "{stops}");
    assert_eq!(report.stops.values().sum::<usize>(), tasks.len(), "{stops}");
    assert!(report.stops.keys().all(|k| k == "done" || k.starts_with("budget:")), "{stops}");
}

#[test]
fn flat_with_a_scripted_model_writes_executes_and_exports_the_plan() {
    let tasks = demo_tasks();
    let apple = tasks.iter().find(|t| t.id == "apple_in_fridge").unwrap();
    let gold = match &apple.gold {
        Some(Ok(p)) => p.actions.iter().map(|a| a.to_string()).collect::<Vec<_>>().join("\n"),
        _ => unreachable!(),
    };
    let c = cfg(PlannerKind::Flat, Strength::Typed, 0, 0);
    let r = plans::run_task(&mut Scripted(gold.clone()), apple, &c);
    assert!(r.score.success, "{r:?}");
    assert_eq!(r.llm_calls, 1);
    assert_eq!(r.plan.len(), 6);
    assert!(!c.protocol().closed_loop, "flat is open-loop");
    // A plan that fails at step 1 is scored as written (open loop): not executable.
    let bad = "[GRAB] <apple> (12)\n[WALK] <fridge> (10)";
    let r2 = plans::run_task(&mut Scripted(bad.into()), apple, &c);
    assert!(!r2.score.executed && r2.plan.len() == 2, "{r2:?}");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("eai.json");
    plans::export_eai(&[r, r2], &tasks, &out).unwrap();
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let list = v.as_array().unwrap();
    assert_eq!(list.len(), 2);
    assert_eq!(list[0]["identifier"], "apple_in_fridge");
    let back =
        step::program::Program::parse(list[0]["llm_output"].as_str().unwrap(), step::program::PlanFormat::Eai).unwrap();
    assert_eq!(back.actions.iter().map(|a| a.to_string()).collect::<Vec<_>>().join("\n"), gold);
}

#[test]
fn flat_with_a_random_weight_tiny_model_always_parses() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tiny.gguf");
    // The flat prompt (system text, example, context) is a few thousand byte-level tokens.
    let spec = step::llm::tiny::TinySpec { context_length: 8192, ..step::llm::tiny::TinySpec::llama() };
    step::llm::tiny::write_tiny_gguf(&spec, &path).unwrap();
    let mut engine = step::llm::engine::Engine::load(&path).unwrap();
    let tasks = demo_tasks();
    let mut c = cfg(PlannerKind::Flat, Strength::Typed, 0, 0);
    c.planner.budgets.max_actions = 4;
    for t in &tasks {
        let r = plans::run_task(&mut engine, t, &c);
        assert_eq!(r.grammar_errors, 0, "{}: {}", t.id, r.stop);
        assert!(!r.stop.starts_with("error"), "{}: {}", t.id, r.stop);
        assert!(r.llm_calls == 1 && (1..=4).contains(&r.plan.len()), "{r:?}");
    }
}

#[test]
fn two_eai_tasks_under_the_random_planner() {
    let Ok(data) = EaiData::open(None) else {
        eprintln!("note: skipping the EAI part: no data");
        return;
    };
    let ids = vec!["27_2".to_string(), "11_1".to_string()];
    let tasks = TaskSource { tasks_file: None, data: Some(data.root) }.load(Some(&ids)).unwrap();
    assert_eq!(tasks.len(), 2);
    for t in &tasks {
        assert_eq!(t.relevance.rule, RelevantRule::FinalGraph);
        let r = plans::run_task(&mut NoModel, t, &cfg(PlannerKind::Random, Strength::Feasible, 0, 10));
        assert!(r.replay_agrees && r.grammar_errors == 0 && r.actions_sent == 10, "{r:?}");
        assert!(r.score.outside_relevant.is_empty(), "the grammar names relevant objects only");
    }
}

#[test]
fn the_cli_runs_the_random_planner_on_the_demo_file_as_json() {
    let dir = tempfile::tempdir().unwrap();
    let export = dir.path().join("x.json");
    let traces = dir.path().join("traces");
    let out = Command::new(env!("CARGO_BIN_EXE_step"))
        .args(["eval", "plan", "--planner", "random", "--random-actions", "12", "--json", "--tasks-file"])
        .arg(repo().join("tests/data/demo_tasks.json"))
        .arg("--export-eai")
        .arg(&export)
        .arg("--trace-dir")
        .arg(&traces)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["planner"], "random");
    assert_eq!(v["summary"]["tasks"], 3);
    assert_eq!(v["grammar_errors"], 0);
    assert!(v["protocol_text"].as_str().unwrap().contains("goals in words"));
    // A task file's plans leave out what EAI's scorer cannot score too (their export is for it);
    // `--all-verbs` offers them (`on_eai_tasks_the_cli_leaves_out_the_actions_eai_cannot_score`).
    assert_eq!(v["excluded_verbs"], serde_json::json!(["SLEEP", "WAKEUP", "LOOKAT_SHORT", "LOOKAT_LONG", "RELEASE"]));
    assert!(export.is_file());
    assert!(traces.join("apple_in_fridge.jsonl").is_file());
    // `step sim run` takes each task's plan out of the export and judges it as the report did.
    for t in v["tasks"].as_array().unwrap() {
        let id = t["id"].as_str().unwrap();
        let sim = Command::new(env!("CARGO_BIN_EXE_step"))
            .args(["sim", "run", "--json", "--task", id, "--tasks-file"])
            .arg(repo().join("tests/data/demo_tasks.json"))
            .arg("--plan")
            .arg(&export)
            .output()
            .unwrap();
        let s: serde_json::Value = serde_json::from_slice(&sim.stdout)
            .unwrap_or_else(|e| panic!("{id}: {e}: {}", String::from_utf8_lossy(&sim.stderr)));
        assert_eq!(s["success"], t["success"], "{id}");
        assert_eq!(s["steps"].as_array().unwrap().len(), t["plan"].as_array().unwrap().len(), "{id}");
    }
    let other = Command::new(env!("CARGO_BIN_EXE_step"))
        .args(["sim", "run", "--task", "held_0_0", "--tasks-file"])
        .arg(repo().join("tests/data/heldout/dev.json"))
        .arg("--plan")
        .arg(&export)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(!other.status.success() && err.contains("none for task 'held_0_0' (it has: apple_in_fridge, heat_milk, watch_tv)"), "{err}");
    let bad = Command::new(env!("CARGO_BIN_EXE_step"))
        .args(["eval", "plan", "--planner", "random", "--protocol", "everything", "--tasks-file"])
        .arg(repo().join("tests/data/demo_tasks.json"))
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("instruction, objects or goals"));
}

#[test]
fn eai_rule_by_gold_run_matches_eai_stored_lists_on_eai_tasks() {
    // Sanity check of the rule a user's task gets: on EAI's own tasks (every 10th), running the gold
    // program and diffing gives about the same lists as EAI's stored final graphs.
    let Ok(data) = EaiData::open(None) else {
        eprintln!("note: skipping the EAI part: no data");
        return;
    };
    let all = TaskSource { tasks_file: None, data: Some(data.root) }.load(None).unwrap();
    let tasks = plans::every(all, 10);
    let (mut stored, mut ours, mut same, mut n) = (0usize, 0usize, 0usize, 0usize);
    for t in &tasks {
        let Some(Ok(gold)) = &t.gold else { continue };
        let (ids, rel) = step::eval::relevant_by_gold_run(&t.world, gold);
        assert_eq!(rel.rule, RelevantRule::GoldRun);
        stored += t.relevant.len();
        ours += ids.len();
        same += (ids == t.relevant) as usize;
        n += 1;
    }
    let (ms, mo) = (stored as f64 / n as f64, ours as f64 / n as f64);
    eprintln!("{n} EAI tasks: stored lists {ms:.2} objects, gold-run rule {mo:.2}; identical for {same}");
    assert!((mo - ms).abs() / ms < 0.15, "stored {ms:.2} vs gold run {mo:.2}");
    assert!(same * 2 > n, "identical lists for only {same} of {n}");
}

#[test]
fn on_eai_tasks_the_cli_leaves_out_the_actions_eai_cannot_score() {
    if EaiData::open(None).is_err() {
        eprintln!("note: skipping: no EAI data");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let run = |extra: &[&str]| {
        let export = dir.path().join(format!("x{}.json", extra.len()));
        let out = Command::new(env!("CARGO_BIN_EXE_step"))
            .args(["eval", "plan", "--planner", "random", "--random-actions", "40", "--json", "--task", "3_1"])
            .args(["--task", "628_1", "--task", "11_1", "--export-eai"])
            .arg(&export)
            .args(extra)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        // The plans' own text (each entry's llm_output), not the escaped JSON around it.
        let entries: Vec<serde_json::Value> = serde_json::from_str(&std::fs::read_to_string(&export).unwrap()).unwrap();
        assert_eq!(entries.len(), 3);
        let plans: String = entries.iter().map(|e| e["llm_output"].as_str().unwrap().to_string()).collect();
        (v, plans)
    };
    let unscoreable = ["SLEEP", "WAKEUP", "LOOKAT_SHORT", "LOOKAT_LONG", "RELEASE"];
    let (v, exported) = run(&[]);
    assert_eq!(v["excluded_verbs"], serde_json::json!(unscoreable));
    for verb in unscoreable {
        assert!(!exported.contains(&format!("\"{verb}\"")), "{verb} exported:\n{exported}");
    }
    // --all-verbs offers them: 120 uniform draws over these small scenes name at least one.
    // (idle steps offered too: the LOOKAT_* verbs change nothing)
    let (v, exported) = run(&["--all-verbs", "--offer-idle-steps"]);
    assert_eq!(v["excluded_verbs"], serde_json::json!([]));
    assert!(unscoreable.iter().any(|verb| exported.contains(&format!("\"{verb}\""))), "{exported}");
}

#[test]
fn random_walks_the_goal_lines() {
    let tasks = demo_tasks();
    let mut c = cfg(PlannerKind::Random, Strength::Feasible, 1, 20);
    c.planner.goal_subgoals = true;
    c.planner.random_steps = 3;
    for targets in [false, true] {
        c.planner.target_subgoals = targets;
        for t in &tasks {
            let lines = step::eval::protocol::subgoals(t, Seen::Goals);
            let a = plans::run_task(&mut NoModel, t, &c);
            let b = plans::run_task(&mut NoModel, t, &c);
            assert_eq!(a.plan, b.plan, "{}: deterministic per seed", t.id);
            // Each draw is one action without targets; a drawn target runs its way to its action.
            if !targets {
                assert!(a.actions_sent <= 3 * lines.len(), "{}: at most random_steps per line: {}", t.id, a.actions_sent);
            }
            assert!(a.actions_sent > 0 && a.replay_agrees && a.grammar_errors == 0 && a.llm_calls == 0, "{a:?}");
        }
    }
}
