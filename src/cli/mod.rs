//! The `step` command line: one clap subcommand per job, each a thin call into the library.
//!
//! Errors reach the user as one `error: …` line with its causes, never a panic; the exit code is 1 for
//! a failed command and 2 for a usage error (clap's own); `sim run` also says whether the task
//! succeeded (3: it did not). A reader that closes our output early (`step … | head -1`) ends the
//! process quietly, as it does any Unix tool.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod args;
pub mod bench;
pub mod bench_nodes;
pub mod eval;
pub mod generate;
pub mod plan;
pub mod sim;

#[derive(Parser, Debug)]
#[command(
    name = "step",
    version,
    about = "Offline subgoal-tree task planner for robots (STEP)",
    after_help = "Exit codes: 0 success; 1 error; 2 usage error; 3 (sim run) the plan ran but the task did not \
                  succeed. Output closed early (e.g. piped into head): the process ends quietly."
)]
pub struct Cli {
    /// Log filter (tracing's EnvFilter syntax), e.g. `info` or `step=debug`; also RUST_LOG.
    #[arg(long, global = true, value_parser = parse_log_filter)]
    pub log: Option<String>,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Plan a task with the STEP subgoal tree on the local model, closed-loop on the world (the main job).
    Plan(plan::PlanArgs),
    /// Re-run a `step plan --trace` file with the same model and settings; check it is identical.
    Replay(plan::ReplayArgs),
    /// Generate text from a prompt with the local model, optionally under a Lark grammar.
    Generate(generate::GenerateArgs),
    /// Benchmarks that print JSON: `step bench llm`.
    Bench(bench::BenchArgs),
    /// Run plans in the symbolic VirtualHome world.
    Sim(sim::SimArgs),
    /// Score plans on task sets (EAI's VirtualHome tasks or your own).
    Eval(eval::EvalArgs),
}

/// Entry point of the binary: parse, set up logging, run, report.
pub fn main() -> ExitCode {
    quiet_on_closed_pipe();
    let cli = Cli::parse();
    init_tracing(cli.log.as_deref());
    match run(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// `sim run`'s code for a plan that ran but whose task did not succeed.
pub const EXIT_TASK_FAILED: u8 = 3;

fn run(command: Command) -> anyhow::Result<ExitCode> {
    match command {
        Command::Plan(a) => plan::run(&a).map(|()| ExitCode::SUCCESS),
        Command::Replay(a) => plan::replay(&a).map(|()| ExitCode::SUCCESS),
        Command::Generate(a) => generate::run(&a).map(|()| ExitCode::SUCCESS),
        Command::Bench(a) => bench::run(&a).map(|()| ExitCode::SUCCESS),
        Command::Sim(a) => sim::run(a),
        Command::Eval(a) => eval::run(a).map(|()| ExitCode::SUCCESS),
    }
}

/// Fails now if `path` cannot be written, so that an output written at the end of a long run is not
/// found unwritable only then. An existing file is left as it is (opened to append, not truncated)
/// until the run writes it: a run that fails first loses no earlier output.
pub(crate) fn check_writable(path: &std::path::Path, what: &str) -> anyhow::Result<()> {
    use anyhow::Context;
    std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(path)
        .with_context(|| format!("creating {what}{}", path.display()))?;
    Ok(())
}

/// `--log`: rejected unless tracing can read it (a typo would otherwise silently log nothing).
fn parse_log_filter(s: &str) -> Result<String, String> {
    tracing_subscriber::EnvFilter::builder()
        .parse(s)
        .map(|_| s.to_string())
        .map_err(|e| format!("{e} (examples: warn, info, step=debug, step::llm=trace)"))
}

fn init_tracing(filter: Option<&str>) {
    use tracing_subscriber::EnvFilter;
    let filter = match filter {
        Some(f) => EnvFilter::new(f),
        None => match std::env::var("RUST_LOG") {
            Ok(v) if !v.is_empty() => EnvFilter::builder().parse(&v).unwrap_or_else(|e| {
                eprintln!("warning: ignoring RUST_LOG={v:?}: {e}");
                EnvFilter::new("warn")
            }),
            _ => EnvFilter::new("warn"),
        },
    };
    // Logs go to stderr so that stdout stays clean for JSON and plans.
    let _ = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).try_init();
}

/// Rust ignores SIGPIPE, so a write to a closed pipe is an error and `println!` panics on it. Restoring
/// the default action ends the process quietly instead, as the reader intended.
fn quiet_on_closed_pipe() {
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any thread exists; SIG_DFL is a valid action.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
