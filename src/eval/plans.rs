//! Planners on task sets (`step eval plan`): each task's request is made under a [`Protocol`], the
//! planner runs against the simulated world, and the plan is scored by [`score`], the same code the
//! gold programs go through, so the planner and the scorer cannot disagree. Per task: the score,
//! the planner's own counters (LLM calls, tokens, actions, failed attempts, replans, grammar errors),
//! per-node latencies; per batch: the [`Summary`] and latency percentiles.
//!
//! Which plan is scored: closed-loop, the actions that ran (failed attempts changed nothing and are
//! counted apart, as failed attempts); open-loop (`flat`, or a dry run), the plan as written, run from
//! the initial state and stopped at its first failure, as EAI scores it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::protocol::{self, Protocol, Seen};
use super::run::{score, PlanInput, Summary, TaskReport};
use super::task::{RelevantRule, Task};
use crate::action::Action;
use crate::llm::engine::{GenOptions, Generate, Generation, Prompt};
use crate::llm::LlmError;
use crate::planner::{
    self, CallRecord, DryRunEnv, Env, PlanOutcome, PlanRequest, PlanStats, PlannerConfig, PlannerKind, SimEnv, StopCause,
    TraceWriter,
};
use crate::program::{PlanFormat, Program};

/// Where a task's actions run during evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum EvalEnv {
    /// The symbolic world answers each action (closed loop).
    Sim,
    /// No answers: every action is reported ok (open loop).
    DryRun,
}

impl std::str::FromStr for EvalEnv {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "sim" => Ok(EvalEnv::Sim),
            "dry-run" => Ok(EvalEnv::DryRun),
            _ => Err(format!("unknown env '{s}' for evaluation: sim or dry-run (a robot bridge is for `step plan`)")),
        }
    }
}

/// How a batch is run.
#[derive(Clone, Debug)]
pub struct PlanEvalConfig {
    pub planner: PlannerConfig,
    pub seen: Seen,
    pub env: EvalEnv,
    /// One trace file per task (`<id>.jsonl`) in this directory.
    pub trace_dir: Option<PathBuf>,
}

impl PlanEvalConfig {
    /// The protocol this configuration runs under.
    pub fn protocol(&self) -> Protocol {
        let closed = self.env == EvalEnv::Sim && self.planner.kind != PlannerKind::Flat;
        Protocol { seen: self.seen, closed_loop: closed }
    }
}

/// A model stand-in for planners that need none (`random`): any call is an error.
pub struct NoModel;

impl Generate for NoModel {
    fn generate(&mut self, _: &Prompt, _: Option<&str>, _: &GenOptions) -> crate::llm::Result<Generation> {
        Err(LlmError::Decode("this planner was given no model (use --model)".into()))
    }
}

/// One task's line in a planner report: the scorer's report plus the planner's counters.
#[derive(Clone, Debug, Serialize)]
pub struct TaskPlanReport {
    #[serde(flatten)]
    pub score: TaskReport,
    pub relevant_rule: RelevantRule,
    pub relevant_objects: usize,
    /// Why the planner stopped.
    pub stop: String,
    /// The same without its detail (`StopCause::kind`): what the report's stop counts group by.
    pub stop_kind: String,
    /// The plan that was scored, one action line each.
    pub plan: Vec<String>,
    pub llm_calls: usize,
    pub prompt_tokens: usize,
    pub reused_tokens: usize,
    pub output_tokens: usize,
    /// Actions sent to the executor.
    pub actions_sent: usize,
    /// Actions the executor refused (closed loop: the planner heard why and went on).
    pub failed_attempts: usize,
    pub replans: usize,
    pub symbolic_rejections: usize,
    /// Model outputs the independent checker rejected (must be 0: grammars make them impossible).
    pub grammar_errors: usize,
    /// Per tree node: the sum of its LLM calls' milliseconds.
    pub node_ms: Vec<f64>,
    /// Reading the task and its context into the model's cache, before the first node (none: the
    /// first call read it, or no model ran).
    pub read_ms: Option<f64>,
    pub read_tokens: Option<usize>,
    pub wall_ms: f64,
    /// Closed loop: the state the planner's world ended in equals the scorer's replay of the plan.
    pub replay_agrees: bool,
}

/// The plan to score (see the module documentation).
fn scored_plan(out: &PlanOutcome, open_loop: bool) -> Vec<Action> {
    if !open_loop {
        return out.executed.clone();
    }
    let tree = &out.tree;
    let root = tree.root();
    let written: Vec<Action> = tree.node(root).children.iter().filter_map(|&c| tree.node(c).action.clone()).collect();
    // A planner whose tree is deeper than one level (a dry-run tree planner) wrote its leaves in order.
    if written.is_empty() {
        tree.plan()
    } else {
        written
    }
}

