//! `step plan`: the main job. An instruction (or a task) on a scene, planned by the STEP subgoal tree
//! with the local model, closed-loop on the symbolic world: the tree is printed as it grows (stderr),
//! then the plan and the outcome (stdout; `--json` for machines). `step replay TRACE` re-runs a trace
//! with the same model and settings and says whether every model output is the same.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, bail, Context};
use clap::Args;
use serde_json::{json, Value};

use super::args::InferenceArgs;
use crate::action::Verb;
use crate::eval::task::Task;
use crate::eval::TaskSource;
use crate::llm::engine::{Engine, Warm, WarmSource};
use crate::llm::locate::{resolve_model, DEFAULT_MODEL};
use crate::llm::sample::Sampling;
use crate::planner::bridge::BridgeEnv;
use crate::planner::replay::{compare, read_trace};
use crate::planner::tree::write_dot;
use crate::planner::{
    plan, Budgets, DryRunEnv, Env, PlanOutcome, PlanRequest, PlannerConfig, PlannerKind, SimEnv,
    StopCause, TraceWriter,
};
use crate::world::World;

#[derive(Args, Debug)]
pub struct PlanArgs {
    /// What to do, in words (default with --task: the task's title and description).
    pub instruction: Option<String>,
    /// A scene graph file (VirtualHome JSON); default: the embedded demo kitchen.
    #[arg(long, value_name = "FILE", conflicts_with = "task")]
    pub scene: Option<PathBuf>,
    /// A task file of your own (JSON list of tasks); with --task. Without it, --task names an EAI task.
    #[arg(long, value_name = "FILE", requires = "task")]
    pub tasks_file: Option<PathBuf>,
    /// Plan this task: its scene, its relevant objects as the focus, and its goal check at the end.
    #[arg(long, value_name = "ID")]
    pub task: Option<String>,
    /// The VirtualHome benchmark data directory (for EAI tasks).
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// Extra context for the planner (e.g. the relevant objects and their states).
    #[arg(long)]
    pub context: Option<String>,
    /// Model: an installed name (smollm2, qwen2.5-coder-0.5b), a .gguf path, or owner/repo:file.gguf.
    #[arg(long, short, default_value = DEFAULT_MODEL)]
    pub model: String,
    /// step | no-tree | no-subgoal-tree (the paper's ablations).
    #[arg(long, default_value = "step")]
    pub planner: String,
    /// Grammar strength: format | typed | feasible.
    #[arg(long, default_value = "feasible")]
    pub grammar: String,
    /// Executor: sim (the symbolic world, closed loop) | dry-run (no feedback) | bridge:CMD (a robot
    /// behind the command CMD, run by `sh -c`: one JSON action a line on its stdin, one JSON outcome a
    /// line on its stdout; see the README's "Robot bridge").
    #[arg(long, default_value = "sim")]
    pub env: String,
    /// Seconds a robot bridge has to answer one action; past it the run stops with a timeout error.
    #[arg(long, default_value_t = BridgeEnv::DEFAULT_TIMEOUT.as_secs_f64(), value_parser = positive_seconds)]
    pub action_timeout: f64,
    /// Deepest subgoal level below the instruction.
    #[arg(long, default_value_t = Budgets::default().max_depth)]
    pub max_depth: usize,
    #[arg(long, default_value_t = Budgets::default().max_children)]
    pub max_children: usize,
    /// Rejected or failed steps a subgoal may have before it is given up.
    #[arg(long, default_value_t = Budgets::default().max_replans)]
    pub max_replans: usize,
    #[arg(long, default_value_t = Budgets::default().max_llm_calls)]
    pub max_llm_calls: usize,
    #[arg(long, default_value_t = Budgets::default().max_actions)]
    pub max_actions: usize,
    /// Wall-clock limit in seconds.
    #[arg(long, value_parser = positive_seconds)]
    pub deadline: Option<f64>,
    /// Do not check execute verdicts against the world before executing them.
    #[arg(long)]
    pub no_symbolic_check: bool,
    #[command(flatten)]
    pub rules: super::args::DecisionArgs,
    /// Most tokens per model answer.
    #[arg(long, default_value_t = PlannerConfig::default().gen.max_tokens)]
    pub max_tokens: usize,
    /// Sample with this seed instead of choosing greedily.
    #[arg(long)]
    pub seed: Option<u64>,
    /// DIAGNOSTIC, an oracle: stop as soon as the task's goal holds (with --task). Never a planner figure.
    #[arg(long, requires = "task")]
    pub oracle_stop: bool,
    /// Write the trace (JSON lines, one event a line, flushed as it goes).
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Write the final tree as Graphviz DOT (and SVG beside it when `dot` is installed).
    #[arg(long, value_name = "FILE")]
    pub dot: Option<PathBuf>,
    /// Print the result as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Do not print the tree as it grows.
    #[arg(long, short)]
    pub quiet: bool,
    #[command(flatten)]
    pub inference: InferenceArgs,
}

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// A trace written by `step plan --trace`.
    pub trace: PathBuf,
    /// Use this model instead of the one the trace names.
    #[arg(long)]
    pub model: Option<String>,
    #[command(flatten)]
    pub inference: InferenceArgs,
}

