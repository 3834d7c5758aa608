//! The robot bridge through `step plan --env "bridge:CMD"`: scripted child processes stand in for a
//! robot that answers (with fields of its own), crashes, speaks garbage or stays silent. Each bad robot is a clear error that
//! names what was sent and what came back, and the trace keeps every event up to it. A tiny
//! random-weight model does the planning (the bridge's wiring is under test, not the plan).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use step::llm::tiny::{write_tiny_gguf, TinySpec};

fn step() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_step"));
    c.env_remove("RUST_LOG").env_remove("RUST_BACKTRACE");
    c.env("STEP_PREFIX_CACHE", env!("CARGO_TARGET_TMPDIR"));
    c
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A tiny model whose context holds the planner's prompts (~4,000 tokens with its tokenizer).
fn tiny_model(dir: &Path) -> PathBuf {
    let p = dir.join("tiny8k.gguf");
    write_tiny_gguf(&TinySpec { context_length: 8192, ..TinySpec::llama().with_seed(1) }, &p).unwrap();
    p
}

/// `step plan` on the demo kitchen with the robot `robot` (a shell command), its trace written to
/// `trace`; the output and the trace's events.
fn plan_with(trace: &Path, model: &Path, robot: &str, extra: &[&str]) -> (Output, Vec<serde_json::Value>) {
    let env = format!("bridge:{robot}");
    let o = step()
        .args(["plan", "put the apple in the fridge", "--no-infer-goals", "--json", "--no-prefix-cache"])
        .args(["--max-llm-calls", "8", "--threads", "1", "-m"])
        .arg(model)
        .args(["--env", &env, "--trace"])
        .arg(trace)
        .args(extra)
        .output()
        .unwrap();
    let events = std::fs::read_to_string(trace)
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("trace line {l:?}: {e}")))
        .collect();
    (o, events)
}

fn kinds<'a>(events: &'a [serde_json::Value], kind: &str) -> Vec<&'a serde_json::Value> {
    events.iter().filter(|e| e["event"] == kind).collect()
}

#[test]
fn a_robot_that_answers_ok_executes_the_plan_and_sees_each_action_as_json() {
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    // The robot logs what it was sent, then answers ok with a field of its own (a timing).
    let log = dir.path().join("robot.log");
    let robot = format!(
        "while read l; do echo \"$l\" >> {}; echo '{{\"status\": \"ok\", \"duration_ms\": 3}}'; done",
        log.display()
    );
    let (o, events) = plan_with(&dir.path().join("ok.jsonl"), &model, &robot, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    // The robot's own field is named once, not an error.
    assert_eq!(stderr(&o).matches("\"duration_ms\"; it is ignored").count(), 1, "{}", stderr(&o));
    let execs = kinds(&events, "exec");
    assert!(!execs.is_empty(), "no action executed: {events:?}");
    let sent: Vec<serde_json::Value> =
        std::fs::read_to_string(&log).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(sent.len(), execs.len());
    for (s, e) in sent.iter().zip(&execs) {
        assert_eq!(s["line"], e["action"], "{s}");
        assert!(s["action"].is_string() && s["args"].is_array(), "{s}");
    }
}

#[test]
fn a_crashing_silent_or_garbage_speaking_robot_is_a_clear_error_and_the_trace_keeps_what_came_before() {
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let cases: [(&str, &str, &[&str], &[&str]); 4] = [
        ("crash", "read l; echo 'motor fault' >&2; exit 3", &[], &["closed its stdout", "motor fault"]),
        // (gone before the first action: writing it hits a closed pipe, which must not end `step`)
        ("gone", "echo 'no robot here' >&2; exit 3", &[], &["no robot here"]),
        ("garbage", "while read l; do echo hello; done", &[], &["hello"]),
        ("silent", "read l; sleep 30", &["--action-timeout", "0.3"], &["300 ms"]),
    ];
    for (name, robot, extra, says) in cases {
        let (o, events) = plan_with(&dir.path().join(format!("{name}.jsonl")), &model, robot, extra);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{robot}: {err}");
        for s in says {
            assert!(err.contains(s), "{robot}: {s:?} not in {err}");
        }
        assert!(err.contains("\"line\""), "the error shows what was sent: {err}");
        assert!(!err.contains("panicked"), "{err}");
        // The trace was written up to the failure: its header, the model's calls, the failed action.
        assert_eq!(events.first().map(|e| e["event"].clone()), Some("header".into()), "{robot}");
        assert!(!kinds(&events, "call").is_empty(), "{robot}: {events:?}");
        assert_eq!(kinds(&events, "exec_error").len(), 1, "{robot}: {events:?}");
    }
}

#[test]
fn a_bridge_needs_a_command_and_its_trace_is_not_replayed() {
    let dir = tempfile::tempdir().unwrap();
    let o = step().args(["plan", "put the apple in the fridge", "--env", "bridge:", "-m", "/nonexistent.gguf"]).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("needs the robot's command"), "{}", stderr(&o));
    let o = step().args(["plan", "put the apple in the fridge", "--env", "robot"]).output().unwrap();
    assert!(stderr(&o).contains("choose sim, dry-run or bridge:CMD"), "{}", stderr(&o));
    let o = step().args(["plan", "x", "--action-timeout", "0"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    // A replay would move the robot again.
    let model = tiny_model(dir.path());
    let trace = dir.path().join("ok.jsonl");
    let (o, _) = plan_with(&trace, &model, "while read l; do echo '{\"status\": \"ok\"}'; done", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = step().arg("replay").arg(&trace).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("robot bridge") && stderr(&o).contains("move the robot again"), "{}", stderr(&o));
}
