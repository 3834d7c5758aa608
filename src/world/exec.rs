//! The executor: VirtualHome's evolving-graph semantics for every primitive action.
//!
//! Each verb is one function that checks the action's preconditions against the current state, in
//! the order VirtualHome/EAI check them, and returns either the list of changes the action makes or a
//! typed failure. [`World::check`] stops there; [`World::execute`] applies the changes. One code path
//! decides both, so "feasible" and "would execute" cannot disagree.
//!
//! Failures follow EAI's error taxonomy. A missing precondition that held earlier in the run (and a
//! later step undid) is a wrong-order error, as EAI's temporal-order checker decides it. Where EAI's
//! label is misleading for a planner (a closed container is an "affordance" error there, an unplugged
//! appliance an "already satisfied" one), `kind` is ours and `eai_kind` keeps EAI's label.
//!
//! Where EAI's executor is more lenient than one might expect, it is followed, because plans are
//! scored against it: closed doors never block a walk (its door check is disabled), PUTBACK/PUTIN do
//! not require SURFACES/CONTAINERS on the destination, PUSH does not require MOVABLE, PLUGOUT of an
//! appliance that is on goes through, STANDUP keeps the robot's ON edge to the seat.

use std::collections::BTreeMap;
use std::fmt;

use serde::Serialize;

use super::state::{Ix, World};
use super::vocab::{Property, Relation, State};
use crate::action::{Action, ObjRef, Verb};

/// EAI's error categories for a step that cannot run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum FailureKind {
    /// A precondition that an earlier step should have established (walk there, open it, grab it).
    MissingStep,
    /// A precondition that held earlier in this run and was undone by a later step.
    WrongOrder,
    /// The object can never take this action (SIT on a fridge, GRAB a wall).
    Affordance,
    /// The action's effect already holds (OPEN an open fridge); the step changes nothing.
    AdditionalStep,
    /// An object id that is not in the scene, or whose class is not the one named: a hallucination.
    UnknownObject,
    /// The wrong number of objects for the verb.
    WrongArity,
}

impl FailureKind {
    /// Snake-case name used in reports.
    pub fn name(self) -> &'static str {
        match self {
            FailureKind::MissingStep => "missing_step",
            FailureKind::WrongOrder => "wrong_order",
            FailureKind::Affordance => "affordance",
            FailureKind::AdditionalStep => "additional_step",
            FailureKind::UnknownObject => "unknown_object",
            FailureKind::WrongArity => "wrong_arity",
        }
    }
}

impl fmt::Display for FailureKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A fact a failed precondition needed (as EAI records it, to tell a missing step from a wrong order).
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub enum Fact {
    /// An edge `from relation to`.
    Edge { from: u32, relation: Relation, to: u32 },
    /// The character holds `to` in either hand; `None`: holds anything.
    Holds { from: u32, to: Option<u32> },
    /// A node state.
    State { id: u32, state: State },
}

/// One precondition that did not hold: `fact`, or its negation.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Missing {
    pub negated: bool,
    pub fact: Fact,
}

/// How several missing preconditions combine (EAI's connective).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Connective {
    /// Only the first one counts.
    First,
    All,
    Any,
}

/// Why an action could not run, in words a model can act on.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, thiserror::Error)]
#[error("{message}")]
pub struct ExecFailure {
    pub kind: FailureKind,
    /// EAI's own label for this failure (differs from `kind` in the few documented places).
    pub eai_kind: FailureKind,
    pub action: Action,
    /// e.g. `cannot GRAB <apple> (12): the robot is not close to it; WALK to <apple> (12) first`.
    pub message: String,
    pub missing: Vec<Missing>,
    pub connective: Connective,
}

/// What a successful action changed (net of changes that cancel out), ids sorted.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Effects {
    pub added: Vec<(u32, Relation, u32)>,
    pub removed: Vec<(u32, Relation, u32)>,
    pub states_added: Vec<(u32, State)>,
    pub states_removed: Vec<(u32, State)>,
}

impl Effects {
    /// Whether the action changed nothing in the graph (LOOKAT, TOUCH, …).
    pub fn is_empty(&self) -> bool {
        self.added.is_empty()
            && self.removed.is_empty()
            && self.states_added.is_empty()
            && self.states_removed.is_empty()
    }
}

