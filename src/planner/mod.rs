//! The STEP planner: a subgoal tree grown by two grammar-constrained LLM roles, closed-loop on an
//! executor (the paper's Algorithm 1).
//!
//! - [`tree`]: the subgoal tree (petgraph), node statuses with their history, JSON and DOT export.
//! - [`env`]: the [`Env`] trait leaves execute against (`sim`, `dry-run`; `bridge:CMD` in `bridge`).
//! - [`trace`]: the JSON-lines trace, flushed per event.
//! - [`prompt`]: the prompts (files under `prompts/`), ordered for prefix reuse.
//! - [`planner`]: Algorithm 1 and the ablations' context modes; beside it `decompose` (the
//!   subgoal decomposition model), `terminate` (the leaf-node termination model and the symbolic
//!   check) and `rules` (what narrows their choices: fresh steps, protected changes, kept goals).
//!
//! [`plan`] is the one entry point for every planner kind.

pub mod baseline;
pub mod bridge;
mod decompose;
pub mod goals;
pub mod env;
pub mod planner;
pub mod prompt;
pub mod replay;
mod rules;
mod terminate;
pub mod trace;
pub mod tree;

use std::time::Duration;

use serde::Serialize;
use serde_json::{json, Value};

use crate::action::{Action, Verb};
use crate::llm::engine::{GenOptions, Generate};
use crate::llm::sample::Sampling;
use crate::world::{Fact, World};

pub use env::{DryRunEnv, Env, EnvError, Outcome, SimEnv};
pub use planner::ContextMode;
pub use trace::TraceWriter;
pub use tree::{NodeId, Status, SubgoalTree, TreeNode};

pub use crate::grammar::Strength;

/// Which planner runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlannerKind {
    /// The subgoal tree: each decision sees its parent and previous sibling.
    Step,
    /// The whole plan in one constrained generation (EAI's protocol).
    Flat,
    /// Ablation: each decision sees its parent and every action executed so far (no siblings).
    NoTree,
    /// Ablation: each decision sees the root and every action executed so far, no subgoals.
    NoSubgoalTree,
    /// A seeded uniform choice among what the grammar admits, in place of the model.
    Random,
}

impl PlannerKind {
    pub const ALL: [PlannerKind; 5] =
        [PlannerKind::Step, PlannerKind::Flat, PlannerKind::NoTree, PlannerKind::NoSubgoalTree, PlannerKind::Random];

    pub fn name(self) -> &'static str {
        match self {
            PlannerKind::Step => "step",
            PlannerKind::Flat => "flat",
            PlannerKind::NoTree => "no-tree",
            PlannerKind::NoSubgoalTree => "no-subgoal-tree",
            PlannerKind::Random => "random",
        }
    }
}

impl std::fmt::Display for PlannerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for PlannerKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        PlannerKind::ALL.into_iter().find(|k| k.name() == s).ok_or_else(|| {
            format!("unknown planner '{s}': choose one of {}", PlannerKind::ALL.map(|k| k.name()).join(", "))
        })
    }
}

/// What the planner is told (the protocol): everything except the instruction is optional.
pub struct PlanRequest {
    /// Title + description, or the user's instruction.
    pub instruction: String,
    /// E.g. relevant objects with their initial states; goals in words.
    pub context: Option<String>,
    /// Object ids grammars may name (the task's relevant objects, or the whole scene).
    pub focus: Vec<u32>,
    /// Subgoals offered to the root's decomposition, one line each (a task's goals in words, when the
    /// protocol shows them): the root's subgoals are chosen among these instead of written freely.
    pub subgoals: Vec<String>,
    /// What the task asks to hold at the end, as facts (the shown goal lines' states and relations,
    /// closeness aside): with [`PlannerConfig::keep_goals`] no step that would make one false while
    /// it holds is offered. Empty unless the protocol shows the goals. Never a reason to stop.
    pub kept: Vec<Fact>,
    /// The verbs the shown goals name as actions the plan must include ("LOOKAT or WATCH"): with
    /// [`PlannerConfig::skip_idle`] they stay offered although they change nothing. Empty unless
    /// the protocol shows the goals.
    pub named_verbs: Vec<Verb>,
    /// DIAGNOSTIC ONLY, an oracle: a goal check the loop may stop at (with `PlannerConfig::oracle_stop`).
    /// A planner that stops because the scorer's goals hold is not deciding when to stop; figures
    /// obtained with it must be labelled as oracle figures and never reported as the planner's.
    pub oracle: Option<Box<dyn Fn(&World) -> bool>>,
}

