//! `step bench nodes`: the cost of one tree node. Runs a planner over tasks and reports, per LLM role
//! (decomposition, termination, flat), latency p50/p99, tokens in (new and reused) and out, and the
//! share of prefill, decode and mask time; per tree node, the p50/p99 of all its calls together;
//! and, apart, reading each task into the cache before its first node.
//! A table on stderr, JSON on stdout.

use std::collections::BTreeMap;
use std::time::Instant;

use clap::Args;
use serde::Serialize;

use super::args::TaskArgs;
use crate::eval::plans::{self, EvalEnv, PlanEvalConfig};
use crate::eval::protocol::Seen;
use crate::planner::Strength;
use crate::llm::engine::{Engine, Warm};
use crate::llm::locate::{resolve_model, DEFAULT_MODEL};
use crate::planner::{CallRecord, PlannerConfig, PlannerKind, SimEnv, TraceWriter};

#[derive(Args, Debug)]
pub struct NodesArgs {
    /// Model: an installed name, a .gguf path, or owner/repo:file.gguf from the local HF cache.
    #[arg(long, short, default_value = DEFAULT_MODEL)]
    pub model: String,
    /// The planner whose calls are measured (random makes none).
    #[arg(long, default_value = "step")]
    pub planner: PlannerKind,
    #[arg(long, default_value = "feasible")]
    pub grammar: Strength,
    #[arg(long, default_value = "goals")]
    pub protocol: Seen,
    #[command(flatten)]
    pub tasks: TaskArgs,
    #[command(flatten)]
    pub inference: super::args::InferenceArgs,
    /// Only these task ids (repeatable); default: every 30th EAI task, or the whole task file.
    #[arg(long = "task", value_name = "ID")]
    pub only: Vec<String>,
    /// Every K-th task (default 30 for EAI's set, 1 for a task file); not with `--task`.
    #[arg(long, value_name = "K", conflicts_with = "only")]
    pub every: Option<usize>,
    /// Most actions per task (keeps the bench short).
    #[arg(long, default_value_t = 20)]
    pub max_actions: usize,
    /// A free-form instruction on the demo kitchen instead of tasks, planned as `step plan` plans
    /// it (the root setting its own goal lines).
    #[arg(long)]
    pub instruction: Option<String>,
}

/// Figures of a group of calls (or of nodes).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Group {
    pub count: usize,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub mean_ms: f64,
    pub tokens_in_new: f64,
    pub tokens_in_reused: f64,
    pub tokens_out: f64,
    pub prefill_share: f64,
    pub decode_share: f64,
    pub mask_share: f64,
}

fn group(calls: &[&CallRecord]) -> Group {
    let n = calls.len();
    if n == 0 {
        return Group::default();
    }
    let mut ms: Vec<f64> = calls.iter().map(|c| c.total_ms).collect();
    ms.sort_by(f64::total_cmp);
    let total: f64 = ms.iter().sum();
    let sum = |f: &dyn Fn(&CallRecord) -> f64| calls.iter().map(|c| f(c)).sum::<f64>();
    let share = |x: f64| if total > 0.0 { x / total } else { 0.0 };
    Group {
        count: n,
        p50_ms: plans::percentile(&ms, 50.0).unwrap_or(0.0),
        p99_ms: plans::percentile(&ms, 99.0).unwrap_or(0.0),
        mean_ms: total / n as f64,
        tokens_in_new: sum(&|c| c.prompt_tokens.saturating_sub(c.reused_tokens) as f64) / n as f64,
        tokens_in_reused: sum(&|c| c.reused_tokens as f64) / n as f64,
        tokens_out: sum(&|c| c.output_tokens as f64) / n as f64,
        prefill_share: share(sum(&|c| c.prefill_ms)),
        // Mask time is measured inside decode; decode's share here is without it.
        decode_share: share(sum(&|c| (c.decode_ms - c.mask_ms).max(0.0))),
        mask_share: share(sum(&|c| c.mask_ms)),
    }
}

/// Reading each task into the cache before its first node: a prefill of its own tokens.
fn reads_group(reads: &[Warm]) -> Group {
    let n = reads.len();
    if n == 0 {
        return Group::default();
    }
    let mut ms: Vec<f64> = reads.iter().map(|r| r.ms).collect();
    ms.sort_by(f64::total_cmp);
    Group {
        count: n,
        p50_ms: plans::percentile(&ms, 50.0).unwrap_or(0.0),
        p99_ms: plans::percentile(&ms, 99.0).unwrap_or(0.0),
        mean_ms: ms.iter().sum::<f64>() / n as f64,
        tokens_in_new: reads.iter().map(|r| r.tokens as f64).sum::<f64>() / n as f64,
        prefill_share: 1.0,
        ..Group::default()
    }
}

