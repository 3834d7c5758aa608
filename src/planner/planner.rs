//! Algorithm 1: grow the subgoal tree depth first, left to right, executing each leaf as soon as it is
//! judged to be an action.
//!
//! At a node the decomposition model (`decompose`) proposes the next child from the node's goal, the
//! previous sibling and how it ended, the observation, and the last rejected attempt; `done`
//! completes the node. The termination model (`terminate`) judges the child: *execute* (after the
//! symbolic check, in the executor; a failure makes the node propose again with the executor's
//! message), *decompose* (recurse into the child), or *replan* (the node proposes again with the
//! cause and reason). A node whose replans or children run over budget is abandoned and its parent
//! goes on; at the root that ends the run, named by the budget. Global budgets (LLM calls, actions,
//! deadline) end the run wherever it is. This file holds the loop and the run's state; the two
//! models and the rules that narrow their choices (`rules`) are beside it.

use std::time::Instant;

use rand::rngs::StdRng;
use rand::SeedableRng;
use serde_json::json;
use sha2::{Digest, Sha256};

use super::decompose::{with_holders, Proposed};
use super::goals::{self, Goals, Wording};
use super::env::{Env, Outcome};
use super::prompt::{NodeView, Prompter, StateLog};
use super::rules::new_facts;
use super::terminate::echoes;
use super::trace::TraceWriter;
use super::tree::{NodeId, Status, SubgoalTree};
use super::{CallRecord, PlanOutcome, PlanRequest, PlanStats, PlannerConfig, PlannerKind, StopCause};
use crate::action::{Action, Verb};
use crate::grammar::{ActionSet, Proposal, Verdict};
use crate::llm::engine::{Generate, Prompt, StopReason, Warm, WarmSource};
use crate::llm::LlmError;
use crate::world::{Fact, World};

/// How the context of each decision is made (the paper's ablations).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContextMode {
    /// Parent + previous sibling (STEP).
    Step,
    /// Parent + every executed action.
    NoTree,
    /// Root + every executed action; the model proposes actions only.
    NoSubgoalTree,
}

impl ContextMode {
    pub fn of(kind: PlannerKind) -> ContextMode {
        match kind {
            PlannerKind::NoTree => ContextMode::NoTree,
            PlannerKind::NoSubgoalTree => ContextMode::NoSubgoalTree,
            _ => ContextMode::Step,
        }
    }
}

/// How a node's expansion ended.
pub(super) enum End {
    /// The model said `done` for it.
    Complete,
    /// A per-node budget ran out (`replans` or `children`).
    Abandoned(&'static str),
}

/// What a node's expansion keeps between its children.
#[derive(Default)]
pub(super) struct NodeLoop {
    /// The previous accepted child, with how it ended.
    pub(super) previous: Option<String>,
    /// The last rejected or failed attempt, with why.
    pub(super) rejected: Option<String>,
    /// Actions rejected since the state last changed (not proposed again until it does).
    pub(super) refused: Vec<Action>,
    /// Actions this node has executed, in order.
    pub(super) done_here: Vec<Action>,
    pub(super) replans: usize,
    pub(super) children: usize,
    pub(super) accepted: usize,
    /// After a subgoal of this node is rejected, given up or echoes the node's own goal, the node
    /// proposes actions only until one runs: a greedy model otherwise writes the same subgoal again.
    pub(super) concrete_only: bool,
    /// The offered subgoal lines (goal lines or target actions) already taken, done or given up.
    pub(super) tried: Vec<String>,
    /// Actions the run had executed when this node's expansion began (the random chooser counts
    /// the steps taken below a node from it).
    pub(super) start_actions: usize,
    /// What this node's steps changed, kept from being undone by its later steps (see
    /// `PlannerConfig::protect_changes`).
    pub(super) established: Vec<Fact>,
    /// The root's goal lines whose fact held when they were done, and those offered again since,
    /// once for each time (see [`Run::undone_lines`]).
    pub(super) met_lines: Vec<String>,
    pub(super) reoffered: Vec<String>,
}

impl NodeLoop {
    /// After the step `text` (action `a`) went to the executor: it ran (`Ok(summary)`), or the
    /// symbolic check or the executor rejected it (`Err(reason)`) and the node proposes again.
    fn executed(&mut self, text: &str, a: &Action, r: Result<String, String>, stats: &mut PlanStats) {
        match r {
            Ok(summary) => {
                self.refused.clear();
                self.done_here.push(a.clone());
                self.accepted += 1;
                self.concrete_only = false;
                self.previous = Some(format!("{text}: {summary}"));
                self.rejected = None;
            }
            Err(reason) => {
                self.refused.push(a.clone());
                self.replans += 1;
                stats.replans += 1;
                self.rejected = Some(rejection(text, &reason));
            }
        }
    }
}

/// One run's state.
pub(crate) struct Run<'a> {
    pub(super) model: &'a mut dyn Generate,
    pub(super) env: &'a mut dyn Env,
    pub(super) req: &'a PlanRequest,
    pub(super) cfg: &'a PlannerConfig,
    pub(super) trace: &'a mut TraceWriter,
    pub(super) mode: ContextMode,
    pub(super) prompter: Prompter,
    /// The prompts without the instruction, where the root's lines are calibrated against them.
    pub(super) uninstructed: Option<Prompter>,
    pub(super) focus: Vec<u32>,
    pub(super) tree: SubgoalTree,
    pub(super) stats: PlanStats,
    pub(super) executed: Vec<Action>,
    pub(super) start: Instant,
    /// The `random` planner's chooser, in place of the model (see [`Run::draw`]).
    pub(super) rng: Option<StdRng>,
    /// `focus` is every object of the scene (nothing narrowed it), so the root narrows it itself.
    pub(super) focus_is_scene: bool,
    /// What the last executed action changed among its objects: the facts that hold after it and
    /// did not before.
    pub(super) last_change: Vec<Fact>,
    /// The root's goal lines: shown by the protocol, or candidates the model chooses among.
    pub(super) goals: Goals,
    /// The state at the start (in the task part of every prompt) and what changed since.
    pub(super) states: StateLog,
    /// Over a whole scene, the objects the instruction names ([`goals::instruction_objects`]).
    pub(super) root_objects: Vec<u32>,
    /// Those and what holds them, with `subgoal_focus`: the root's focus, listed first in every
    /// observation (empty: the whole focus, in id order).
    pub(super) root_view: Vec<u32>,
    /// Over a whole scene, where every verb the instruction says takes no object ("stand up",
    /// "get up from the chair"), those verbs: the root's only steps (see `Run::menu`).
    pub(super) bare_verbs: Vec<Verb>,
    /// Over a whole scene, where the instruction names no object but verbs that ask something of
    /// theirs ("have a drink"), those verbs; `root_objects` are then the objects that afford them.
    pub(super) afforded_by: Vec<Verb>,
    /// Over a whole scene, where every verb the instruction asks of its things is one none of them
    /// affords ("open the apple"), what the user is told ([`goals::unafforded`]): the root is then
    /// offered no step.
    pub(super) cannot: Option<String>,
}