impl PlanRequest {
    /// The objects the request is about in `w`: its focus, or where none is given the whole scene
    /// (the character excluded).
    pub fn focus_in(&self, w: &World) -> Vec<u32> {
        if self.focus.is_empty() {
            w.nodes().map(|n| n.id).filter(|&id| id != w.character()).collect()
        } else {
            self.focus.clone()
        }
    }

    pub fn new(instruction: impl Into<String>, focus: Vec<u32>) -> PlanRequest {
        PlanRequest {
            instruction: instruction.into(),
            context: None,
            focus,
            subgoals: Vec::new(),
            kept: Vec::new(),
            named_verbs: Vec::new(),
            oracle: None,
        }
    }
}

impl std::fmt::Debug for PlanRequest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PlanRequest")
            .field("instruction", &self.instruction)
            .field("context", &self.context)
            .field("focus", &self.focus)
            .field("subgoals", &self.subgoals)
            .field("kept", &self.kept)
            .field("named_verbs", &self.named_verbs)
            .field("oracle", &self.oracle.is_some())
            .finish()
    }
}

/// Limits that guarantee the loop ends; the one that ends it is named in [`StopCause::Budget`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Budgets {
    /// Deepest node below the root (the root is depth 0); a decomposition deeper is a replan.
    pub max_depth: usize,
    /// Children a node may have (replanned ones included) before it is abandoned.
    pub max_children: usize,
    /// Replans (rejected or failed children) per node before it is abandoned.
    pub max_replans: usize,
    pub max_llm_calls: usize,
    pub max_actions: usize,
    /// Wall-clock limit for the whole run.
    #[serde(serialize_with = "ser_opt_duration")]
    pub deadline: Option<Duration>,
}

fn ser_opt_duration<S: serde::Serializer>(d: &Option<Duration>, s: S) -> Result<S::Ok, S::Error> {
    match d {
        Some(d) => s.serialize_some(&d.as_secs_f64()),
        None => s.serialize_none(),
    }
}

impl Default for Budgets {
    fn default() -> Self {
        Budgets { max_depth: 3, max_children: 10, max_replans: 3, max_llm_calls: 300, max_actions: 40, deadline: None }
    }
}