/// One change to the state. Set-valued targets are resolved when applied, in order, as the
/// simulator's state changers are.
#[derive(Clone, Debug)]
pub(crate) enum Op {
    Add(Ix, Relation, Ix),
    /// Adds the edge both ways (CLOSE is symmetric).
    AddBoth(Ix, Relation, Ix),
    Remove(Ix, Relation, Ix),
    /// Removes every edge of these relations from the node, and (if `reverse`) to it.
    RemoveAll(Ix, &'static [Relation], bool),
    /// Character CLOSE (both ways) to every node INSIDE this one.
    CloseToInsideOf(Ix, Ix),
    /// Character CLOSE (both ways) to every node this one is ON.
    CloseToSupportsOf(Ix, Ix),
    /// Character CLOSE (both ways) to every non-room node this one is INSIDE.
    CloseToContainersOf(Ix, Ix),
    /// Character CLOSE (both ways) to every body part.
    CloseToBodyParts(Ix),
    /// Character FACING whatever this node faces (sitting on a sofa faces the sofa's TV).
    FaceAsIt(Ix, Ix),
    State(Ix, State, bool),
    GrabRecord(Ix, Option<(Ix, Relation)>),
}

/// A precondition failure before it is classified (wrong order or not) and worded in full.
struct Fail {
    kind: FailureKind,
    eai_kind: FailureKind,
    reason: String,
    missing: Vec<Missing>,
    connective: Connective,
}

impl Fail {
    fn new(kind: FailureKind, reason: impl Into<String>) -> Fail {
        Fail { kind, eai_kind: kind, reason: reason.into(), missing: Vec::new(), connective: Connective::First }
    }
    fn eai(mut self, k: FailureKind) -> Fail {
        self.eai_kind = k;
        self
    }
    fn needs(mut self, negated: bool, fact: Fact) -> Fail {
        self.missing.push(Missing { negated, fact });
        self
    }
    fn connective(mut self, c: Connective) -> Fail {
        self.connective = c;
        self
    }
}

type Check = Result<Vec<Op>, Fail>;

const FACING_ONLY: &[Relation] = &[Relation::Facing];
const WALK_CLEARS: &[Relation] = &[Relation::Inside, Relation::Close, Relation::Facing];
const GRAB_CLEARS: &[Relation] =
    &[Relation::On, Relation::Inside, Relation::Close, Relation::HoldsLh, Relation::HoldsRh];
const HANDS: &[Relation] = &[Relation::HoldsRh, Relation::HoldsLh];

use FailureKind::{AdditionalStep, Affordance, MissingStep};

impl World {
    /// Whether `action` would succeed now, and if not, why. Never changes the state.
    pub fn check(&self, action: &Action) -> Result<(), ExecFailure> {
        self.effects_of(action).map(|_| ())
    }

    /// Runs one action: on success the state changes and the net effects are returned; on failure
    /// the state is unchanged.
    pub fn execute(&mut self, action: &Action) -> Result<Effects, ExecFailure> {
        let ops = self.effects_of(action)?;
        Ok(self.apply(&ops))
    }

    /// Preconditions → the action's changes, or a classified, worded failure.
    pub(crate) fn effects_of(&self, action: &Action) -> Result<Vec<Op>, ExecFailure> {
        let fail = |kind: FailureKind, message: String| ExecFailure {
            kind,
            eai_kind: kind,
            action: action.clone(),
            message,
            missing: Vec::new(),
            connective: Connective::First,
        };
        if action.args.len() != action.verb.arity() {
            return Err(fail(
                FailureKind::WrongArity,
                format!(
                    "cannot {action}: {} takes {} object(s), got {}",
                    action.verb,
                    action.verb.arity(),
                    action.args.len()
                ),
            ));
        }
        let mut ixs = Vec::with_capacity(2);
        for a in &action.args {
            ixs.push(self.resolve(a).map_err(|m| fail(FailureKind::UnknownObject, format!("cannot {action}: {m}")))?);
        }
        let a = ixs.first().copied().unwrap_or(0);
        let b = ixs.get(1).copied().unwrap_or(0);
        let r = match action.verb {
            Verb::Walk | Verb::Run => self.walk(a),
            Verb::Find => self.find(a),
            Verb::Greet => self.greet(a),
            Verb::Sit => self.sit(a),
            Verb::Lie => self.lie(a),
            Verb::StandUp => self.standup(),
            Verb::Grab => self.grab(a),
            Verb::Open => self.open_close(a, false),
            Verb::Close => self.open_close(a, true),
            Verb::PutBack => self.put(a, b, Relation::On),
            Verb::PutIn => self.put(a, b, Relation::Inside),
            Verb::PutObjBack => self.putobjback(a),
            Verb::SwitchOn => self.switch(a, true),
            Verb::SwitchOff => self.switch(a, false),
            Verb::Drink => self.drink(a),
            Verb::TurnTo => Ok(vec![
                Op::RemoveAll(self.char_ix(), FACING_ONLY, false),
                Op::Add(self.char_ix(), Relation::Facing, a),
            ]),
            Verb::LookAt | Verb::LookAtShort | Verb::LookAtLong | Verb::PointAt => self.lookat(a),
            Verb::Wipe => self.wipe(a),
            Verb::PutOn => self.puton(a),
            Verb::PutOff => self.putoff(a),
            Verb::Drop | Verb::Release => self.drop_obj(a),
            Verb::Read => self.read(a),
            Verb::Touch => self.touch(a),
            Verb::Pour => self.pour(a, b),
            Verb::Type => self.type_on(a),
            Verb::Watch => self.watch(a),
            Verb::Push | Verb::Pull | Verb::Move => self.move_obj(a, action.verb),
            Verb::Wash | Verb::Rinse | Verb::Scrub => self.wash(a),
            Verb::Squeeze => self.squeeze(a),
            Verb::PlugIn => self.plug(a, true),
            Verb::PlugOut => self.plug(a, false),
            Verb::Cut => self.cut(a),
            Verb::Eat => self.eat(a),
            Verb::Sleep | Verb::WakeUp => self.sleep(),
        };
        r.map_err(|f| self.classify(action, f))
    }

