//! Bad input a new user tries, through the `step` binary: each case gets a clear answer (an error
//! naming the problem and the fix, a warning, or a documented exit code), never a panic. Tiny
//! random-weight models stand in for real ones where inference runs; no benchmark data needed.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use step::llm::tiny::{write_tiny_gguf, TinySpec};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn step() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_step"));
    c.env_remove("RUST_LOG");
    // Prefix snapshots of the runs that load a model go under the build's temporary directory.
    c.env("STEP_PREFIX_CACHE", env!("CARGO_TARGET_TMPDIR"));
    c
}

fn run(args: &[&str]) -> Output {
    step().args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn demo_tasks() -> String {
    repo().join("tests/data/demo_tasks.json").display().to_string()
}

const GOOD_PLAN: &str = "[WALK] <apple> (12)\n[GRAB] <apple> (12)\n[WALK] <fridge> (10)\n[OPEN] <fridge> (10)\n\
[PUTIN] <apple> (12) <fridge> (10)\n[CLOSE] <fridge> (10)\n";

fn write(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p.display().to_string()
}

fn sim(plan: &str, extra: &[&str]) -> Output {
    let tasks = demo_tasks();
    let mut args = vec!["sim", "run", "--tasks-file", &tasks, "--task", "apple_in_fridge", "--plan", plan];
    args.extend_from_slice(extra);
    run(&args)
}

fn tiny_model(dir: &Path) -> String {
    let p = dir.join("tiny.gguf");
    write_tiny_gguf(&TinySpec::llama().with_seed(1), &p).unwrap();
    p.display().to_string()
}

#[test]
fn a_closed_stdout_pipe_ends_the_process_quietly_without_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let plan = write(dir.path(), "plan.txt", GOOD_PLAN.as_bytes());
    for args in [
        vec!["sim", "run", "--tasks-file", &demo_tasks(), "--task", "apple_in_fridge", "--plan", &plan],
        vec!["eval", "gold", "--tasks-file", &demo_tasks(), "--json"],
    ] {
        // The reader is gone before the child starts: its first write meets a pipe nobody reads
        // (deterministic, unlike closing the reader after the spawn on a busy machine).
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let mut child = step().args(&args).stdout(writer).stderr(Stdio::piped()).spawn().unwrap();
        let mut err = String::new();
        child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
        let status = child.wait().unwrap();
        assert!(!err.contains("panicked") && !err.contains("Broken pipe"), "{args:?}: {err}");
        // Ended by SIGPIPE, as `yes | head -1` ends `yes`: no exit code, no message.
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(status.signal(), Some(13), "{args:?}: {status:?} {err}");
    }
}

