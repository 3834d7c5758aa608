//! `step sim run`: runs one plan on one task in the symbolic world and prints each step's outcome and
//! the goal check.

use std::io::{IsTerminal, Read};
use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::{Args, Subcommand, ValueEnum};

use crate::eval::{run_plan, StepResult, TaskSource};
use crate::program::{PlanFormat, Program};

#[derive(Args, Debug)]
pub struct SimArgs {
    #[command(subcommand)]
    pub command: SimCommand,
}

#[derive(Subcommand, Debug)]
pub enum SimCommand {
    /// Run a plan on a task: each step's outcome (ok, or the failure kind and why), then the goals.
    Run(RunArgs),
}

/// The plan formats, for `--format`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum FormatArg {
    /// VirtualHome program lines: `[WALK] <kitchen> (11)`, optionally under a title and description.
    Lines,
    /// A JSON list of {"verb", "args": [{"class_name", "id"}]}.
    Json,
    /// EAI's LLM-output object: {"WALK": ["kitchen", 11], ...}.
    Eai,
}

impl From<FormatArg> for PlanFormat {
    fn from(f: FormatArg) -> PlanFormat {
        match f {
            FormatArg::Lines => PlanFormat::Lines,
            FormatArg::Json => PlanFormat::Json,
            FormatArg::Eai => PlanFormat::Eai,
        }
    }
}

/// Where tasks come from (shared by the commands that take tasks).
#[derive(Args, Debug, Clone, Default)]
pub struct TaskArgs {
    /// A task file of your own (JSON list of tasks); without it, EAI's VirtualHome tasks are used.
    #[arg(long, value_name = "FILE")]
    pub tasks_file: Option<PathBuf>,
    /// The VirtualHome benchmark data directory (holding eai/ and resources/); default: $STEP_VH_DATA,
    /// else ../shared/bench/virtualhome beside the repo.
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
}

impl TaskArgs {
    pub fn source(&self) -> TaskSource {
        TaskSource { tasks_file: self.tasks_file.clone(), data: self.data.clone() }
    }
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// The task id (e.g. 27_2 for EAI's tasks, or an id from --tasks-file).
    #[arg(long)]
    pub task: String,
    /// The plan file (`-` for standard input).
    #[arg(long, value_name = "FILE")]
    pub plan: PathBuf,
    /// The plan's format; guessed from the text when absent.
    #[arg(long, value_enum)]
    pub format: Option<FormatArg>,
    #[command(flatten)]
    pub tasks: TaskArgs,
}

pub fn run(args: SimArgs) -> anyhow::Result<()> {
    match args.command {
        SimCommand::Run(a) => run_one(a),
    }
}

fn read_plan(path: &PathBuf) -> anyhow::Result<String> {
    if path.as_os_str() == "-" {
        let mut s = String::new();
        if std::io::stdin().is_terminal() {
            bail!("--plan - reads the plan from standard input, but nothing is piped in");
        }
        std::io::stdin().read_to_string(&mut s).context("reading the plan from standard input")?;
        return Ok(s);
    }
    std::fs::read_to_string(path).with_context(|| format!("cannot read plan file {}", path.display()))
}

fn run_one(a: RunArgs) -> anyhow::Result<()> {
    let text = read_plan(&a.plan)?;
    let format = a.format.map(PlanFormat::from).unwrap_or_else(|| PlanFormat::detect(&text));
    let program =
        Program::parse(&text, format).with_context(|| format!("cannot read the plan in {}", a.plan.display()))?;
    let tasks = a.tasks.source().load(Some(std::slice::from_ref(&a.task)))?;
    let Some(task) = tasks.first() else { bail!("task '{}' was not loaded", a.task) };
    println!("task {}: {}", task.id, task.title);
    if !task.description.is_empty() {
        println!("  {}", task.description);
    }
    let out = run_plan(task, &program);
    let width = out.steps.iter().map(|s| s.action.len()).max().unwrap_or(0);
    for s in &out.steps {
        let status = match &s.result {
            StepResult::Ok { .. } => "ok".to_string(),
            StepResult::Skipped { failure } => format!("skipped ({}): {}", failure.kind, failure.message),
            StepResult::Failed { failure } => {
                let eai = if failure.eai_kind != failure.kind { format!(", EAI: {}", failure.eai_kind) } else { String::new() };
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
        println!("note: objects outside the task's relevant list (EAI's scorer would reject the plan): {}", objs.join(", "));
    }
    println!("success: {}", if out.success { "yes" } else { "no" });
    Ok(())
}
