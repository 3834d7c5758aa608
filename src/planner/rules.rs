//! The rules over the world that narrow what a decision is offered, each a flag of
//! `PlannerConfig`, each obeyed by the random chooser too so that figures stay comparable: fresh
//! steps (no repeats), protected changes (a node does not undo its own work), kept goals (nothing
//! the shown goals ask for is undone, and a hand a hold line reserves stays free for it), idle
//! steps (none that change nothing). They try candidates on a copy of the world. None of them
//! ends a run or a line: when to stop stays the model's decision.

use serde_json::json;

use super::planner::{NodeLoop, Run};
use super::tree::NodeId;
use super::StopCause;
use crate::action::{Action, Verb};
use crate::grammar::ActionSet;
use crate::world::vocab::Relation;
use crate::world::{Fact, World};

impl Run<'_> {
    /// The actions of `set` (an exact set) that undo nothing to keep and, below the root, are not
    /// idle: neither what this node's steps changed (`protect_changes`) nor what the task asks for
    /// (`keep_goals`) is made false (the node's own changes may give way to a step that makes a
    /// kept goal true), and a step that would change nothing is left out (`skip_idle`). One trial
    /// of each candidate on a copy of the world answers all three; one that cannot run is left to
    /// the checks after.
    pub(super) fn keep_what_is_done(&self, set: ActionSet, st: &NodeLoop, is_root: bool) -> Result<ActionSet, StopCause> {
        let established: &[Fact] = if self.cfg.protect_changes { &st.established } else { &[] };
        let kept: &[Fact] = if self.keeps_goals() { &self.goals.kept } else { &[] };
        let idle_rule = !is_root && self.idle_rule();
        let ActionSet::Exact(list) = set else { return Ok(set) };
        if established.is_empty() && kept.is_empty() && !idle_rule {
            return Ok(ActionSet::Exact(list));
        }
        let w = self.world()?;
        // A step that brings about a kept goal fact may undo the node's own earlier changes (the
        // plate it put on the food does not stop it picking the food up); never a kept fact.
        let keep = |a: &Action| {
            trial(w, a).is_none_or(|after| {
                !makes_false(w, &after, kept)
                    && (!makes_false(w, &after, established) || gains_any(w, &after, kept))
                    && !takes_a_reserved_hand(w, &after, kept)
                    && !(idle_rule && self.skips_idle(a.verb) && changes_nothing(w, &after, a))
            })
        };
        Ok(ActionSet::Exact(list.into_iter().filter(|a| keep(a)).collect()))
    }

    /// Whether the rules for shown goals apply (see `PlannerConfig::keep_goals`): steps that undo
    /// what the task asks for are left out, and with them idle steps and `lines_done_at`. A task
    /// whose goals are only closeness and actions (pet the cat: be close to it, TOUCH it) keeps no
    /// fact, yet its lines are goal lines all the same.
    pub(super) fn keeps_goals(&self) -> bool {
        self.cfg.keep_goals && (!self.goals.kept.is_empty() || !self.goals.named_verbs.is_empty())
    }

    /// Whether idle steps are left out at all (`PlannerConfig::skip_idle`, where the goals are kept).
    fn idle_rule(&self) -> bool {
        self.cfg.skip_idle && self.keeps_goals()
    }

    /// Whether a step of `verb` that changes nothing is left out: under the idle rule, unless the
    /// goals name the verb as an action the plan must include.
    pub(super) fn skips_idle(&self, verb: Verb) -> bool {
        self.idle_rule() && !self.goals.named_verbs.contains(&verb)
    }

    /// The object of `line` when it is a left hand's hold line that is not met and cannot be met
    /// by a grab now: the right hand is free (GRAB fills it first) and the object is not held.
    fn left_hold_before_right(&self, line: &str) -> Option<u32> {
        if !self.keeps_goals() {
            return None;
        }
        let w = self.env.world()?;
        let Fact::Edge { relation: Relation::HoldsLh, to: x, .. } = *self.line_fact(line)? else { return None };
        (!w.held().iter().any(|&(h, id)| h == Relation::HoldsRh || id == x)).then_some(x)
    }

    /// Whether the root's goal line `line` waits for its hand: it asks for something in the left
    /// hand while the right hand is free and another line, not yet taken, asks for something else
    /// there. GRAB fills the right hand first, so the left hand's line is met only after the right
    /// one (see `takes_a_reserved_hand`, which keeps a step from spoiling either). An inferred
    /// left-hand line waits for its own right-hand twin the same way
    /// ([`Goals::waits_for_the_right_hand`](super::goals::Goals::waits_for_the_right_hand)).
    pub(super) fn waits_for_its_hand(&self, line: &str, tried: &[String]) -> bool {
        if self.goals.waits_for_the_right_hand(line, tried) {
            return true;
        }
        let (Some(x), Some(w)) = (self.left_hold_before_right(line), self.env.world()) else { return false };
        self.goals.kept.iter().any(|g| {
            if !matches!(*g, Fact::Edge { relation: Relation::HoldsRh, to: y, .. } if y != x) || w.holds(g) {
                return false;
            }
            let right_line = w.describe(g);
            !tried.contains(&right_line) && self.goals.lines.contains(&right_line)
        })
    }

    /// The object of the left hand's hold line `node` works on, while the right hand is free and
    /// the object is not held: grabbing it now would put it in the right hand.
    pub(super) fn left_hand_to_fill(&self, node: NodeId) -> Option<u32> {
        if !self.under_offered(node) {
            return None;
        }
        self.left_hold_before_right(&self.tree.node(node).text)
    }

    /// The kept fact a goal line states, if it states one (an action line, or closeness, does not).
    pub(super) fn line_fact(&self, line: &str) -> Option<&Fact> {
        let w = self.env.world()?;
        self.goals.kept.iter().find(|f| w.describe(f) == line)
    }

    /// [`Self::line_fact`], when it holds now: the line is met.
    pub(super) fn met_line_fact(&self, line: &str) -> Option<&Fact> {
        let w = self.env.world()?;
        self.line_fact(line).filter(|f| w.holds(f))
    }

    /// Where the goals are kept: a goal line that was met when done, and whose fact a later step
    /// has made false (a target's way: SWITCHOFF of a dishwasher that is to be on, to open it and
    /// put the plates in), is offered to the root again, each time it is undone, up to
    /// [`REOFFERS`] times (a fragile fact, FACING the computer, is undone by every later line
    /// that walks or turns). Not a stop rule: it only lets the root take a line again that its
    /// own steps undid; lines given up are not offered again.
    pub(super) fn undone_lines(&mut self, st: &mut NodeLoop) -> Result<(), StopCause> {
        let w = self.world()?;
        let undone: Vec<String> = st
            .met_lines
            .iter()
            .filter(|l| st.reoffered.iter().filter(|r| r == l).count() < REOFFERS)
            .filter(|l| self.line_fact(l).is_some_and(|f| !w.holds(f)))
            // (not a line a later one let go: the bread's place in the microwave, once it is to
            // be on the plate)
            .filter(|l| !self.goals.contradicts_taken(l))
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

    /// Records in `st` what the step that just ran changed, but holding and closeness (means, not
    /// ends: a grab is undone by the put it was for).
    pub(super) fn establish(&self, st: &mut NodeLoop) {
        let means = |f: &Fact| is_edge(f, &[Relation::HoldsRh, Relation::HoldsLh, Relation::Close]);
        st.established.extend(self.last_change.iter().filter(|f| !means(f)).cloned());
    }
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

/// How many of the run's latest actions [`fresh_steps`] keeps from being chosen again.
pub const RECENT: usize = 3;

/// The run's last [`RECENT`] actions.
pub(super) fn recent(executed: &[Action]) -> &[Action] {
    &executed[executed.len().saturating_sub(RECENT)..]
}

/// The facts among `a`'s objects and the robot that hold `after` it and not `now` (see
/// [`new_facts`]).
pub(super) fn gained(now: &World, after: &World, a: &Action) -> Vec<Fact> {
    let ids: Vec<u32> = a.args.iter().map(|o| o.id).collect();
    new_facts(now.character(), after.facts_among(&ids), |f| now.holds(f))
}

/// The facts of `then` that did not hold before (`held`), as the rules and a step's report both
/// say them: closeness only as the robot's (its mirror, or two objects put side by side, says
/// nothing a goal line asks), and no object's relation to itself.
pub(super) fn new_facts(robot: u32, then: Vec<Fact>, held: impl Fn(&Fact) -> bool) -> Vec<Fact> {
    let said = |f: &Fact| match *f {
        Fact::Edge { from, to, .. } if from == to => false,
        Fact::Edge { from, relation: Relation::Close, .. } => from == robot,
        _ => true,
    };
    then.into_iter().filter(|f| !held(f) && said(f)).collect()
}

/// Whether the state `after` a target's way holds a fact among the target's objects that does not
/// hold now, closeness aside: a target that changes nothing (putting the apple back where it lies,
/// by way of a grab) is no subgoal.
pub(super) fn changes_its_objects(now: &World, after: &World, target: &Action) -> bool {
    gained(now, after, target).iter().any(|f| !is_edge(f, &[Relation::Close]))
}

/// How many times one goal line is offered to the root again after later steps undid it: the
/// cap bounds the run (two lines whose ways undo each other cannot go on forever).
pub(super) const REOFFERS: usize = 3;

/// Whether a fact of `facts` that holds `now` does not hold `after`.
pub(super) fn makes_false(now: &World, after: &World, facts: &[Fact]) -> bool {
    facts.iter().any(|f| now.holds(f) && !after.holds(f))
}

/// Whether a fact of `facts` that does not hold `now` holds `after`.
pub(super) fn gains_any(now: &World, after: &World, facts: &[Fact]) -> bool {
    facts.iter().any(|f| !now.holds(f) && after.holds(f))
}

/// Whether going from `now` to `after` spoils a hold the task asks for and does not have yet: the
/// hand a goal line reserves (free now) takes another object, or the line's object lands in the
/// other hand (unless a line asks for it there too). VirtualHome's GRAB fills the right hand first,
/// so "hold the toothbrush in the left hand" is met by grabbing it second, never first; a tiny model
/// cannot see that, and a random one meets it by chance.
pub(super) fn takes_a_reserved_hand(now: &World, after: &World, kept: &[Fact]) -> bool {
    let (held_now, held_after) = (now.held(), after.held());
    kept.iter().any(|f| {
        let Fact::Edge { from, relation: hand @ (Relation::HoldsRh | Relation::HoldsLh), to: x } = *f else { return false };
        if now.holds(f) {
            return false;
        }
        let other = if hand == Relation::HoldsRh { Relation::HoldsLh } else { Relation::HoldsRh };
        let elsewhere = Fact::Edge { from, relation: other, to: x };
        let hand_taken = !held_now.iter().any(|&(h, _)| h == hand) && held_after.iter().any(|&(h, id)| h == hand && id != x);
        let wrong_hand = !now.holds(&elsewhere) && after.holds(&elsewhere) && !kept.contains(&elsewhere);
        hand_taken || wrong_hand
    })
}

/// The world after running `a` on a copy of `w`, if it can run.
pub(super) fn trial(w: &World, a: &Action) -> Option<World> {
    let mut after = w.clone();
    after.execute(a).ok()?;
    Some(after)
}

/// Whether the facts among `a`'s objects and the robot are the same `after` it as `now` (nothing
/// gained, nothing lost).
pub(super) fn changes_nothing(now: &World, after: &World, a: &Action) -> bool {
    let ids: Vec<u32> = a.args.iter().map(|o| o.id).collect();
    let (before, then) = (now.facts_among(&ids), after.facts_among(&ids));
    before.len() == then.len() && then.iter().all(|f| before.contains(f))
}

/// Whether all `a` does, run `now` (on the way from `start`), is to let go of what a hand holds
/// and bring back what held at `start`: water poured where it already was (VirtualHome's houses
/// keep the coffee maker's water inside it; the way to pour it takes it out in hand). Like a step
/// that changes nothing, it brings about no line a goal can ask, only its verb.
pub(super) fn only_lets_go(start: &World, now: &World, after: &World, a: &Action) -> bool {
    let ids: Vec<u32> = a.args.iter().map(|o| o.id).collect();
    let (before, then) = (now.facts_among(&ids), after.facts_among(&ids));
    let hand = |f: &Fact| is_edge(f, &[Relation::HoldsRh, Relation::HoldsLh]);
    then.iter().all(|f| before.contains(f) || start.holds(f)) && before.iter().all(|f| then.contains(f) || hand(f))
}

/// Whether `f` is an edge of one of these relations.
pub(super) fn is_edge(f: &Fact, relations: &[Relation]) -> bool {
    matches!(f, Fact::Edge { relation, .. } if relations.contains(relation))
}