/// How a planner runs.
#[derive(Clone, Debug)]
pub struct PlannerConfig {
    pub kind: PlannerKind,
    pub strength: Strength,
    pub budgets: Budgets,
    /// Check each *execute* verdict against the belief world (`why_not`) before executing; a doomed
    /// one becomes a replan with the executor's reason.
    pub symbolic_check: bool,
    /// Sampling and the token cap of each call.
    pub gen: GenOptions,
    /// Seed of the `random` planner.
    pub random_seed: u64,
    /// Actions the `random` planner executes before it stops (when the request offers no subgoals).
    pub random_actions: usize,
    /// Actions the `random` planner executes under each offered subgoal before it says `done` there.
    pub random_steps: usize,
    /// Goal lines the `random` planner sets (with `infer_goals`), drawn uniformly among the
    /// candidates, before it says `done` at the root.
    pub random_lines: usize,
    /// Below the root, a node's actions name only the objects its text names (and what holds them);
    /// see `planner::Run::node_focus`.
    pub subgoal_focus: bool,
    /// When the protocol shows the goals, offer them to the root as its subgoals (one per goal line)
    /// instead of letting it write its own.
    pub goal_subgoals: bool,
    /// Offer a node, as its subgoals, the actions over its objects that cannot run yet (a target:
    /// "make this action possible, then do it"), written as the action; a target node proposes
    /// actions and is done when its action runs. Feasible grammar only; not for the root's goal lines.
    pub target_subgoals: bool,
    /// Below a target subgoal the one step offered is the world's next step towards its action
    /// (`World::first_step_towards`: the step each failure names, followed back); the model chose the
    /// target, the embodiment knows the way. Off: the model chooses among the feasible actions.
    /// Either way a target is offered only when its way names no object outside the run's focus.
    pub target_steps: bool,
    /// A goal line offered to the root is reached by one step: its node is complete once one child
    /// (an action, or a target whose action ran) has been accepted, instead of when the model says
    /// `done` there. A fixed structure (one chosen action a goal line), not a look at the goals' state.
    pub single_step_lines: bool,
    /// DIAGNOSTIC ONLY: stop when `PlanRequest::oracle` says the goal holds (see there).
    pub oracle_stop: bool,
    /// Ask the termination model about an action the symbolic check already found runnable (it can
    /// then only reject it for congruence). Off: the world's check is the verdict on actions, and the
    /// model judges subgoals only.
    pub judge_actions: bool,
    /// Drop steps that repeat recent ones (see `rules::fresh_steps`; exact action sets only;
    /// the random planner obeys it too).
    pub fresh_steps: bool,
    /// Say, after each step, what it changed among its objects in the goal lines' words ("ok, now
    /// television is ON"; a robot bridge's own observation, when it sends one, instead).
    pub report_changes: bool,
    /// A node's steps do not undo what its earlier steps changed (SWITCHOFF after its SWITCHON, STANDUP
    /// after its SIT): a candidate step is tried on a copy of the world first. Holding and closeness
    /// are left out: they are means (a grab is undone by the put it was for). The random planner
    /// obeys it too. A rule on the node's own steps, not a look at the goals; where the goals are
    /// kept, it does not bar a step that makes one of them true (the walk into the room the task
    /// names, after a turn to face it; the grab of the food the node had put a plate on).
    pub protect_changes: bool,
    /// Do not offer a step that would make false a fact the task asks for while it holds
    /// ([`PlanRequest::kept`]: PLUGOUT of a television that is to stay plugged in, putting down what
    /// is to be held). A chosen target is judged by its own action, not by the steps on its way (a
    /// closed fridge that is to stay closed may be opened to put the apple in, and closed again by
    /// its own line). A line met when done that a later line's way made false is offered to the
    /// root again, each time, up to three times. A hold not yet met reserves its hand: no step
    /// fills that hand with another object or puts the object in the other hand, a left hand's
    /// line waits for the right hand's (GRAB fills the right hand first), and below a left hand's
    /// line with the right hand free, grabbing another object of the focus is offered as the way
    /// to it. The random planner obeys it too. It reads the goal lines the protocol shows, and
    /// never decides when to stop. It applies where the protocol shows goals at all: a task whose
    /// goals are only closeness and actions keeps no fact but is under its rules (`skip_idle`,
    /// `lines_done_at`) all the same.
    pub keep_goals: bool,
    /// Where the task's goals are kept, do not offer a step that changes nothing among its objects
    /// and the robot (LOOKAT, TOUCH, WASH of a clean plate): no state or relation can come of it.
    /// The verbs the goals name as actions ([`PlanRequest::named_verbs`]) stay. The random planner
    /// obeys it too. A rule on what a step does, read from the world, never a reason to stop.
    pub skip_idle: bool,
    /// Where `done` may be answered, the model is done when its own probability of `done` as the
    /// answer's first word (against `action:` and `subgoal:`) is at least this: greedy decoding takes
    /// `done` only when it comes first, and a tiny model shown more action lines than `done` lines
    /// rarely puts it first even once the goal's action has run. `None`: greedy decoding alone.
    /// Not used where the task's goals are kept (`keep_goals` with [`PlanRequest::kept`]): there a
    /// step past the goal cannot undo it, and a tiny model's early `done` only loses the line
    /// (SmolLM2 on `--every 6`: 52% of tasks with the check, 78% on the first 41 without), so
    /// [`PlannerConfig::lines_done_at`] decides there, with the children budget behind it.
    pub done_at: Option<f64>,
    /// On the task's goal lines with the goals kept, the model is done with a line when its own
    /// probability of `done` as the answer's first word is at least this; below it `done` is not
    /// offered to that decision. `None`: greedy decoding decides (`done` when it comes first).
    /// Greedy decoding took a tiny model's `done` early, before the line's goal (61% of `--every 6`
    /// against 67% with 0.5).
    pub lines_done_at: Option<f64>,
    /// Show each decision the steps it may write, each with what running it would make true among
    /// its objects and the robot, read from a trial on a copy of the world ("[LIE] <couch> (352):
    /// character is LYING"; at most 24), so a model can match a goal line's words against them.
    /// Needs a world model; the choice stays the model's (the grammar is unchanged). Off: SmolLM2
    /// met as many tasks without it (24 of 30 on `--every 6`, against 23) at a third of the time a
    /// call (each list is ~650 prompt tokens).
    pub show_effects: bool,
    /// Where the protocol shows no goals, the root first chooses its own goal lines, one at a time,
    /// among the lines the world can state about its objects (`goals::candidates`), and says
    /// `done` when it has set enough; each line is then worked as a shown goal line. Needs a world
    /// model; not in `no-subgoal-tree`. The lines are the model's choice: nothing reads the task's goals.
    pub infer_goals: bool,
    /// Below a goal line the root set itself (`infer_goals`), offer only the steps and targets
    /// that make the line true or run its verb, where any do (read from trials on the world; the
    /// random planner obeys it too). Below a shown line that names actions ("POUR", "READ or
    /// LOOKAT"), only steps and targets of those verbs, where any are offered: the line's words,
    /// not the world, say what is congruent with it. A shown line's fact is never worked out so.
    pub toward_lines: bool,
    /// With `infer_goals`, offer as goal lines the verbs of every step that changes nothing
    /// (LOOKAT, TOUCH, PULL), not only those the instruction names ([`goals::names_verb`]), and
    /// every posture, not only the one whose verb it names.
    pub all_verb_lines: bool,
    /// With `infer_goals`, where the instruction names objects, offer only lines about them
    /// ([`goals::candidates`]), and meet a line about the robot alone on them where it can be
    /// (`toward_own_line`): the goals the root sets are congruent with its instruction.
    pub named_lines: bool,
    /// With `infer_goals`, where the instruction says a verb of an object ("open the fridge") or
    /// a relation between two ("the bread on the plate"), leave out that object's lines of other
    /// verbs and the other relation (`goals::candidates`): the parent's words, plainly said.
    pub said_lines: bool,
    /// With `infer_goals`, do not offer a line whose state holds now: a goal the root sets is a
    /// change to bring about ("fridge is CLOSED" comes back once a step has opened the fridge).
    pub skip_held_lines: bool,
    /// With `infer_goals`, the root chooses its line by how much more likely the instruction
    /// makes it: each answer's log probability less its log probability under the same prompt
    /// with the instruction left out (pointwise mutual information), so that a short or
    /// familiar answer (`done`, the menu's first line) does not win on its form alone.
    pub calibrate_lines: bool,
    /// How a proposed action is chosen once the model has said it proposes one.
    pub choose: ActionChoice,
    /// Verbs no grammar offers (e.g. those EAI's scorer cannot execute, on EAI's tasks).
    pub excluded_verbs: Vec<Verb>,
    /// Bytes of the observation shown in each prompt.
    pub observe_budget: usize,
    /// Longest subgoal text a decomposition may write.
    pub subgoal_chars: usize,
    /// Longest replan reason a verdict may write.
    pub reason_chars: usize,
}