/// Where the world came from, recorded in the trace so replay can rebuild it.
fn scene_meta(args: &PlanArgs) -> Value {
    match (&args.task, &args.scene) {
        (Some(t), _) => json!({"kind": "task", "task": t, "tasks_file": args.tasks_file, "data": args.data}),
        (None, Some(p)) => json!({"kind": "file", "path": p}),
        (None, None) => json!({"kind": "demo"}),
    }
}

/// The world and (for a task) the task, from a scene record.
fn load_scene(scene: &Value) -> anyhow::Result<(World, Option<Task>)> {
    let path_of = |k: &str| scene.get(k).and_then(Value::as_str).map(PathBuf::from);
    match scene.get("kind").and_then(Value::as_str) {
        Some("demo") => Ok((World::demo(), None)),
        Some("file") => {
            let p = path_of("path").ok_or_else(|| anyhow!("scene record without a path"))?;
            Ok((World::load(&p).with_context(|| format!("loading scene {}", p.display()))?, None))
        }
        Some("task") => {
            let id = scene.get("task").and_then(Value::as_str).ok_or_else(|| anyhow!("task record without an id"))?;
            let src = TaskSource { tasks_file: path_of("tasks_file"), data: path_of("data") };
            let task = src.load_for_planning(Some(&[id.to_string()]))?.into_iter().next().ok_or_else(|| anyhow!("no task {id}"))?;
            Ok((task.world.clone(), Some(task)))
        }
        other => bail!("unknown scene record {other:?} in the trace"),
    }
}

fn make_env(name: &str, world: World, focus: Vec<u32>, timeout: Duration) -> anyhow::Result<Box<dyn Env>> {
    match name {
        "sim" => Ok(Box::new(SimEnv::new(world, focus))),
        "dry-run" => Ok(Box::new(DryRunEnv::new(world, focus))),
        other => match BridgeEnv::command_of(other) {
            Some(command) => Ok(Box::new(BridgeEnv::spawn(command, world, focus, timeout)?)),
            None if other.starts_with("bridge:") => {
                bail!("--env bridge: needs the robot's command after the colon, e.g. --env \"bridge:./robot.py\"")
            }
            None => bail!("unknown executor '{other}': choose sim, dry-run or bridge:CMD"),
        },
    }
}

/// A number of seconds above zero.
fn positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x > 0.0 && x.is_finite() => Ok(x),
        _ => Err(format!("'{s}' is not a number of seconds above 0 (e.g. 60)")),
    }
}

/// Size and sha256 of the first 4 MiB: tells model files apart without hashing hundreds of MB.
fn model_fingerprint(path: &Path) -> Value {
    use sha2::{Digest, Sha256};
    let size = std::fs::metadata(path).map(|m| m.len()).ok();
    let mut head = Vec::new();
    let sha = std::fs::File::open(path).ok().and_then(|f| f.take(4 << 20).read_to_end(&mut head).ok()).map(|_| {
        let d = Sha256::digest(&head);
        d.iter().map(|b| format!("{b:02x}")).collect::<String>()
    });
    json!({"path": path, "size": size, "sha256_first_4mib": sha})
}

