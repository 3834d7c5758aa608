//! What the executor reports: failures in EAI's taxonomy (with the facts a failed precondition
//! needed, for the wrong-order rule) and the net effects of an action that ran.

use std::fmt;

use serde::{Deserialize, Serialize};

use crate::action::Action;
use crate::world::vocab::{Relation, State};

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
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
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