    /// An action's object → node, checking the id exists and names that class.
    fn resolve(&self, o: &ObjRef) -> Result<Ix, String> {
        let Some(ix) = self.ix(o.id) else {
            let same: Vec<String> = self.ids_of_class(&o.class_name).iter().take(5).map(|i| format!("({i})")).collect();
            return Err(if same.is_empty() {
                format!("there is no object with id {} and no <{}> in the scene", o.id, o.class_name)
            } else {
                format!("there is no object with id {}; the <{}> in the scene: {}", o.id, o.class_name, same.join(", "))
            });
        };
        let actual = self.class_ix(ix);
        if actual != o.class_name {
            return Err(format!("object {} is a <{}>, not a <{}>", o.id, actual, o.class_name));
        }
        Ok(ix)
    }

    /// Wrong order (EAI's temporal-order rule) or not, and the full message.
    fn classify(&self, action: &Action, f: Fail) -> ExecFailure {
        let mut kind = f.kind;
        let mut eai_kind = f.eai_kind;
        let mut message = format!("cannot {action}: {}", f.reason);
        if f.kind == MissingStep && !f.missing.is_empty() {
            let held: Vec<bool> = f.missing.iter().map(|m| self.held_earlier(m)).collect();
            let earlier = match f.connective {
                Connective::All => held.iter().all(|&h| h),
                Connective::Any => held.iter().any(|&h| h),
                Connective::First => held.first().copied().unwrap_or(false),
            };
            if earlier {
                kind = FailureKind::WrongOrder;
                if eai_kind == MissingStep {
                    eai_kind = FailureKind::WrongOrder;
                }
                message.push_str(" (this held earlier in the plan; a later step undid it)");
            }
        }
        ExecFailure { kind, eai_kind, action: action.clone(), message, missing: f.missing, connective: f.connective }
    }

    fn held_earlier(&self, m: &Missing) -> bool {
        match (&m.fact, m.negated) {
            (Fact::Edge { from, relation, to }, false) => match (self.ix(*from), self.ix(*to)) {
                (Some(f), Some(t)) => self.edge_held_earlier(f, *relation, t),
                _ => false,
            },
            (Fact::Holds { to: Some(to), .. }, false) => self.ix(*to).is_some_and(|t| {
                let c = self.char_ix();
                self.edge_held_earlier(c, Relation::HoldsRh, t) || self.edge_held_earlier(c, Relation::HoldsLh, t)
            }),
            (Fact::Holds { to: None, .. }, false) => self.history.character_held_something,
            (Fact::Holds { to: None, .. }, true) => self.history.character_hands_were_free,
            (Fact::State { id, state }, false) => self.ix(*id).is_some_and(|i| self.state_held_earlier(i, *state)),
            (Fact::State { id, state }, true) => self.ix(*id).is_some_and(|i| self.state_absent_earlier(i, *state)),
            // EAI never records these shapes.
            (Fact::Edge { .. }, true) | (Fact::Holds { to: Some(_), .. }, true) => false,
        }
    }

    // ----- shared checks --------------------------------------------------------------------------

    /// VirtualHome's "close" with its loose rule: close to it, or close to something that is close
    /// to it or that it stands on.
    pub(crate) fn is_close(&self, node: Ix) -> bool {
        let c = self.char_ix();
        if self.has_ix(c, Relation::Close, node) {
            return true;
        }
        self.targets(c, Relation::Close)
            .any(|x| self.has_ix(x, Relation::Close, node) || self.has_ix(node, Relation::On, x))
    }

    /// INSIDE something (not a room) that is CLOSED.
    fn inside_closed(&self, node: Ix) -> Option<Ix> {
        self.targets(node, Relation::Inside).find(|&x| !self.is_room_ix(x) && self.states_ix(x).contains(State::Closed))
    }

    fn free_hand(&self) -> Option<Relation> {
        let c = self.char_ix();
        HANDS.iter().copied().find(|&h| self.targets(c, h).next().is_none())
    }

    fn holding_hand(&self, node: Ix) -> Option<Relation> {
        let c = self.char_ix();
        HANDS.iter().copied().find(|&h| self.has_ix(c, h, node))
    }

    fn is_facing(&self, node: Ix) -> bool {
        let c = self.char_ix();
        self.has_ix(c, Relation::Facing, node)
            || self.targets(c, Relation::Facing).any(|x| self.has_ix(x, Relation::Facing, node))
    }

    fn lbl(&self, ix: Ix) -> String {
        self.label_ix(ix)
    }

    fn need_close(&self, node: Ix) -> Result<(), Fail> {
        if self.is_close(node) {
            return Ok(());
        }
        let l = self.lbl(node);
        Err(Fail::new(MissingStep, format!("the robot is not close to {l}; WALK to {l} first"))
            .needs(false, Fact::Edge { from: self.character(), relation: Relation::Close, to: self.id(node) }))
    }

    fn need_free_hand(&self) -> Result<Relation, Fail> {
        self.free_hand().ok_or_else(|| {
            let held: Vec<String> =
                self.held().iter().map(|&(_, id)| self.node(id).map(|n| n.label()).unwrap_or_default()).collect();
            Fail::new(
                MissingStep,
                format!(
                    "both hands are full (holding {}); PUTBACK, PUTIN or DROP one of them first",
                    held.join(" and ")
                ),
            )
            .needs(true, Fact::Holds { from: self.character(), to: None })
            .connective(Connective::Any)
        })
    }

