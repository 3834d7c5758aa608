//! The subgoal decomposition model (the paper's section III-B): at a node, what the next child may
//! be and the model's choice of it. The grammar is built before every decision from the embodiment
//! and the live world: the actions that can run now (narrowed by the rules in `rules`), the targets
//! the world knows a way to, the task's goal lines at the root, and `done`. The model sees the
//! node's goal, its previous sibling and the observation only (`Run::view`); the `random` planner
//! draws from the same grammar instead.

use std::time::Instant;

use rand::Rng;
use serde_json::json;

use super::planner::{grammar_error, prompt_hash, ContextMode, End, NodeLoop, Run};
use super::goals;
use super::prompt::NodeView;
use super::rules::{changes_its_objects, changes_nothing, fresh_steps, gained, makes_false, recent, takes_a_reserved_hand, trial};
use super::tree::NodeId;
use super::{ActionChoice, CallRecord, StopCause};
use crate::action::{Action, ObjRef, Verb};
use crate::grammar::{ActionSet, DecomposeGrammar, Proposal, Strength};
use crate::llm::engine::{Prompt, Score};
use crate::scene_grammar::typed_actions;
use crate::world::vocab::{Property, Relation};
use crate::world::{Fact, World};

/// What a decision at a node may write: the decomposition grammar, the targets among its actions
/// (one chosen becomes a subgoal worked towards below it), and how `done` is judged there.
pub(super) struct Menu {
    pub(super) grammar: DecomposeGrammar,
    pub(super) targets: Vec<Action>,
    /// The model is done when its probability of `done` reaches this (see `PlannerConfig::done_at`).
    done_at: Option<f64>,
    /// Below `done_at`, `done` leaves the grammar (goal lines with the goals kept).
    strict: bool,
    /// The answer is the likeliest whole line of the menu (a root setting its own goals).
    whole: bool,
}

/// The relations among `kept` whose object is the one `a` acts on (its first).
fn relations_of(kept: &[Fact], a: &Action) -> Vec<Fact> {
    let Some(first) = a.args.first() else { return Vec::new() };
    kept.iter().filter(|f| matches!(f, Fact::Edge { from, .. } if *from == first.id)).cloned().collect()
}

/// The decomposition model's answer to one decision.
pub(super) enum Proposed {
    /// What it wrote, and that parsed.
    Text(String, Proposal),
    /// The random chooser had nothing to draw and `done` was not offered: the node is given up.
    Nothing,
    /// The grammar was not complete within the token cap: a rejected attempt.
    TokenLimit,
}