#[derive(Serialize)]
struct NodesReport {
    model: String,
    planner: String,
    strength: String,
    tasks: usize,
    by_role: BTreeMap<String, Group>,
    /// Every call of a tree node together (a node is decomposed and judged).
    per_node: Group,
    /// Each task and its context read into the cache before its first node (not in the node
    /// figures: a task is read once, however many nodes follow).
    task_read: Group,
    /// Before the first node: loading the model, and the system message put in its cache (read
    /// from its snapshot, or computed); not in the node figures.
    model_load_ms: f64,
    prefix: Option<Warm>,
    wall_s: f64,
}

pub fn run(a: &NodesArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    if let Some(instr) = &a.instruction {
        super::plan::nonempty(instr)?;
    }
    if a.every == Some(0) {
        // (read as 1, it benched every task, all 342 of EAI's, where the user asked for a few)
        anyhow::bail!("--every 0: give K >= 1 (every K-th task)");
    }
    let path = resolve_model(&a.model)?;
    a.inference.apply();
    let mut engine = Engine::load(&path)?;
    engine.set_prefix_dir(a.inference.prefix_dir());
    let mut cfg = PlanEvalConfig {
        planner: PlannerConfig { kind: a.planner, strength: a.grammar, ..PlannerConfig::default() },
        seen: a.protocol,
        env: EvalEnv::Sim,
        trace_dir: None,
    };
    cfg.planner.budgets.max_actions = a.max_actions;
    // Every call, and every decision (a node's calls merged), task by task.
    let mut calls: Vec<CallRecord> = Vec::new();
    let mut nodes: Vec<CallRecord> = Vec::new();
    let mut prefix = None;
    let mut reads: Vec<Warm> = Vec::new();
    let n_tasks;
    if let Some(instr) = &a.instruction {
        let w = crate::world::World::demo();
        let focus: Vec<u32> = w.nodes().map(|n| n.id).collect();
        let mut env = SimEnv::new(w, focus.clone());
        let req = crate::planner::PlanRequest::new(instr.clone(), focus);
        let main_job = PlannerConfig { infer_goals: true, ..cfg.planner.clone() };
        let out = crate::planner::plan(&mut engine, &mut env, &req, &main_job, &mut TraceWriter::sink());
        nodes.extend(CallRecord::decisions(&out.stats.calls));
        calls.extend(out.stats.calls);
        prefix = out.stats.warm;
        reads.extend(out.stats.read);
        n_tasks = 1;
    } else {
        let source = a.tasks.source();
        let only = (!a.only.is_empty()).then_some(a.only.as_slice());
        let k = a.every.unwrap_or(if source.tasks_file.is_some() || only.is_some() { 1 } else { 30 });
        let tasks = plans::every(source.load_for_planning(only)?, k);
        n_tasks = tasks.len();
        for (i, t) in tasks.iter().enumerate() {
            eprintln!("[{}/{}] {} ({})", i + 1, tasks.len(), t.id, t.title);
            let (_, stats) = plans::run_task_stats(&mut engine, t, &cfg);
            prefix = prefix.or(stats.warm);
            reads.extend(stats.read);
            nodes.extend(CallRecord::decisions(&stats.calls));
            calls.extend(stats.calls);
        }
    }
    let mut roles: BTreeMap<String, Vec<&CallRecord>> = BTreeMap::new();
    for c in &calls {
        roles.entry(c.role.to_string()).or_default().push(c);
    }
    let by_role: BTreeMap<String, Group> = roles.iter().map(|(k, v)| (k.clone(), group(v))).collect();
    let node_refs: Vec<&CallRecord> = nodes.iter().collect();
    let report = NodesReport {
        model: path.display().to_string(),
        planner: a.planner.to_string(),
        strength: a.grammar.to_string(),
        tasks: n_tasks,
        by_role,
        per_node: group(&node_refs),
        task_read: reads_group(&reads),
        model_load_ms: engine.load_ms(),
        prefix,
        wall_s: t0.elapsed().as_secs_f64(),
    };
    eprintln!(
        "{:<12} {:>6} {:>9} {:>9} {:>8} {:>8} {:>7} {:>8} {:>7} {:>6}",
        "role", "calls", "p50 ms", "p99 ms", "in new", "reused", "out", "prefill", "decode", "mask"
    );
    let rows = report
        .by_role
        .iter()
        .map(|(k, g)| (k.as_str(), g))
        .chain([("per node", &report.per_node), ("task read", &report.task_read)]);
    for (name, g) in rows {
        eprintln!(
            "{:<12} {:>6} {:>9.1} {:>9.1} {:>8.1} {:>8.1} {:>7.1} {:>7.0}% {:>6.0}% {:>5.0}%",
            name,
            g.count,
            g.p50_ms,
            g.p99_ms,
            g.tokens_in_new,
            g.tokens_in_reused,
            g.tokens_out,
            100.0 * g.prefill_share,
            100.0 * g.decode_share,
            100.0 * g.mask_share
        );
    }
    let how = match &report.prefix {
        Some(w) => format!("system message {} tokens {}", w.tokens, w.describe()),
        None => "system message computed by the first call".into(),
    };
    eprintln!("before the first node: model loaded in {:.0} ms, {how}", report.model_load_ms);
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
