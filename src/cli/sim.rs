//! `step sim run`: runs one plan on one task in the symbolic world and prints each step's outcome and
//! the goal check (or, with `--json`, the same as one JSON object). The exit code says whether the
//! task succeeded, so scripts can branch on it.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::{Args, Subcommand};
use serde_json::json;

use super::args::{parse_plan_format, read_input, TaskArgs};
use super::EXIT_TASK_FAILED;
use crate::eval::{run_plan, StepResult};
use crate::program::{exported_plan, PlanFormat, Program};

#[derive(Args, Debug)]
pub struct SimArgs {
    #[command(subcommand)]
    pub command: SimCommand,
}

#[derive(Subcommand, Debug)]
pub enum SimCommand {
    /// Run a plan on a task: each step's outcome (ok, or the failure kind and why), then the goals.
    #[command(after_help = "\
Exit codes: 0 the task succeeded (every step ran and every goal is met); 3 the plan was read and run but the \
task did not succeed (a step failed or a goal is unmet); 1 error (unreadable plan, unknown task, missing \
data); 2 usage error.")]
    Run(RunArgs),
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// The task id (e.g. 27_2 for EAI's tasks, or an id from --tasks-file).
    #[arg(long)]
    pub task: String,
    /// The plan file (`-` for standard input); from a file of `step eval plan --export-eai` plans, the task's own.
    #[arg(long, value_name = "FILE")]
    pub plan: PathBuf,
    /// The plan's format: lines, json or eai; guessed from the text when absent.
    #[arg(long, value_parser = parse_plan_format, value_name = "lines|json|eai")]
    pub format: Option<PlanFormat>,
    #[command(flatten)]
    pub tasks: TaskArgs,
    /// Print one JSON object: the task, every step's outcome, the goals and the verdict.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: SimArgs) -> anyhow::Result<ExitCode> {
    match args.command {
        SimCommand::Run(a) => run_one(a),
    }
}

fn run_one(a: RunArgs) -> anyhow::Result<ExitCode> {
    let text = read_input(&a.plan, "plan file")?;
    // A file of exported plans (`step eval plan --export-eai`) holds one plan per task: the task's own runs.
    let exported = if matches!(a.format, None | Some(PlanFormat::Eai)) { exported_plan(&text, &a.task) } else { None };
    let (text, format) = match exported {
        Some(Ok(plan)) => (plan, PlanFormat::Eai),
        Some(Err(why)) => bail!("{}: {why}", a.plan.display()),
        None => {
            let format = a.format.unwrap_or_else(|| PlanFormat::detect(&text));
            (text, format)
        }
    };
    let program =
        Program::parse(&text, format).with_context(|| format!("cannot read the plan in {}", a.plan.display()))?;
    let tasks = a.tasks.source().load(Some(std::slice::from_ref(&a.task)))?;
    let Some(task) = tasks.first() else { bail!("task '{}' was not loaded", a.task) };
    let out = run_plan(task, &program);
    let code = if out.success { ExitCode::SUCCESS } else { ExitCode::from(EXIT_TASK_FAILED) };
    if a.json {
        let g = &out.goals;
        let report = json!({
            "task": task.id,
            "title": task.title,
            "steps": out.steps,
            "not_run": program.actions.len() - out.steps.len(),
            "executed": out.executed,
            "goals": {"state": g.state(), "relation": g.relation(), "action": g.action(), "unmet": g.unmet()},
            "outside_relevant": out.outside_relevant.iter().map(|o| o.to_string()).collect::<Vec<_>>(),
            "success": out.success,
        });
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(code);
    }
    println!("task {}: {}", task.id, task.title);
    if !task.description.is_empty() {
        println!("  {}", task.description);
    }
    let width = out.steps.iter().map(|s| s.action.len()).max().unwrap_or(0);
    for s in &out.steps {
        let status = match &s.result {
            StepResult::Ok { .. } => "ok".to_string(),
            StepResult::Skipped { failure } => format!("skipped ({}): {}", failure.kind, failure.message),
            StepResult::Failed { failure } => {
                let eai = if failure.eai_kind != failure.kind {
                    format!(", EAI: {}", failure.eai_kind)
                } else {
                    String::new()
                };
                format!("FAILED {}{eai}: {}", failure.kind, failure.message)
            }
        };
        println!("{:>4}  {:<width$}  {status}", s.step, s.action);
    }
    let not_run = program.actions.len() - out.steps.len();
    if not_run > 0 {
        println!("      ({not_run} later step(s) not run)");
    }
    println!("executed: {}", if out.executed { "yes" } else { "no" });
    let g = &out.goals;
    println!(
        "goals: state {}/{}, relation {}/{}, action {}/{}",
        g.state().met,
        g.state().total,
        g.relation().met,
        g.relation().total,
        g.action().met,
        g.action().total
    );
    for u in g.unmet() {
        println!("  unmet: {u}");
    }
    if !out.outside_relevant.is_empty() {
        let objs: Vec<String> = out.outside_relevant.iter().map(|o| o.to_string()).collect();
        println!(
            "note: objects outside the task's relevant list (EAI's scorer would reject the plan): {}",
            objs.join(", ")
        );
    }
    println!("success: {}", if out.success { "yes" } else { "no" });
    Ok(code)
}
