//! Evaluation: task sets (EAI's VirtualHome set, a user's own task file), goal checks as EAI defines
//! them, running a plan through the world's executor, and the metrics and error taxonomy of a batch.
//!
//! - [`dataset`]: EAI's files, read in place (the scene archive is streamed, never unpacked to disk).
//! - [`task`]: [`Task`] (scene, goal, gold plan, relevant objects); users' task files.
//! - [`goal`]: node, edge and action goals and their check.
//! - [`run`]: running a plan on a task, step by step through `World::step`.
//! - [`score`]: one task's report (parse errors, run failures, goals).
//! - [`report`]: the batch [`Summary`], its rates and text table.
//! - [`plans`]: planners on task sets (`step eval plan`), scored by [`score`]'s scorer.
//! - [`protocol`]: what a planner is told about a task (instruction, objects, goals; open or closed loop).

pub mod dataset;
pub mod goal;
pub mod plans;
pub mod protocol;
pub mod report;
pub mod run;
pub mod score;
pub mod task;

use std::path::PathBuf;

pub use dataset::{EaiData, DATA_ENV};
pub use goal::{ActionGoal, Count, EdgeGoal, Goal, GoalCheck, NodeGoal, RawGoal};
pub use run::{run_plan, score, PlanInput, RunOutcome, StepOutcome, StepResult, Summary, TaskReport};
pub use task::{diff_graphs, relevant_by_diff, relevant_by_gold_run, relevant_by_goal, Relevance, RelevantRule, Task, TaskOrigin};

use crate::world::GraphError;

/// Why tasks could not be loaded or run.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(
        "EAI's VirtualHome data set was not found{}; looked in: {}. Point at it with --data DIR or the \
         STEP_VH_DATA environment variable: the directory that holds eai/ and resources/ (with \
         eai/resources/task_state_LTL_formula_accurate.json)",
        if *explicit { " at the given path" } else { "" },
        looked.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
    )]
    DataMissing { looked: Vec<PathBuf>, explicit: bool },
    #[error("cannot read {}: {error}", path.display())]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{path}:{line}:{column}: {message}")]
    Json { path: PathBuf, line: usize, column: usize, message: String },
    #[error("{path}: {message}")]
    Data { path: PathBuf, message: String },
    #[error("scene archive {path}: {message}")]
    Archive { path: PathBuf, message: String },
    #[error(transparent)]
    Graph(#[from] GraphError),
    #[error("{file}: task '{task}': {message}")]
    Task { file: PathBuf, task: String, message: String },
    #[error("no task '{id}' in {source_name} (tasks look like: {})", examples.join(", "))]
    UnknownTask { id: String, source_name: String, examples: Vec<String> },
}

/// Where tasks come from: a user's task file, else EAI's data set (at `data`, or found).
#[derive(Clone, Debug, Default)]
pub struct TaskSource {
    pub tasks_file: Option<PathBuf>,
    pub data: Option<PathBuf>,
}

impl TaskSource {
    /// Loads all tasks, or only those with the given ids (an unknown id is an error).
    pub fn load(&self, only: Option<&[String]>) -> Result<Vec<Task>, EvalError> {
        let only: Option<std::collections::BTreeSet<String>> = only.map(|o| o.iter().cloned().collect());
        match &self.tasks_file {
            Some(f) => {
                let tasks = task::load_file(f, self.data.as_deref())?;
                match only {
                    None => Ok(tasks),
                    Some(ids) => {
                        if let Some(bad) = ids.iter().find(|id| !tasks.iter().any(|t| &t.id == *id)) {
                            return Err(EvalError::UnknownTask {
                                id: bad.clone(),
                                source_name: format!("task file {}", f.display()),
                                examples: tasks.iter().take(5).map(|t| t.id.clone()).collect(),
                            });
                        }
                        Ok(tasks.into_iter().filter(|t| ids.contains(&t.id)).collect())
                    }
                }
            }
            None => task::load_eai(&EaiData::open(self.data.as_deref())?, only.as_ref()),
        }
    }

    /// [`TaskSource::load`] for a planner: a task whose gold program cannot run is refused, since
    /// its object list (EAI's rule runs the program) was cut short where it stopped, without the
    /// objects of its later steps, and the task would be planned on less than it needs. (Scoring
    /// the gold programs themselves, `step eval gold`, loads them all and reports each failure.)
    pub fn load_for_planning(&self, only: Option<&[String]>) -> Result<Vec<Task>, EvalError> {
        let tasks = self.load(only)?;
        let short = tasks
            .iter()
            .filter(|t| t.relevance.rule == RelevantRule::GoldRun)
            .find_map(|t| t.relevance.note.as_deref().map(|note| (t, note)));
        if let (Some((t, note)), Some(file)) = (short, &self.tasks_file) {
            return Err(EvalError::Task {
                file: file.clone(),
                task: t.id.clone(),
                message: format!(
                    "gold: {note}: fix the program (it makes the task's object list), or list the objects in \"relevant\""
                ),
            });
        }
        Ok(tasks)
    }
}