    fn need_holding(&self, node: Ix) -> Result<Relation, Fail> {
        self.holding_hand(node).ok_or_else(|| {
            let l = self.lbl(node);
            Fail::new(MissingStep, format!("the robot is not holding {l}; GRAB {l} first"))
                .needs(false, Fact::Holds { from: self.character(), to: Some(self.id(node)) })
        })
    }

    fn need_not_inside_closed(&self, node: Ix) -> Result<(), Fail> {
        match self.inside_closed(node) {
            None => Ok(()),
            Some(box_ix) => {
                let b = self.lbl(box_ix);
                Err(Fail::new(
                    MissingStep,
                    format!("{} is inside {b}, which is CLOSED; OPEN {b} first", self.lbl(node)),
                )
                // EAI records the object's own OPEN state here.
                .needs(false, Fact::State { id: self.id(node), state: State::Open }))
            }
        }
    }

    fn need_prop(&self, node: Ix, p: Property, what: &str) -> Result<(), Fail> {
        if self.props_ix(node).contains(p) {
            Ok(())
        } else {
            Err(Fail::new(Affordance, format!("{} {what} (it lacks {p})", self.lbl(node))))
        }
    }

    fn not_sitting_or_lying(&self) -> Result<(), Fail> {
        let c = self.char_ix();
        let s = self.states_ix(c);
        if s.contains(State::Sitting) || s.contains(State::Lying) {
            let how = if s.contains(State::Sitting) { "sitting" } else { "lying" };
            let ch = self.character();
            return Err(Fail::new(MissingStep, format!("the robot is {how}; STANDUP first"))
                .needs(true, Fact::State { id: ch, state: State::Sitting })
                .needs(true, Fact::State { id: ch, state: State::Lying })
                .connective(Connective::All));
        }
        Ok(())
    }

    // ----- verbs ----------------------------------------------------------------------------------

    fn walk(&self, node: Ix) -> Check {
        self.not_sitting_or_lying()?;
        let c = self.char_ix();
        let Some(room) = self.room_ix(node) else {
            return Err(Fail::new(
                Affordance,
                format!("{} is not in any room, so it cannot be reached", self.lbl(node)),
            ));
        };
        // Doors are never in the way: VirtualHome's closed-door check is disabled in EAI's executor.
        let old_room = self.room_ix(c);
        let held: Vec<Ix> = HANDS.iter().flat_map(|&h| self.targets(c, h)).collect();
        let mut ops = vec![Op::RemoveAll(c, WALK_CLEARS, true), Op::Add(c, Relation::Inside, room)];
        if room != node {
            ops.push(Op::CloseToContainersOf(c, node));
            ops.push(Op::CloseToBodyParts(c));
            ops.push(Op::AddBoth(c, Relation::Close, node));
        }
        for &h in &held {
            ops.push(Op::RemoveAll(h, WALK_CLEARS, true));
        }
        for &h in &held {
            ops.push(Op::AddBoth(c, Relation::Close, h));
            // Held objects land in the room the robot walked from (as the simulator does).
            if let Some(r) = old_room {
                ops.push(Op::Add(h, Relation::Inside, r));
            }
        }
        if self.props_ix(node).contains(Property::CanOpen) {
            ops.push(Op::CloseToInsideOf(c, node));
        }
        ops.push(Op::CloseToSupportsOf(c, node));
        Ok(ops)
    }

    fn find(&self, node: Ix) -> Check {
        let c = self.char_ix();
        let worn = self.has_ix(node, Relation::On, c);
        if worn || self.props_ix(node).contains(Property::BodyPart) || self.is_close(node) {
            self.need_close(node)?;
            Ok(vec![Op::RemoveAll(c, FACING_ONLY, false), Op::AddBoth(c, Relation::Close, node)])
        } else {
            self.walk(node)
        }
    }

    fn greet(&self, node: Ix) -> Check {
        self.need_prop(node, Property::Person, "is not a person")?;
        Ok(vec![])
    }

    fn occupancy_ok(&self, node: Ix, lying: bool) -> Result<(), Fail> {
        let class = self.class_ix(node);
        let max = if lying {
            match class {
                "couch" | "bathtub" | "loveseat" | "sofa" => 2,
                "bed" => 3,
                _ => 1,
            }
        } else {
            match class {
                "couch" | "bed" | "sofa" => 4,
                "loveseat" | "pianobench" | "bench" => 2,
                _ => 1,
            }
        };
        let n = self.sources(node, Relation::On).count();
        if n >= max {
            let on: Vec<String> = self.sources(node, Relation::On).take(3).map(|x| self.lbl(x)).collect();
            return Err(Fail::new(
                MissingStep,
                format!("{} is occupied ({} on it); choose another place", self.lbl(node), on.join(", ")),
            ));
        }
        Ok(())
    }

    fn sit(&self, node: Ix) -> Check {
        self.need_close(node)?;
        let c = self.char_ix();
        if self.states_ix(c).contains(State::Sitting) {
            return Err(Fail::new(AdditionalStep, "the robot is already sitting"));
        }
        self.need_prop(node, Property::Sittable, "cannot be sat on")?;
        self.occupancy_ok(node, false)?;
        Ok(vec![
            Op::Add(c, Relation::On, node),
            Op::FaceAsIt(c, node),
            Op::State(c, State::Lying, false),
            Op::State(c, State::Sitting, true),
        ])
    }