/// The default [`PlannerConfig::done_at`].
pub const DONE_AT: f64 = 0.2;

/// The default [`PlannerConfig::lines_done_at`]: SmolLM2-135M's probability of `done` under goal
/// lines stays low whatever the state (mean 0.23, highest 0.54 over 471 decisions on `--every 6`),
/// so only its most confident `done` is taken; short of it, a line ends when nothing fresh is left
/// to do or at the children budget.
pub const LINES_DONE_AT: f64 = 0.5;

impl Default for PlannerConfig {
    fn default() -> Self {
        PlannerConfig {
            kind: PlannerKind::Step,
            strength: Strength::Feasible,
            budgets: Budgets::default(),
            symbolic_check: true,
            gen: GenOptions { max_tokens: 48, ..GenOptions::default() },
            random_seed: 0,
            random_actions: 30,
            random_steps: 10,
            random_lines: 4,
            subgoal_focus: true,
            goal_subgoals: true,
            target_subgoals: true,
            target_steps: true,
            single_step_lines: false,
            oracle_stop: false,
            judge_actions: false,
            fresh_steps: true,
            report_changes: true,
            protect_changes: true,
            keep_goals: true,
            skip_idle: true,
            done_at: Some(DONE_AT),
            lines_done_at: Some(LINES_DONE_AT),
            show_effects: false,
            infer_goals: false,
            toward_lines: true,
            all_verb_lines: false,
            named_lines: true,
            said_lines: true,
            skip_held_lines: true,
            calibrate_lines: false,
            choose: ActionChoice::Generate,
            excluded_verbs: Vec::new(),
            observe_budget: 600,
            subgoal_chars: 40,
            reason_chars: 48,
        }
    }
}

impl PlannerConfig {
    /// The actions the grammar of a decision admits: the strength's set over `focus` in `world`,
    /// without the excluded verbs. Every planner builds its grammars through this.
    pub fn action_set(&self, strength: Strength, world: &World, focus: &[u32]) -> crate::grammar::ActionSet {
        crate::scene_grammar::action_set(strength, world, focus).without(&self.excluded_verbs)
    }
}

