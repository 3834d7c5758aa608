//! The `step` command line: one clap subcommand per job, each a thin call into the library.
//!
//! Errors reach the user as one `error: …` line with its causes, never a panic; the exit code is 1 for
//! a failed command and 2 for a usage error (clap's own).

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod bench;
pub mod bench_nodes;
pub mod eval;
pub mod generate;
pub mod sim;

#[derive(Parser, Debug)]
#[command(name = "step", version, about = "Offline subgoal-tree task planner for robots (STEP)")]
pub struct Cli {
    /// Log filter (tracing's EnvFilter syntax), e.g. `info` or `step=debug`; also RUST_LOG.
    #[arg(long, global = true)]
    pub log: Option<String>,
    /// CPU threads for inference (default: the machine's cores). Read once, before the first
    /// forward pass.
    #[arg(long, global = true)]
    pub threads: Option<usize>,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
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
    let cli = Cli::parse();
    init_tracing(cli.log.as_deref());
    if let Some(n) = cli.threads {
        set_threads(n);
    }
    match run(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Generate(a) => generate::run(&a),
        Command::Bench(a) => bench::run(&a),
        Command::Sim(a) => sim::run(a),
        Command::Eval(a) => eval::run(a),
    }
}

fn init_tracing(filter: Option<&str>) {
    use tracing_subscriber::EnvFilter;
    let filter = match filter {
        Some(f) => EnvFilter::new(f),
        None => EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("warn")),
    };
    // Logs go to stderr so that stdout stays clean for JSON and plans.
    let _ = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).try_init();
}

/// candle sizes its worker pool from these variables the first time it is used, so they are set
/// before any model is loaded.
fn set_threads(n: usize) {
    let n = n.max(1).to_string();
    std::env::set_var("CANDLE_NUM_THREADS", &n);
    std::env::set_var("RAYON_NUM_THREADS", &n);
}