    fn lie(&self, node: Ix) -> Check {
        self.need_close(node)?;
        let c = self.char_ix();
        if self.states_ix(c).contains(State::Lying) {
            return Err(Fail::new(AdditionalStep, "the robot is already lying"));
        }
        self.need_prop(node, Property::Lieable, "cannot be lain on")?;
        self.occupancy_ok(node, true)?;
        Ok(vec![Op::Add(c, Relation::On, node), Op::State(c, State::Sitting, false), Op::State(c, State::Lying, true)])
    }

    fn standup(&self) -> Check {
        let c = self.char_ix();
        let s = self.states_ix(c);
        if !s.contains(State::Sitting) && !s.contains(State::Lying) {
            return Err(Fail::new(AdditionalStep, "the robot is not sitting or lying"));
        }
        // The simulator keeps the robot's ON edge to the seat; only the states change.
        Ok(vec![Op::State(c, State::Sitting, false), Op::State(c, State::Lying, false)])
    }

    fn grab(&self, node: Ix) -> Check {
        let class = self.class_ix(node);
        if !self.props_ix(node).contains(Property::Grabbable) && class != "water" && class != "child" {
            return Err(Fail::new(Affordance, format!("{} cannot be grabbed (it lacks GRABBABLE)", self.lbl(node))));
        }
        if self.grabbed_from.contains_key(&node) {
            return Err(Fail::new(AdditionalStep, format!("{} is already held", self.lbl(node))));
        }
        self.need_close(node)?;
        self.need_not_inside_closed(node)?;
        let hand = self.need_free_hand()?;
        let c = self.char_ix();
        // Where it came from (first of ON, INSIDE, CLOSE that is not a room): PUTOBJBACK returns it
        // there, and the robot becomes close to it. The simulator takes the first member of a Python
        // set of ids, whose order follows `id & mask` for a table sized by the set's length; we take
        // the same order, so that gold programs end in the same state (measured: see world-status).
        let from = [Relation::On, Relation::Inside, Relation::Close].into_iter().find_map(|r| {
            let ids: Vec<Ix> = self.targets(node, r).collect();
            let mask = py_set_mask(ids.len());
            ids.into_iter()
                .filter(|&x| !self.is_room_ix(x))
                .min_by_key(|&x| (self.id(x) as u64 & mask, self.id(x)))
                .map(|x| (x, r))
        });
        let mut ops =
            vec![Op::RemoveAll(node, GRAB_CLEARS, true), Op::AddBoth(c, Relation::Close, node), Op::Add(c, hand, node)];
        if let Some(room) = self.room_ix(c) {
            ops.push(Op::Add(node, Relation::Inside, room));
        }
        if let Some((x, r)) = from {
            ops.push(Op::AddBoth(c, Relation::Close, x));
            ops.push(Op::GrabRecord(node, Some((x, r))));
        }
        Ok(ops)
    }

    fn open_close(&self, node: Ix, close: bool) -> Check {
        let class = self.class_ix(node);
        if !self.props_ix(node).contains(Property::CanOpen) && class != "desk" && class != "window" {
            return Err(Fail::new(
                Affordance,
                format!("{} cannot be opened or closed (it lacks CAN_OPEN)", self.lbl(node)),
            ));
        }
        self.need_close(node)?;
        if !close {
            self.need_free_hand()?;
        }
        let s = self.states_ix(node);
        let l = self.lbl(node);
        if close && !s.contains(State::Open) {
            return Err(Fail::new(AdditionalStep, format!("{l} is not open (nothing to close)")));
        }
        if !close && !s.contains(State::Closed) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already open")));
        }
        if !close && s.contains(State::On) {
            return Err(Fail::new(MissingStep, format!("{l} is ON; SWITCHOFF {l} first"))
                .eai(AdditionalStep)
                .needs(false, Fact::State { id: self.id(node), state: State::Off }));
        }
        let (gone, new) = if close { (State::Open, State::Closed) } else { (State::Closed, State::Open) };
        Ok(vec![Op::State(node, gone, false), Op::State(node, new, true)])
    }

    /// PUTBACK / PUTIN / PUTOBJBACK's common check: holding it, close to the destination, and for
    /// INSIDE an open (or not openable) destination.
    fn puttable(&self, obj: Ix, dest: Ix, r: Relation) -> Result<(), Fail> {
        self.need_holding(obj)?;
        self.need_close(dest)?;
        if r == Relation::Inside
            && self.props_ix(dest).contains(Property::CanOpen)
            && !self.states_ix(dest).contains(State::Open)
        {
            let d = self.lbl(dest);
            return Err(Fail::new(MissingStep, format!("{d} is CLOSED; OPEN {d} first"))
                .eai(Affordance)
                .needs(false, Fact::State { id: self.id(dest), state: State::Open }));
        }
        Ok(())
    }

    fn put_ops(&self, obj: Ix, dest: Ix, r: Relation) -> Vec<Op> {
        let c = self.char_ix();
        vec![
            Op::Remove(c, Relation::HoldsLh, obj),
            Op::Remove(c, Relation::HoldsRh, obj),
            Op::AddBoth(c, Relation::Close, dest),
            Op::AddBoth(obj, Relation::Close, dest),
            Op::Add(obj, r, dest),
            Op::GrabRecord(obj, None),
        ]
    }