/// Runs the tree planner (kinds `step`, `no-tree`, `no-subgoal-tree`).
pub(crate) fn run_tree(
    model: &mut dyn Generate,
    env: &mut dyn Env,
    req: &PlanRequest,
    cfg: &PlannerConfig,
    trace: &mut TraceWriter,
) -> PlanOutcome {
    let focus = match env.world() {
        Some(w) => req.focus_in(w),
        None => req.focus.clone(),
    };
    let focus_is_scene = env.world().is_some_and(|w| {
        let n = w.nodes().filter(|n| n.id != w.character()).count();
        focus.iter().filter(|&&id| id != w.character()).count() >= n
    });
    // Over a whole scene, the objects the instruction names (and what holds them) lead the view,
    // which the budget would otherwise fill with the first objects by id.
    let (mut root_objects, mut root_view, mut read_as, mut afforded) = (Vec::new(), Vec::new(), None, Vec::new());
    if let Some(w) = env.world().filter(|_| focus_is_scene) {
        root_objects = goals::instruction_objects(w, &focus, &req.instruction);
        // One that names what to do but no object ("have a drink") is about the few things that
        // afford it: SmolLM2, free to choose over the whole scene, sat on the chair.
        if root_objects.is_empty() {
            (root_objects, afforded) = goals::afforded_objects(w, &focus, &req.instruction);
        }
        if cfg.subgoal_focus && !root_objects.is_empty() {
            root_view = with_holders(w, &root_objects, &focus);
            let labels = |ids: &[u32]| -> Vec<String> { ids.iter().filter_map(|&id| w.node(id).map(|n| n.label())).collect() };
            let key = if afforded.is_empty() { "named" } else { "afforded" };
            let mut read = json!({key: labels(&root_objects), "holding_them": labels(&root_view[root_objects.len()..])});
            if !afforded.is_empty() {
                read["by_verbs"] = json!(afforded.iter().map(|v| v.name()).collect::<Vec<_>>());
            }
            read_as = Some(read);
        }
    }
    // (SmolLM2 walked to a chair and sat for "stand up" said of a robot standing, and took the
    // chair for "get up from the chair")
    let said: Vec<Verb> = Verb::ALL.iter().copied().filter(|v| goals::names_verb(&req.instruction, *v)).collect();
    // (not "sleep", which is taken lying on a thing: `afforded_objects` found it)
    let bare_verbs = if focus_is_scene && afforded.is_empty() && said.iter().all(|v| v.arity() == 0) { said } else { Vec::new() };
    // (SmolLM2 took the apple in hand for "open the apple", and switched the fridge on for "eat
    // the fridge", and said done)
    let cannot = env
        .world()
        .filter(|_| focus_is_scene && afforded.is_empty())
        .and_then(|w| goals::unafforded(w, &focus, &req.instruction, &root_objects))
        .map(|(_, told)| told);
    let start_state = env.observe(&root_view, cfg.observe_budget);
    let mut run = Run {
        states: StateLog::new(&start_state),
        bare_verbs,
        root_objects,
        afforded_by: afforded,
        cannot,
        root_view,
        focus_is_scene,
        last_change: Vec::new(),
        model,
        env,
        req,
        cfg,
        trace,
        mode: ContextMode::of(cfg.kind),
        prompter: Prompter::new(&req.instruction, req.context.as_deref(), &start_state),
        uninstructed: None,
        focus,
        tree: SubgoalTree::new(&req.instruction),
        stats: PlanStats::default(),
        executed: Vec::new(),
        start: Instant::now(),
        rng: (cfg.kind == PlannerKind::Random).then(|| StdRng::seed_from_u64(cfg.random_seed)),
        goals: Goals::shown(req),
    };
    run.node_event(0);
    if let Some(objects) = read_as {
        // What the planner took the instruction to be about: a user can see a misreading at once.
        run.trace.event("instruction_objects", objects);
    }
    if let Some(why) = run.cannot.clone() {
        run.trace.event("goal_candidates", json!({"lines": [], "why": why}));
    }
    let root = run.tree.root();
    run.infer_goals();
    run.warm();
    run.set_status(root, Status::Decomposing, "the instruction");
    let stop = match run.expand(root, None) {
        Ok(End::Complete) => {
            let lines = !run.goals.lines.is_empty() && run.mode != ContextMode::NoSubgoalTree;
            let why = match (lines, run.goals.inferred) {
                (true, false) => "every offered goal line was taken",
                (true, true) => "the model said done after setting its goals",
                (false, _) => "the model said done",
            };
            // (offered no step, it is done without a call: the root says why)
            let why = match &run.cannot {
                Some(cannot) => format!("nothing to do: {cannot}"),
                None => why.to_string(),
            };
            run.set_status(root, Status::Executed, why);
            StopCause::Done
        }
        Ok(End::Abandoned(budget)) => {
            run.set_status(root, Status::Abandoned, format!("{budget} budget"));
            StopCause::Budget(budget)
        }
        Err(stop) => stop,
    };
    run.stats.wall_ms = run.start.elapsed().as_secs_f64() * 1e3;
    PlanOutcome { tree: run.tree, executed: run.executed, stop, stats: run.stats }
}