/// How the planner picks the action of an `action:` proposal.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ActionChoice {
    /// The action the model wrote, greedily, token by token under the grammar.
    Generate,
    /// The most likely (per token) of every action the grammar admits, scored whole after the
    /// same prompt: a token-by-token greedy choice commits to a verb before seeing the objects,
    /// a whole-line score does not. Needs an exact action set (`feasible`); else as `Generate`.
    Score,
}

impl ActionChoice {
    pub fn name(self) -> &'static str {
        match self {
            ActionChoice::Generate => "generate",
            ActionChoice::Score => "score",
        }
    }
}

impl std::str::FromStr for ActionChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "generate" => Ok(ActionChoice::Generate),
            "score" => Ok(ActionChoice::Score),
            _ => Err(format!("unknown action choice '{s}': choose generate or score")),
        }
    }
}

/// Why the loop ended.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "stop", content = "detail", rename_all = "snake_case")]
pub enum StopCause {
    /// The root is complete: the model said `done` there, or (goal lines offered) every line was taken.
    Done,
    /// A budget ran out: which one (`depth`, `children`, `replans`, `llm_calls`, `actions`, `deadline`).
    Budget(&'static str),
    /// DIAGNOSTIC: the oracle goal check held.
    Oracle,
    /// The model or the executor failed; the trace up to it is intact.
    Error(String),
}

impl StopCause {
    /// The stop without its detail, for counting stops over many runs: `done`, `budget:<which>`,
    /// `oracle` or `error`.
    pub fn kind(&self) -> String {
        match self {
            StopCause::Done => "done".into(),
            StopCause::Budget(b) => format!("budget:{b}"),
            StopCause::Oracle => "oracle".into(),
            StopCause::Error(_) => "error".into(),
        }
    }
}

impl std::fmt::Display for StopCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StopCause::Done => f.write_str("done (the root is complete: `done` there, or every offered goal line taken)"),
            StopCause::Budget(b) => write!(f, "budget: {b}"),
            StopCause::Oracle => f.write_str("oracle goal check (diagnostic)"),
            StopCause::Error(e) => write!(f, "error: {e}"),
        }
    }
}

/// One LLM call.
#[derive(Clone, Debug, Serialize)]
pub struct CallRecord {
    /// `decompose`, `terminate` or `flat` (generations); `done_check` (the model's probability of
    /// `done`) or `score` (a choice among whole answers ranked by likelihood).
    pub role: &'static str,
    /// The tree node the call was about.
    pub node: usize,
    /// sha256 of the rendered prompt's messages and the grammar (hex, first 16 chars).
    pub prompt_hash: String,
    pub output: String,
    pub prompt_tokens: usize,
    pub reused_tokens: usize,
    pub output_tokens: usize,
    pub forced_tokens: usize,
    pub prefill_ms: f64,
    pub decode_ms: f64,
    pub mask_ms: f64,
    pub total_ms: f64,
    pub stop: String,
}

impl CallRecord {
    /// The record of one scoring pass (`role`: `done_check` or `score`) that chose `chosen` among
    /// the candidates.
    pub fn of_scoring(
        role: &'static str,
        node: usize,
        prompt_hash: String,
        s: &crate::llm::engine::Scoring,
        chosen: &str,
        total_ms: f64,
    ) -> CallRecord {
        CallRecord {
            role,
            node,
            prompt_hash,
            output: chosen.to_string(),
            prompt_tokens: s.prompt_tokens,
            reused_tokens: s.reused_tokens,
            output_tokens: s.run_tokens,
            forced_tokens: 0,
            prefill_ms: s.ms,
            decode_ms: 0.0,
            mask_ms: 0.0,
            total_ms,
            stop: "scored".into(),
        }
    }

    /// Whether this call begins a new decision, after a call of role `previous`: a decision is a
    /// done check (where `done` may be answered), the call that proposes a node (a decomposition,
    /// or `choose`: the likeliest of whole answers, as the root sets its goal lines, after its
    /// `calibrate` baseline where there is one), and the calls that judge or score the proposal.
    /// Latency "per node" is per decision.
    pub fn starts_decision(&self, previous: Option<&str>) -> bool {
        match self.role {
            "done_check" => true,
            "calibrate" | "decompose" | "flat" => previous != Some("done_check"),
            "choose" => !matches!(previous, Some("done_check" | "calibrate")),
            _ => previous.is_none(),
        }
    }

