//! EAI's VirtualHome gold programs, end to end: every one parses, round-trips through EAI's plan
//! format, executes, and meets its goals, except the exceptions established and explained in
//! /work/notes (README section "Scoring against EAI"). Needs the benchmark data (found as the CLI finds
//! it: $STEP_VH_DATA, else `shared/bench/virtualhome` beside the repo); skipped with a note when it is
//! absent, unless STEP_REQUIRE_DATA=1.

use std::sync::OnceLock;

use step::eval::{score, EaiData, PlanInput, Summary, Task, TaskSource};
use step::program::{PlanFormat, Program};

fn tasks() -> Option<&'static Vec<Task>> {
    static TASKS: OnceLock<Option<Vec<Task>>> = OnceLock::new();
    TASKS
        .get_or_init(|| match EaiData::open(None) {
            Err(e) => {
                if std::env::var("STEP_REQUIRE_DATA").is_ok_and(|v| v == "1") {
                    panic!("STEP_REQUIRE_DATA=1 but the data is missing: {e}");
                }
                // Straight to stderr: libtest captures eprintln!, and the note should be seen.
                use std::io::Write;
                let _ = writeln!(std::io::stderr(), "note: skipping the EAI gold tests: {e}");
                None
            }
            Ok(d) => Some(TaskSource { tasks_file: None, data: Some(d.root) }.load(None).expect("EAI tasks load")),
        })
        .as_ref()
}

fn gold(t: &Task) -> &Program {
    match &t.gold {
        Some(Ok(p)) => p,
        Some(Err(e)) => panic!("{}: gold program does not parse: {e}", t.id),
        None => panic!("{}: no gold program", t.id),
    }
}

#[test]
fn all_342_gold_programs_parse_and_round_trip_through_every_format() {
    let Some(tasks) = tasks() else { return };
    assert_eq!(tasks.len(), 342);
    for t in tasks {
        let p = gold(t);
        assert!(!p.actions.is_empty(), "{}", t.id);
        for f in PlanFormat::ALL {
            let back = Program::parse(&p.write(f), f).unwrap_or_else(|e| panic!("{} in {f}: {e}", t.id));
            assert_eq!(back.actions, p.actions, "{} via {f}", t.id);
        }
    }
}

/// Tasks whose gold program executes but leaves a goal unmet, with the goal (see the README section).
const GOALS_UNMET: &[(&str, &str)] = &[("688_1", "no edge 65 HOLDS_LH 1000")];

/// Tasks whose gold program names objects outside EAI's relevant-object list (EAI's scorer rejects
/// them as hallucinations; here they run, and succeed).
const OUTSIDE_RELEVANT: usize = 19;

#[test]
fn gold_programs_execute_and_meet_their_goals() {
    let Some(tasks) = tasks() else { return };
    let reports: Vec<_> = tasks.iter().map(|t| score(t, &PlanInput::Plan(gold(t).clone()))).collect();
    let s = Summary::of(&reports);
    let not_executed: Vec<String> = reports
        .iter()
        .filter(|r| !r.executed)
        .map(|r| format!("{}: {}", r.id, r.error.as_ref().map_or("?", |e| e.message.as_str())))
        .collect();
    assert!(not_executed.is_empty(), "gold programs that do not execute: {not_executed:#?}");
    let unmet: Vec<(String, String)> =
        reports.iter().filter(|r| !r.success).map(|r| (r.id.clone(), r.unmet_goals.join("; "))).collect();
    let expected: Vec<(String, String)> = GOALS_UNMET.iter().map(|(a, b)| (a.to_string(), b.to_string())).collect();
    assert_eq!(unmet, expected);
    assert_eq!((s.tasks, s.parsed, s.executed, s.succeeded), (342, 342, 342, 341));
    assert_eq!(s.plans_outside_relevant, OUTSIDE_RELEVANT);
    // Every goal category is exercised, and all goals but the one above are met.
    assert_eq!(s.total_goals.total - s.total_goals.met, 1);
    assert!(s.state_goals.total > 0 && s.relation_goals.total > 0 && s.action_goals.total > 0);
}

#[test]
fn relevant_objects_include_the_character_and_every_goal_object_for_eai_tasks() {
    let Some(tasks) = tasks() else { return };
    for t in tasks {
        assert!(t.relevant.contains(&t.world.character()), "{}", t.id);
        for id in t.goal.object_ids() {
            assert!(t.relevant.contains(&id), "{}: goal object {id} not relevant", t.id);
        }
    }
}

#[test]
fn a_task_file_can_use_an_eai_scene_with_its_own_goal() {
    let Some(tasks) = tasks() else { return };
    let Some(eai) = tasks.iter().find(|t| t.id == "27_2") else { panic!("27_2 missing") };
    let lines: Vec<String> = gold(eai).actions.iter().map(|a| a.to_string()).collect();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("tasks.json");
    let task = serde_json::json!([{
        "id": "mine", "scene": "27_2", "title": "Run the washing machine",
        "vh_goal": {"goal": [{"id": 1001, "class_name": "washing_machine", "state": "ON"}], "actions": []},
        "gold": lines,
    }]);
    std::fs::write(&file, task.to_string()).unwrap();
    let data = EaiData::open(None).unwrap().root;
    let mine = TaskSource { tasks_file: Some(file), data: Some(data) }.load(None).unwrap();
    assert_eq!(mine.len(), 1);
    assert_eq!(mine[0].world.len(), eai.world.len(), "the EAI task's initial scene");
    let r = score(&mine[0], &PlanInput::Plan(gold(&mine[0]).clone()));
    assert!(r.success, "{r:?}");
    // Relevant objects by the goal rule: the washing machine, the robot, and their rooms.
    assert!(mine[0].relevant.contains(&1001) && mine[0].relevant.contains(&mine[0].world.character()));
}

/// The held-out task files (`tests/data/heldout`: tasks of EAI's kinds on EAI's scenes, with
/// objects and goals drawn by its `make_tasks.py`, seeds 0 and 1) load with EAI's rule for the
/// relevant objects, and every gold program meets its task's goals.
#[test]
fn the_held_out_tasks_load_and_their_gold_programs_meet_their_goals() {
    if tasks().is_none() {
        return;
    }
    let data = EaiData::open(None).unwrap().root;
    for (file, n) in [("dev.json", 66), ("test.json", 66)] {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/heldout").join(file);
        let tasks = TaskSource { tasks_file: Some(path), data: Some(data.clone()) }.load(None).unwrap();
        assert_eq!(tasks.len(), n, "{file}");
        for t in &tasks {
            let r = score(t, &PlanInput::Plan(gold(t).clone()));
            assert!(r.executed && r.success, "{file} {}: {r:?}", t.id);
            assert_eq!(t.relevance.rule, step::eval::RelevantRule::GoldRun, "{file} {}", t.id);
        }
    }
}