impl Run<'_> {
    /// With `infer_goals`, where the protocol shows no goals: the root's subgoals become the lines
    /// the world can state about its objects, for the model to choose among (see `goals`). Left
    /// as it is without a world, over too many objects, or when nothing can be stated.
    fn infer_goals(&mut self) {
        if !self.cfg.infer_goals || !self.goals.lines.is_empty() || self.mode == ContextMode::NoSubgoalTree {
            return;
        }
        // (words that ask only what cannot be done are told so, `run_tree`, and set no goal)
        if self.cannot.is_some() {
            return;
        }
        let Ok(focus) = self.node_focus(self.tree.root()) else { return };
        let Some(w) = self.env.world() else { return };
        let instruction = self.tree.node(self.tree.root()).text.clone();
        // An instruction that names nothing of a whole scene ("do the chores") would have the
        // model score a line for every state of every object: about a minute of prefill on the
        // demo kitchen, for a choice nothing in the instruction informs. The root proposes steps.
        // (So too where every verb it says takes no object: those verbs are its steps.)
        if self.focus_is_scene && (self.root_objects.is_empty() || !self.bare_verbs.is_empty()) {
            let mut why = String::from(match self.root_objects.is_empty() {
                true => "the instruction names no object of the scene",
                false => "the instruction says no verb of its objects",
            });
            // (a verb it says that takes no object is its steps; one that cannot run now is
            // told, not left as an empty plan: "stand up" said of a robot standing)
            for &v in &self.bare_verbs {
                let Ok(step) = Action::new(v, vec![]) else { continue };
                match w.why_not(&step) {
                    Some(f) => why.push_str(&format!("; its words say {step}: {}", f.message)),
                    None => why.push_str(&format!("; its words say {step}")),
                }
            }
            self.trace.event("goal_candidates", json!({"lines": [], "why": why}));
            return;
        }
        let objects = focus.iter().filter(|&&id| id != w.character()).count();
        if objects > goals::MAX_GOAL_OBJECTS {
            self.trace.event("goal_candidates", json!({"lines": [], "why": format!(
                "{objects} objects: more than {} to set goals over", goals::MAX_GOAL_OBJECTS)}));
            return;
        }
        let named = (!self.cfg.all_verb_lines).then_some(instruction.as_str());
        // (one that names no object but what to do is about the objects that afford it, `run_tree`,
        // and asks only what it does to them)
        let afforded = self.cfg.named_lines && !self.afforded_by.is_empty();
        let about = match (self.cfg.named_lines, afforded) {
            (true, true) => self.root_objects.clone(),
            (true, false) => goals::instruction_objects(w, &focus, &instruction),
            (false, _) => Vec::new(),
        };
        let wording = if self.cfg.said_lines { Wording::of(w, &focus, &instruction) } else { Wording::default() };
        let said = self.cfg.said_lines.then_some(&wording);
        let (mut candidates, mut said) = goals::candidates(w, &focus, &self.cfg.excluded_verbs, named, &about, said);
        if afforded {
            (candidates, said) = goals::made_by_verbs(w, &about, &self.afforded_by, candidates, said);
        }
        if candidates.is_empty() {
            return;
        }
        self.goals = Goals::inferred(w, candidates, said, about, wording);
        self.prompter = self.prompter.clone().setting_goals();
        self.uninstructed = self.cfg.calibrate_lines.then(|| self.prompter.without_instruction());
        // (with the things the words say, a group each: the root takes a line of each before it
        // may be done)
        // (and which of those hold already: a user asking for what is so is told, not shown an
        // empty plan alone)
        let holding: Vec<&String> =
            self.goals.said.iter().flatten().filter(|l| self.goals.holds_at_start(l, w)).collect();
        // (and which wait, at the start, for a line of what the words say before them: the
        // order they give, `Goals::waits_for_a_thing_said_first`)
        let lines = &self.goals.lines;
        let waiting: Vec<&String> = lines.iter().filter(|l| self.goals.waits_for_a_thing_said_first(l, w, lines)).collect();
        self.trace.event("goal_candidates", json!({"lines": lines, "said": self.goals.said, "holding": holding, "waiting": waiting}));
    }

    /// Puts the prompts' shared beginning in the model's cache before the first call: the system
    /// message (read from its snapshot where one is kept; see `llm::prefix`), then the task and
    /// its context, which every prompt of the run begins its user turn with. Their times are
    /// reported on their own (`warm` and `read` events), so node latencies are the nodes' own;
    /// what the model computes is the same either way. A failure here is not the run's: the first
    /// call computes the prefix, or meets the same error and handles it as calls do.
    fn warm(&mut self) {
        if self.cfg.kind == PlannerKind::Random {
            return;
        }
        let prefix = self.prompter.prefix();
        let warm = self.model.warm(&prefix);
        self.stats.warm = self.prepared("warm", warm, |w| json!(w));
        let read = self.model.read(&prefix, self.prompter.task());
        self.stats.read = self.prepared("read", read, |r| json!({"tokens": r.tokens, "ms": r.ms}));
    }

    /// Traces one preparation of the cache (`warm`: the system message; `read`: the task) and
    /// returns it for the stats, unless the model had nothing to prepare. A failure is traced and
    /// costs nothing else: the first call then computes what it needs.
    fn prepared(
        &mut self,
        event: &str,
        done: crate::llm::Result<Warm>,
        fields: impl Fn(&Warm) -> serde_json::Value,
    ) -> Option<Warm> {
        match done {
            Ok(w) if w.source == WarmSource::None => None,
            Ok(w) => {
                self.trace.event(event, fields(&w));
                Some(w)
            }
            Err(e) => {
                self.trace.event(event, json!({"error": e.to_string()}));
                None
            }
        }
    }

    fn node_event(&mut self, id: NodeId) {
        let n = self.tree.node(id);
        self.trace.event(
            "node",
            json!({"node": id, "parent": n.parent, "depth": n.depth, "text": n.text,
                   "action": n.action.as_ref().map(|a| a.to_string())}),
        );
    }

    pub(super) fn set_status(&mut self, id: NodeId, status: Status, why: impl Into<String>) {
        let why = why.into();
        let mut fields = json!({"node": id, "status": status.name(), "why": why});
        if let Status::Mapped { action } = &status {
            fields["action"] = json!(action.to_string());
        }
        self.tree.set_status(id, status, why);
        self.trace.event("status", fields);
    }

    /// The global budgets, checked before every model call and every action.
    pub(super) fn check_global(&self) -> Result<(), StopCause> {
        let b = &self.cfg.budgets;
        if let Some(d) = b.deadline {
            if self.start.elapsed() >= d {
                return Err(StopCause::Budget("deadline"));
            }
        }
        if self.stats.llm_calls >= b.max_llm_calls {
            return Err(StopCause::Budget("llm_calls"));
        }
        Ok(())
    }

    pub(super) fn world(&self) -> Result<&World, StopCause> {
        self.env.world().ok_or_else(|| {
            StopCause::Error(format!(
                "the executor '{}' has no world model, and the grammars are built from one",
                self.env.name()
            ))
        })
    }

    /// The actions a decision at `node` may write: the strength's set over the node's objects.
    pub(super) fn action_set(&self, node: NodeId) -> Result<ActionSet, StopCause> {
        Ok(self.cfg.action_set(self.cfg.strength, self.world()?, &self.node_focus(node)?))
    }

    /// The context of a decision at `node`.
    pub(super) fn view(&mut self, node: NodeId, previous: Option<&str>, rejected: Option<&str>) -> NodeView {
        // The view as bounded at the start: the objects it leaves out (the building's floors and
        // walls first) are left out of the changes too, as they were of the whole state.
        let observation =
            self.states.since(&self.env.observe(&self.root_view, self.cfg.observe_budget), self.cfg.observe_budget);
        let history = || Some(self.executed.iter().map(|a| a.to_string()).collect());
        // (a line of a plural name, in the words of the object it has gone on to)
        let text = &self.tree.node(node).text;
        let goal = self.env.world().map_or_else(|| text.clone(), |w| self.goals.asks_now(text, w));
        match self.mode {
            ContextMode::Step => NodeView {
                observation,
                goal,
                previous: previous.map(str::to_string),
                history: None,
                rejected: rejected.map(str::to_string),
                blocked: None,
                options: None,
            },
            ContextMode::NoTree => NodeView {
                observation,
                goal,
                previous: None,
                history: history(),
                rejected: rejected.map(str::to_string),
                blocked: None,
                options: None,
            },
            ContextMode::NoSubgoalTree => NodeView {
                observation,
                goal: self.req.instruction.clone(),
                previous: None,
                history: history(),
                rejected: rejected.map(str::to_string),
                blocked: None,
                options: None,
            },
        }
    }

    /// One model call under `lark`. `Ok(None)`: the grammar was not complete within the token cap,
    /// which the caller treats as a rejected attempt.
    pub(super) fn call(
        &mut self,
        role: &'static str,
        node: NodeId,
        prompt: &Prompt,
        lark: &str,
    ) -> Result<Option<String>, StopCause> {
        self.check_global()?;
        let hash = prompt_hash(prompt, lark);
        log_prompt(role, node, prompt);
        tracing::trace!("{role} grammar at node {node}:\n{lark}");
        let t = Instant::now();
        let r = self.model.generate(prompt, Some(lark), &self.cfg.gen);
        let total_ms = t.elapsed().as_secs_f64() * 1e3;
        self.stats.llm_calls += 1;
        let g = match r {
            Ok(g) => g,
            Err(e) if is_token_budget(&e) => {
                self.trace.event(
                    "call_error",
                    json!({"role": role, "node": node, "prompt_hash": hash,
                    "kind": "token_budget", "error": e.to_string()}),
                );
                return Ok(None);
            }
            Err(e) => {
                self.trace.event(
                    "call_error",
                    json!({"role": role, "node": node, "prompt_hash": hash,
                    "kind": "error", "error": e.to_string()}),
                );
                return Err(StopCause::Error(format!("{role} call at node {node}: {e}")));
            }
        };
        if g.stop == StopReason::Context {
            self.trace.event(
                "call_error",
                json!({"role": role, "node": node, "prompt_hash": hash,
                "kind": "context", "error": "the model's context is full", "so_far": g.text}),
            );
            return Err(StopCause::Error(format!(
                "{role} call at node {node}: the model's context filled before the answer was complete"
            )));
        }
        self.record(CallRecord::of(role, node, hash, &g, total_ms));
        Ok(Some(g.text))
    }

    /// Counts a model call's tokens, traces it and files it under its node.
    pub(super) fn record(&mut self, rec: CallRecord) {
        self.stats.prompt_tokens += rec.prompt_tokens;
        self.stats.reused_tokens += rec.reused_tokens;
        self.stats.output_tokens += rec.output_tokens;
        self.stats.forced_tokens += rec.forced_tokens;
        self.trace.event("call", serde_json::to_value(&rec).unwrap_or_default());
        self.tree.add_call(rec.node, self.stats.calls.len());
        self.stats.calls.push(rec);
    }

    /// Expands `node` until the model says `done` for it or a per-node budget abandons it. A target
    /// subgoal (`target`: its action, see `PlannerConfig::target_subgoals`) is done when that action runs.
    ///
    /// Each turn of the loop makes one child: the decomposition model proposes it (`menu`,
    /// `propose`), the world or the termination model judges it (`judge`), and it is executed,
    /// decomposed (recursively) or replanned.
    fn expand(&mut self, node: NodeId, target: Option<Action>) -> Result<End, StopCause> {
        let depth = self.tree.node(node).depth;
        let budgets = self.cfg.budgets.clone();
        let mut st = NodeLoop { start_actions: self.executed.len(), ..NodeLoop::default() };
        // The root is bounded by the run's budgets (calls, actions, deadline) alone: abandoning it
        // ends the run, and a plan needs more steps than a subgoal.
        let is_root = node == self.tree.root();
        // With `single_step_lines`, a node under an offered goal line is complete once one step (an
        // action, or a target whose action ran) has been accepted.
        let one_step = self.under_offered(node) && self.cfg.single_step_lines;
        // A line the model set itself (`infer_goals`) says what completes it: its state or relation
        // holding, or a step of its verb having run. (A shown goal line's completion stays the
        // model's `done`: the world checking the task's own goals would be an oracle.)
        let mut set_line = if self.under_offered(node) { self.goals.meaning(&self.tree.node(node).text).cloned() } else { None };
        let set_verb = match &set_line {
            Some(goals::Meaning::Verb(v)) => Some(*v),
            _ => None,
        };
        // Whether a step that ran completes this node.
        let completes = |a: &Action| target.as_ref() == Some(a) || one_step || set_verb == Some(a.verb);
        loop {
            if !is_root && st.replans > budgets.max_replans {
                return Ok(End::Abandoned("replans"));
            }
            if !is_root && st.children >= budgets.max_children {
                return Ok(End::Abandoned("children"));
            }
            if let (Some(goals::Meaning::Fact(f)), Some(w)) = (&set_line, self.env.world()) {
                if w.holds(f) {
                    // (a line of a plural name goes on to the next of its objects)
                    let text = self.tree.node(node).text.clone();
                    if self.goals.advance(&text, w) {
                        set_line = self.goals.meaning(&text).cloned();
                        // (nothing is done toward the next one yet: no `done` before a step)
                        st.accepted = 0;
                        let of = match &set_line {
                            Some(goals::Meaning::Fact(Fact::State { id, .. } | Fact::Edge { from: id, .. })) => Some(*id),
                            _ => None,
                        };
                        let now = self.goals.asks_now(&text, w);
                        self.trace.event("line_next", json!({"node": node, "line": text, "object": of, "now": now}));
                        continue;
                    }
                    self.trace.event("line_holds", json!({"node": node, "line": text}));
                    return Ok(End::Complete);
                }
            }
            self.check_global()?;
            let mut view = self.view(node, st.previous.as_deref(), st.rejected.as_deref());
            if let Some(t) = &target {
                view.blocked = self.world()?.why_not(t).map(|f| f.message);
            }
            // The decomposition model: what it may write here, and what it writes.
            let menu = match self.menu(node, target.as_ref(), &mut st, &mut view)? {
                Ok(menu) => menu,
                Err(end) => return Ok(end),
            };
            let (text, proposal) = match self.propose(node, &menu, &view, &st)? {
                Proposed::Text(text, proposal) => (text, proposal),
                Proposed::Nothing => return Ok(End::Abandoned("random_steps")),
                Proposed::TokenLimit => {
                    st.replans += 1;
                    self.stats.replans += 1;
                    st.rejected = Some("(no answer within the token limit)".into());
                    continue;
                }
            };
            // (`target_child`: a target, a subgoal named by its action)
            let (child_text, child_action, target_child) = match &proposal {
                Proposal::Done => return Ok(End::Complete),
                Proposal::Subgoal(s) => (s.clone(), None, None),
                Proposal::Action(a) if menu.targets.contains(a) => (a.to_string(), None, Some(a.clone())),
                Proposal::Action(a) => (a.to_string(), Some(a.clone()), None),
            };
            let child = self.tree.add_child(node, child_text.clone(), child_action.clone());
            st.children += 1;
            self.node_event(child);
            if child_action.is_none() && self.goals.lines.contains(&child_text) {
                st.tried.push(child_text.clone());
                if is_root {
                    self.goals.take(&child_text);
                }
            }
            // Only free text can echo: a goal line at the root and a target are congruent by
            // construction, even where they repeat the goal's first word ("DRINK" under "Drink",
            // the target "[DRINK] <cup> (1000)" under the line "DRINK").
            let root_line = is_root && self.goals.lines.contains(&child_text);
            let free_text = child_action.is_none() && target_child.is_none() && !root_line;
            if free_text && echoes(&child_text, &self.tree.node(node).text) {
                self.set_status(child, Status::Replanned, "congruence: it repeats its parent's goal");
                st.replans += 1;
                self.stats.replans += 1;
                st.concrete_only = true;
                st.rejected = Some(format!("{child_text}: it repeats the goal; give one action"));
                continue;
            }
            // With the symbolic checks on, the world decides whether a proposed action can run now
            // (affordance and environment): a runnable one is executed without asking the model,
            // a doomed one is rejected with the executor's reason. The model is asked about an action
            // only for congruence, and only with `judge_actions` (a tiny model's congruence verdicts
            // were found to reject nearly every action, copying the prompt's text as the reason).
            if let (Some(a), true, false) = (&child_action, self.cfg.symbolic_check, self.cfg.judge_actions) {
                self.set_status(child, Status::Mapped { action: a.clone() }, "an action (the world checks it)");
                let r = self.execute(child, a)?;
                let ran = r.is_ok();
                st.executed(&child_text, a, r, &mut self.stats);
                if ran {
                    self.establish(&mut st);
                }
                if ran && completes(a) {
                    return Ok(End::Complete);
                }
                continue;
            }

            // An offered goal line is congruent by construction, and whether one action does it is
            // found by decomposing it (a tiny model's verdicts on such lines were found to be
            // replans with made-up reasons); a target is congruent and not runnable now by
            // construction. Both are decomposed without a verdict.
            if target_child.is_some() {
                st.tried.push(child_text.clone());
            }
            let offered_child = child_action.is_none() && (root_line || target_child.is_some());

            // The termination model's verdict on the new child.
            let Some(verdict) = self.judge(child, child_action.as_ref(), depth, &view, &text, offered_child)? else {
                self.set_status(child, Status::Replanned, "no verdict within the token limit");
                st.replans += 1;
                self.stats.replans += 1;
                st.rejected = Some(format!("{child_text}: no verdict within the token limit"));
                continue;
            };
            match verdict {
                Verdict::Replan { cause, reason } => {
                    st.refused.extend(child_action.clone());
                    st.concrete_only |= child_action.is_none();
                    self.set_status(child, Status::Replanned, format!("{cause}: {reason}"));
                    st.replans += 1;
                    self.stats.replans += 1;
                    st.rejected = Some(rejection(&child_text, &reason));
                }
                Verdict::Decompose if depth + 1 >= budgets.max_depth => {
                    // Unreachable under the grammar (decompose is not offered this deep); kept so a
                    // model that ignores grammars still cannot exceed the depth budget.
                    self.set_status(child, Status::Replanned, "depth budget: too deep to decompose");
                    st.replans += 1;
                    self.stats.replans += 1;
                    st.rejected = Some(format!("{child_text}: too vague; propose one action"));
                }
                Verdict::Decompose => {
                    self.set_status(child, Status::Decomposing, "not one action");
                    match self.expand(child, target_child.clone())? {
                        End::Complete => {
                            let stepless = !self.tree.node(child).children.iter().any(|&c| self.tree.node(c).status == Status::Executed);
                            // (Nothing below changes the world: the same answer serves the met lines.)
                            let held = self.met_line_fact(&child_text).is_some();
                            let why = match (stepless, held) {
                                (true, true) => "it already held: nothing to do",
                                (true, false) => "complete without a step",
                                _ => "all its steps are done",
                            };
                            self.set_status(child, Status::Executed, why);
                            st.accepted += 1;
                            // A target's own action ran last: what it changed is said here too.
                            st.previous = Some(match (&target_child, self.change_report()) {
                                (Some(_), Some(change)) => format!("{child_text}: done, {change}"),
                                _ => format!("{child_text}: done"),
                            });
                            if target_child.is_some() {
                                self.establish(&mut st);
                            }
                            if is_root && held {
                                st.met_lines.push(child_text.clone());
                            }
                            st.rejected = None;
                            if one_step || target_child.as_ref().is_some_and(|t| set_verb == Some(t.verb)) {
                                return Ok(End::Complete);
                            }
                        }
                        End::Abandoned(budget) => {
                            self.stats.abandoned += 1;
                            let why = match budget {
                                "unreachable" => "the world names no way to its action from here".to_string(),
                                b => format!("{b} budget"),
                            };
                            self.set_status(child, Status::Abandoned, why);
                            // The parent goes on, told that this step was given up; it counts as a
                            // rejected attempt so a parent cannot abandon children forever.
                            st.replans += 1;
                            st.concrete_only = true;
                            st.previous = Some(format!("{child_text}: given up"));
                            st.rejected = None;
                        }
                    }
                }
                Verdict::Execute(a) => {
                    self.set_status(child, Status::Mapped { action: a.clone() }, "one action");
                    let r = self.execute(child, &a)?;
                    let ran = r.is_ok();
                    st.executed(&child_text, &a, r, &mut self.stats);
                    if ran {
                        self.establish(&mut st);
                    }
                    if ran && completes(&a) {
                        return Ok(End::Complete);
                    }
                }
            }
        }
    }

    /// "now <fact>, …": what the last step changed, in the goal lines' words, when changes are
    /// reported and it changed any.
    pub(super) fn change_report(&self) -> Option<String> {
        let facts = self.last_change_words().filter(|_| self.cfg.report_changes)?;
        Some(format!("now {}", facts.join(", ")))
    }

    /// What the last step changed, in the goal lines' words (`None`: nothing, or no world to say it).
    pub(super) fn last_change_words(&self) -> Option<Vec<String>> {
        let w = self.env.world().filter(|_| !self.last_change.is_empty())?;
        Some(self.last_change.iter().map(|f| w.describe(f)).collect())
    }

    /// The symbolic check, then the executor. `Ok(Ok(summary))`: executed; `Ok(Err(reason))`: the
    /// child was rejected or failed and the parent proposes again.
    fn execute(&mut self, child: NodeId, a: &Action) -> Result<Result<String, String>, StopCause> {
        if let Some(reason) = self.symbolic_check(child, a)? {
            return Ok(Err(reason));
        }
        if self.executed.len() >= self.cfg.budgets.max_actions || self.stats.actions >= self.cfg.budgets.max_actions {
            return Err(StopCause::Budget("actions"));
        }
        self.check_global()?;
        self.stats.actions += 1;
        // What the action changed among its objects, reported in the goal lines' words ("now fridge
        // is OPEN"): the observation in full does not show a tiny model which line just came true.
        let ids: Vec<u32> = a.args.iter().map(|o| o.id).collect();
        let before = self.env.world().map(|w| w.facts_among(&ids));
        let outcome = self.env.execute(a).map_err(|e| {
            self.trace.event("exec_error", json!({"node": child, "action": a.to_string(), "error": e.to_string()}));
            StopCause::Error(format!("executing {a}: {e}"))
        })?;
        self.trace.event("exec", json!({"node": child, "action": a.to_string(), "outcome": outcome}));
        let r = match &outcome {
            Outcome::Ok { .. } | Outcome::Skipped { .. } => {
                self.executed.push(a.clone());
                self.set_status(child, Status::Executed, outcome.summary());
                self.last_change = match (&before, self.env.world()) {
                    (Some(before), Some(w)) => new_facts(w.character(), w.facts_among(&ids), |f| before.contains(f)),
                    _ => Vec::new(),
                };
                if let Some(facts) = self.last_change_words() {
                    self.trace.event("changed", json!({"node": child, "facts": facts}));
                }
                Ok(match (&outcome, self.change_report()) {
                    (Outcome::Skipped { .. }, _) => "ok (it already was so)".to_string(),
                    (Outcome::Ok { observation: Some(o) }, _) => format!("ok, {o}"),
                    (_, Some(change)) => format!("ok, {change}"),
                    _ => "ok".to_string(),
                })
            }
            Outcome::Failed { reason, .. } => {
                self.stats.failed_executions += 1;
                self.set_status(child, Status::Failed, reason.clone());
                Err(reason.clone())
            }
        };
        if self.cfg.oracle_stop {
            if let (Some(oracle), Some(w)) = (&self.req.oracle, self.env.world()) {
                if oracle(w) {
                    return Err(StopCause::Oracle);
                }
            }
        }
        Ok(r)
    }
}