    /// One run's calls merged decision by decision (see [`CallRecord::starts_decision`]): each
    /// keeps the role and node of the call that opened it, with the tokens and milliseconds of
    /// all its calls summed. Merging by the calls' node instead would charge a parent with all its
    /// children's proposals.
    pub fn decisions(calls: &[CallRecord]) -> Vec<CallRecord> {
        let mut out: Vec<CallRecord> = Vec::new();
        let mut previous = None;
        for c in calls {
            match out.last_mut() {
                Some(m) if !c.starts_decision(previous) => {
                    m.prompt_tokens += c.prompt_tokens;
                    m.reused_tokens += c.reused_tokens;
                    m.output_tokens += c.output_tokens;
                    m.forced_tokens += c.forced_tokens;
                    m.prefill_ms += c.prefill_ms;
                    m.decode_ms += c.decode_ms;
                    m.mask_ms += c.mask_ms;
                    m.total_ms += c.total_ms;
                }
                _ => out.push(c.clone()),
            }
            previous = Some(c.role);
        }
        out
    }

    /// The record of one generation: its tokens and timings as the engine reported them.
    pub fn of(
        role: &'static str,
        node: usize,
        prompt_hash: String,
        g: &crate::llm::engine::Generation,
        total_ms: f64,
    ) -> CallRecord {
        CallRecord {
            role,
            node,
            prompt_hash,
            output: g.text.clone(),
            prompt_tokens: g.prompt_tokens,
            reused_tokens: g.reused_tokens,
            output_tokens: g.tokens.len(),
            forced_tokens: g.forced_tokens,
            prefill_ms: g.timings.prefill_ms,
            decode_ms: g.timings.decode_ms,
            mask_ms: g.timings.mask_us.iter().sum::<f64>() / 1e3,
            total_ms,
            stop: format!("{:?}", g.stop).to_lowercase(),
        }
    }
}

/// Counters of one run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PlanStats {
    pub llm_calls: usize,
    pub prompt_tokens: usize,
    pub reused_tokens: usize,
    pub output_tokens: usize,
    pub forced_tokens: usize,
    /// Children rejected by the model, by the symbolic check, or failed in execution.
    pub replans: usize,
    pub failed_executions: usize,
    /// *execute* verdicts the symbolic check turned into replans.
    pub symbolic_rejections: usize,
    pub abandoned: usize,
    /// Actions sent to the executor.
    pub actions: usize,
    pub wall_ms: f64,
    pub calls: Vec<CallRecord>,
    /// How the prompts' shared beginning got into the model's cache before the first call (none:
    /// the first call computed it, or no model ran).
    pub warm: Option<crate::llm::engine::Warm>,
    /// The task and its context read into the cache after it, before the first node (none: the
    /// first call read them).
    pub read: Option<crate::llm::engine::Warm>,
}

impl PlanStats {
    /// Share of prompt tokens whose KV cache was reused.
    pub fn reuse_rate(&self) -> f64 {
        if self.prompt_tokens == 0 {
            0.0
        } else {
            self.reused_tokens as f64 / self.prompt_tokens as f64
        }
    }
}

/// The result of a run.
#[derive(Clone, Debug)]
pub struct PlanOutcome {
    pub tree: SubgoalTree,
    /// Actions sent to the executor, in order, that did not fail (ok or skipped).
    pub executed: Vec<Action>,
    pub stop: StopCause,
    pub stats: PlanStats,
}

impl PlannerConfig {
    /// The settings as JSON (the trace header; [`PlannerConfig::from_json`] reads it back for replay).
    pub fn to_json(&self) -> Value {
        json!({
            "kind": self.kind.name(),
            "strength": self.strength,
            "budgets": self.budgets,
            "symbolic_check": self.symbolic_check,
            "max_tokens": self.gen.max_tokens,
            "sampling": self.gen.sampling,
            "reuse_prefix": self.gen.reuse_prefix,
            "random_seed": self.random_seed,
            "random_actions": self.random_actions,
            "random_steps": self.random_steps,
            "random_lines": self.random_lines,
            "subgoal_focus": self.subgoal_focus,
            "goal_subgoals": self.goal_subgoals,
            "target_subgoals": self.target_subgoals,
            "target_steps": self.target_steps,
            "single_step_lines": self.single_step_lines,
            "oracle_stop": self.oracle_stop,
            "judge_actions": self.judge_actions,
            "fresh_steps": self.fresh_steps,
            "report_changes": self.report_changes,
            "protect_changes": self.protect_changes,
            "skip_idle": self.skip_idle,
            "keep_goals": self.keep_goals,
            "done_at": self.done_at,
            "lines_done_at": self.lines_done_at,
            "show_effects": self.show_effects,
            "infer_goals": self.infer_goals,
            "toward_lines": self.toward_lines,
            "all_verb_lines": self.all_verb_lines,
            "named_lines": self.named_lines,
            "said_lines": self.said_lines,
            "skip_held_lines": self.skip_held_lines,
            "calibrate_lines": self.calibrate_lines,
            "choose": self.choose.name(),
            "excluded_verbs": self.excluded_verbs.iter().map(|v| v.name()).collect::<Vec<_>>(),
            "observe_budget": self.observe_budget,
            "subgoal_chars": self.subgoal_chars,
            "reason_chars": self.reason_chars,
        })
    }

