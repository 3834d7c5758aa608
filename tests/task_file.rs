//! Users' own task files (the demo kitchen example under tests/data, and each kind of bad file), and
//! the `step sim run` / `step eval gold` commands on them. No benchmark data needed.

use std::path::{Path, PathBuf};
use std::process::Command;

use step::eval::{score, PlanInput, Summary, TaskSource};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn example() -> PathBuf {
    repo().join("tests/data/demo_tasks.json")
}

fn load(path: &Path) -> Result<Vec<step::eval::Task>, step::eval::EvalError> {
    TaskSource { tasks_file: Some(path.to_path_buf()), data: None }.load(None)
}

#[test]
fn the_example_task_file_loads_and_its_gold_plans_succeed() {
    let tasks = load(&example()).unwrap();
    let ids: Vec<&str> = tasks.iter().map(|t| t.id.as_str()).collect();
    assert_eq!(ids, ["apple_in_fridge", "heat_milk", "watch_tv"]);
    let reports: Vec<_> = tasks
        .iter()
        .map(|t| {
            let plan = match &t.gold {
                Some(Ok(p)) => PlanInput::Plan(p.clone()),
                _ => PlanInput::Missing,
            };
            score(t, &plan)
        })
        .collect();
    for r in &reports {
        if r.id != "heat_milk" {
            assert!(r.success, "{r:?}");
        }
    }
    let s = Summary::of(&reports);
    assert_eq!((s.tasks, s.executed, s.succeeded), (3, 2, 2));
    assert_eq!(s.errors.get("no_plan"), Some(&1));
    // With a gold program, EAI's rule: the objects whose node or edges change when the gold program
    // runs (the robot, the fridge, the counter the apple leaves, the things it was close to), plus the
    // gold program's own objects.
    let apple = &tasks[0];
    assert_eq!(apple.relevant, [3, 10, 11, 12, 13, 14, 24, 26]);
    assert_eq!(apple.relevance.rule, step::eval::RelevantRule::GoldRun);
}

/// Writes a one-task file around `task` (JSON object text) and returns the load error.
fn error_of(task: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tasks.json");
    std::fs::write(&path, format!("[{task}]")).unwrap();
    load(&path).err().map(|e| e.to_string()).unwrap_or_else(|| panic!("no error for {task}"))
}