/// Prints the tree as it grows, from the trace's events.
fn echo_tree() -> Box<dyn FnMut(&str, &Value)> {
    let mut depth_of: Vec<usize> = Vec::new();
    Box::new(move |kind, v| {
        let node = v.get("node").and_then(Value::as_u64).map(|n| n as usize);
        let indent = |n: Option<usize>, depth_of: &Vec<usize>| {
            "  ".repeat(n.and_then(|n| depth_of.get(n).copied()).unwrap_or(0))
        };
        match kind {
            "node" => {
                let d = v.get("depth").and_then(Value::as_u64).unwrap_or(0) as usize;
                if let Some(n) = node {
                    if depth_of.len() <= n {
                        depth_of.resize(n + 1, 0);
                    }
                    depth_of[n] = d;
                }
                let text = v.get("text").and_then(Value::as_str).unwrap_or("");
                eprintln!("{}{} {text}", "  ".repeat(d), if d == 0 { "#" } else { "-" });
            }
            "verdict" => {
                eprintln!("{}    -> {}", indent(node, &depth_of), v["verdict"].as_str().unwrap_or(""));
            }
            // A line of a plural name met for one of its objects, going on to the next.
            "line_next" => {
                eprintln!("{}    [met; next: {}]", indent(node, &depth_of), v["now"].as_str().unwrap_or(""));
            }
            "instruction_objects" => {
                let list = |key: &str| {
                    let all: Vec<&str> = v[key].as_array().into_iter().flatten().filter_map(Value::as_str).collect();
                    let more = all.len().saturating_sub(12);
                    let more = if more > 0 { format!(" and {more} more") } else { String::new() };
                    format!("{}{more}", all[..all.len().min(12)].join(", "))
                };
                let holding = list("holding_them");
                let holding = if holding.is_empty() { String::new() } else { format!("; on or in: {holding}") };
                // (one that names no object is about what its verbs can be done with: "have a
                // drink" printed "the instruction names ;" before that was told)
                match v.get("afforded") {
                    Some(_) => eprintln!("  [the instruction names no object; {} can be done with: {}{holding}]", list("by_verbs"), list("afforded")),
                    None => eprintln!("  [the instruction names {}{holding}]", list("named")),
                }
            }
            "goal_candidates" => {
                if let Some(why) = v["why"].as_str() {
                    eprintln!("  [no goal lines: {why}]");
                }
                // What the words say, one thing a group: a line of each is taken before `done`.
                let holding: Vec<&str> = v["holding"].as_array().into_iter().flatten().filter_map(Value::as_str).collect();
                let marked = |l: &str| if holding.contains(&l) { format!("{l} (holds already)") } else { l.to_string() };
                let said: Vec<String> = v["said"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|g| g.as_array().into_iter().flatten().filter_map(Value::as_str).map(marked).collect::<Vec<_>>().join(" or "))
                    .collect();
                if !said.is_empty() {
                    eprintln!("  [the words say: {}]", said.join("; "));
                }
            }
            "warm" => match (v["error"].as_str(), serde_json::from_value::<Warm>(v.clone())) {
                (Some(e), _) => eprintln!("  [system message not prepared ahead: {e}]"),
                (None, Ok(w)) if w.source != WarmSource::Cached => {
                    eprintln!("  [system message: {} tokens {}]", w.tokens, w.describe())
                }
                _ => {}
            },
            "read" => match v["error"].as_str() {
                Some(e) => eprintln!("  [task not read ahead: {e}]"),
                None => eprintln!("  [task: {} tokens read in {:.0} ms]", v["tokens"], v["ms"].as_f64().unwrap_or(0.0)),
            },
            "symbolic_check" => {
                eprintln!("{}    x symbolic check: {}", indent(node, &depth_of), v["message"].as_str().unwrap_or(""));
            }
            "exec" => {
                let o = &v["outcome"];
                let s = match o["status"].as_str() {
                    Some("failed") => format!("FAILED: {}", o["reason"].as_str().unwrap_or("")),
                    Some("skipped") => "skipped (already so)".to_string(),
                    _ => "ok".to_string(),
                };
                eprintln!("{}    = {} {s}", indent(node, &depth_of), v["action"].as_str().unwrap_or(""));
            }
            "status" => {
                let st = v["status"].as_str().unwrap_or("");
                if matches!(st, "abandoned")
                    || (st == "executed"
                        && matches!(
                            v["why"].as_str(),
                            Some("all its steps are done" | "it already held: nothing to do" | "complete without a step")
                        ))
                {
                    eprintln!("{}    [{st}: {}]", indent(node, &depth_of), v["why"].as_str().unwrap_or(""));
                }
            }
            "call_error" => eprintln!("{}    ! {}", indent(node, &depth_of), v["error"].as_str().unwrap_or("")),
            _ => {}
        }
    })
}