    /// Reads [`PlannerConfig::to_json`]'s output; missing fields keep their defaults (the
    /// goal-line rules, newer than some traces, take the value those traces ran with).
    pub fn from_json(v: &Value) -> Result<PlannerConfig, String> {
        let mut c = PlannerConfig::default();
        let usize_of = |v: &Value, k: &str| -> Result<Option<usize>, String> {
            match v.get(k) {
                None | Some(Value::Null) => Ok(None),
                Some(x) => {
                    x.as_u64().map(|n| Some(n as usize)).ok_or_else(|| format!("settings.{k}: not a number: {x}"))
                }
            }
        };
        if let Some(k) = v.get("kind").and_then(Value::as_str) {
            c.kind = k.parse()?;
        }
        if let Some(s) = v.get("strength").and_then(Value::as_str) {
            c.strength = s.parse().map_err(|e: crate::grammar::UnknownStrength| e.to_string())?;
        }
        if let Some(b) = v.get("budgets") {
            let d = Budgets::default();
            c.budgets = Budgets {
                max_depth: usize_of(b, "max_depth")?.unwrap_or(d.max_depth),
                max_children: usize_of(b, "max_children")?.unwrap_or(d.max_children),
                max_replans: usize_of(b, "max_replans")?.unwrap_or(d.max_replans),
                max_llm_calls: usize_of(b, "max_llm_calls")?.unwrap_or(d.max_llm_calls),
                max_actions: usize_of(b, "max_actions")?.unwrap_or(d.max_actions),
                deadline: match b.get("deadline").and_then(Value::as_f64) {
                    Some(s) => Some(
                        Duration::try_from_secs_f64(s)
                            .map_err(|_| format!("budgets.deadline: {s} is not a number of seconds of 0 or more"))?,
                    ),
                    None => None,
                },
            };
        }
        if let Some(x) = v.get("symbolic_check").and_then(Value::as_bool) {
            c.symbolic_check = x;
        }
        if let Some(n) = usize_of(v, "max_tokens")? {
            c.gen.max_tokens = n;
        }
        if let Some(s) = v.get("sampling") {
            c.gen.sampling =
                serde_json::from_value::<Sampling>(s.clone()).map_err(|e| format!("settings.sampling: {e}"))?;
        }
        if let Some(x) = v.get("reuse_prefix").and_then(Value::as_bool) {
            c.gen.reuse_prefix = x;
        }
        if let Some(n) = v.get("random_seed").and_then(Value::as_u64) {
            c.random_seed = n;
        }
        if let Some(n) = usize_of(v, "random_actions")? {
            c.random_actions = n;
        }
        if let Some(n) = usize_of(v, "random_steps")? {
            c.random_steps = n;
        }
        if let Some(n) = usize_of(v, "random_lines")? {
            c.random_lines = n;
        }
        if let Some(x) = v.get("oracle_stop").and_then(Value::as_bool) {
            c.oracle_stop = x;
        }
        // Traces written before these settings existed ran with them as shown.
        c.judge_actions = v.get("judge_actions").and_then(Value::as_bool).unwrap_or(true);
        c.fresh_steps = v.get("fresh_steps").and_then(Value::as_bool).unwrap_or(false);
        c.subgoal_focus = v.get("subgoal_focus").and_then(Value::as_bool).unwrap_or(false);
        c.goal_subgoals = v.get("goal_subgoals").and_then(Value::as_bool).unwrap_or(false);
        c.target_subgoals = v.get("target_subgoals").and_then(Value::as_bool).unwrap_or(false);
        c.target_steps = v.get("target_steps").and_then(Value::as_bool).unwrap_or(false);
        c.single_step_lines = v.get("single_step_lines").and_then(Value::as_bool).unwrap_or(false);
        c.report_changes = v.get("report_changes").and_then(Value::as_bool).unwrap_or(false);
        c.protect_changes = v.get("protect_changes").and_then(Value::as_bool).unwrap_or(false);
        c.keep_goals = v.get("keep_goals").and_then(Value::as_bool).unwrap_or(false);
        c.skip_idle = v.get("skip_idle").and_then(Value::as_bool).unwrap_or(false);
        c.done_at = v.get("done_at").and_then(Value::as_f64);
        c.lines_done_at = v.get("lines_done_at").and_then(Value::as_f64);
        c.show_effects = v.get("show_effects").and_then(Value::as_bool).unwrap_or(false);
        c.infer_goals = v.get("infer_goals").and_then(Value::as_bool).unwrap_or(false);
        // (traces written before the rule have no key: they ran without it)
        c.toward_lines = v.get("toward_lines").and_then(Value::as_bool).unwrap_or(false);
        c.all_verb_lines = v.get("all_verb_lines").and_then(Value::as_bool).unwrap_or(true);
        c.named_lines = v.get("named_lines").and_then(Value::as_bool).unwrap_or(false);
        c.said_lines = v.get("said_lines").and_then(Value::as_bool).unwrap_or(false);
        c.skip_held_lines = v.get("skip_held_lines").and_then(Value::as_bool).unwrap_or(false);
        c.calibrate_lines = v.get("calibrate_lines").and_then(Value::as_bool).unwrap_or(false);
        c.choose = match v.get("choose").and_then(Value::as_str) {
            None => ActionChoice::Generate,
            Some(s) => s.parse()?,
        };
        if let Some(list) = v.get("excluded_verbs").and_then(Value::as_array) {
            c.excluded_verbs = list
                .iter()
                .map(|x| {
                    let name = x.as_str().unwrap_or_default();
                    name.parse::<Verb>().map_err(|_| format!("settings.excluded_verbs: unknown action {x}"))
                })
                .collect::<Result<_, _>>()?;
        }
        if let Some(n) = usize_of(v, "observe_budget")? {
            c.observe_budget = n;
        }
        if let Some(n) = usize_of(v, "subgoal_chars")? {
            c.subgoal_chars = n;
        }
        if let Some(n) = usize_of(v, "reason_chars")? {
            c.reason_chars = n;
        }
        Ok(c)
    }
}