    fn put(&self, obj: Ix, dest: Ix, r: Relation) -> Check {
        self.puttable(obj, dest, r)?;
        Ok(self.put_ops(obj, dest, r))
    }

    fn putobjback(&self, obj: Ix) -> Check {
        let Some(&(dest, r)) = self.grabbed_from.get(&obj) else {
            let l = self.lbl(obj);
            return Err(Fail::new(MissingStep, format!("{l} was not grabbed from anywhere; GRAB {l} first"))
                .needs(false, Fact::Holds { from: self.character(), to: Some(self.id(obj)) }));
        };
        self.puttable(obj, dest, r)?;
        Ok(self.put_ops(obj, dest, r))
    }

    fn switch(&self, node: Ix, on: bool) -> Check {
        self.need_prop(node, Property::HasSwitch, "has no switch")?;
        self.need_close(node)?;
        let s = self.states_ix(node);
        let l = self.lbl(node);
        if on && !s.contains(State::Off) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already on")));
        }
        if !on && !s.contains(State::On) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already off")));
        }
        if on && s.contains(State::PluggedOut) {
            return Err(Fail::new(MissingStep, format!("{l} is unplugged; PLUGIN {l} first"))
                .eai(AdditionalStep)
                .needs(false, Fact::State { id: self.id(node), state: State::PluggedIn }));
        }
        let (gone, new) = if on { (State::Off, State::On) } else { (State::On, State::Off) };
        Ok(vec![Op::State(node, gone, false), Op::State(node, new, true)])
    }

    fn drink(&self, node: Ix) -> Check {
        let p = self.props_ix(node);
        if !p.contains(Property::Drinkable) && !p.contains(Property::Recipient) {
            return Err(Fail::new(Affordance, format!("{} is not something to drink from", self.lbl(node))));
        }
        self.need_holding(node)?;
        Ok(vec![])
    }

    fn lookat(&self, node: Ix) -> Check {
        if !self.is_facing(node) {
            let l = self.lbl(node);
            return Err(Fail::new(MissingStep, format!("the robot is not facing {l}; TURNTO {l} first"))
                .needs(false, Fact::Edge { from: self.character(), relation: Relation::Facing, to: self.id(node) }));
        }
        Ok(vec![])
    }

    fn wipe(&self, node: Ix) -> Check {
        self.need_close(node)?;
        if self.hands_free() {
            return Err(Fail::new(
                MissingStep,
                "the robot holds nothing to wipe with; GRAB a cloth (e.g. a rag or towel) first",
            )
            .needs(false, Fact::Holds { from: self.character(), to: None })
            .connective(Connective::Any));
        }
        Ok(clean(node))
    }

    fn puton(&self, node: Ix) -> Check {
        self.need_holding(node)?;
        self.need_prop(node, Property::Clothes, "is not clothing")?;
        let c = self.char_ix();
        Ok(vec![
            Op::Add(node, Relation::On, c),
            Op::Remove(c, Relation::HoldsLh, node),
            Op::Remove(c, Relation::HoldsRh, node),
        ])
    }

    fn putoff(&self, node: Ix) -> Check {
        let c = self.char_ix();
        if !self.has_ix(node, Relation::On, c) {
            return Err(Fail::new(MissingStep, format!("the robot is not wearing {}", self.lbl(node)))
                .needs(false, Fact::Edge { from: self.id(node), relation: Relation::On, to: self.character() }));
        }
        self.need_prop(node, Property::Clothes, "is not clothing")?;
        Ok(vec![Op::Remove(node, Relation::On, c)])
    }

    fn drop_obj(&self, node: Ix) -> Check {
        self.need_holding(node)?;
        let c = self.char_ix();
        let mut ops = vec![Op::Remove(c, Relation::HoldsLh, node), Op::Remove(c, Relation::HoldsRh, node)];
        if let Some(room) = self.room_ix(c) {
            ops.push(Op::Add(node, Relation::Inside, room));
        }
        ops.push(Op::GrabRecord(node, None));
        Ok(ops)
    }

    fn read(&self, node: Ix) -> Check {
        self.need_prop(node, Property::Readable, "cannot be read")?;
        self.need_holding(node)?;
        Ok(vec![])
    }

    fn touch(&self, node: Ix) -> Check {
        self.need_close(node)?;
        self.need_not_inside_closed(node)?;
        Ok(vec![])
    }

    fn pour(&self, src: Ix, dest: Ix) -> Check {
        let p = self.props_ix(src);
        if !p.contains(Property::Pourable) && !p.contains(Property::Drinkable) {
            return Err(Fail::new(Affordance, format!("{} cannot be poured", self.lbl(src))));
        }
        let dc = self.class_ix(dest);
        if !self.props_ix(dest).contains(Property::Recipient) && !matches!(dc, "hands_both" | "sponge" | "face") {
            return Err(Fail::new(
                Affordance,
                format!("{} cannot receive a pour (it lacks RECIPIENT)", self.lbl(dest)),
            ));
        }
        self.need_holding(src)?;
        self.need_close(dest)?;
        let mut ops = vec![Op::Add(src, Relation::Inside, dest)];
        if self.class_ix(src) == "water" {
            let c = self.char_ix();
            ops.push(Op::Remove(c, Relation::HoldsLh, src));
            ops.push(Op::Remove(c, Relation::HoldsRh, src));
        }
        Ok(ops)
    }

    fn type_on(&self, node: Ix) -> Check {
        self.need_close(node)?;
        if self.class_ix(node) != "keyboard" {
            self.need_prop(node, Property::HasSwitch, "cannot be typed on")?;
        }
        Ok(vec![])
    }

    fn watch(&self, node: Ix) -> Check {
        self.need_prop(node, Property::Lookable, "cannot be watched")?;
        let c = self.char_ix();
        let (cr, nr) = (self.room_ix(c), self.room_ix(node));
        if cr.is_none() || cr != nr {
            let l = self.lbl(node);
            let where_ = nr.map(|r| format!(" (it is in {})", self.lbl(r))).unwrap_or_default();
            return Err(Fail::new(MissingStep, format!("{l} is not in the robot's room{where_}; WALK to {l} first"))
                .eai(Affordance));
        }
        let l = self.lbl(node);
        let facing = Fact::Edge { from: self.character(), relation: Relation::Facing, to: self.id(node) };
        if !self.is_facing(node) {
            return Err(
                Fail::new(MissingStep, format!("the robot is not facing {l}; TURNTO {l} first")).needs(false, facing)
            );
        }
        let s = self.states_ix(c);
        if self.class_ix(node) != "computer"
            && (s.contains(State::Sitting) || s.contains(State::Lying))
            && !self.has_ix(c, Relation::Facing, node)
        {
            return Err(Fail::new(
                MissingStep,
                format!("the robot is not facing {l} from where it sits; TURNTO {l} first"),
            )
            .needs(false, facing));
        }
        self.need_not_inside_closed(node)?;
        Ok(vec![])
    }

    fn move_obj(&self, node: Ix, verb: Verb) -> Check {
        let class = self.class_ix(node);
        // As in EAI: PUSH is never refused for lack of MOVABLE; chairs and curtains always move.
        if !self.props_ix(node).contains(Property::Movable)
            && verb != Verb::Push
            && class != "button"
            && class != "chair"
            && class != "curtain"
        {
            return Err(Fail::new(Affordance, format!("{} cannot be moved (it lacks MOVABLE)", self.lbl(node))));
        }
        self.need_close(node)?;
        self.need_not_inside_closed(node)?;
        self.need_free_hand()?;
        Ok(vec![])
    }

    fn wash(&self, node: Ix) -> Check {
        self.need_close(node)?;
        Ok(clean(node))
    }

    fn squeeze(&self, node: Ix) -> Check {
        self.need_free_hand()?;
        self.need_close(node)?;
        const SQUEEZABLE: &[&str] = &[
            "cleaning_solution",
            "tooth_paste",
            "shampoo",
            "food_peanut_butter",
            "dish_soap",
            "soap",
            "towel",
            "rag",
            "paper",
            "sponge",
            "food_lemon",
            "check",
        ];
        if !self.props_ix(node).contains(Property::Clothes) && !SQUEEZABLE.contains(&self.class_ix(node)) {
            return Err(Fail::new(Affordance, format!("{} cannot be squeezed", self.lbl(node))));
        }
        Ok(vec![])
    }

    fn plug(&self, node: Ix, plug_in: bool) -> Check {
        self.need_prop(node, Property::HasPlug, "has no plug")?;
        self.need_close(node)?;
        self.need_free_hand()?;
        let s = self.states_ix(node);
        let l = self.lbl(node);
        if plug_in && !s.contains(State::PluggedOut) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already plugged in")));
        }
        if !plug_in && !s.contains(State::PluggedIn) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already unplugged")));
        }
        // EAI lets PLUGOUT of an appliance that is ON go through.
        let (gone, new) =
            if plug_in { (State::PluggedOut, State::PluggedIn) } else { (State::PluggedIn, State::PluggedOut) };
        Ok(vec![Op::State(node, gone, false), Op::State(node, new, true)])
    }

    fn cut(&self, node: Ix) -> Check {
        self.need_free_hand()?;
        self.need_close(node)?;
        self.need_prop(node, Property::Eatable, "is not food")?;
        self.need_prop(node, Property::Cuttable, "cannot be cut")?;
        let c = self.char_ix();
        let has_knife = HANDS.iter().flat_map(|&h| self.targets(c, h)).any(|x| self.class_ix(x).contains("knife"));
        if !has_knife {
            return Err(Fail::new(MissingStep, "the robot is not holding a knife; GRAB a knife first"));
        }
        Ok(vec![])
    }

    fn eat(&self, node: Ix) -> Check {
        self.need_close(node)?;
        if self.props_ix(node).contains(Property::Eatable) {
            return Ok(vec![]);
        }
        // A plate is "eaten from" if something edible is on it.
        if self.sources(node, Relation::On).any(|x| self.props_ix(x).contains(Property::Eatable)) {
            return Ok(vec![]);
        }
        Err(Fail::new(Affordance, format!("{} is not food and has no food on it", self.lbl(node))))
    }

    fn sleep(&self) -> Check {
        let c = self.char_ix();
        let s = self.states_ix(c);
        if !s.contains(State::Lying) && !s.contains(State::Sitting) {
            let ch = self.character();
            return Err(Fail::new(MissingStep, "the robot is not lying or sitting; LIE on a bed or SIT first")
                .needs(false, Fact::State { id: ch, state: State::Lying })
                .needs(false, Fact::State { id: ch, state: State::Sitting }));
        }
        Ok(vec![])
    }

    // ----- applying changes -----------------------------------------------------------------------

    /// Applies changes in order and returns their net effect.
    pub(crate) fn apply(&mut self, ops: &[Op]) -> Effects {
        let mut edges_before: BTreeMap<(Ix, Relation, Ix), bool> = BTreeMap::new();
        let mut states_before: BTreeMap<(Ix, State), bool> = BTreeMap::new();
        for op in ops {
            match *op {
                Op::Add(f, r, t) => self.logged_add(&mut edges_before, f, r, t),
                Op::AddBoth(f, r, t) => {
                    self.logged_add(&mut edges_before, f, r, t);
                    self.logged_add(&mut edges_before, t, r, f);
                }
                Op::Remove(f, r, t) => self.logged_remove(&mut edges_before, f, r, t),
                Op::RemoveAll(n, rels, reverse) => {
                    for &r in rels {
                        let outs: Vec<Ix> = self.targets(n, r).collect();
                        for t in outs {
                            self.logged_remove(&mut edges_before, n, r, t);
                        }
                        if reverse {
                            let ins: Vec<Ix> = self.sources(n, r).collect();
                            for f in ins {
                                self.logged_remove(&mut edges_before, f, r, n);
                            }
                        }
                    }
                }
                Op::CloseToInsideOf(c, n) => {
                    let xs: Vec<Ix> = self.sources(n, Relation::Inside).collect();
                    self.close_to_all(&mut edges_before, c, &xs);
                }
                Op::CloseToSupportsOf(c, n) => {
                    let xs: Vec<Ix> = self.targets(n, Relation::On).collect();
                    self.close_to_all(&mut edges_before, c, &xs);
                }
                Op::CloseToContainersOf(c, n) => {
                    let xs: Vec<Ix> = self.targets(n, Relation::Inside).filter(|&x| !self.is_room_ix(x)).collect();
                    self.close_to_all(&mut edges_before, c, &xs);
                }
                Op::CloseToBodyParts(c) => {
                    let xs = self.st.body_parts.clone();
                    self.close_to_all(&mut edges_before, c, &xs);
                }
                Op::FaceAsIt(c, n) => {
                    let xs: Vec<Ix> = self.targets(n, Relation::Facing).collect();
                    for x in xs {
                        self.logged_add(&mut edges_before, c, Relation::Facing, x);
                    }
                }
                Op::State(n, s, on) => {
                    let cur = self.states_ix(n).contains(s);
                    states_before.entry((n, s)).or_insert(cur);
                    self.set_state(n, s, on);
                }
                Op::GrabRecord(n, rec) => match rec {
                    Some(v) => {
                        self.grabbed_from.insert(n, v);
                    }
                    None => {
                        self.grabbed_from.remove(&n);
                    }
                },
            }
        }
        let free = self.hands_free();
        self.history.character_hands_were_free |= free;
        self.history.character_held_something |= !free;
        let mut fx = Effects::default();
        for ((f, r, t), before) in edges_before {
            let now = self.has_ix(f, r, t);
            if now != before {
                let e = (self.id(f), r, self.id(t));
                if now {
                    fx.added.push(e)
                } else {
                    fx.removed.push(e)
                }
            }
        }
        for ((n, s), before) in states_before {
            let now = self.states_ix(n).contains(s);
            if now != before {
                if now {
                    fx.states_added.push((self.id(n), s))
                } else {
                    fx.states_removed.push((self.id(n), s))
                }
            }
        }
        fx.added.sort();
        fx.removed.sort();
        fx.states_added.sort();
        fx.states_removed.sort();
        fx
    }

    fn close_to_all(&mut self, log: &mut BTreeMap<(Ix, Relation, Ix), bool>, c: Ix, xs: &[Ix]) {
        for &x in xs {
            self.logged_add(log, c, Relation::Close, x);
            self.logged_add(log, x, Relation::Close, c);
        }
    }

    fn logged_add(&mut self, log: &mut BTreeMap<(Ix, Relation, Ix), bool>, f: Ix, r: Relation, t: Ix) {
        let cur = self.has_ix(f, r, t);
        log.entry((f, r, t)).or_insert(cur);
        self.add_edge(f, r, t);
    }

    fn logged_remove(&mut self, log: &mut BTreeMap<(Ix, Relation, Ix), bool>, f: Ix, r: Relation, t: Ix) {
        let cur = self.has_ix(f, r, t);
        log.entry((f, r, t)).or_insert(cur);
        self.remove_edge(f, r, t);
    }
}

/// The slot mask of a CPython set holding `n` small ints (table 8, grown ×4 used when 3/5 full).
fn py_set_mask(n: usize) -> u64 {
    let mut size: u64 = 8;
    while (n as u64) * 5 >= (size - 1) * 3 {
        let mut new = 8;
        while new <= (n as u64) * 4 {
            new <<= 1;
        }
        size = new.max(size * 2);
    }
    size - 1
}

fn clean(node: Ix) -> Vec<Op> {
    vec![Op::State(node, State::Dirty, false), Op::State(node, State::Clean, true)]
}
