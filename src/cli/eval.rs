//! `step eval gold`: runs every task's gold program and prints the counts, the metrics and each
//! exception (JSON with `--json`).

use std::io::IsTerminal;
use std::time::Instant;

use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::Serialize;

use super::args::TaskArgs;
use crate::eval::{score, PlanInput, Summary, TaskReport};

#[derive(Args, Debug)]
pub struct EvalArgs {
    #[command(subcommand)]
    pub command: EvalCommand,
}

#[derive(Subcommand, Debug)]
pub enum EvalCommand {
    /// Run every task's gold program; print the counts, the metrics and every exception.
    Gold(GoldArgs),
}

#[derive(Args, Debug)]
pub struct GoldArgs {
    #[command(flatten)]
    pub tasks: TaskArgs,
    /// Only these task ids (repeatable).
    #[arg(long = "task", value_name = "ID")]
    pub only: Vec<String>,
    /// Print the report as JSON (summary, rates, every task, timings) instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct Timing {
    load_s: f64,
    run_s: f64,
    wall_s: f64,
}

#[derive(Serialize)]
struct GoldReport<'a> {
    source: String,
    summary: &'a Summary,
    rates: crate::eval::run::Rates,
    tasks: &'a [TaskReport],
    timing: Timing,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    match args.command {
        EvalCommand::Gold(a) => gold(a),
    }
}

fn gold(a: GoldArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let tty = std::io::stderr().is_terminal();
    let spinner = tty.then(|| {
        let s = ProgressBar::new_spinner().with_message("loading tasks");
        s.enable_steady_tick(std::time::Duration::from_millis(100));
        s
    });
    let source = a.tasks.source();
    let only = (!a.only.is_empty()).then_some(a.only.as_slice());
    let tasks = source.load(only)?;
    if let Some(s) = spinner {
        s.finish_and_clear();
    }
    let load_s = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let bar = tty.then(|| {
        let b = ProgressBar::new(tasks.len() as u64);
        if let Ok(style) = ProgressStyle::with_template("{bar:40} {pos}/{len} gold programs") {
            b.set_style(style);
        }
        b
    });
    let reports: Vec<TaskReport> = tasks
        .par_iter()
        .map(|t| {
            let plan = match &t.gold {
                Some(Ok(p)) => PlanInput::Plan(p.clone()),
                Some(Err(e)) => PlanInput::Unreadable(e.clone()),
                None => PlanInput::Missing,
            };
            let r = score(t, &plan);
            if let Some(b) = &bar {
                b.inc(1);
            }
            r
        })
        .collect();
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let run_s = t1.elapsed().as_secs_f64();
    let summary = Summary::of(&reports);
    let source_name = match &source.tasks_file {
        Some(f) => format!("task file {}", f.display()),
        None => "EAI VirtualHome tasks".to_string(),
    };
    let timing = Timing { load_s, run_s, wall_s: t0.elapsed().as_secs_f64() };
    if a.json {
        let report =
            GoldReport { source: source_name, summary: &summary, rates: summary.rates(), tasks: &reports, timing };
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!("gold programs of {} ({} tasks)", source_name, summary.tasks);
    print!("{}", summary.table());
    let exceptions: Vec<&TaskReport> =
        reports.iter().filter(|r| !r.success || !r.outside_relevant.is_empty()).collect();
    if !exceptions.is_empty() {
        println!("exceptions:");
    }
    for r in exceptions {
        let mut why = Vec::new();
        if let Some(e) = &r.error {
            let at = e.step.map(|s| format!(" at step {s}")).unwrap_or_default();
            why.push(format!("{}{at}: {}", e.kind, e.message));
        }
        if r.executed && !r.unmet_goals.is_empty() {
            why.push(format!("goals unmet: {}", r.unmet_goals.join("; ")));
        }
        if !r.outside_relevant.is_empty() {
            why.push(format!("uses objects outside the relevant list: {}", r.outside_relevant.join(", ")));
        }
        let verdict = if r.success { "success" } else { "FAIL" };
        println!("  {} ({}) {verdict}: {}", r.id, r.title, why.join(" | "));
    }
    println!("time: load {:.2} s, run {:.3} s, wall {:.2} s", timing.load_s, timing.run_s, timing.wall_s);
    Ok(())
}