impl Run<'_> {
    /// What the decision at `node` may write (its grammar) and how `done` is judged there, or how
    /// the node ends without a decision: a target with no way left to its action is given up, and a
    /// root whose offered goal lines were all taken is complete.
    ///
    /// The actions are the grammar strength's set over the node's objects, narrowed by the rules
    /// (`rules`); beside them the node's targets, and at the root the goal lines not yet taken.
    pub(super) fn menu(
        &mut self,
        node: NodeId,
        target: Option<&Action>,
        st: &mut NodeLoop,
        view: &mut NodeView,
    ) -> Result<Result<Menu, End>, StopCause> {
        let depth = self.tree.node(node).depth;
        let max_depth = self.cfg.budgets.max_depth;
        let is_root = node == self.tree.root();
        // An action this node has just rejected is not proposed again until the state changes;
        // only exact sets can drop one. With `fresh_steps`, steps that repeat recent ones are
        // dropped too; without, at least the action the node has just executed (a greedy tiny
        // model otherwise repeats one step forever).
        let set = self.action_set(node)?;
        // An instruction whose every verb takes no object ("stand up", "get up from the chair"):
        // the root's steps are those verbs' alone, and it is done when none can run.
        let bare = is_root && (!self.bare_verbs.is_empty() || self.cannot.is_some());
        let set = if bare {
            // (words that ask only what their things cannot have done to them: no step at all)
            let others: Vec<Verb> = Verb::ALL.iter().copied().filter(|v| self.cannot.is_some() || !self.bare_verbs.contains(v)).collect();
            set.without(&others)
        } else {
            set
        };
        // The root's subgoals are the request's offered lines (a task's goals in words) not yet
        // taken; once all are taken it proposes actions or `done`.
        let offered = is_root && !self.goals.lines.is_empty();
        let may_target = target.is_none() && !offered && depth + 1 < max_depth && !st.concrete_only && !bare;
        let targets = self.target_menu(node, &set, may_target, st)?;
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
        let actions = self.keep_what_is_done(actions, st, is_root)?;
        // With target steps, a target node's one step is the world's next step towards its action.
        let toward = match (target, self.cfg.target_steps) {
            (Some(t), true) => Some(self.world()?.first_step_towards(t)),
            _ => None,
        };
        let actions = match (toward, actions) {
            (Some(Some(step)), _) if !self.cfg.excluded_verbs.contains(&step.verb) && self.in_focus(&step) => {
                ActionSet::Exact(vec![step])
            }
            (Some(_), _) => return Ok(Err(End::Abandoned("unreachable"))),
            // Targets are written as actions: the model names the action it wants done, and one
            // that cannot run yet becomes a subgoal worked out below it.
            (None, ActionSet::Exact(mut list)) if !targets.is_empty() => {
                list.extend(targets.iter().cloned());
                ActionSet::Exact(list)
            }
            (None, actions) => actions,
        };
        let actions = self.toward_own_line(node, actions, &targets)?;
        if offered && self.keeps_goals() {
            self.undone_lines(st)?;
        }
        let subgoal_menu: Vec<String> = if offered {
            // (a line that contradicts one the root set itself is no longer offered)
            // (nor, yet, a left hand's hold line that waits for the right hand's, shown or inferred)
            // (nor, where the root sets its own goals, a state that holds now: a goal is a change
            // to bring about; "fridge is CLOSED" is offered again once a step has opened it)
            let holds = |l: &String| match self.goals.meaning(l) {
                Some(goals::Meaning::Fact(f)) => self.env.world().is_some_and(|w| w.holds(f)),
                _ => false,
            };
            let open: Vec<String> = self
                .goals
                .lines
                .iter()
                .filter(|l| !st.tried.contains(l) && !self.goals.contradicts_taken(l) && !self.waits_for_its_hand(l, &st.tried))
                .filter(|l| !(self.cfg.skip_held_lines && holds(l)))
                .cloned()
                .collect();
            // (nor an appliance's ON line while a line offered puts a thing in it, nor the robot's
            // way to where a thing is carried before it is taken, nor an action line before what
            // the words say first of its thing: see `Goals::waits_for_a_thing_put_in`,
            // `Goals::waits_for_a_thing_carried`, `Goals::waits_for_a_thing_said_first`)
            match self.env.world() {
                Some(w) => open
                    .iter()
                    .filter(|l| {
                        !self.goals.waits_for_a_thing_put_in(l, w, &open)
                            && !self.goals.waits_for_a_thing_carried(l, w, &open)
                            && !self.goals.waits_for_a_thing_said_first(l, w, &open)
                    })
                    .cloned()
                    .collect(),
                None => open,
            }
        } else {
            Vec::new()
        };
        // A root whose offered subgoals have all been taken is complete: its decomposition was
        // the goal lines, and each was done or given up below it.
        if offered && subgoal_menu.is_empty() {
            return Ok(Err(End::Complete));
        }
        // With target subgoals, a node's only subgoals are its targets (free text is not offered:
        // tiny models' own subgoals were found to echo or drift), and a target node proposes
        // actions only.
        let with_targets = self.cfg.target_subgoals && !offered && self.cfg.strength == Strength::Feasible;
        let allow_subgoal = self.mode != ContextMode::NoSubgoalTree
            && depth + 1 < max_depth
            // (a root with lines left takes the next one: a taken line is never offered again)
            && (!st.concrete_only || offered)
            && target.is_none()
            && !with_targets
            && !self.under_offered(node)
            && !bare
            && (!offered || !subgoal_menu.is_empty());
        // `done` before any step would end a goal with nothing done; it is offered once a child
        // has been accepted, once every offered subgoal was taken, or when nothing else can be
        // written.
        // (a target node with target steps ends when its action runs, not when the model says so)
        // A root shown goal lines is decomposed into them: it is not done while one is left to take.
        // A root choosing its own goal lines (`infer_goals`) is done when the model says so, once
        // it has taken one.
        // (nor while a thing its instruction's words say is offered and none of its lines taken:
        // "put the apple in the fridge and close it"; nor when it has only gone into rooms and a
        // line about something else is offered: "go to the toilet")
        let inferring = offered && self.goals.inferred;
        let unsaid = |g: &Vec<String>| !g.iter().any(|l| st.tried.contains(l)) && g.iter().any(|l| subgoal_menu.contains(l));
        // (below a line of a verb taken lying or sitting, SLEEP, the posture is the way to it, as
        // a target's steps are to its action: the line ends when the verb runs, once it can;
        // SmolLM2 lay on the sofa for "sleep" and said done)
        let posture_way = self.under_offered(node)
            && matches!(self.goals.meaning(&self.tree.node(node).text), Some(goals::Meaning::Verb(v)) if goals::TAKEN_IN_A_POSTURE.contains(v))
            && !matches!(&actions, ActionSet::Exact(l) if l.is_empty());
        let allow_done = if inferring {
            let arrived_only = self.goals.only_arrived(self.world()?, &st.tried, &subgoal_menu);
            !st.tried.is_empty() && !self.goals.said.iter().any(unsaid) && !arrived_only
        } else if posture_way {
            false
        } else {
            !(target.is_some() && self.cfg.target_steps)
                && !(offered && allow_subgoal)
                && (st.accepted > 0 || (!allow_subgoal && actions.is_empty()))
        };
        // While offered lines remain, the root decomposes into them (actions come below them):
        // given the choice, both models wrote actions at the root and never took a line.
        let actions = if offered && allow_subgoal { ActionSet::Exact(Vec::new()) } else { actions };
        if self.cfg.show_effects {
            view.options = self.effects_menu(&actions, &targets)?;
        }
        if inferring {
            view.options = Some(goals::menu_text(&subgoal_menu));
        }
        // Where the goals are kept, `lines_done_at` judges `done` (strictly: below it the model
        // may not write it); elsewhere `done_at` (below it the model may still write it). (The
        // root setting its own goals answers with its likeliest whole line instead: `whole`.)
        let (done_at, strict) = if self.keeps_goals() {
            (self.cfg.lines_done_at, self.cfg.lines_done_at.is_some())
        } else {
            (self.cfg.done_at, false)
        };
        let grammar = DecomposeGrammar { actions, subgoal_chars: self.cfg.subgoal_chars, allow_subgoal, allow_done, subgoal_menu };
        Ok(Ok(Menu { grammar, targets, done_at, strict, whole: inferring }))
    }

    /// The decomposition model's answer to a decision (or the random chooser's): a decision with
    /// exactly one admissible answer asks no model; where `done` may be answered the model is first
    /// scored on it (`done_check`); then it writes under the grammar, and with `--choose score` its
    /// action is replaced by the likeliest admitted one (`rank`).
    pub(super) fn propose(&mut self, node: NodeId, menu: &Menu, view: &NodeView, st: &NodeLoop) -> Result<Proposed, StopCause> {
        let dg = &menu.grammar;
        let lark = dg.to_lark().map_err(|e| StopCause::Error(format!("decomposition grammar: {e}")))?;
        let prompt = self.prompter.decompose(view);
        let text = if let Some(line) = dg.only_choice() {
            // One admissible answer: asking a model (or drawing) could not change it.
            line
        } else if self.rng.is_some() {
            match self.draw(dg, st, menu.whole) {
                Some(t) => t,
                None => return Ok(Proposed::Nothing),
            }
        } else if menu.whole {
            let uninstructed = self.uninstructed.as_ref().map(|p| p.decompose(view));
            self.likeliest(node, &prompt, uninstructed.as_ref(), dg)?
        } else if dg.allow_done && self.done_check(node, &prompt, dg.allow_subgoal, menu.done_at)? {
            "done".to_string()
        } else {
            // Below the goal lines' threshold the model is not done: `done` leaves the grammar
            // (while anything else can be written).
            let something_else = dg.allow_subgoal || !matches!(&dg.actions, ActionSet::Exact(l) if l.is_empty());
            let lark = if dg.allow_done && menu.strict && something_else {
                let no_done = DecomposeGrammar { allow_done: false, ..dg.clone() };
                no_done.to_lark().map_err(|e| StopCause::Error(format!("decomposition grammar: {e}")))?
            } else {
                lark
            };
            let Some(text) = self.call("decompose", node, &prompt, &lark)? else {
                return Ok(Proposed::TokenLimit);
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
        Ok(Proposed::Text(text, proposal))
    }

    /// Whether `node` is one of the root's offered goal lines: below one the node proposes actions
    /// (the line already is the subgoal and names its objects; tiny models' own subgoals there were
    /// found to drift off them).
    pub(super) fn under_offered(&self, node: NodeId) -> bool {
        let n = self.tree.node(node);
        node != self.tree.root() && n.parent == Some(self.tree.root()) && self.goals.lines.contains(&n.text)
    }

    /// Whether every object `a` names is in the run's focus: a plan names only the objects it was
    /// given (EAI's scorer rejects any other as a hallucination), also on the way to a target (a
    /// closed container of the target that is not in the focus blocks it).
    pub(super) fn in_focus(&self, a: &Action) -> bool {
        a.args.iter().all(|o| self.focus.contains(&o.id))
    }

    /// The objects a decision at `node` may name. With `subgoal_focus`: the focus objects the node's
    /// text names, by class name or `(id)`, with the objects holding them (inside or on), so a
    /// subgoal's choices are about what it is about; a text that names none keeps the whole focus.
    /// The root does so only when its focus is the whole scene.
    pub(super) fn node_focus(&self, node: NodeId) -> Result<Vec<u32>, StopCause> {
        // The root keeps a focus the request narrowed (a task's relevant objects); over the whole
        // scene, it too is narrowed to what its instruction names.
        if !self.cfg.subgoal_focus || (node == self.tree.root() && !self.focus_is_scene) {
            return Ok(self.focus.clone());
        }
        // The root's text is the user's own words, read once at the start (`Run::root_view`).
        if node == self.tree.root() {
            return Ok(if self.root_view.is_empty() { self.focus.clone() } else { self.root_view.clone() });
        }
        let w = self.world()?;
        let named = named_objects(w, &self.focus, &self.goals.asks_now(&self.tree.node(node).text, w));
        if named.is_empty() {
            return Ok(self.focus.clone());
        }
        Ok(with_holders(w, &named, &self.focus))
    }

    /// The target subgoals a decision at `node` may write: the actions of the
    /// `typed` set over the node's objects that cannot run now (the runnable ones are offered as
    /// actions) and that the world knows a way to, moves left out (a walk is never out of reach),
    /// each taken at most once per node, and only those that change something among their objects.
    /// `feasible` is the node's feasible set. Empty unless `PlannerConfig::target_subgoals` and
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
        let mut candidates = typed_actions(w, &self.node_focus(node)?);
        // Below a left hand's hold line with the right hand free, the way to it is to grab
        // something else first (GRAB fills the right hand first): the focus's other grabs too.
        if let Some(x) = self.left_hand_to_fill(node) {
            let others: Vec<Action> = typed_actions(w, &self.focus)
                .into_iter()
                .filter(|a| a.verb == Verb::Grab && a.args.first().is_some_and(|o| o.id != x) && !candidates.contains(a))
                .collect();
            candidates.extend(others);
        }
        // Below a goal line whose fact holds, no target whose way undoes it: the way may undo a
        // line that a later line can take again, but not the one being worked on, which is met
        // (a robot sitting on the chair it was to sit on stood up on the way to carrying that chair).
        let own_met: Vec<Fact> = if self.keeps_goals() && self.under_offered(node) {
            self.met_line_fact(&self.tree.node(node).text).cloned().into_iter().collect()
        } else {
            Vec::new()
        };
        // Only targets the world knows a way to: not an affordance error, not already so.
        let menu = candidates
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
                    && !(self.keeps_goals() && makes_false(&before, &after, &self.goals.kept))
                    // (the way may undo what a later step can set again: the fridge opened on the
                    // way to a PUTIN closes again, the robot walks back to the sofa; not a kept
                    // relation of the very object the target places: the coffee that is to stay ON
                    // the coffee maker, grabbed on the way to a PUTIN into it)
                    && !(self.keeps_goals() && makes_false(w, &after, &relations_of(&self.goals.kept, a)))
                    // (nor the line it is taken under, while that line holds: `own_met`)
                    && !makes_false(w, &after, &own_met)
                    // (nor may it take a hand a hold line reserves, way included)
                    && !(self.keeps_goals() && takes_a_reserved_hand(w, &after, &self.goals.kept))
                    && !(self.skips_idle(a.verb) && changes_nothing(&before, &after, a))
            })
            .collect();
        Ok(menu)
    }

    /// Below a goal line the model set itself (`infer_goals`): only the steps and targets that
    /// make the line true (its fact holds after them, a target's way included), none where no
    /// step can (the line ends), or those that run its verb. The line is the model's own
    /// subgoal; the world knows which steps achieve it (SmolLM2 put the apple ON the fridge under
    /// "apple is INSIDE to fridge").
    /// Below a shown line that names actions ("POUR", "READ or LOOKAT"), only those actions, read
    /// from the line's words: a step of another verb is not congruent with it (SmolLM2 wrote
    /// PUTBACK under "POUR" in every "Make coffee"). A shown line's fact is never worked out in
    /// the world: which steps make the task's own goals true would be the oracle the method
    /// rules out. Either way, a thing to be washed by hand is taken first (`held_to_wash`).
    fn toward_own_line(&self, node: NodeId, actions: ActionSet, targets: &[Action]) -> Result<ActionSet, StopCause> {
        let ActionSet::Exact(list) = actions else { return Ok(actions) };
        if !self.cfg.toward_lines || !self.under_offered(node) {
            return Ok(ActionSet::Exact(list));
        }
        let text = &self.tree.node(node).text;
        let w = self.world()?;
        let named = &self.goals.named_objects;
        let on_named = |a: &&Action| !a.args.is_empty() && a.args.iter().all(|o| named.contains(&o.id));
        // By a verb the instruction says of the object, where one does it.
        let said_of = |a: &&Action| a.args.first().is_some_and(|o| self.goals.wording.verbs_of(o.id).contains(&a.verb));
        let achieving: Vec<Action> = match self.goals.meaning(text) {
            // An action line is done on the objects the words say it of, else on named ones
            // (SmolLM2 washed the bathtub for "wash the dishes"), where it can be.
            Some(goals::Meaning::Verb(v)) => {
                let doing: Vec<Action> = list.iter().filter(|a| a.verb == *v).cloned().collect();
                let said: Vec<u32> = self.goals.wording.said.iter().filter(|(_, x)| x == v).map(|(o, _)| *o).collect();
                // Where none it is said of is within reach (the plates across the kitchen), the
                // walk to them first: an action line's step is never a target (it changes nothing).
                let walks: Vec<Action> =
                    list.iter().filter(|a| a.verb == Verb::Walk && a.args.first().is_some_and(|o| said.contains(&o.id))).cloned().collect();
                if !doing.iter().any(|a| said_of(&a)) && !walks.is_empty() {
                    walks
                } else if doing.is_empty() {
                    // Where the verb cannot be done now (the water to drink is not in hand), the
                    // first step of the way to doing it on a named object (one the words say it
                    // of, where there is one); with no way, none, and the line ends. Any step at
                    // all was offered before: SmolLM2 sat on six seats in turn under "DRINK".
                    let aims = typed_actions(w, named).into_iter().filter(|a| a.verb == *v).collect();
                    let aims = narrowed(aims, said_of);
                    // A verb of no object that waits for the robot to lie or sit (SLEEP): the
                    // posture, on a named thing where one fits, else on one of the focus; where
                    // it can be taken now, that step itself (a way leads up to it, not into it).
                    let postures = narrowed(goals::bare_postures(w, *v, &self.focus, &self.focus), on_named);
                    let now: Vec<Action> = postures.iter().filter(|a| list.contains(a)).cloned().collect();
                    if !now.is_empty() {
                        return Ok(ActionSet::Exact(now));
                    }
                    let aims = if postures.is_empty() { aims } else { postures };
                    return Ok(ActionSet::Exact(self.first_steps(w, aims, &list, |_, _| true)));
                } else {
                    narrowed(narrowed(doing, on_named), said_of)
                }
            }
            Some(goals::Meaning::Fact(f)) => {
                let making: Vec<Action> =
                    list.iter().filter(|a| outcome(w, a, targets).is_some_and(|after| after.holds(f))).cloned().collect();
                // With no step that makes it true now, the way in, else none and the line ends
                // (any step was offered before: SmolLM2 switched on the phone it was to put on
                // the desk).
                if making.is_empty() {
                    return Ok(ActionSet::Exact(self.way_in(w, f, &list, targets)));
                }
                // A line about the robot alone ("character is SITTING") came of an action on an
                // object the instruction names: made true there, where it can be (SmolLM2 sat
                // on a chair when asked to sit on the sofa).
                let alone = matches!(f, Fact::State { id, .. } if *id == w.character());
                let making = if alone { narrowed(making, on_named) } else { making };
                // A liquid no hand can hold by itself (water) is poured, where pouring makes the
                // line true, not put: VirtualHome's programs never put water anywhere. So is a
                // drink into a cup ("fill the mug with milk": SmolLM2 put the milk carton in it),
                // but not a cup itself (the mug is put in the sink, not poured).
                let recipient = |o: &ObjRef| w.node(o.id).is_some_and(|n| n.properties.contains(Property::Recipient));
                let poured = |a: &&Action| {
                    let (Some(what), Some(into)) = (a.args.first(), a.args.get(1)) else { return false };
                    a.verb == Verb::Pour && (!goals::can_be_held(w, what.id) || (recipient(into) && !recipient(what)))
                };
                let making = narrowed(making, poured);
                // And by a verb the instruction says of the object ("sit on the sofa": SIT, not
                // LIE, for "character is ON to sofa").
                narrowed(making, said_of)
            }
            None => {
                let verbs = goals::line_verbs(text);
                list.iter().filter(|a| verbs.contains(&a.verb)).cloned().collect()
            }
        };
        Ok(ActionSet::Exact(if achieving.is_empty() { list } else { self.held_to_wash(w, &list, achieving) }))
    }

    /// A thing washed by hand is held first: where a hand can take it now, the step toward
    /// washing it (WASH, RINSE, SCRUB, WIPE) is to take it, and while one is held it is washed
    /// before another is taken. SmolLM2 washed the plate where it lay; VirtualHome's programs of
    /// washing dishes by hand grab each dish before they wash it.
    fn held_to_wash(&self, w: &World, list: &[Action], achieving: Vec<Action>) -> Vec<Action> {
        if self.cfg.excluded_verbs.contains(&Verb::Grab) {
            return achieving;
        }
        let held = |id: u32| w.holds(&Fact::Holds { from: w.character(), to: Some(id) });
        let by_hand = |a: &Action| goals::WASHING.contains(&a.verb) && a.args.first().is_some_and(|x| goals::can_be_held(w, x.id));
        let washes_held = achieving.iter().any(|a| by_hand(a) && held(a.args[0].id));
        let mut steps: Vec<Action> = Vec::new();
        for a in achieving {
            let step = if !by_hand(&a) || held(a.args[0].id) {
                a
            } else if washes_held {
                continue;
            } else {
                let grab = Action { verb: Verb::Grab, args: vec![a.args[0].clone()] };
                if list.contains(&grab) { grab } else { a }
            };
            if !steps.contains(&step) {
                steps.push(step);
            }
        }
        steps
    }

    /// The first step of the world's way to each of `aims` that `ok` takes (given the world the
    /// way leaves before the aim), where the way stays in the focus and that step is offered in
    /// `list`; each step once.
    fn first_steps(&self, w: &World, aims: Vec<Action>, list: &[Action], ok: impl Fn(&World, &Action) -> bool) -> Vec<Action> {
        let mut first: Vec<Action> = Vec::new();
        for a in aims {
            let Some((way, before)) = w.way_to(&a) else { continue };
            if way.iter().all(|s| self.in_focus(s)) && ok(&before, &a) {
                first.extend(way.into_iter().next().filter(|s| list.contains(s) && !first.contains(s)));
            }
        }
        first
    }

    /// The steps toward a fact line that no step of `list` makes true now: the first step of the
    /// world's way to a step that does (STANDUP before the walk into the bedroom); else, for a
    /// hold line whose hand holds something else, the steps that put that thing down (the
    /// world's way to a grab never empties a hand; the thing held may be outside the line's
    /// objects, so its own steps too, where they undo no line kept); else none.
    fn way_in(&self, w: &World, f: &Fact, list: &[Action], targets: &[Action]) -> Vec<Action> {
        let robot = w.character();
        let ids: Vec<u32> = match *f {
            Fact::Edge { from, to, .. } => vec![from, to],
            Fact::State { id, .. } => vec![id],
            Fact::Holds { from, to } => std::iter::once(from).chain(to).collect(),
        };
        let ids: Vec<u32> = ids.into_iter().filter(|&id| id != robot).collect();
        let makes = |before: &World, a: &Action| trial(before, a).is_some_and(|after| after.holds(f));
        let first = self.first_steps(w, typed_actions(w, &ids), list, makes);
        if !first.is_empty() {
            return first;
        }
        let Fact::Edge { from, relation: hand @ (Relation::HoldsRh | Relation::HoldsLh), to: x } = *f else { return Vec::new() };
        if from != robot {
            return Vec::new();
        }
        let Some(other) = w.edges().into_iter().find(|&(by, r, t)| by == robot && r == hand && t != x).map(|e| e.2) else {
            return Vec::new();
        };
        let held = Fact::Edge { from: robot, relation: hand, to: other };
        let own = w.feasible_actions_among(&[other]).into_iter().filter(|a| {
            !self.cfg.excluded_verbs.contains(&a.verb)
                && !list.contains(a)
                && trial(w, a).is_some_and(|after| !(self.keeps_goals() && makes_false(w, &after, &self.goals.kept)))
        });
        let mut steps: Vec<Action> = list.iter().cloned().chain(own).collect();
        steps.retain(|a| outcome(w, a, targets).is_some_and(|after| !after.holds(&held)));
        steps
    }

    /// Whether the model is done at `node` by its own probability of `done` as its answer's first
    /// word (see `PlannerConfig::done_at`). A model that cannot score leaves it to generation.
    fn done_check(&mut self, node: NodeId, prompt: &Prompt, subgoals: bool, at: Option<f64>) -> Result<bool, StopCause> {
        let Some(at) = at else { return Ok(false) };
        self.check_global()?;
        let mut words = vec!["done".to_string(), "action:".to_string()];
        if subgoals {
            words.push("subgoal:".to_string());
        }
        let hash = prompt_hash(prompt, &words.join("\n"));
        super::planner::log_prompt("done_check", node, prompt);
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
        self.record(CallRecord::of_scoring("done_check", node, hash, &scoring, if done { "done" } else { "go on" }, total_ms));
        self.trace.event("done_check", json!({"node": node, "p_done": (p * 1000.0).round() / 1000.0, "done": done}));
        Ok(done)
    }

    /// The likeliest whole answer among the menu's subgoal lines and `done` (when offered): each is
    /// scored as the complete answer and the highest total log probability wins (the first on a
    /// tie). Greedy decoding commits to the first token alone: a tiny model that copies the
    /// menu's lines one after another never wrote `done` there, where the whole answers' odds
    /// compare `done` with each line as a whole. With `uninstructed` (the same prompt without the
    /// instruction), each score is less the answer's score there (`PlannerConfig::calibrate_lines`).
    fn likeliest(&mut self, node: NodeId, prompt: &Prompt, uninstructed: Option<&Prompt>, dg: &DecomposeGrammar) -> Result<String, StopCause> {
        let mut answers: Vec<String> = dg.subgoal_menu.iter().map(|l| format!("subgoal: {l}")).collect();
        if dg.allow_done {
            answers.push("done".to_string());
        }
        let prior = match uninstructed {
            Some(p) => {
                let likeliest = |s: &[Score]| index_of_best(s.len(), |i| s[i].logprob);
                Some(self.scores("calibrate", node, p, &answers, likeliest)?.0.iter().map(|s| s.logprob).collect::<Vec<f64>>())
            }
            None => None,
        };
        let best = self.best_scored("choose", node, prompt, &answers, |s| s.logprob, prior.as_deref(), json!({"whole": true}))?;
        Ok(answers.swap_remove(best))
    }

    /// The action of an `action:` proposal chosen by likelihood: every action of an exact set is
    /// scored whole as the proposal line, and the best per token wins (the first on a tie). Other
    /// sets, or a single choice, keep the `written` action.
    fn rank(&mut self, node: NodeId, prompt: &Prompt, set: &ActionSet, written: Action) -> Result<Action, StopCause> {
        let ActionSet::Exact(list) = set else { return Ok(written) };
        if list.len() < 2 {
            return Ok(written);
        }
        let lines: Vec<String> = list.iter().map(|a| format!("action: {a}")).collect();
        let best = self.best_scored("score", node, prompt, &lines, Score::mean, None, json!({"written": format!("action: {written}")}))?;
        Ok(list[best].clone())
    }

    /// One scoring call over `answers`: the index of the best by `key` less its `prior` (the
    /// first on a tie), recorded as a call of `role` and traced with the top five (and `fields`).
    /// `choose`: the scores are the decision itself; `score`: they rank what a decomposition call
    /// wrote.
    #[allow(clippy::too_many_arguments)]
    fn best_scored(
        &mut self,
        role: &'static str,
        node: NodeId,
        prompt: &Prompt,
        answers: &[String],
        key: fn(&Score) -> f64,
        prior: Option<&[f64]>,
        mut fields: serde_json::Value,
    ) -> Result<usize, StopCause> {
        let value = |scores: &[Score], i: usize| key(&scores[i]) - prior.map_or(0.0, |p| p[i]);
        let best_of = |scores: &[Score]| index_of_best(scores.len(), |i| value(scores, i));
        let (scores, best) = self.scores(role, node, prompt, answers, best_of)?;
        let mut top: Vec<(f64, &str)> = (0..scores.len()).map(|i| value(&scores, i)).zip(answers.iter().map(String::as_str)).collect();
        top.sort_by(|a, b| b.0.total_cmp(&a.0));
        fields["node"] = json!(node);
        fields["top"] = top.iter().take(5).map(|(s, l)| json!([l, (s * 1000.0).round() / 1000.0])).collect();
        self.trace.event("scores", fields);
        Ok(best)
    }

    /// One scoring call over `answers`: the scores and the index `pick` chooses among them,
    /// recorded as a call of `role` whose output is that answer.
    fn scores(
        &mut self,
        role: &'static str,
        node: NodeId,
        prompt: &Prompt,
        answers: &[String],
        pick: impl Fn(&[Score]) -> usize,
    ) -> Result<(Vec<Score>, usize), StopCause> {
        self.check_global()?;
        let hash = prompt_hash(prompt, &answers.join("\n"));
        super::planner::log_prompt(role, node, prompt);
        let t = Instant::now();
        let scoring = self.model.score(prompt, answers).map_err(|e| {
            self.trace.event("call_error", json!({"role": role, "node": node, "prompt_hash": hash,
                "kind": "error", "error": e.to_string()}));
            StopCause::Error(format!("score call at node {node}: {e}"))
        })?;
        let total_ms = t.elapsed().as_secs_f64() * 1e3;
        self.stats.llm_calls += 1;
        let best = pick(&scoring.scores);
        self.record(CallRecord::of_scoring(role, node, hash, &scoring, &answers[best], total_ms));
        Ok((scoring.scores, best))
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
            let facts: Vec<String> = outcome(w, a, targets).map(|after| gained(w, &after, a)).unwrap_or_default().iter().take(3).map(|f| w.describe(f)).collect();
            if facts.is_empty() {
                s.push_str(&format!("{a}: nothing new\n"));
            } else {
                s.push_str(&format!("{a}: {}\n", facts.join(", ")));
            }
        }
        Ok(Some(s))
    }

    /// The `random` planner's decomposition, in place of the model's (it walks the tree only when
    /// subgoals are offered; see `planner::plan`): at the root, an offered line not yet taken, drawn
    /// uniformly; below it, a uniform draw among the admitted actions until the node has executed
    /// `random_steps` of them (or none is left), then `done`. Its only stopping rule is that fixed
    /// length: nothing in it looks at the goals' state.
    /// `None`: nothing can be drawn and `done` is not offered (no step taken): the node is given up.
    fn draw(&mut self, dg: &DecomposeGrammar, st: &NodeLoop, setting_goals: bool) -> Option<String> {
        let rng = self.rng.as_mut().expect("draw is called for the random planner only");
        // A root setting its own goals (`infer_goals`) sets `random_lines` of them, then is done.
        if setting_goals && st.tried.len() >= self.cfg.random_lines && dg.allow_done {
            return Some("done".to_string());
        }
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

/// The world after `a`: run now, or, for one of the `targets`, after its way.
fn outcome(w: &World, a: &Action, targets: &[Action]) -> Option<World> {
    if targets.contains(a) {
        w.before_running(a).and_then(|b| trial(&b, a))
    } else {
        trial(w, a)
    }
}

/// `named` and, after them, the objects of `focus` that hold one of them (it is on or inside
/// them), rooms aside: a choice about an object includes where it is.
pub(crate) fn with_holders(w: &World, named: &[u32], focus: &[u32]) -> Vec<u32> {
    let mut out = named.to_vec();
    for (from, r, to) in w.edges() {
        if named.contains(&from)
            && matches!(r, Relation::Inside | Relation::On)
            && focus.contains(&to)
            && !out.contains(&to)
            && !w.node(to).is_some_and(|n| n.is_room())
        {
            out.push(to);
        }
    }
    out
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

/// The most steps [`Run::effects_menu`] shows (a prompt's tail stays a few hundred tokens).
const MAX_SHOWN_STEPS: usize = 24;

/// The index in `0..n` of the greatest `value` (the first on a tie; 0 where `n` is 0).
fn index_of_best(n: usize, value: impl Fn(usize) -> f64) -> usize {
    (0..n).fold(0, |best, i| if value(i) > value(best) { i } else { best })
}

/// The actions of `list` that pass `keep`, where any does; else `list` whole: a preference among
/// ways, never a reason to have none.
fn narrowed(list: Vec<Action>, keep: impl Fn(&&Action) -> bool) -> Vec<Action> {
    if list.iter().any(|a| keep(&a)) {
        list.into_iter().filter(|a| keep(&a)).collect()
    } else {
        list
    }
}