fn is_grammar_error(stop: &StopCause) -> bool {
    matches!(stop, StopCause::Error(e) if e.contains("grammar error"))
}

/// Runs the planner on one task and scores what it did.
pub fn run_task(model: &mut dyn Generate, task: &Task, cfg: &PlanEvalConfig) -> TaskPlanReport {
    run_task_stats(model, task, cfg).0
}

/// [`run_task`], also returning the planner's counters with every LLM call (for `step bench nodes`).
pub fn run_task_stats(model: &mut dyn Generate, task: &Task, cfg: &PlanEvalConfig) -> (TaskPlanReport, PlanStats) {
    let proto = cfg.protocol();
    let focus = protocol::focus(task, cfg.seen);
    let req = PlanRequest {
        context: protocol::context(task, cfg.seen),
        subgoals: if cfg.planner.goal_subgoals { protocol::subgoals(task, cfg.seen) } else { Vec::new() },
        kept: protocol::kept(task, cfg.seen),
        named_verbs: protocol::named_verbs(task, cfg.seen),
        ..PlanRequest::new(protocol::instruction(task), focus.clone())
    };
    let mut trace = match &cfg.trace_dir {
        Some(d) => TraceWriter::create(&d.join(format!("{}.jsonl", sanitize(&task.id))))
            .unwrap_or_else(|_| TraceWriter::sink()),
        None => TraceWriter::sink(),
    };
    trace.event(
        "task",
        serde_json::json!({"id": task.id, "protocol": proto.to_string(), "relevant_rule": task.relevance.rule.name(),
                           "context": req.context}),
    );
    let (out, end) = match cfg.env {
        EvalEnv::Sim => {
            let mut env = SimEnv::new(task.world.clone(), focus);
            let out = planner::plan(model, &mut env, &req, &cfg.planner, &mut trace);
            let end = env.world().cloned();
            (out, end)
        }
        EvalEnv::DryRun => {
            let mut env = DryRunEnv::new(task.world.clone(), focus);
            (planner::plan(model, &mut env, &req, &cfg.planner, &mut trace), None)
        }
    };
    let plan = scored_plan(&out, !proto.closed_loop);
    let input = if plan.is_empty() { PlanInput::Missing } else { PlanInput::Plan(Program::new(plan.clone())) };
    let report = score(task, &input);
    // The scorer replays the plan from the initial state; closed-loop it must reach the planner's state.
    let replay_agrees = match (&end, &input, proto.closed_loop) {
        (Some(end), PlanInput::Plan(p), true) => {
            let r = super::run::run_plan(task, p);
            r.end.edges() == end.edges() && r.end.nodes().zip(end.nodes()).all(|(a, b)| a.states == b.states)
        }
        _ => true,
    };
    // A tree node's latency: the decision that proposed it.
    let node_ms: Vec<f64> = CallRecord::decisions(&out.stats.calls).iter().map(|d| d.total_ms).collect();
    trace.event("score", serde_json::to_value(&report).unwrap_or_default());
    let r = TaskPlanReport {
        relevant_rule: task.relevance.rule,
        relevant_objects: task.relevant.len(),
        stop: out.stop.to_string(),
        stop_kind: out.stop.kind(),
        plan: plan.iter().map(|a| a.to_string()).collect(),
        llm_calls: out.stats.llm_calls,
        prompt_tokens: out.stats.prompt_tokens,
        reused_tokens: out.stats.reused_tokens,
        output_tokens: out.stats.output_tokens,
        actions_sent: out.stats.actions,
        failed_attempts: out.stats.failed_executions,
        replans: out.stats.replans,
        symbolic_rejections: out.stats.symbolic_rejections,
        grammar_errors: is_grammar_error(&out.stop) as usize,
        node_ms,
        read_ms: out.stats.read.as_ref().map(|r| r.ms),
        read_tokens: out.stats.read.as_ref().map(|r| r.tokens),
        wall_ms: out.stats.wall_ms,
        replay_agrees,
        score: report,
    };
    (r, out.stats)
}

fn sanitize(id: &str) -> String {
    id.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' || c == '-' { c } else { '_' }).collect()
}

/// Percentiles of a sample (nearest rank); `None` when empty.
pub fn percentile(sorted: &[f64], p: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    Some(sorted[rank.clamp(1, sorted.len()) - 1])
}

/// Mean and total of a per-task counter.
#[derive(Clone, Debug, Serialize)]
pub struct PerTask {
    pub total: usize,
    pub mean: f64,
}

fn per_task(reports: &[TaskPlanReport], f: impl Fn(&TaskPlanReport) -> usize) -> PerTask {
    let total: usize = reports.iter().map(f).sum();
    PerTask { total, mean: if reports.is_empty() { 0.0 } else { total as f64 / reports.len() as f64 } }
}

