//! One step of a run: an action, its outcome, and EAI's additional-step rule. Every caller that runs
//! plans (the plan scorer, the planner's simulated environment) goes through [`World::step`], so the
//! rule is written once.

use serde::Serialize;

use super::exec::{Effects, ExecFailure, FailureKind};
use super::state::World;
use crate::action::Action;

/// What one step did.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum StepResult {
    /// The action ran; the state changed by `effects`.
    Ok { effects: Effects },
    /// An additional step: its effect already held; nothing changed and the run goes on.
    Skipped { failure: ExecFailure },
    /// The action could not run; nothing changed and a run stops here.
    Failed { failure: ExecFailure },
}

impl StepResult {
    /// Whether a run may go on after this step (it ran, or it was an additional step).
    pub fn goes_on(&self) -> bool {
        !matches!(self, StepResult::Failed { .. })
    }

    /// Whether the action ran and changed the state (counts towards action goals).
    pub fn ran(&self) -> bool {
        matches!(self, StepResult::Ok { .. })
    }

    /// The failure, for a skipped or failed step.
    pub fn failure(&self) -> Option<&ExecFailure> {
        match self {
            StepResult::Ok { .. } => None,
            StepResult::Skipped { failure } | StepResult::Failed { failure } => Some(failure),
        }
    }
}

impl World {
    /// Runs one action as a step of a run: on success the state changes; an action whose effect
    /// already holds is skipped (EAI's additional step: nothing changes, the run goes on); any other
    /// failure leaves the state unchanged and is reported as failed.
    pub fn step(&mut self, action: &Action) -> StepResult {
        match self.execute(action) {
            Ok(effects) => StepResult::Ok { effects },
            Err(failure) if failure.kind == FailureKind::AdditionalStep => StepResult::Skipped { failure },
            Err(failure) => StepResult::Failed { failure },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::action::{ObjRef, Verb};

    fn act(verb: Verb, id: u32) -> Action {
        Action::new(verb, vec![ObjRef::new("fridge", id)]).unwrap()
    }

    #[test]
    fn a_step_runs_skips_an_effect_that_already_holds_and_fails_otherwise() {
        let mut w = World::demo();
        let fridge = w.ids_of_class("fridge")[0];
        let walk = act(Verb::Walk, fridge);
        let open = act(Verb::Open, fridge);
        let r = w.step(&walk);
        assert!(r.ran() && r.goes_on(), "{r:?}");
        let r = w.step(&open);
        assert!(r.ran(), "{r:?}");
        let before = w.clone();
        let r = w.step(&open);
        assert!(matches!(r, StepResult::Skipped { .. }) && r.goes_on(), "{r:?}");
        assert_eq!(r.failure().unwrap().kind, FailureKind::AdditionalStep);
        assert!(w.to_graph() == before.to_graph(), "a skipped step changes nothing");
        let r = w.step(&act(Verb::Sit, fridge));
        assert!(matches!(r, StepResult::Failed { .. }) && !r.goes_on(), "{r:?}");
        assert!(w.to_graph() == before.to_graph(), "a failed step changes nothing");
    }
}