fn config(args: &PlanArgs) -> anyhow::Result<PlannerConfig> {
    let kind: PlannerKind = args.planner.parse().map_err(|e: String| anyhow!(e))?;
    if !matches!(kind, PlannerKind::Step | PlannerKind::NoTree | PlannerKind::NoSubgoalTree) {
        bail!("--planner {kind} is not available in `step plan` in this build: use step, no-tree or no-subgoal-tree");
    }
    let mut cfg = PlannerConfig {
        kind,
        strength: args.grammar.parse().map_err(|e: crate::grammar::UnknownStrength| anyhow!(e))?,
        budgets: Budgets {
            max_depth: args.max_depth,
            max_children: args.max_children,
            max_replans: args.max_replans,
            max_llm_calls: args.max_llm_calls,
            max_actions: args.max_actions,
            deadline: args.deadline.map(Duration::from_secs_f64),
        },
        symbolic_check: !args.no_symbolic_check,
        oracle_stop: args.oracle_stop,
        ..PlannerConfig::default()
    };
    if args.max_depth == 0 {
        bail!("--max-depth must be at least 1 (the instruction's own steps)");
    }
    cfg.gen.max_tokens = args.max_tokens;
    args.rules.apply(&mut cfg);
    // The main job (an instruction, no goals shown) sets its own goal lines unless told not to:
    // without them SmolLM2 put the demo's apple on the fridge, not in it.
    cfg.infer_goals = !args.rules.no_infer_goals;
    if let Some(seed) = args.seed {
        cfg.gen.sampling = Sampling::Sample { temperature: 0.7, top_p: 0.95, seed };
    }
    Ok(cfg)
}

/// The request and the oracle for a scene record.
fn request(
    instruction: Option<&str>,
    context: Option<String>,
    world: &World,
    task: Option<&Task>,
    oracle: bool,
) -> anyhow::Result<PlanRequest> {
    let instruction = match (instruction, task) {
        (Some(i), _) => nonempty(i)?.to_string(),
        (None, Some(t)) => format!("{}. {}", t.title.trim_end_matches('.'), t.description),
        (None, None) => bail!("say what to do: step plan \"put the apple in the fridge\" (or --task ID)"),
    };
    let focus = match task {
        Some(t) if !t.relevant.is_empty() => t.relevant.clone(),
        _ => world.nodes().map(|n| n.id).filter(|&id| id != world.character()).collect(),
    };
    let mut req = PlanRequest::new(instruction, focus);
    req.context = context;
    if oracle {
        let t = task.ok_or_else(|| anyhow!("--oracle-stop needs --task"))?;
        let goal = t.goal.clone();
        req.oracle = Some(Box::new(move |w: &World| goal.check(w, &[]).all_met()));
    }
    Ok(req)
}

/// The instruction, unless it is blank (there would be nothing to plan for).
pub(crate) fn nonempty(instruction: &str) -> anyhow::Result<&str> {
    if instruction.trim().is_empty() {
        bail!("the instruction is empty: say what to do, e.g. step plan \"put the apple in the fridge\"");
    }
    Ok(instruction)
}

/// The engine, with the grammar compiler's free-text slice (subgoals and reasons are free text).
fn load_engine(path: &Path, inference: &InferenceArgs) -> anyhow::Result<Engine> {
    let mut engine = Engine::load_with_slices(path, &[crate::grammar::TEXT_SLICE.to_string()])?;
    engine.set_prefix_dir(inference.prefix_dir());
    Ok(engine)
}