/// Verbs of our embodiment that EAI's own scorer cannot score, left out of the grammars on EAI's
/// tasks so exported plans can be scored there: SLEEP and WAKEUP are not in its action space (a
/// hallucination error), LOOKAT_SHORT and LOOKAT_LONG have no executor there (the scorer crashes),
/// and RELEASE is missing from the list its hallucination check accepts (`valid_actions` in EAI's
/// `eval_utils.py`), so a plan with it is scored a hallucination although EAI's executor runs it.
pub const EAI_UNSCOREABLE: [crate::action::Verb; 5] = [
    crate::action::Verb::Sleep,
    crate::action::Verb::WakeUp,
    crate::action::Verb::LookAtShort,
    crate::action::Verb::LookAtLong,
    crate::action::Verb::Release,
];

/// The batch report.
#[derive(Clone, Debug, Serialize)]
pub struct PlanEvalReport {
    pub planner: String,
    pub strength: String,
    pub protocol: Protocol,
    pub protocol_text: String,
    pub comparable_with_eai_table: bool,
    /// Verbs no grammar offered (see [`EAI_UNSCOREABLE`]).
    pub excluded_verbs: Vec<String>,
    pub source: String,
    pub summary: Summary,
    pub rates: super::run::Rates,
    pub grammar_errors: usize,
    pub llm_calls: PerTask,
    pub prompt_tokens: PerTask,
    pub reused_tokens: PerTask,
    pub output_tokens: PerTask,
    pub actions_sent: PerTask,
    pub executed_actions: PerTask,
    pub failed_attempts: PerTask,
    pub replans: PerTask,
    pub node_ms_p50: Option<f64>,
    pub node_ms_p99: Option<f64>,
    /// Reading each task before its first node (see [`TaskPlanReport::read_ms`]).
    pub read_ms_p50: Option<f64>,
    pub read_ms_p99: Option<f64>,
    pub read_tokens: PerTask,
    pub replay_disagreements: usize,
    /// Tasks per relevant-object rule, and the mean list length under each.
    pub relevant_rules: BTreeMap<String, (usize, f64)>,
    pub stops: BTreeMap<String, usize>,
    pub total_s: f64,
    pub tasks: Vec<TaskPlanReport>,
}

impl PlanEvalReport {
    pub fn new(cfg: &PlanEvalConfig, source: String, tasks: Vec<TaskPlanReport>, total_s: f64) -> PlanEvalReport {
        let scores: Vec<TaskReport> = tasks.iter().map(|t| t.score.clone()).collect();
        let summary = Summary::of(&scores);
        let mut node_ms: Vec<f64> = tasks.iter().flat_map(|t| t.node_ms.iter().copied()).collect();
        node_ms.sort_by(f64::total_cmp);
        let mut read_ms: Vec<f64> = tasks.iter().filter_map(|t| t.read_ms).collect();
        read_ms.sort_by(f64::total_cmp);
        let mut rules: BTreeMap<String, (usize, usize)> = BTreeMap::new();
        let mut stops: BTreeMap<String, usize> = BTreeMap::new();
        for t in &tasks {
            let e = rules.entry(t.relevant_rule.name().to_string()).or_default();
            e.0 += 1;
            e.1 += t.relevant_objects;
            // Stops grouped by kind, without task-specific detail.
            *stops.entry(t.stop_kind.clone()).or_default() += 1;
        }
        let proto = cfg.protocol();
        PlanEvalReport {
            planner: cfg.planner.kind.to_string(),
            // The strength the planner really used (flat cannot be feasible-constrained).
            strength: match cfg.planner.kind {
                crate::planner::PlannerKind::Flat => crate::planner::baseline::flat_strength(cfg.planner.strength),
                _ => cfg.planner.strength,
            }
            .to_string(),
            protocol: proto,
            protocol_text: proto.to_string(),
            comparable_with_eai_table: proto.comparable_with_eai(),
            excluded_verbs: cfg.planner.excluded_verbs.iter().map(|v| v.name().to_string()).collect(),
            source,
            rates: summary.rates(),
            summary,
            grammar_errors: tasks.iter().map(|t| t.grammar_errors).sum(),
            llm_calls: per_task(&tasks, |t| t.llm_calls),
            prompt_tokens: per_task(&tasks, |t| t.prompt_tokens),
            reused_tokens: per_task(&tasks, |t| t.reused_tokens),
            output_tokens: per_task(&tasks, |t| t.output_tokens),
            actions_sent: per_task(&tasks, |t| t.actions_sent),
            executed_actions: per_task(&tasks, |t| t.plan.len()),
            failed_attempts: per_task(&tasks, |t| t.failed_attempts),
            replans: per_task(&tasks, |t| t.replans),
            node_ms_p50: percentile(&node_ms, 50.0),
            node_ms_p99: percentile(&node_ms, 99.0),
            read_ms_p50: percentile(&read_ms, 50.0),
            read_ms_p99: percentile(&read_ms, 99.0),
            read_tokens: per_task(&tasks, |t| t.read_tokens.unwrap_or(0)),
            replay_disagreements: tasks.iter().filter(|t| !t.replay_agrees).count(),
            relevant_rules: rules.into_iter().map(|(k, (n, sum))| (k, (n, sum as f64 / n.max(1) as f64))).collect(),
            stops,
            total_s,
            tasks,
        }
    }

