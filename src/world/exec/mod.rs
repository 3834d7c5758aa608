//! The executor: VirtualHome's evolving-graph semantics for every primitive action.
//!
//! Each verb is one function that checks the action's preconditions against the current state, in
//! the order VirtualHome/EAI check them, and returns either the list of changes the action makes or a
//! typed failure. [`World::check`] stops there; [`World::execute`] applies the changes. One code path
//! decides both, so "feasible" and "would execute" cannot disagree.
//!
//! The files follow those seams: this one dispatches a verb to its handler and classifies failures;
//! [`failure`] holds the reported types, `checks` the preconditions several verbs share, `verbs` one
//! handler per verb (named after it: `walk`, `grab`, `open_close`, …, listed in the dispatch below),
//! and `apply` the change list and how it is applied.
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

use super::observe::Tool;
use super::state::{Ix, World};
use super::vocab::{Property, Relation, State};
use crate::action::{Action, ObjRef, Verb};

mod apply;
mod checks;
pub mod failure;
#[cfg(test)]
mod tests;
mod verbs;

pub(crate) use apply::Op;
pub use failure::{Connective, Effects, ExecFailure, Fact, FailureKind, Missing};

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

/// Added to a missing step's message when the missing fact held earlier in the plan (EAI's
/// wrong-order case). It comes after the named fix ("...; GRAB <x> (1) first"), so whoever reads
/// the fix back out of a message strips it first ([`World::way_to`]).
pub(crate) const UNDONE_NOTE: &str = " (this held earlier in the plan; a later step undid it)";

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
                message.push_str(UNDONE_NOTE);
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
}