pub fn run(args: &PlanArgs) -> anyhow::Result<()> {
    args.inference.apply();
    let cfg = config(args)?;
    let scene = scene_meta(args);
    let (world, task) = load_scene(&scene)?;
    let req = request(args.instruction.as_deref(), args.context.clone(), &world, task.as_ref(), args.oracle_stop)?;
    let unknown = crate::planner::goals::unknown_objects(&world, &req.instruction);
    let named = named_objects(&world, &req.instruction);
    // An instruction given here whose things are all missing ("look at the clock") is not
    // planned: the model would act on something else (SmolLM2 looked at the apple), and nothing
    // it did would be what was asked. (A task's own text is planned as the benchmark asks.)
    if args.instruction.is_some() && !unknown.is_empty() && names_no_thing(&world, &named) {
        bail!("{}", unknown_note(&unknown, &world, true));
    }
    // One that names no object at all, not even a room, and no action of the robot ("hello",
    // "relax", words of another language) says nothing the robot could do: planned, SmolLM2 closed
    // the door and drank from the mug. It is not planned either.
    if args.instruction.is_some() && unknown.is_empty() && says_nothing_to_do(&named, &req.instruction) {
        bail!(
            "nothing was planned: the instruction names no object of the scene and no action of the robot; say what \
             to do with which object, e.g. step plan \"put the apple in the fridge\" (the scene's objects: {}; the \
             robot's actions: {})",
            object_kinds(&world),
            Verb::listing().to_lowercase()
        );
    }
    if !unknown.is_empty() {
        eprintln!("warning: {}", unknown_note(&unknown, &world, false));
    }
    for missing in crate::planner::goals::missing_tools(&world, &req.focus_in(&world), &req.instruction) {
        eprintln!("warning: {missing}");
    }
    // An unwritable --dot path is found before the model loads, not after it (the tree is written at the end).
    if let Some(p) = &args.dot {
        super::check_writable(p, "DOT file ")?;
    }
    let mut env = make_env(&args.env, world, req.focus.clone(), Duration::from_secs_f64(args.action_timeout))?;
    let path = resolve_model(&args.model)?;
    let mut engine = load_engine(&path, &args.inference)?;
    let mut trace = match &args.trace {
        Some(p) => TraceWriter::create(p).with_context(|| format!("creating trace file {}", p.display()))?,
        None => TraceWriter::sink(),
    };
    trace.set_meta(json!({"model": model_fingerprint(&path), "scene": scene, "env": args.env}));
    if !args.quiet {
        trace.set_echo(echo_tree());
    }
    let out = plan(&mut engine, env.as_mut(), &req, &cfg, &mut trace);
    if let Some(e) = trace.error() {
        eprintln!("warning: the trace could not be written completely: {e}");
    }
    let goals = task.as_ref().and_then(|t| env.world().map(|w| t.goal.check(w, &out.executed)));
    // The plan is printed first: a DOT file that cannot be written loses nothing else.
    report(args.json, &out, goals.as_ref(), &path, &unknown)?;
    if let Some(p) = &args.dot {
        let svg = write_dot(&out.tree.to_dot(), p).with_context(|| format!("writing {}", p.display()))?;
        if let Some(svg) = svg {
            eprintln!("tree: {} and {}", p.display(), svg.display());
        }
    }
    if let StopCause::Error(e) = &out.stop {
        bail!("the planner stopped on an error: {e}");
    }
    Ok(())
}

/// The warning for instruction phrases that name no object of the scene, with what the scene does
/// have, so that the user can reword the instruction or give another scene (`alone`: it names
/// nothing else).
fn unknown_note(unknown: &[String], world: &World, alone: bool) -> String {
    let (lead, nothing_else) = if alone { ("nothing was planned: ", ", and it names no other object of the scene") } else { ("", "") };
    format!(
        "{lead}the instruction names {}, and no object of the scene is called that{nothing_else}; the planner can \
         only use the scene's objects ({}): reword the instruction, or give a scene that has it (--scene FILE)",
        quoted(unknown),
        object_kinds(world)
    )
}

