//! Algorithm 1: grow the subgoal tree depth first, left to right, executing each leaf as soon as it is
//! judged to be an action.
//!
//! At a node the decomposition model proposes the next child (from the node's goal, the previous
//! sibling and how it ended, the observation, and the last rejected attempt); `done` completes the
//! node. The termination model judges the child: *execute* (after the symbolic check, in the
//! executor; a failure makes the node propose again with the executor's message), *decompose* (recurse
//! into the child), or *replan* (the node proposes again with the cause and reason). A node whose
//! replans or children run over budget is abandoned and its parent goes on; at the root that ends the
//! run, named by the budget. Global budgets (LLM calls, actions, deadline) end the run wherever it is.

use std::time::Instant;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde_json::json;
use sha2::{Digest, Sha256};

use super::env::{Env, Outcome};
use crate::grammar::{ActionSet, Cause, DecomposeGrammar, Proposal, Verdict, VerdictGrammar};
use super::prompt::{NodeView, Prompter};
use super::trace::TraceWriter;
use super::tree::{NodeId, Status, SubgoalTree};
use super::{ActionChoice, CallRecord, PlanOutcome, PlanRequest, PlanStats, PlannerConfig, PlannerKind, StopCause};
use crate::action::{Action, Verb};
use crate::grammar::Strength;
use crate::scene_grammar::typed_actions;
use crate::llm::engine::{Generate, Prompt, Score, StopReason};
use crate::llm::LlmError;
use crate::world::vocab::Relation;
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
enum End {
    /// The model said `done` for it.
    Complete,
    /// A per-node budget ran out (`replans` or `children`).
    Abandoned(&'static str),
}

/// What a node's expansion keeps between its children.
#[derive(Default)]
struct NodeLoop {
    /// The previous accepted child, with how it ended.
    previous: Option<String>,
    /// The last rejected or failed attempt, with why.
    rejected: Option<String>,
    /// Actions rejected since the state last changed (not proposed again until it does).
    refused: Vec<Action>,
    /// Actions this node has executed, in order.
    done_here: Vec<Action>,
    replans: usize,
    children: usize,
    accepted: usize,
    /// After a subgoal of this node is rejected, given up or echoes the node's own goal, the node
    /// proposes actions only until one runs: a greedy model otherwise writes the same subgoal again.
    concrete_only: bool,
    /// The offered subgoal lines (goal lines or target actions) already taken, done or given up.
    tried: Vec<String>,
    /// Actions the run had executed when this node's expansion began (the random chooser counts
    /// the steps taken below a node from it).
    start_actions: usize,
    /// What this node's steps changed, kept from being undone by its later steps (see
    /// `PlannerConfig::protect_changes`).
    established: Vec<Fact>,
    /// The root's goal lines whose fact held when they were done, and those offered again since
    /// (see [`Run::undone_lines`]).
    met_lines: Vec<String>,
    reoffered: Vec<String>,
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
    model: &'a mut dyn Generate,
    env: &'a mut dyn Env,
    req: &'a PlanRequest,
    cfg: &'a PlannerConfig,
    trace: &'a mut TraceWriter,
    mode: ContextMode,
    prompter: Prompter,
    focus: Vec<u32>,
    tree: SubgoalTree,
    stats: PlanStats,
    executed: Vec<Action>,
    start: Instant,
    /// The `random` planner's chooser, in place of the model (see [`Run::draw`]).
    rng: Option<StdRng>,
    /// `focus` is every object of the scene (nothing narrowed it), so the root narrows it itself.
    focus_is_scene: bool,
    /// What the last executed action changed among its objects: the facts that hold after it and
    /// did not before.
    last_change: Vec<Fact>,
}

/// Runs the tree planner (kinds `step`, `no-tree`, `no-subgoal-tree`).
pub(crate) fn run_tree(
    model: &mut dyn Generate,
    env: &mut dyn Env,
    req: &PlanRequest,
    cfg: &PlannerConfig,
    trace: &mut TraceWriter,
) -> PlanOutcome {
    let focus = match (req.focus.is_empty(), env.world()) {
        (false, _) | (true, None) => req.focus.clone(),
        // No focus given: the whole scene (the character excluded).
        (true, Some(w)) => w.nodes().map(|n| n.id).filter(|&id| id != w.character()).collect(),
    };
    let focus_is_scene = env.world().is_some_and(|w| {
        let n = w.nodes().filter(|n| n.id != w.character()).count();
        focus.iter().filter(|&&id| id != w.character()).count() >= n
    });
    let mut run = Run {
        focus_is_scene,
        last_change: Vec::new(),
        model,
        env,
        req,
        cfg,
        trace,
        mode: ContextMode::of(cfg.kind),
        prompter: Prompter::new(&req.instruction, req.context.as_deref()),
        focus,
        tree: SubgoalTree::new(&req.instruction),
        stats: PlanStats::default(),
        executed: Vec::new(),
        start: Instant::now(),
        rng: (cfg.kind == PlannerKind::Random).then(|| StdRng::seed_from_u64(cfg.random_seed)),
    };
    run.node_event(0);
    let root = run.tree.root();
    run.set_status(root, Status::Decomposing, "the instruction");
    let stop = match run.expand(root, None) {
        Ok(End::Complete) => {
            let lines = !req.subgoals.is_empty() && run.mode != ContextMode::NoSubgoalTree;
            let why = if lines { "every offered goal line was taken" } else { "the model said done" };
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
    fn node_event(&mut self, id: NodeId) {
        let n = self.tree.node(id);
        self.trace.event(
            "node",
            json!({"node": id, "parent": n.parent, "depth": n.depth, "text": n.text,
                   "action": n.action.as_ref().map(|a| a.to_string())}),
        );
    }

    fn set_status(&mut self, id: NodeId, status: Status, why: impl Into<String>) {
        let why = why.into();
        let mut fields = json!({"node": id, "status": status.name(), "why": why});
        if let Status::Mapped { action } = &status {
            fields["action"] = json!(action.to_string());
        }
        self.tree.set_status(id, status, why);
        self.trace.event("status", fields);
    }

    /// The global budgets, checked before every model call and every action.
    fn check_global(&self) -> Result<(), StopCause> {
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

    fn world(&self) -> Result<&World, StopCause> {
        self.env.world().ok_or_else(|| {
            StopCause::Error(format!(
                "the executor '{}' has no world model, and the grammars are built from one",
                self.env.name()
            ))
        })
    }

    /// The actions a decision at `node` may write: the strength's set over the node's objects.
    fn action_set(&self, node: NodeId) -> Result<ActionSet, StopCause> {
        Ok(self.cfg.action_set(self.cfg.strength, self.world()?, &self.node_focus(node)?))
    }

    /// Whether every object `a` names is in the run's focus: a plan names only the objects it was
    /// given (EAI's scorer rejects any other as a hallucination), also on the way to a target (a
    /// closed container of the target that is not in the focus blocks it).
    fn in_focus(&self, a: &Action) -> bool {
        a.args.iter().all(|o| self.focus.contains(&o.id))
    }

    /// The objects a decision at `node` may name. With `subgoal_focus`: the focus objects the node's
    /// text names, by class name or `(id)`, with the objects holding them (inside or on), so a
    /// subgoal's choices are about what it is about; a text that names none keeps the whole focus.
    /// The root does so only when its focus is the whole scene.
    fn node_focus(&self, node: NodeId) -> Result<Vec<u32>, StopCause> {
        // The root keeps a focus the request narrowed (a task's relevant objects); over the whole
        // scene, it too is narrowed to what its instruction names.
        if !self.cfg.subgoal_focus || (node == self.tree.root() && !self.focus_is_scene) {
            return Ok(self.focus.clone());
        }
        let w = self.world()?;
        let named = named_objects(w, &self.focus, &self.tree.node(node).text);
        if named.is_empty() {
            return Ok(self.focus.clone());
        }
        let mut out = named.clone();
        for (from, r, to) in w.edges() {
            if named.contains(&from)
                && matches!(r, Relation::Inside | Relation::On)
                && self.focus.contains(&to)
                && !out.contains(&to)
                && !w.node(to).is_some_and(|n| n.is_room())
            {
                out.push(to);
            }
        }
        Ok(out)
    }

    /// The target subgoals a decision at `node` may write: the actions of the
    /// `typed` set over the node's objects that cannot run now (the runnable ones are offered as
    /// actions) and that the world knows a way to, moves left out (a walk is never out of reach),
    /// each taken at most once per node, and only those that change something among their objects.
    /// `feasible` is the node's feasible set. Empty unless [`PlannerConfig::target_subgoals`] and
    /// the feasible grammar are on and the node may have subgoals at all (`allowed`).
    fn target_menu(
        &self,
        node: NodeId,
        feasible: &ActionSet,
        allowed: bool,
        st: &NodeLoop,
    ) -> Result<Vec<Action>, StopCause> {
        let ActionSet::Exact(feasible) = feasible else { return Ok(Vec::new()) };
        if !allowed || !self.cfg.target_subgoals || self.mode == ContextMode::NoSubgoalTree {
            return Ok(Vec::new());
        }
        let w = self.world()?;
        // Only targets the world knows a way to: not an affordance error, not already so.
        let menu = typed_actions(w, &self.node_focus(node)?)
            .into_iter()
            .filter(|a| !matches!(a.verb, Verb::Walk | Verb::Run | Verb::Find))
            .filter(|a| !self.cfg.excluded_verbs.contains(&a.verb) && !feasible.contains(a))
            .filter(|a| !st.tried.contains(&a.to_string()))
            // A target is judged by its own action, in the state its way leads to (one walk of the
            // way and one trial per candidate): it must change something among its objects, undo
            // nothing the task asks for, and (with `skip_idle`) not be an idle step itself (LOOKAT
            // by way of TURNTO).
            .filter(|a| {
                // (a way through an object outside the focus would name one the plan was not given)
                let Some((way, before)) = w.way_to(a) else { return false };
                if !way.iter().all(|s| self.in_focus(s)) {
                    return false;
                }
                let Some(after) = trial(&before, a) else { return false };
                changes_its_objects(w, &after, a)
                    && !(self.keeps_goals() && makes_false(&before, &after, &self.req.kept))
                    && !(self.skips_idle(a.verb) && changes_nothing(&before, &after, a))
            })
            .collect();
        Ok(menu)
    }

    /// The context of a decision at `node`.
    fn view(&self, node: NodeId, previous: Option<&str>, rejected: Option<&str>) -> NodeView {
        let observation = self.env.observe(self.cfg.observe_budget);
        let history = || Some(self.executed.iter().map(|a| a.to_string()).collect());
        match self.mode {
            ContextMode::Step => NodeView {
                observation,
                goal: self.tree.node(node).text.clone(),
                previous: previous.map(str::to_string),
                history: None,
                rejected: rejected.map(str::to_string),
                blocked: None,
                options: None,
            },
            ContextMode::NoTree => NodeView {
                observation,
                goal: self.tree.node(node).text.clone(),
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
    fn call(
        &mut self,
        role: &'static str,
        node: NodeId,
        prompt: &Prompt,
        lark: &str,
    ) -> Result<Option<String>, StopCause> {
        self.check_global()?;
        let hash = prompt_hash(prompt, lark);
        // The full prompt only on request (`--log step::planner=trace`): it is long, and the trace
        // keeps its hash.
        if tracing::enabled!(tracing::Level::TRACE) {
            if let Prompt::Chat(m) = prompt {
                let turns: Vec<String> = m.iter().skip(1).map(|m| format!("[{}]\n{}", m.role, m.content)).collect();
                tracing::trace!("{role} prompt at node {node} (the system message left out):\n{}", turns.join("\n"));
            }
        }
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
    fn record(&mut self, rec: CallRecord) {
        self.stats.prompt_tokens += rec.prompt_tokens;
        self.stats.reused_tokens += rec.reused_tokens;
        self.stats.output_tokens += rec.output_tokens;
        self.stats.forced_tokens += rec.forced_tokens;
        self.trace.event("call", serde_json::to_value(&rec).unwrap_or_default());
        self.tree.add_call(rec.node, self.stats.calls.len());
        self.stats.calls.push(rec);
    }

    /// Whether the model is done at `node` by its own probability of `done` as its answer's first
    /// word (see [`PlannerConfig::done_at`]). A model that cannot score leaves it to generation.
    fn done_check(&mut self, node: NodeId, prompt: &Prompt, subgoals: bool, at: Option<f64>) -> Result<bool, StopCause> {
        let Some(at) = at else { return Ok(false) };
        self.check_global()?;
        let mut words = vec!["done".to_string(), "action:".to_string()];
        if subgoals {
            words.push("subgoal:".to_string());
        }
        let hash = prompt_hash(prompt, &words.join("\n"));
        let t = Instant::now();
        let scoring = match self.model.score(prompt, &words) {
            Ok(s) => s,
            Err(e) => {
                self.trace.event("call_error", json!({"role": "done_check", "node": node, "prompt_hash": hash,
                    "kind": "no_score", "error": e.to_string()}));
                return Ok(false);
            }
        };
        let total_ms = t.elapsed().as_secs_f64() * 1e3;
        self.stats.llm_calls += 1;
        // The share of `done` among the answers' first words.
        let odds: Vec<f64> = scoring.scores.iter().map(|s| s.logprob.exp()).collect();
        let p = odds[0] / odds.iter().sum::<f64>().max(f64::MIN_POSITIVE);
        let done = p >= at;
        self.record(CallRecord::of_scoring(node, hash, &scoring, if done { "done" } else { "go on" }, total_ms));
        self.trace.event("done_check", json!({"node": node, "p_done": (p * 1000.0).round() / 1000.0, "done": done}));
        Ok(done)
    }

    /// The action of an `action:` proposal chosen by likelihood: every action of an exact set is
    /// scored whole as the proposal line, and the best per token wins (the first on a tie). Other
    /// sets, or a single choice, keep the `written` action.
    fn rank(&mut self, node: NodeId, prompt: &Prompt, set: &ActionSet, written: Action) -> Result<Action, StopCause> {
        let ActionSet::Exact(list) = set else { return Ok(written) };
        if list.len() < 2 {
            return Ok(written);
        }
        self.check_global()?;
        let lines: Vec<String> = list.iter().map(|a| format!("action: {a}")).collect();
        let hash = prompt_hash(prompt, &lines.join("\n"));
        let t = Instant::now();
        let scoring = self.model.score(prompt, &lines).map_err(|e| {
            self.trace.event("call_error", json!({"role": "score", "node": node, "prompt_hash": hash,
                "kind": "error", "error": e.to_string()}));
            StopCause::Error(format!("score call at node {node}: {e}"))
        })?;
        let total_ms = t.elapsed().as_secs_f64() * 1e3;
        self.stats.llm_calls += 1;
        let mut best = 0;
        for (i, s) in scoring.scores.iter().enumerate() {
            if s.mean() > scoring.scores[best].mean() {
                best = i;
            }
        }
        self.record(CallRecord::of_scoring(node, hash, &scoring, &lines[best], total_ms));
        let mut top: Vec<(f64, &str)> = scoring.scores.iter().map(Score::mean).zip(lines.iter().map(String::as_str)).collect();
        top.sort_by(|a, b| b.0.total_cmp(&a.0));
        self.trace.event("scores", json!({"node": node, "written": format!("action: {written}"),
            "top": top.iter().take(5).map(|(s, l)| json!([l, (s * 1000.0).round() / 1000.0])).collect::<Vec<_>>()}));
        Ok(list[best].clone())
    }

    /// Expands `node` until the model says `done` for it or a per-node budget abandons it. A target
    /// subgoal (`target`: its action, see `PlannerConfig::target_subgoals`) is done when that action runs.
    fn expand(&mut self, node: NodeId, target: Option<Action>) -> Result<End, StopCause> {
        let depth = self.tree.node(node).depth;
        let budgets = self.cfg.budgets.clone();
        let mut st = NodeLoop { start_actions: self.executed.len(), ..NodeLoop::default() };
        // The root is bounded by the run's budgets (calls, actions, deadline) alone: abandoning it
        // ends the run, and a plan needs more steps than a subgoal.
        let is_root = node == self.tree.root();
        // Below an offered line the node proposes actions: the line already is the subgoal, and
        // names its objects (tiny models' own subgoals there were found to drift off them).
        let under_offered = !is_root
            && self.tree.node(node).parent == Some(self.tree.root())
            && self.req.subgoals.contains(&self.tree.node(node).text);
        // With `single_step_lines`, such a node is complete once one step (an action, or a target
        // whose action ran) has been accepted.
        let one_step = under_offered && self.cfg.single_step_lines;
        // Whether a step that ran completes this node.
        let completes = |a: &Action| target.as_ref() == Some(a) || one_step;
        loop {
            if !is_root && st.replans > budgets.max_replans {
                return Ok(End::Abandoned("replans"));
            }
            if !is_root && st.children >= budgets.max_children {
                return Ok(End::Abandoned("children"));
            }
            self.check_global()?;
            let mut view = self.view(node, st.previous.as_deref(), st.rejected.as_deref());
            if let Some(t) = &target {
                view.blocked = self.world()?.why_not(t).map(|f| f.message);
            }
            // An action this node has just rejected is not proposed again until the state changes;
            // only exact sets can drop one. With `fresh_steps`, steps that repeat recent ones are
            // dropped too; without, at least the action the node has just executed (a greedy tiny
            // model otherwise repeats one step forever).
            let set = self.action_set(node)?;
            // The root's subgoals are the request's offered lines (a task's goals in words) not yet
            // taken; once all are taken it proposes actions or `done`.
            let offered = is_root && !self.req.subgoals.is_empty();
            let may_target = target.is_none() && !offered && depth + 1 < budgets.max_depth && !st.concrete_only;
            let targets = self.target_menu(node, &set, may_target, &st)?;
            let actions = match set {
                ActionSet::Exact(list) => {
                    let list: Vec<Action> = list.into_iter().filter(|a| !st.refused.contains(a)).collect();
                    ActionSet::Exact(if self.cfg.fresh_steps {
                        let fresh = fresh_steps(list, &self.executed, &st.done_here);
                        // A node that has taken steps and has nothing new left to do is offered
                        // `done` (or a subgoal) rather than a repeat.
                        let recent = recent(&self.executed);
                        if st.accepted > 0 && fresh.iter().all(|a| st.done_here.contains(a) || recent.contains(a)) {
                            Vec::new()
                        } else {
                            fresh
                        }
                    } else {
                        list.into_iter().filter(|a| st.done_here.last() != Some(a)).collect()
                    })
                }
                set => set,
            };
            // Neither what this node's steps changed nor what the task asks for is undone: one trial
            // of each candidate on a copy of the world answers both.
            let mut protected: Vec<Fact> = Vec::new();
            if self.cfg.protect_changes {
                protected.extend(st.established.iter().cloned());
            }
            if self.keeps_goals() {
                protected.extend(self.req.kept.iter().cloned());
            }
            // Where the goals are kept, a step that would change nothing is not offered below the
            // root either (the same trial tells).
            let skip_idle = self.cfg.skip_idle && self.keeps_goals() && !is_root;
            let actions = match actions {
                ActionSet::Exact(list) if !protected.is_empty() || skip_idle => {
                    let w = self.world()?;
                    // (one that cannot run is left to the checks after)
                    let keep = |a: &Action| {
                        trial(w, a).is_none_or(|after| {
                            !makes_false(w, &after, &protected) && !(skip_idle && self.skips_idle(a.verb) && changes_nothing(w, &after, a))
                        })
                    };
                    ActionSet::Exact(list.into_iter().filter(|a| keep(a)).collect())
                }
                set => set,
            };
            // With target steps, a target node's one step is the world's next step towards its action.
            let toward = match (&target, self.cfg.target_steps) {
                (Some(t), true) => Some(self.world()?.first_step_towards(t)),
                _ => None,
            };
            let actions = match (toward, actions) {
                (Some(Some(step)), _) if !self.cfg.excluded_verbs.contains(&step.verb) && self.in_focus(&step) => {
                    ActionSet::Exact(vec![step])
                }
                (Some(_), _) => return Ok(End::Abandoned("unreachable")),
                // Targets are written as actions: the model names the action it wants done, and one
                // that cannot run yet becomes a subgoal worked out below it.
                (None, ActionSet::Exact(mut list)) if !targets.is_empty() => {
                    list.extend(targets.iter().cloned());
                    ActionSet::Exact(list)
                }
                (None, actions) => actions,
            };
            if offered && self.keeps_goals() {
                self.undone_lines(&mut st)?;
            }
            let subgoal_menu: Vec<String> = if offered {
                self.req.subgoals.iter().filter(|l| !st.tried.contains(l)).cloned().collect()
            } else {
                Vec::new()
            };
            // A root whose offered subgoals have all been taken is complete: its decomposition was
            // the goal lines, and each was done or given up below it.
            if offered && subgoal_menu.is_empty() {
                return Ok(End::Complete);
            }
            // With target subgoals, a node's only subgoals are its targets (free text is not offered:
            // tiny models' own subgoals were found to echo or drift), and a target node proposes
            // actions only.
            let with_targets = self.cfg.target_subgoals && !offered && self.cfg.strength == Strength::Feasible;
            let allow_subgoal = self.mode != ContextMode::NoSubgoalTree
                && depth + 1 < budgets.max_depth
                // (a root with lines left takes the next one: a taken line is never offered again)
                && (!st.concrete_only || offered)
                && target.is_none()
                && !with_targets
                && !under_offered
                && (!offered || !subgoal_menu.is_empty());
            // `done` before any step would end a goal with nothing done; it is offered once a child
            // has been accepted, once every offered subgoal was taken, or when nothing else can be
            // written.
            // (a target node with target steps ends when its action runs, not when the model says so)
            // A root shown goal lines is decomposed into them: it is not done while one is left to take.
            let allow_done = !(target.is_some() && self.cfg.target_steps)
                && !(offered && allow_subgoal)
                && (st.accepted > 0 || (!allow_subgoal && actions.is_empty()));
            // While offered lines remain, the root decomposes into them (actions come below them):
            // given the choice, both models wrote actions at the root and never took a line.
            let actions = if offered && allow_subgoal { ActionSet::Exact(Vec::new()) } else { actions };
            if self.cfg.show_effects {
                view.options = self.effects_menu(&actions, &targets)?;
            }
            let dg = DecomposeGrammar { actions, subgoal_chars: self.cfg.subgoal_chars, allow_subgoal, allow_done, subgoal_menu };
            let lark = dg.to_lark().map_err(|e| StopCause::Error(format!("decomposition grammar: {e}")))?;
            let prompt = self.prompter.decompose(&view);
            let only = dg.only_choice();
            // Where the goals are kept, `lines_done_at` judges `done` (strictly: below it the model
            // may not write it); elsewhere `done_at` (below it the model may still write it).
            let (done_at, lines_strict) = if self.keeps_goals() {
                (self.cfg.lines_done_at, self.cfg.lines_done_at.is_some())
            } else {
                (self.cfg.done_at, false)
            };
            let text = if let Some(line) = only {
                // One admissible answer: asking a model (or drawing) could not change it.
                line
            } else if self.rng.is_some() {
                match self.draw(&dg, &st) {
                    Some(t) => t,
                    None => return Ok(End::Abandoned("random_steps")),
                }
            } else if dg.allow_done && self.done_check(node, &prompt, dg.allow_subgoal, done_at)? {
                "done".to_string()
            } else {
                // Below the goal lines' threshold the model is not done: `done` leaves the grammar
                // (while anything else can be written).
                let something_else = dg.allow_subgoal || !matches!(&dg.actions, ActionSet::Exact(l) if l.is_empty());
                let lark = if dg.allow_done && lines_strict && something_else {
                    let no_done = DecomposeGrammar { allow_done: false, ..dg.clone() };
                    no_done.to_lark().map_err(|e| StopCause::Error(format!("decomposition grammar: {e}")))?
                } else {
                    lark
                };
                let Some(text) = self.call("decompose", node, &prompt, &lark)? else {
                    st.replans += 1;
                    self.stats.replans += 1;
                    st.rejected = Some("(no answer within the token limit)".into());
                    continue;
                };
                text
            };
            let proposal = dg.parse(&text).map_err(|e| grammar_error("decompose", node, &text, &e.to_string()))?;
            let proposal = match proposal {
                Proposal::Action(a) if self.cfg.choose == ActionChoice::Score => {
                    Proposal::Action(self.rank(node, &prompt, &dg.actions, a)?)
                }
                p => p,
            };
            // (`target_child`: a target, a subgoal named by its action)
            let (child_text, child_action, target_child) = match &proposal {
                Proposal::Done => return Ok(End::Complete),
                Proposal::Subgoal(s) => (s.clone(), None, None),
                Proposal::Action(a) if targets.contains(a) => (a.to_string(), None, Some(a.clone())),
                Proposal::Action(a) => (a.to_string(), Some(a.clone()), None),
            };
            let child = self.tree.add_child(node, child_text.clone(), child_action.clone());
            st.children += 1;
            self.node_event(child);
            if child_action.is_none() && self.req.subgoals.contains(&child_text) {
                st.tried.push(child_text.clone());
            }
            if child_action.is_none() && echoes(&child_text, &self.tree.node(node).text) {
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

            // An offered subgoal (one of the task's goal lines) is congruent by construction, and
            // whether one action does it is found by decomposing it (its first action, then `done`):
            // it is decomposed without a verdict, as the random chooser does. A tiny model's verdicts
            // on such lines were found to be replans with made-up reasons.
            // A target subgoal is congruent and not runnable now by construction: decomposed too.
            if target_child.is_some() {
                st.tried.push(child_text.clone());
            }
            let offered_child = child_action.is_none()
                && ((is_root && self.req.subgoals.contains(&child_text)) || target_child.is_some());

            // The verdict on the new child. A proposed action can only be executed or rejected, so
            // its grammar names that one action (the verdict is mostly forced tokens, still the
            // model's choice).
            // With the symbolic checks on, an action the world says is executable now cannot be
            // rejected for affordance or environment (the world decides those, not a guess): the
            // model may still reject it as not serving the goal (congruence).
            let vg = match &child_action {
                Some(a) => {
                    let grounded = self.cfg.symbolic_check && self.world()?.why_not(a).is_none();
                    VerdictGrammar {
                        actions: ActionSet::Exact(vec![a.clone()]),
                        reason_chars: self.cfg.reason_chars,
                        allow_decompose: false,
                        causes: if grounded { vec![Cause::Congruence] } else { Cause::ALL.to_vec() },
                    }
                }
                None => VerdictGrammar {
                    actions: self.action_set(child)?,
                    reason_chars: self.cfg.reason_chars,
                    allow_decompose: depth + 1 < budgets.max_depth,
                    causes: Cause::ALL.to_vec(),
                },
            };
            let lark = vg.to_lark().map_err(|e| StopCause::Error(format!("verdict grammar: {e}")))?;
            let prompt = self.prompter.terminate(&view, &text);
            // The random chooser decomposes every subgoal it draws (its actions went to the world above).
            let vtext = if self.rng.is_some() || offered_child {
                Some("decompose".to_string())
            } else {
                self.call("terminate", child, &prompt, &lark)?
            };
            let Some(vtext) = vtext else {
                self.set_status(child, Status::Replanned, "no verdict within the token limit");
                st.replans += 1;
                self.stats.replans += 1;
                st.rejected = Some(format!("{child_text}: no verdict within the token limit"));
                continue;
            };
            let verdict = vg.parse(&vtext).map_err(|e| grammar_error("terminate", child, &vtext, &e.to_string()))?;
            self.trace.event("verdict", json!({"node": child, "verdict": vtext}));
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
                            self.set_status(child, Status::Executed, "all its steps are done");
                            st.accepted += 1;
                            // A target's own action ran last: what it changed is said here too.
                            st.previous = Some(match (&target_child, self.change_report()) {
                                (Some(_), Some(change)) => format!("{child_text}: done, {change}"),
                                _ => format!("{child_text}: done"),
                            });
                            if target_child.is_some() {
                                self.establish(&mut st);
                            }
                            if is_root && self.line_fact(&child_text).is_some_and(|f| self.env.world().is_some_and(|w| w.holds(f))) {
                                st.met_lines.push(child_text.clone());
                            }
                            st.rejected = None;
                            if one_step {
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

    /// Whether the rules for shown goals apply (see `PlannerConfig::keep_goals`): steps that undo
    /// what the task asks for are left out, and with them idle steps and `lines_done_at`. A task
    /// whose goals are only closeness and actions (pet the cat: be close to it, TOUCH it) keeps no
    /// fact, yet its lines are goal lines all the same.
    fn keeps_goals(&self) -> bool {
        self.cfg.keep_goals && (!self.req.kept.is_empty() || !self.req.named_verbs.is_empty())
    }

    /// The kept fact a goal line states, if it states one (an action line, or closeness, does not).
    fn line_fact(&self, line: &str) -> Option<&Fact> {
        let w = self.env.world()?;
        self.req.kept.iter().find(|f| w.describe(f) == line)
    }

    /// Where the goals are kept: a goal line that was met when done, and whose fact a later step
    /// has made false (a target's way: SWITCHOFF of a dishwasher that is to be on, to open it and
    /// put the plates in), is offered to the root again, once. Not a stop rule: it only lets the
    /// root take a line again that its own steps undid; lines given up are not offered again.
    fn undone_lines(&mut self, st: &mut NodeLoop) -> Result<(), StopCause> {
        let w = self.world()?;
        let undone: Vec<String> = st
            .met_lines
            .iter()
            .filter(|l| !st.reoffered.contains(l))
            .filter(|l| self.line_fact(l).is_some_and(|f| !w.holds(f)))
            .cloned()
            .collect();
        for line in undone {
            st.tried.retain(|t| *t != line);
            st.met_lines.retain(|t| *t != line);
            self.trace.event("reoffered", json!({"line": line, "why": "a later step made it false"}));
            st.reoffered.push(line);
        }
        Ok(())
    }

    /// The options of a decision with their effects (see `PlannerConfig::show_effects`): each
    /// action it may write, with the facts among its objects and the robot that running it (a
    /// target: its way, then it) would make true, in the goal lines' words.
    fn effects_menu(&self, actions: &ActionSet, targets: &[Action]) -> Result<Option<String>, StopCause> {
        let ActionSet::Exact(list) = actions else { return Ok(None) };
        if list.is_empty() {
            return Ok(None);
        }
        let w = self.world()?;
        let mut s = String::from("Steps you can take, and what each makes true:\n");
        for a in list.iter().take(MAX_SHOWN_STEPS) {
            let after = if targets.contains(a) { w.before_running(a).and_then(|b| trial(&b, a)) } else { trial(w, a) };
            let facts: Vec<String> = after.map(|after| gained(w, &after, a)).unwrap_or_default().iter().take(3).map(|f| w.describe(f)).collect();
            if facts.is_empty() {
                s.push_str(&format!("{a}: nothing new\n"));
            } else {
                s.push_str(&format!("{a}: {}\n", facts.join(", ")));
            }
        }
        Ok(Some(s))
    }

    /// Whether a step of `verb` that changes nothing is left out (see `PlannerConfig::skip_idle`).
    fn skips_idle(&self, verb: Verb) -> bool {
        self.cfg.skip_idle && self.keeps_goals() && !self.req.named_verbs.contains(&verb)
    }

    /// "now <fact>, …": what the last step changed, in the goal lines' words, when changes are
    /// reported and it changed any.
    fn change_report(&self) -> Option<String> {
        let facts = self.last_change_words().filter(|_| self.cfg.report_changes)?;
        Some(format!("now {}", facts.join(", ")))
    }

    /// What the last step changed, in the goal lines' words (`None`: nothing, or no world to say it).
    fn last_change_words(&self) -> Option<Vec<String>> {
        let w = self.env.world().filter(|_| !self.last_change.is_empty())?;
        Some(self.last_change.iter().map(|f| w.describe(f)).collect())
    }

    /// Records in `st` what the step that just ran changed, but holding and closeness (means, not
    /// ends: a grab is undone by the put it was for).
    fn establish(&self, st: &mut NodeLoop) {
        let means = |f: &Fact| is_edge(f, &[Relation::HoldsRh, Relation::HoldsLh, Relation::Close]);
        st.established.extend(self.last_change.iter().filter(|f| !means(f)).cloned());
    }

    /// The symbolic check, then the executor. `Ok(Ok(summary))`: executed; `Ok(Err(reason))`: the
    /// child was rejected or failed and the parent proposes again.
    fn execute(&mut self, child: NodeId, a: &Action) -> Result<Result<String, String>, StopCause> {
        if self.cfg.symbolic_check {
            if let Some(f) = self.world()?.why_not(a) {
                self.stats.symbolic_rejections += 1;
                self.trace.event(
                    "symbolic_check",
                    json!({"node": child, "action": a.to_string(),
                    "kind": f.kind.name(), "message": f.message}),
                );
                self.set_status(child, Status::Replanned, format!("environment: {} (symbolic check)", f.message));
                return Ok(Err(f.message));
            }
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
                    (Some(before), Some(w)) => w.facts_among(&ids).into_iter().filter(|f| !before.contains(f)).collect(),
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

impl Run<'_> {
    /// The `random` planner's decomposition, in place of the model's (it walks the tree only when
    /// subgoals are offered; see `planner::plan`): at the root, an offered line not yet taken, drawn
    /// uniformly; below it, a uniform draw among the admitted actions until the node has executed
    /// `random_steps` of them (or none is left), then `done`. Its only stopping rule is that fixed
    /// length: nothing in it looks at the goals' state.
    /// `None`: nothing can be drawn and `done` is not offered (no step taken): the node is given up.
    fn draw(&mut self, dg: &DecomposeGrammar, st: &NodeLoop) -> Option<String> {
        let rng = self.rng.as_mut().expect("draw is called for the random planner only");
        if dg.allow_subgoal && !dg.subgoal_menu.is_empty() {
            return Some(format!("subgoal: {}", dg.subgoal_menu[rng.random_range(0..dg.subgoal_menu.len())]));
        }
        // Steps taken below this node count, in its target subgoals too; targets are among the
        // actions, so one uniform draw covers both.
        if self.executed.len() - st.start_actions >= self.cfg.random_steps {
            return dg.allow_done.then(|| "done".to_string());
        }
        match super::baseline::draw(&dg.actions, rng) {
            Some(a) => Some(format!("action: {a}")),
            None => dg.allow_done.then(|| "done".to_string()),
        }
    }
}

/// The objects of `focus` that `text` names: by class name (a whole word, case-insensitive) or by id
/// written as `(id)`. The robot itself ("character is SITTING") is not an object its actions name.
pub(crate) fn named_objects(w: &World, focus: &[u32], text: &str) -> Vec<u32> {
    let words: Vec<String> = text
        .split(|c: char| !(c.is_alphanumeric() || c == '_'))
        .filter(|w| !w.is_empty())
        .map(str::to_lowercase)
        .collect();
    focus
        .iter()
        .copied()
        .filter(|&id| id != w.character())
        .filter(|&id| {
            text.contains(&format!("({id})"))
                || w.node(id).is_some_and(|n| words.iter().any(|x| *x == n.class_name.to_lowercase()))
        })
        .collect()
}

/// Whether a proposed subgoal only repeats its parent's goal (the same words, or the start of them):
/// decomposing it would make the same decision one level down.
fn echoes(subgoal: &str, goal: &str) -> bool {
    let words = |s: &str| -> Vec<String> {
        s.split(|c: char| !c.is_alphanumeric()).filter(|w| !w.is_empty()).map(str::to_lowercase).collect()
    };
    let (s, g) = (words(subgoal), words(goal));
    !s.is_empty() && (g.starts_with(&s) || s.starts_with(&g))
}

/// The choices without the steps that repeat earlier ones, when anything else can be done: a walk
/// (or run) right after one (the first was pointless), any of the run's last [`RECENT`] actions, and
/// any action the node has already executed (`done_here`): the STEP context shows a node only its
/// previous step, so a greedy model that comes back to a state it has seen makes the same choice
/// again and cycles. The embodiment's rule, not a task's; every planner that chooses actions one at a
/// time obeys it, the random one included, so figures stay comparable.
pub(crate) fn fresh_steps(list: Vec<Action>, executed: &[Action], done_here: &[Action]) -> Vec<Action> {
    let moves = |a: &Action| matches!(a.verb, Verb::Walk | Verb::Run);
    let after_move = executed.last().is_some_and(moves);
    let recent = recent(executed);
    let fresh: Vec<Action> = list
        .iter()
        .filter(|a| !(after_move && moves(a)) && !recent.contains(a) && !done_here.contains(a))
        .cloned()
        .collect();
    if fresh.is_empty() {
        list
    } else {
        fresh
    }
}

/// Whether the state `after` a target's way holds a fact among the target's objects that does not
/// hold now (closeness aside): a target that changes nothing (putting the apple back where it lies,
/// by way of a grab) is no subgoal.
fn changes_its_objects(now: &World, after: &World, target: &Action) -> bool {
    let ids: Vec<u32> = target.args.iter().map(|o| o.id).collect();
    after.facts_among(&ids).iter().any(|f| !is_edge(f, &[Relation::Close]) && !now.holds(f))
}

/// The most steps [`Run::effects_menu`] shows (a prompt's tail stays a few hundred tokens).
const MAX_SHOWN_STEPS: usize = 24;

/// The facts among `a`'s objects and the robot that hold `after` it and not `now`, closeness only
/// as the robot's (the object's mirror of it says nothing more).
fn gained(now: &World, after: &World, a: &Action) -> Vec<Fact> {
    let ids: Vec<u32> = a.args.iter().map(|o| o.id).collect();
    let robot = now.character();
    after
        .facts_among(&ids)
        .into_iter()
        .filter(|f| !now.holds(f))
        .filter(|f| !matches!(f, Fact::Edge { from, relation: Relation::Close, .. } if *from != robot))
        .collect()
}

/// Whether a fact of `facts` that holds `now` does not hold `after`.
fn makes_false(now: &World, after: &World, facts: &[Fact]) -> bool {
    facts.iter().any(|f| now.holds(f) && !after.holds(f))
}

/// The world after running `a` on a copy of `w`, if it can run.
fn trial(w: &World, a: &Action) -> Option<World> {
    let mut after = w.clone();
    after.execute(a).ok()?;
    Some(after)
}

/// Whether the facts among `a`'s objects and the robot are the same `after` it as `now` (nothing
/// gained, nothing lost).
fn changes_nothing(now: &World, after: &World, a: &Action) -> bool {
    let ids: Vec<u32> = a.args.iter().map(|o| o.id).collect();
    let (before, then) = (now.facts_among(&ids), after.facts_among(&ids));
    before.len() == then.len() && then.iter().all(|f| before.contains(f))
}

/// Whether `f` is an edge of one of these relations.
fn is_edge(f: &Fact, relations: &[Relation]) -> bool {
    matches!(f, Fact::Edge { relation, .. } if relations.contains(relation))
}

/// How many of the run's latest actions [`fresh_steps`] keeps from being chosen again.
pub const RECENT: usize = 3;

/// The run's last [`RECENT`] actions.
fn recent(executed: &[Action]) -> &[Action] {
    &executed[executed.len().saturating_sub(RECENT)..]
}

/// "step: why", without repeating the step when the reason already names it (executor messages do).
fn rejection(step: &str, reason: &str) -> String {
    if reason.contains(step) {
        reason.to_string()
    } else {
        format!("{step}: {reason}")
    }
}

fn grammar_error(role: &str, node: NodeId, text: &str, e: &str) -> StopCause {
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