fn task(scene: &str, goal: &str, gold: &str) -> String {
    format!(r#"{{"id": "t1", "scene": "{scene}", "title": "T", "vh_goal": {{"goal": [{goal}], "actions": []}}{gold}}}"#)
}

fn kitchen() -> String {
    repo().join("src/world/demo_kitchen.json").display().to_string()
}

#[test]
fn an_unknown_object_id_in_a_goal_names_the_task_and_the_id() {
    let e = error_of(&task(&kitchen(), r#"{"id": 999, "class_name": "apple", "state": "ON"}"#, ""));
    assert!(e.contains("task 't1'") && e.contains("object id 999"), "{e}");
    let e = error_of(&task(&kitchen(), r#"{"from_id": 12, "relation_type": "INSIDE", "to_id": 998}"#, ""));
    assert!(e.contains("task 't1'") && e.contains("object id 998"), "{e}");
    let e = error_of(&task(&kitchen(), r#"{"id": 12, "class_name": "banana", "state": "ON"}"#, ""));
    assert!(e.contains("<banana> (12)") && e.contains("is <apple>"), "{e}");
}

#[test]
fn bad_goals_and_gold_plans_are_named() {
    let e = error_of(&task(&kitchen(), r#"{"id": 12, "class_name": "apple", "state": "SHINY"}"#, ""));
    assert!(e.contains("task 't1': vh_goal: goal 1: unknown state 'SHINY'"), "{e}");
    let e = error_of(&task(&kitchen(), "", r#", "gold": ["[WALK] <apple> (12)", "[GRAB] <apple>"]"#));
    assert!(e.contains("task 't1': gold: lines plan, line 2"), "{e}");
    let e = error_of(&task(&kitchen(), "", r#", "gold": ["[PUTIN] <apple> (12)"]"#));
    assert!(e.contains("PUTIN takes 2 object(s), got 1"), "{e}");
    let e = error_of(&task(&kitchen(), "", r#", "gold": ["[WALK] <apple> (12)", "[GRAB] <pear> (777)"]"#));
    assert!(e.contains("step 2") && e.contains("object id 777"), "{e}");
}

#[test]
fn a_gold_program_that_cannot_run_is_refused_for_planning_and_reported_by_eval_gold() {
    // It made the object list of the steps before the failing one (the apple alone here, not the
    // fridge of the goal), silently: `step eval plan` then planned the task without the fridge.
    let goal = r#"{"from_id": 12, "relation_type": "INSIDE", "to_id": 10}"#;
    let gold = r#", "gold": ["[GRAB] <apple> (12)", "[WALK] <fridge> (10)"]"#;
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, task: String| {
        let path = dir.path().join(name);
        std::fs::write(&path, format!("[{task}]")).unwrap();
        path
    };
    let broken = write("broken.json", task(&kitchen(), goal, gold));
    let source = |path: &Path| TaskSource { tasks_file: Some(path.to_path_buf()), data: None };
    let e = source(&broken).load_for_planning(None).unwrap_err().to_string();
    assert!(e.contains("task 't1': gold: the gold program fails at step 1 ([GRAB] <apple> (12))"), "{e}");
    assert!(e.contains("WALK to <apple> (12) first") && e.contains("\"relevant\""), "{e}");
    let (ok, _, err) = step_cmd(&["eval", "plan", "--planner", "random", "--tasks-file", &broken.display().to_string()]);
    assert!(!ok && err.contains("fails at step 1"), "{err}");
    // Scoring the gold programs loads the task and reports the failing step, as before.
    assert!(load(&broken).is_ok());
    let (_, out, err) = step_cmd(&["eval", "gold", "--tasks-file", &broken.display().to_string()]);
    assert!(out.contains("missing_step at step 1"), "{out}{err}");
    // With the objects listed, the list is used as given, and the program is not run for one.
    let listed = write("listed.json", task(&kitchen(), goal, &format!(r#"{gold}, "relevant": [12, 10]"#)));
    let tasks = source(&listed).load_for_planning(None).unwrap();
    assert_eq!(tasks[0].relevant, [10, 12]);
}

#[test]
fn a_task_without_goals_is_refused_since_any_plan_would_meet_it() {
    // It once counted as met, so `eval plan` reported 100% task success for any plan.
    let e = error_of(&task(&kitchen(), "", ""));
    assert!(e.contains("task 't1'") && e.contains("no goal conditions and no actions"), "{e}");
    let with_action = r#"{"id": "t1", "scene": "SCENE", "title": "T", "vh_goal": {"goal": [], "actions": ["GRAB"]}}"#;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tasks.json");
    std::fs::write(&path, format!("[{}]", with_action.replace("SCENE", &kitchen()))).unwrap();
    assert!(load(&path).is_ok(), "an action goal alone is a goal");
}

#[test]
fn a_task_no_plan_could_meet_or_plan_from_is_refused() {
    // Each once loaded: the goal below was failed by every plan, the empty list let the planner
    // name any object while the report said "0.0 objects each", the blank title planned from ".".
    let fridge = |state: &str| format!(r#"{{"id": 10, "class_name": "fridge", "state": "{state}"}}"#);
    let e = error_of(&task(&kitchen(), &format!("{}, {}", fridge("OPEN"), fridge("CLOSED")), ""));
    assert!(e.contains("task 't1'") && e.contains("<fridge> (10) to be both OPEN and CLOSED"), "{e}");
    let e = error_of(&task(&kitchen(), &fridge("OPEN"), r#", "relevant": []"#));
    assert!(e.contains("task 't1'") && e.contains("relevant is an empty list"), "{e}");
    let e = error_of(&task(&kitchen(), &fridge("OPEN"), "").replace(r#""title": "T""#, r#""title": " ""#));
    assert!(e.contains("task 't1'") && e.contains("title is empty"), "{e}");
    // A scene no plan could stand on is refused with the node and the fix.
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene.json");
    let mut graph: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(kitchen()).unwrap()).unwrap();
    let fridge_node = graph["nodes"].as_array_mut().unwrap().iter_mut().find(|n| n["id"] == 10).unwrap();
    fridge_node["states"].as_array_mut().unwrap().push("OPEN".into());
    std::fs::write(&scene, graph.to_string()).unwrap();
    let e = error_of(&task(&scene.display().to_string(), &fridge("OPEN"), ""));
    assert!(e.contains("states OPEN and CLOSED both given"), "{e}");
}

#[test]
fn bad_files_and_scenes_say_what_is_wrong() {
    let e = error_of(&task("no_such_scene.json", "", ""));
    assert!(e.contains("neither a graph file") && e.contains("no_such_scene.json"), "{e}");
    let e = error_of(r#"{"id": "t1", "scene": "x", "title": "T", "vh_goals": {}}"#);
    assert!(e.contains("unknown field `vh_goals`"), "{e}");
    let e = error_of(r#"{"id": "t1", "scene": "x" "title": "T"}"#);
    assert!(e.contains("tasks.json:1:"), "{e}");
    let dup = task(&kitchen(), "", "");
    let e = error_of(&format!("{dup}, {dup}"));
    assert!(e.contains("task 't1'") && e.contains("more than one task"), "{e}");
    let dir = tempfile::tempdir().unwrap();
    let bad_scene = dir.path().join("scene.json");
    std::fs::write(&bad_scene, r#"{"nodes": [{"id": 1, "class_name": "kitchen"}], "edges": []}"#).unwrap();
    let e = error_of(&task(&bad_scene.display().to_string(), "", ""));
    assert!(e.contains("character"), "a scene without the robot is refused: {e}");
}

fn step_cmd(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_step"))
        .args(args)
        .env("STEP_PREFIX_CACHE", env!("CARGO_TARGET_TMPDIR"))
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn sim_run_prints_each_step_and_the_goal_check() {
    let dir = tempfile::tempdir().unwrap();
    let plan = dir.path().join("plan.json");
    // EAI's format, as an LLM would write it.
    std::fs::write(
        &plan,
        r#"{"WALK": ["apple", 12], "GRAB": ["apple", 12], "WALK": ["fridge", 10], "OPEN": ["fridge", 10],
            "PUTIN": ["apple", 12, "fridge", 10], "CLOSE": ["fridge", 10]}"#,
    )
    .unwrap();
    let ex = example().display().to_string();
    let p = plan.display().to_string();
    let (ok, out, err) = step_cmd(&["sim", "run", "--tasks-file", &ex, "--task", "apple_in_fridge", "--plan", &p]);
    assert!(ok, "{err}");
    assert!(out.contains("[PUTIN] <apple> (12) <fridge> (10)") && out.contains("success: yes"), "{out}");

    std::fs::write(&plan, "[GRAB] <apple> (12)\n[WALK] <fridge> (10)\n").unwrap();
    let (ok, out, _) =
        step_cmd(&["sim", "run", "--tasks-file", &ex, "--task", "apple_in_fridge", "--plan", &p, "--format", "lines"]);
    assert!(!ok, "a plan that ran but failed exits non-zero (3)");
    assert!(out.contains("FAILED missing_step") && out.contains("1 later step(s) not run"), "{out}");
    assert!(out.contains("unmet: no edge 12 INSIDE 10") && out.contains("success: no"), "{out}");

    std::fs::write(&plan, "[GRAB] <apple> (12)\n[FLY] <fridge> (10)\n").unwrap();
    let (ok, _, err) = step_cmd(&["sim", "run", "--tasks-file", &ex, "--task", "apple_in_fridge", "--plan", &p]);
    assert!(!ok && err.contains("line 2, column 2: unknown action 'FLY'"), "{err}");

    std::fs::write(&plan, "[WALK] <fridge> (10)\n").unwrap();
    let (ok, _, err) = step_cmd(&["sim", "run", "--tasks-file", &ex, "--task", "nope", "--plan", &p]);
    assert!(!ok && err.contains("no task 'nope'"), "{err}");
}

#[test]
fn eval_gold_reports_counts_as_json_and_missing_data_is_a_clear_error() {
    let ex = example().display().to_string();
    let (ok, out, err) = step_cmd(&["eval", "gold", "--tasks-file", &ex, "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["summary"]["tasks"], 3);
    assert_eq!(v["summary"]["succeeded"], 2);
    assert_eq!(v["summary"]["errors"]["no_plan"], 1);
    assert_eq!(v["tasks"].as_array().map(|a| a.len()), Some(3));

    let (ok, out, _) = step_cmd(&["eval", "gold", "--tasks-file", &ex]);
    assert!(ok && out.contains("task success") && out.contains("2/3") && out.contains("time:"), "{out}");

    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().display().to_string();
    let (ok, _, err) = step_cmd(&["eval", "gold", "--data", &d]);
    assert!(!ok && err.contains(&d) && err.contains("--data") && err.contains("STEP_VH_DATA"), "{err}");
}
