//! Running a plan on a task.
//!
//! A plan runs step by step through [`World::step`]. A step whose effect already holds
//! (an additional step) changes nothing and the run goes on, as in EAI; any other failure stops the
//! run, and the plan is not executable. Goals are checked in the state the run ended in, against the
//! actions that executed; a task succeeds only when the plan executed to the end AND every goal is
//! met (EAI also counts goals met by a plan that failed partway; here they count towards the goal
//! rates, never towards success).
//!
//! The module is split by job: running (here), [`super::score`] (one task's report), and
//! [`super::report`] (a batch's metrics and text table). Their names are re-exported here so
//! `eval::run::{score, Summary, …}` keep working.

use serde::Serialize;

use super::goal::GoalCheck;
use super::task::Task;
use crate::action::{Action, ObjRef};
use crate::program::Program;
use crate::world::{ExecFailure, World};

pub use super::report::{Rates, Summary};
pub use super::score::{score, ErrorReport, PlanInput, TaskReport};
pub use crate::world::StepResult;

#[derive(Clone, Debug, Serialize)]
pub struct StepOutcome {
    /// 1-based step number.
    pub step: usize,
    pub action: String,
    #[serde(flatten)]
    pub result: StepResult,
}

/// The outcome of running one plan on one task.
#[derive(Clone, Debug)]
pub struct RunOutcome {
    /// The steps that were tried (the run stops at the first failed one).
    pub steps: Vec<StepOutcome>,
    /// Every step ran (additional steps allowed) and the plan was not empty.
    pub executed: bool,
    pub failure: Option<ExecFailure>,
    pub goals: GoalCheck,
    pub success: bool,
    /// Objects the plan names that are not among the task's relevant objects (EAI's scorer rejects
    /// such plans as hallucinations; here it is reported only).
    pub outside_relevant: Vec<ObjRef>,
    /// The state the run ended in.
    pub end: World,
}

/// Runs `plan` on `task` from the task's initial state.
pub fn run_plan(task: &Task, plan: &Program) -> RunOutcome {
    let mut world = task.world.clone();
    let mut steps = Vec::with_capacity(plan.actions.len());
    let mut executed_actions: Vec<Action> = Vec::with_capacity(plan.actions.len());
    let mut failure = None;
    for (i, a) in plan.actions.iter().enumerate() {
        let result = world.step(a);
        if result.ran() {
            executed_actions.push(a.clone());
        }
        if !result.goes_on() {
            failure = result.failure().cloned();
        }
        steps.push(StepOutcome { step: i + 1, action: a.to_string(), result });
        if failure.is_some() {
            break;
        }
    }
    let executed = failure.is_none() && !plan.actions.is_empty();
    let goals = task.goal.check(&world, &executed_actions);
    let success = executed && goals.all_met();
    let mut outside: Vec<ObjRef> = plan
        .actions
        .iter()
        .flat_map(|a| a.args.iter())
        .filter(|o| task.relevant.binary_search(&o.id).is_err())
        .cloned()
        .collect();
    outside.sort();
    outside.dedup();
    RunOutcome { steps, executed, failure, goals, success, outside_relevant: outside, end: world }
}