    /// The report as text.
    pub fn table(&self) -> String {
        let mut out = format!(
            "planner {} (grammar {}) on {} ({} tasks)\nprotocol: {}{}\n",
            self.planner,
            self.strength,
            self.source,
            self.summary.tasks,
            self.protocol_text,
            if self.comparable_with_eai_table {
                " (EAI's protocol)"
            } else {
                " (not EAI's protocol: do not compare with EAI's table)"
            }
        );
        if !self.excluded_verbs.is_empty() {
            out.push_str(&format!(
                "actions not offered: {} (EAI's scorer cannot score them; --all-verbs offers them)\n",
                self.excluded_verbs.join(", ")
            ));
        }
        out.push_str(&self.summary.table());
        out.push_str(&format!("grammar errors: {}\n", self.grammar_errors));
        let row = |name: &str, p: &PerTask| format!("  {name:<22} {:>9.2} per task ({} in all)\n", p.mean, p.total);
        out.push_str("per task:\n");
        out.push_str(&row("LLM calls", &self.llm_calls));
        out.push_str(&row("prompt tokens", &self.prompt_tokens));
        out.push_str(&row("  of them reused", &self.reused_tokens));
        out.push_str(&row("output tokens", &self.output_tokens));
        out.push_str(&row("actions sent", &self.actions_sent));
        out.push_str(&row("actions in the plan", &self.executed_actions));
        out.push_str(&row("failed attempts", &self.failed_attempts));
        out.push_str(&row("replans", &self.replans));
        let ms = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.1} ms"));
        out.push_str(&format!("per-node latency: p50 {}, p99 {}\n", ms(self.node_ms_p50), ms(self.node_ms_p99)));
        if self.read_ms_p50.is_some() {
            out.push_str(&format!(
                "reading the task before its first node: p50 {}, p99 {}, {:.0} tokens a task\n",
                ms(self.read_ms_p50),
                ms(self.read_ms_p99),
                self.read_tokens.mean
            ));
        }
        let rules: Vec<String> =
            self.relevant_rules.iter().map(|(k, (n, m))| format!("{k}: {n} tasks, {m:.1} objects each")).collect();
        out.push_str(&format!("relevant objects by rule: {}\n", rules.join("; ")));
        let stops: Vec<String> = self.stops.iter().map(|(k, n)| format!("{k}={n}")).collect();
        out.push_str(&format!("stops: {}\n", stops.join(" ")));
        if self.replay_disagreements > 0 {
            out.push_str(&format!(
                "WARNING: the scorer's replay disagrees with the planner's world on {} task(s)\n",
                self.replay_disagreements
            ));
        }
        out.push_str(&format!("total time: {:.1} s\n", self.total_s));
        out
    }
}

/// The scored plans in EAI's LLM-output format: `[{"identifier", "llm_output"}]`, for EAI's scorer.
pub fn export_eai(reports: &[TaskPlanReport], tasks: &[Task], path: &Path) -> std::io::Result<()> {
    let by_id: BTreeMap<&str, &Task> = tasks.iter().map(|t| (t.id.as_str(), t)).collect();
    let mut list = Vec::with_capacity(reports.len());
    for r in reports {
        if !by_id.contains_key(r.score.id.as_str()) {
            continue;
        }
        let actions: Vec<Action> = r.plan.iter().filter_map(|l| crate::program::parse_step_line(l).ok()).collect();
        let text = Program::new(actions).write(PlanFormat::Eai);
        list.push(serde_json::json!({"identifier": r.score.id, "llm_output": text}));
    }
    let text = serde_json::to_string_pretty(&list).map_err(std::io::Error::other)?;
    std::fs::write(path, text + "\n")
}

/// Every K-th task (the first, the (K+1)-th, …) in id order: a fixed subset for development.
pub fn every(mut tasks: Vec<Task>, k: usize) -> Vec<Task> {
    tasks.sort_by_key(|t| super::dataset::task_id_key(&t.id));
    if k <= 1 {
        return tasks;
    }
    tasks.into_iter().enumerate().filter(|(i, _)| i % k == 0).map(|(_, t)| t).collect()
}