/// "step: why", without repeating the step when the reason already names it (executor messages do).
pub(super) fn rejection(step: &str, reason: &str) -> String {
    if reason.contains(step) {
        reason.to_string()
    } else {
        format!("{step}: {reason}")
    }
}

pub(super) fn grammar_error(role: &str, node: NodeId, text: &str, e: &str) -> StopCause {
    StopCause::Error(format!("grammar error: the {role} output at node {node} does not parse ({e}): {text:?}"))
}

/// Whether the model stopped because the grammar was not complete within the token cap.
fn is_token_budget(e: &LlmError) -> bool {
    matches!(e, LlmError::TokenBudget { .. })
}

/// sha256 of the prompt's messages and the grammar, hex, first 16 characters.
pub(crate) fn prompt_hash(prompt: &Prompt, lark: &str) -> String {
    let mut h = Sha256::new();
    match prompt {
        Prompt::Text(t) => h.update(t.as_bytes()),
        Prompt::Chat(ms) => {
            for m in ms {
                h.update(m.role.as_bytes());
                h.update([0]);
                h.update(m.content.as_bytes());
                h.update([0]);
            }
        }
    }
    h.update([1]);
    h.update(lark.as_bytes());
    let d = h.finalize();
    d.iter().take(8).map(|b| format!("{b:02x}")).collect()
}

/// The full prompt of a call, only on request (`--log step::planner=trace`): it is long, and the
/// trace keeps its hash.
pub(super) fn log_prompt(role: &str, node: NodeId, prompt: &Prompt) {
    if tracing::enabled!(tracing::Level::TRACE) {
        if let Prompt::Chat(m) = prompt {
            let turns: Vec<String> = m.iter().skip(1).map(|m| format!("[{}]\n{}", m.role, m.content)).collect();
            tracing::trace!("{role} prompt at node {node} (the system message left out):\n{}", turns.join("\n"));
        }
    }
}