/// Runs a planner of any kind on `req` against `env`, writing the trace as it goes: a `header` event
/// (settings, request, executor, first observation, and whatever the caller put in
/// [`TraceWriter::set_meta`]: model, scene), the run's events, and an `end` event.
pub fn plan(
    model: &mut dyn Generate,
    env: &mut dyn Env,
    req: &PlanRequest,
    cfg: &PlannerConfig,
    trace: &mut TraceWriter,
) -> PlanOutcome {
    let header = json!({
        "version": env!("CARGO_PKG_VERSION"),
        "meta": trace.meta().clone(),
        "settings": cfg.to_json(),
        "request": {"instruction": req.instruction, "context": req.context, "focus": req.focus,
                    "subgoals": req.subgoals, "kept": req.kept, "named_verbs": req.named_verbs,
                    "oracle": req.oracle.is_some() && cfg.oracle_stop},
        "env": env.name(),
        "observation": env.observe(&[], cfg.observe_budget),
    });
    trace.event("header", header);
    let out = match cfg.kind {
        PlannerKind::Step | PlannerKind::NoTree | PlannerKind::NoSubgoalTree => {
            planner::run_tree(model, env, req, cfg, trace)
        }
        PlannerKind::Flat => baseline::flat(model, env, req, cfg, trace),
        // With offered subgoals (or goals to set), the random chooser walks the same tree as the
        // model (one subgoal at a time, each node's actions over its own objects); without, it
        // draws over the whole focus.
        PlannerKind::Random if !req.subgoals.is_empty() || cfg.infer_goals => {
            planner::run_tree(model, env, req, cfg, trace)
        }
        PlannerKind::Random => baseline::random(env, req, cfg, trace),
    };
    trace.event(
        "end",
        json!({
            "stop": out.stop,
            "executed": out.executed.iter().map(|a| a.to_string()).collect::<Vec<_>>(),
            "nodes": out.tree.len(),
            "llm_calls": out.stats.llm_calls,
            "prompt_tokens": out.stats.prompt_tokens,
            "reused_tokens": out.stats.reused_tokens,
            "output_tokens": out.stats.output_tokens,
            "replans": out.stats.replans,
            "failed_executions": out.stats.failed_executions,
            "symbolic_rejections": out.stats.symbolic_rejections,
            "actions": out.stats.actions,
            "wall_ms": out.stats.wall_ms,
            "tree": out.tree.to_json(),
        }),
    );
    out
}
#[cfg(test)]
mod tests;
