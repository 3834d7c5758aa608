//! Where the planner's leaves run: the [`Env`] trait and its two in-process implementations.
//!
//! [`SimEnv`] is the symbolic world itself (closed loop: every action's real outcome comes back).
//! [`DryRunEnv`] gives no feedback: every action "succeeds", and the planner's belief is the initial
//! world advanced by the actions that would have run. The robot bridge (`bridge:CMD`, a child process)
//! lives in `bridge.rs`. All three expose a belief [`World`] so grammars and symbolic checks work the
//! same way whatever executes the actions.

use serde::Serialize;

use crate::action::Action;
use crate::world::{StepResult, World};

/// What executing one action did.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum Outcome {
    /// It ran; `observation` is whatever the executor reported back (a robot's sensor text, say).
    Ok { observation: Option<String> },
    /// Its effect already held: nothing changed and the plan goes on (EAI's additional-step rule).
    Skipped { reason: String },
    /// It could not run. `reason` is the executor's message (it names the fix); `kind` its category
    /// (EAI's taxonomy for the simulator, free text for a robot).
    Failed { reason: String, kind: Option<String> },
}

impl Outcome {
    pub fn is_failure(&self) -> bool {
        matches!(self, Outcome::Failed { .. })
    }

    /// A short form for prompts and the tree view.
    pub fn summary(&self) -> String {
        match self {
            Outcome::Ok { observation: None } => "ok".into(),
            Outcome::Ok { observation: Some(o) } => format!("ok ({o})"),
            Outcome::Skipped { reason } => format!("skipped: {reason}"),
            Outcome::Failed { reason, .. } => format!("failed: {reason}"),
        }
    }
}

/// An executor that could not be asked at all (as opposed to an action that failed).
#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    #[error("the executor crashed or closed its pipe after being sent `{sent}`: {detail}")]
    Crashed { sent: String, detail: String },
    #[error("the executor did not answer `{sent}` within {timeout_ms} ms")]
    Timeout { sent: String, timeout_ms: u64 },
    #[error("the executor answered {received:?} to `{sent}`, which is not an outcome: {detail}")]
    Garbage { sent: String, received: String, detail: String },
    #[error("could not start the executor {command:?}: {detail}")]
    Spawn { command: String, detail: String },
    #[error("executor i/o: {0}")]
    Io(#[from] std::io::Error),
}

/// Something the planner executes leaves against.
pub trait Env {
    /// `sim`, `dry-run`, `bridge:CMD`.
    fn name(&self) -> &str;
    /// A bounded text view of the state for prompts (at most `budget` bytes), the objects of
    /// `first` listed before the others (the objects an instruction names, where the view is a
    /// whole house that the budget cuts).
    fn observe(&self, first: &[u32], budget: usize) -> String;
    fn execute(&mut self, action: &Action) -> Result<Outcome, EnvError>;
    /// The planner's belief of the world (sim: the world itself; dry-run: the initial world advanced
    /// by the planner's own actions; bridge: a shadow world advanced by actions the robot reports
    /// ok). Used for typed/feasible grammars and the symbolic checks; `None`: no world model.
    fn world(&self) -> Option<&World>;
}

/// One action in the world ([`World::step`]: the executor and the additional-step rule, the same code
/// the scorer runs), as an [`Outcome`].
pub(crate) fn world_step(world: &mut World, action: &Action) -> Outcome {
    match world.step(action) {
        StepResult::Ok { .. } => Outcome::Ok { observation: None },
        StepResult::Skipped { failure } => Outcome::Skipped { reason: failure.message },
        StepResult::Failed { failure } => {
            Outcome::Failed { reason: failure.message, kind: Some(failure.kind.name().to_string()) }
        }
    }
}

/// The symbolic world as the executor (closed loop).
#[derive(Clone, Debug)]
pub struct SimEnv {
    world: World,
    /// Objects the observation describes (the task's relevant objects, or the whole scene).
    focus: Vec<u32>,
}

impl SimEnv {
    pub fn new(world: World, focus: Vec<u32>) -> Self {
        Self { world, focus }
    }

    pub fn into_world(self) -> World {
        self.world
    }
}

impl Env for SimEnv {
    fn name(&self) -> &str {
        "sim"
    }

    fn observe(&self, first: &[u32], budget: usize) -> String {
        self.world.observe_first(&self.focus, first, budget)
    }

    fn execute(&mut self, action: &Action) -> Result<Outcome, EnvError> {
        Ok(world_step(&mut self.world, action))
    }

    fn world(&self) -> Option<&World> {
        Some(&self.world)
    }
}

/// No executor: every action is reported ok; the belief advances by the actions that would run.
#[derive(Clone, Debug)]
pub struct DryRunEnv {
    belief: World,
    focus: Vec<u32>,
}

impl DryRunEnv {
    pub fn new(world: World, focus: Vec<u32>) -> Self {
        Self { belief: world, focus }
    }

    pub fn into_world(self) -> World {
        self.belief
    }
}

impl Env for DryRunEnv {
    fn name(&self) -> &str {
        "dry-run"
    }

    fn observe(&self, first: &[u32], budget: usize) -> String {
        self.belief.observe_first(&self.focus, first, budget)
    }

    fn execute(&mut self, action: &Action) -> Result<Outcome, EnvError> {
        // The belief follows the action only when the action could run in it; either way the planner
        // hears "ok", since a dry run has nobody to say otherwise.
        let _ = world_step(&mut self.belief, action);
        Ok(Outcome::Ok { observation: None })
    }

    fn world(&self) -> Option<&World> {
        Some(&self.belief)
    }
}