/// The scene's kinds of object (rooms and the robot aside), the first 40 by name and a count of
/// the rest: what an instruction may name.
fn object_kinds(world: &World) -> String {
    let kinds: std::collections::BTreeSet<&str> = world
        .nodes()
        .filter(|n| n.id != world.character() && !n.is_room())
        .map(|n| n.class_name)
        .collect();
    let listed: Vec<&str> = kinds.iter().copied().take(40).collect();
    let more = if kinds.len() > listed.len() { format!(" and {} more", kinds.len() - listed.len()) } else { String::new() };
    format!("{}{more}", listed.join(", "))
}

/// The objects of `world`, rooms included, that `instruction` names.
fn named_objects(world: &World, instruction: &str) -> Vec<u32> {
    let all: Vec<u32> = world.nodes().map(|n| n.id).collect();
    crate::planner::goals::instruction_objects(world, &all, instruction)
}

/// Whether an instruction that names the objects `named` (none: not even a room) names no verb
/// of the robot's either (split round its object too: "turn it on").
fn says_nothing_to_do(named: &[u32], instruction: &str) -> bool {
    named.is_empty() && crate::planner::goals::verbs_named(instruction).is_empty()
}

/// Whether the objects an instruction names, `named`, are rooms only (or none).
fn names_no_thing(world: &World, named: &[u32]) -> bool {
    named.iter().all(|&id| world.node(id).is_some_and(|n| n.is_room()))
}

/// `"a", "b"`: the phrases as the warning and the note quote them.
fn quoted(phrases: &[String]) -> String {
    phrases.iter().map(|p| format!("\"{p}\"")).collect::<Vec<_>>().join(", ")
}