#[test]
fn sim_run_exit_code_says_whether_the_task_succeeded() {
    let dir = tempfile::tempdir().unwrap();
    let good = write(dir.path(), "good.txt", GOOD_PLAN.as_bytes());
    let o = sim(&good, &[]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let failing = write(dir.path(), "bad.txt", b"[GRAB] <apple> (12)\n");
    let o = sim(&failing, &[]);
    assert_eq!(o.status.code(), Some(3), "a plan that ran but failed: {}", stdout(&o));
    assert!(stdout(&o).contains("success: no"));
    let o = sim(&dir.path().join("missing.txt").display().to_string(), &[]);
    assert_eq!(o.status.code(), Some(1), "an unreadable plan is an error");
    assert!(stderr(&o).contains("missing.txt"), "the error names the path: {}", stderr(&o));
    let help = stdout(&run(&["sim", "run", "--help"]));
    assert!(help.contains("Exit codes") && help.contains("3 the plan was read and run"), "{help}");
}

#[test]
fn sim_run_json_reports_steps_goals_and_success() {
    let dir = tempfile::tempdir().unwrap();
    let plan = write(dir.path(), "plan.txt", GOOD_PLAN.as_bytes());
    let o = sim(&plan, &["--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["success"], true);
    assert_eq!(v["steps"].as_array().unwrap().len(), 6);
    assert_eq!(v["steps"][0]["status"], "ok");
    assert_eq!(v["goals"]["relation"]["met"], 1);
}

#[test]
fn a_byte_order_mark_is_stripped_from_plans_and_task_files() {
    let dir = tempfile::tempdir().unwrap();
    let bom = |s: &str| [b"\xef\xbb\xbf".as_slice(), s.as_bytes()].concat();
    let lines = write(dir.path(), "lines.txt", &bom(GOOD_PLAN));
    let o = sim(&lines, &[]);
    assert_eq!(o.status.code(), Some(0), "lines plan with a BOM: {}{}", stdout(&o), stderr(&o));
    let eai = write(
        dir.path(),
        "eai.json",
        &bom(
            r#"{"WALK": ["apple", 12], "GRAB": ["apple", 12], "WALK": ["fridge", 10], "OPEN": ["fridge", 10], "PUTIN": ["apple", 12, "fridge", 10], "CLOSE": ["fridge", 10]}"#,
        ),
    );
    let o = sim(&eai, &[]);
    assert_eq!(o.status.code(), Some(0), "eai plan with a BOM: {}", stderr(&o));
    // A task file with a BOM, beside the original so its relative scene path still resolves.
    let tasks = std::fs::read_to_string(demo_tasks()).unwrap();
    let copy = repo().join("tests/data").join(format!("bom-{}.json", std::process::id()));
    std::fs::write(&copy, bom(&tasks)).unwrap();
    let o = run(&["eval", "gold", "--tasks-file", &copy.display().to_string()]);
    let _ = std::fs::remove_file(&copy);
    assert!(o.status.success(), "task file with a BOM: {}", stderr(&o));
}

#[test]
fn a_step_like_line_that_does_not_parse_is_an_error_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let plan = write(dir.path(), "plan.txt", b"Step 1: [WALK] <apple> (12)\n[GRAB] <apple> (12)\n");
    let o = sim(&plan, &[]);
    assert_eq!(o.status.code(), Some(1), "{}", stdout(&o));
    let e = stderr(&o);
    assert!(e.contains("line 1") && e.contains("remove 'Step 1:'"), "{e}");
}

#[test]
fn threads_are_capped_to_the_machine_with_a_warning_and_zero_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let o = run(&["generate", "--model", &model, "--raw", "-p", "hi", "--max-tokens", "2", "--threads", "1000"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("warning: --threads 1000 is more than this machine's"), "{}", stderr(&o));
    let o = run(&["generate", "--model", &model, "-p", "hi", "--threads", "0"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--threads") && stderr(&o).contains("at least 1 thread"), "{}", stderr(&o));
}

#[test]
fn threads_is_offered_only_by_commands_that_run_inference() {
    let o = run(&["sim", "run", "--threads", "2", "--task", "x", "--plan", "-"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stdout(&run(&["generate", "--help"])).contains("--threads"));
    assert!(stdout(&run(&["bench", "llm", "--help"])).contains("--threads"));
    assert!(!stdout(&run(&["eval", "gold", "--help"])).contains("--threads"));
}

#[test]
fn sampling_parameters_are_validated() {
    for (args, needle) in [
        (vec!["--seed", "1", "--temperature", "-1"], "temperature"),
        (vec!["--seed", "1", "--temperature", "NaN"], "temperature"),
        (vec!["--seed", "1", "--temperature", "inf"], "temperature"),
        (vec!["--seed", "1", "--top-p", "0"], "top-p"),
        (vec!["--seed", "1", "--top-p", "1.5"], "top-p"),
        (vec!["--temperature", "0.5"], "--seed"),
    ] {
        let mut all = vec!["generate", "-p", "hi", "--model", "/nonexistent.gguf"];
        all.extend_from_slice(&args);
        let o = run(&all);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(needle), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn a_bad_log_filter_is_an_error() {
    let o = run(&["--log", "step=loudest", "sim", "run", "--task", "x", "--plan", "-"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--log"), "{}", stderr(&o));
}

#[test]
fn every_zero_is_rejected_by_each_command_that_takes_it() {
    // `bench nodes` read 0 as 1 and benched every task of the file (all 342 of EAI's).
    for args in [
        &["eval", "plan", "--planner", "random", "--tasks-file", &demo_tasks(), "--every", "0"][..],
        &["bench", "nodes", "--planner", "random", "--tasks-file", &demo_tasks(), "--every", "0"][..],
    ] {
        let o = run(args);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("--every 0: give K >= 1"), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn every_with_chosen_tasks_is_refused() {
    // Both at once ran every K-th of the ids given: with two ids and `--every 2`, one task.
    let tasks = demo_tasks();
    for cmd in [&["eval", "plan"][..], &["bench", "nodes"][..]] {
        let mut args = cmd.to_vec();
        args.extend(["--planner", "random", "--tasks-file", &tasks, "--task", "watch_tv", "--task", "apple_in_fridge", "--every", "2"]);
        let o = run(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("--every") && stderr(&o).contains("--task"), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn bench_llm_rejects_zero_runs() {
    let o = run(&["bench", "llm", "--runs", "0"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--runs"), "{}", stderr(&o));
}

#[test]
fn grammar_limits_are_checked_before_the_model_loads() {
    let dir = tempfile::tempdir().unwrap();
    // The model path does not exist: a grammar error proves the grammar was checked first.
    let wide: Vec<String> = (0..2500).map(|i| format!("\"item{i}\"")).collect();
    let wide = write(dir.path(), "wide.lark", format!("start: {}\n", wide.join(" | ")).as_bytes());
    let o = run(&["generate", "-p", "x", "--model", "/nonexistent.gguf", "--grammar", &wide]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("2500 alternatives") && e.contains("split it into nested rules"), "{e}");
    let endless = write(dir.path(), "endless.lark", b"start: \"a\" start\n");
    let e = stderr(&run(&["generate", "-p", "x", "--model", "/nonexistent.gguf", "--grammar", &endless]));
    assert!(e.contains("never ends") || e.contains("cannot be satisfied"), "{e}");
    assert!(!e.contains("model not found"), "{e}");
}

#[test]
fn generate_reads_the_prompt_from_a_file_or_stdin_and_streams_the_same_text() {
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let prompt = write(dir.path(), "prompt.txt", "\u{feff}open the fridge".as_bytes());
    let by_flag = run(&["generate", "--model", &model, "-p", "open the fridge", "--max-tokens", "12"]);
    assert!(by_flag.status.success(), "{}", stderr(&by_flag));
    let by_file = run(&["generate", "--model", &model, "--prompt-file", &prompt, "--max-tokens", "12"]);
    assert_eq!(stdout(&by_file), stdout(&by_flag), "{}", stderr(&by_file));
    let mut child = step()
        .args(["generate", "--model", &model, "--prompt-file", "-", "--max-tokens", "12"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    child.stdin.take().unwrap().write_all(b"open the fridge").unwrap();
    let o = child.wait_with_output().unwrap();
    assert_eq!(stdout(&o), stdout(&by_flag));
    // The streamed text is the final text: --json's "text" plus the closing newline.
    let j = run(&["generate", "--model", &model, "-p", "open the fridge", "--max-tokens", "12", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&j.stdout).unwrap();
    assert_eq!(format!("{}\n", v["text"].as_str().unwrap()), stdout(&by_flag));
    assert!(v["context_length"].as_u64().unwrap() > 0);
}

#[test]
fn help_documents_the_task_file_schema_context_and_exit_codes() {
    let sim = stdout(&run(&["sim", "run", "--help"]));
    assert!(sim.contains("\"vh_goal\"") && sim.contains("\"scene\""), "{sim}");
    let gen = stdout(&run(&["generate", "--help"]));
    assert!(gen.contains("context") && gen.contains("Exit codes"), "{gen}");
    let top = stdout(&run(&["--help"]));
    assert!(top.contains("Exit codes"), "{top}");
}

#[test]
fn done_at_must_be_a_probability() {
    for bad in ["0", "1.5", "abc"] {
        let o = run(&["plan", "put the apple in the fridge", "--done-at", bad]);
        assert_eq!(o.status.code(), Some(2), "{bad}: {}", stderr(&o));
        assert!(stderr(&o).contains("--done-at") && stderr(&o).contains("0.2"), "{}", stderr(&o));
    }
}

#[test]
fn bench_llm_busy_neighbour_takes_a_count_or_all() {
    for bad in ["0", "two", "65"] {
        let o = run(&["bench", "llm", "--busy-neighbour", bad, "--model", "/nonexistent.gguf"]);
        assert_eq!(o.status.code(), Some(2), "{bad}: {}", stderr(&o));
        assert!(stderr(&o).contains("neighbour count") && stderr(&o).contains("`all`"), "{bad}: {}", stderr(&o));
    }
    // A count, `all`, or no value parse (and the run then stops at the missing model, before any
    // neighbour starts).
    for good in [&["--busy-neighbour", "2"][..], &["--busy-neighbour", "all"], &["--busy-neighbour"]] {
        let o = run(&[&["bench", "llm", "--model", "/nonexistent.gguf"][..], good].concat());
        assert!(stderr(&o).contains("model not found"), "{good:?}: {}", stderr(&o));
    }
}

#[test]
fn an_instruction_naming_an_object_the_scene_lacks_is_warned_about_and_reported() {
    let dir = tempfile::tempdir().unwrap();
    // The planner's prompts are ~4,000 tokens with the tiny tokenizer.
    let model = dir.path().join("tiny8k.gguf");
    write_tiny_gguf(&TinySpec { context_length: 8192, ..TinySpec::llama().with_seed(1) }, &model).unwrap();
    let model = model.display().to_string();
    let plan = |instruction: &str| {
        run(&["plan", instruction, "-m", &model, "--json", "--no-prefix-cache", "--max-llm-calls", "4", "--threads", "1"])
    };
    let o = plan("put the unicorn in the fridge");
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("the instruction names \"unicorn\", and no object of the scene is called that"), "{err}");
    assert!(err.contains("fridge") && err.contains("--scene FILE"), "{err}");
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["unknown_objects"], serde_json::json!(["unicorn"]));
    // The demo's own objects raise nothing, and the tree says what the instruction was read to name.
    let o = plan("put the apple in the fridge");
    assert!(!stderr(&o).contains("no object of the scene"), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("[the instruction names <fridge> (10), <apple> (12); on or in: <kitchencounter> (11)]"),
        "{}",
        stderr(&o)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["unknown_objects"], serde_json::json!([]));
    // One that names no object is read as about what its verbs can be done with (this line was
    // "[the instruction names ]").
    let o = plan("go to sleep");
    assert!(stderr(&o).contains("[the instruction names no object; SLEEP can be done with: <sofa> (30)]"), "{}", stderr(&o));
}

#[test]
fn an_instruction_naming_nothing_the_scene_has_is_an_error_before_the_model_loads() {
    // SmolLM2 looked at the apple for "look at the clock" and found the apple for "make some
    // toast": the warning was printed, and a plan of something else followed.
    for (instruction, missing) in [("look at the clock", "\"clock\""), ("go to the kitchen and make some toast", "\"toast\"")] {
        let o = run(&["plan", instruction, "-m", "/nonexistent.gguf"]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{instruction}: {err}");
        assert!(err.contains("nothing was planned") && err.contains(missing) && err.contains("--scene FILE"), "{instruction}: {err}");
        assert!(!err.contains("model not found"), "{instruction}: {err}");
    }
    // One thing of the scene named is enough to plan (and then the model is looked for).
    let o = run(&["plan", "put the unicorn in the fridge", "-m", "/nonexistent.gguf"]);
    assert!(stderr(&o).contains("model not found") && !stderr(&o).contains("nothing was planned"), "{}", stderr(&o));
}

#[test]
fn an_instruction_naming_no_object_and_no_action_is_an_error_before_the_model_loads() {
    // SmolLM2 closed the door and drank from the mug for words of another language, and looked at
    // every object in turn for "苹果".
    for instruction in ["hello", "relax", "asdf qwer", "苹果", "ßüñ 苹果 🍎"] {
        let o = run(&["plan", instruction, "-m", "/nonexistent.gguf"]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{instruction}: {err}");
        assert!(err.contains("nothing was planned: the instruction names no object of the scene and no action of the robot"), "{instruction}: {err}");
        assert!(err.contains("the scene's objects: apple, book,") && err.contains("sit") && err.contains("switchon"), "{instruction}: {err}");
        assert!(!err.contains("model not found"), "{instruction}: {err}");
    }
    // An action alone ("sit down", as a noun: "have a drink", split round "it": "turn it on"),
    // or a room alone ("go to the kitchen"), is enough to plan.
    for instruction in ["sit down", "go to the kitchen", "have a drink", "turn it on"] {
        let o = run(&["plan", instruction, "-m", "/nonexistent.gguf"]);
        assert!(stderr(&o).contains("model not found") && !stderr(&o).contains("nothing was planned"), "{instruction}: {}", stderr(&o));
    }
}

#[test]
fn a_blank_instruction_is_an_error_before_the_model_loads() {
    for blank in ["", "   "] {
        for args in [&["plan", blank][..], &["bench", "nodes", "--instruction", blank]] {
            let o = run(&[args, &["-m", "/nonexistent.gguf"][..]].concat());
            assert_eq!(o.status.code(), Some(1), "{args:?}: {}", stderr(&o));
            assert!(stderr(&o).contains("the instruction is empty"), "{args:?}: {}", stderr(&o));
        }
    }
}

#[test]
fn an_unwritable_dot_path_is_an_error_before_the_model_loads() {
    // It was found only after the whole run, which then ended without printing its plan.
    let o = run(&["plan", "put the apple in the fridge", "--dot", "/nonexistent-dir/tree.dot", "-m", "/nonexistent.gguf"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("creating DOT file /nonexistent-dir/tree.dot"), "{}", stderr(&o));
    // The check does not empty a DOT file an earlier run wrote: this run fails (no model) before
    // it would write its own.
    let dir = tempfile::tempdir().unwrap();
    let dot = dir.path().join("tree.dot");
    std::fs::write(&dot, "digraph earlier {}\n").unwrap();
    let o = run(&["plan", "put the apple in the fridge", "--dot", dot.to_str().unwrap(), "-m", "/nonexistent.gguf"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&dot).unwrap(), "digraph earlier {}\n");
}

#[test]
fn an_unwritable_export_path_is_an_error_before_the_tasks_run() {
    let tasks = demo_tasks();
    let o = run(&["eval", "plan", "--planner", "random", "--tasks-file", &tasks, "--export-eai", "/nonexistent-dir/p.json"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("creating /nonexistent-dir/p.json"), "{}", stderr(&o));
    assert!(stdout(&o).is_empty(), "no task ran: {}", stdout(&o));
}

#[test]
fn deadline_and_action_timeout_are_seconds_above_zero() {
    // `--deadline nan` once reached Duration::from_secs_f64 and panicked.
    for flag in ["--deadline", "--action-timeout"] {
        for bad in ["nan", "inf", "0", "-1", "soon"] {
            let o = run(&["plan", "put the apple in the fridge", &format!("{flag}={bad}"), "-m", "/nonexistent.gguf"]);
            assert_eq!(o.status.code(), Some(2), "{flag}={bad}: {}", stderr(&o));
            assert!(stderr(&o).contains("not a number of seconds above 0"), "{flag}={bad}: {}", stderr(&o));
        }
    }
}

#[test]
fn bench_llm_says_how_deep_a_cache_the_model_can_hold() {
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let o = run(&["bench", "llm", "-m", &model, "--runs", "1", "--decode-tokens", "4", "--depth", "100000"]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("--depth 100000") && err.contains("give --depth"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}