fn report(
    json_out: bool,
    out: &PlanOutcome,
    goals: Option<&crate::eval::goal::GoalCheck>,
    model: &Path,
    unknown: &[String],
) -> anyhow::Result<()> {
    let s = &out.stats;
    let node_ms: Vec<f64> = s.calls.iter().map(|c| c.total_ms).collect();
    if json_out {
        let v = json!({
            "model": model,
            "plan": out.executed.iter().map(|a| a.to_string()).collect::<Vec<_>>(),
            "stop": out.stop,
            "goals_met": goals.map(|g| g.all_met()),
            "unmet_goals": goals.map(|g| g.unmet()),
            "unknown_objects": unknown,
            "stats": {
                "llm_calls": s.llm_calls, "prompt_tokens": s.prompt_tokens, "reused_tokens": s.reused_tokens,
                "reuse_rate": s.reuse_rate(), "output_tokens": s.output_tokens, "forced_tokens": s.forced_tokens,
                "replans": s.replans, "failed_executions": s.failed_executions,
                "symbolic_rejections": s.symbolic_rejections, "abandoned": s.abandoned, "actions": s.actions,
                "wall_ms": s.wall_ms, "call_ms_p50": percentile(&node_ms, 0.5), "call_ms_p99": percentile(&node_ms, 0.99),
                "prefix": s.warm, "task_read": s.read,
            },
            "tree": out.tree.to_json(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!("plan:");
    for a in &out.executed {
        println!("  {a}");
    }
    if out.executed.is_empty() {
        println!("  (nothing executed)");
    }
    println!("stop: {}", out.stop);
    if !unknown.is_empty() {
        println!("note: the instruction names {}, which the scene does not have (see the warning above)", quoted(unknown));
    }
    if let Some(g) = goals {
        if g.all_met() {
            println!("goals: all met");
        } else {
            println!("goals: not met: {}", g.unmet().join("; "));
        }
    }
    println!(
        "model calls: {} ({} prompt tokens, {:.0}% reused; {} output tokens, {} forced), p50 {:.0} ms, p99 {:.0} ms; replans {}, failed actions {}, symbolic rejections {}; {:.1} s",
        s.llm_calls,
        s.prompt_tokens,
        100.0 * s.reuse_rate(),
        s.output_tokens,
        s.forced_tokens,
        percentile(&node_ms, 0.5),
        percentile(&node_ms, 0.99),
        s.replans,
        s.failed_executions,
        s.symbolic_rejections,
        s.wall_ms / 1e3
    );
    Ok(())
}

/// Nearest-rank percentile (0 for no data).
fn percentile(xs: &[f64], q: f64) -> f64 {
    if xs.is_empty() {
        return 0.0;
    }
    let mut v = xs.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    let i = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    v[i]
}

pub fn replay(args: &ReplayArgs) -> anyhow::Result<()> {
    args.inference.apply();
    let recorded = read_trace(&args.trace).map_err(|e| anyhow!(e))?;
    if let Some(n) = recorded.cut_line {
        eprintln!(
            "warning: {}:{n}: the last line is cut off (the run was killed while writing it); replaying the events before it",
            args.trace.display()
        );
    }
    let h = &recorded.header;
    let cfg = PlannerConfig::from_json(&h["settings"]).map_err(|e| anyhow!("{}: {e}", args.trace.display()))?;
    let meta = &h["meta"];
    let (world, task) = load_scene(&meta["scene"])?;
    let r = &h["request"];
    let instruction = r["instruction"].as_str().ok_or_else(|| anyhow!("the trace's header has no instruction"))?;
    let mut req = request(
        Some(instruction),
        r["context"].as_str().map(str::to_string),
        &world,
        task.as_ref(),
        r["oracle"].as_bool() == Some(true),
    )?;
    req.focus = r["focus"]
        .as_array()
        .map(|a| a.iter().filter_map(|x| x.as_u64().map(|n| n as u32)).collect())
        .unwrap_or_default();
    req.subgoals = r["subgoals"]
        .as_array()
        .map(|a| a.iter().filter_map(|x| x.as_str().map(str::to_string)).collect())
        .unwrap_or_default();
    // (traces written before kept goals and named verbs existed have none)
    req.kept = header_list(r, "kept", "kept goals", &args.trace)?;
    req.named_verbs = header_list(r, "named_verbs", "named verbs", &args.trace)?;
    let env_name = h["env"].as_str().unwrap_or("sim");
    if env_name.starts_with("bridge:") {
        bail!(
            "{} ran on a robot bridge ({env_name}): replaying it would move the robot again; replay checks \
             runs on the simulator (sim) or dry-run",
            args.trace.display()
        );
    }
    let mut env = make_env(env_name, world, req.focus.clone(), BridgeEnv::DEFAULT_TIMEOUT)?;
    let model = match &args.model {
        Some(m) => resolve_model(m)?,
        None => PathBuf::from(
            meta["model"]["path"].as_str().ok_or_else(|| anyhow!("the trace names no model; pass --model"))?,
        ),
    };
    let fp = model_fingerprint(&model);
    if args.model.is_none() && fp != meta["model"] {
        eprintln!("warning: the model file changed since the trace was written ({} vs {})", fp, meta["model"]);
    }
    let mut engine = load_engine(&model, &args.inference)?;
    let out = plan(&mut engine, env.as_mut(), &req, &cfg, &mut TraceWriter::sink());
    let diffs = compare(&recorded, &out);
    if diffs.is_empty() && recorded.end.is_none() {
        println!(
            "identical as far as the trace goes: its {} model calls (it has no end event: the run was cut short, \
             e.g. killed); the replay went on to {} calls, {} actions, stop: {}",
            recorded.calls.len(),
            out.stats.llm_calls,
            out.executed.len(),
            out.stop
        );
        Ok(())
    } else if diffs.is_empty() {
        println!("identical: {} model calls, {} actions, stop: {}", out.stats.llm_calls, out.executed.len(), out.stop);
        Ok(())
    } else {
        for d in &diffs {
            println!("{d}");
        }
        bail!("the replay differs from the trace ({} difference(s); the first is above)", diffs.len())
    }
}

/// A list in a trace header's request, empty where the header has none; `what` names it in errors.
fn header_list<T: serde::de::DeserializeOwned>(r: &Value, key: &str, what: &str, trace: &Path) -> anyhow::Result<Vec<T>> {
    match r.get(key) {
        Some(v) => serde_json::from_value(v.clone()).map_err(|e| anyhow!("{}: the header's {what}: {e}", trace.display())),
        None => Ok(Vec::new()),
    }
}
