//! `step bench …`: whole-pipeline benchmarks that print JSON (stdout) and a short table (stderr).

use std::process::{Child, Command, Stdio};

use clap::{Args, Subcommand};

use crate::bench::{burn, run_llm_bench, LlmBenchConfig, LlmBenchReport};
use crate::llm::engine::Engine;
use crate::llm::locate::{resolve_model, DEFAULT_MODEL};

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchCommand,
}

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// The LLM runtime: load, prefill, decode (plain and constrained), mask time, memory.
    Llm(LlmArgs),
    /// One planner tree node: decomposition and termination latency p50/p99, tokens, time split.
    Nodes(super::bench_nodes::NodesArgs),
    /// Keep one core busy for a while (the neighbour process of --busy-neighbour).
    #[command(hide = true)]
    Burn {
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
    },
}

#[derive(Args, Debug)]
pub struct LlmArgs {
    /// Model: an installed name, a .gguf path, or owner/repo:file.gguf from the local HF cache.
    #[arg(long, short, default_value = DEFAULT_MODEL)]
    pub model: String,
    /// Repetitions; each figure is the median.
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Tokens to decode per run.
    #[arg(long, default_value_t = 64)]
    pub decode_tokens: usize,
    /// Measure while other processes keep every core busy (a shared robot CPU).
    #[arg(long)]
    pub busy_neighbour: bool,
}

pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    match &args.what {
        BenchCommand::Llm(a) => llm(a),
        BenchCommand::Nodes(a) => super::bench_nodes::run(a),
        BenchCommand::Burn { seconds } => {
            burn(*seconds);
            Ok(())
        }
    }
}

fn llm(a: &LlmArgs) -> anyhow::Result<()> {
    let path = resolve_model(&a.model)?;
    let mut engine = Engine::load(&path)?;
    let cfg = LlmBenchConfig { runs: a.runs, decode_tokens: a.decode_tokens };
    let neighbours = if a.busy_neighbour { spawn_neighbours()? } else { Vec::new() };
    let report = run_llm_bench(&mut engine, &cfg);
    for mut c in neighbours {
        let _ = c.kill();
        let _ = c.wait();
    }
    let report = report?;
    let mut json = serde_json::to_value(&report)?;
    json["busy_neighbour"] = serde_json::Value::Bool(a.busy_neighbour);
    eprintln!("{}", table(&report));
    println!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}

/// One burning process per core, so our threads always have a competitor.
fn spawn_neighbours() -> anyhow::Result<Vec<Child>> {
    let exe = std::env::current_exe()?;
    let n = std::thread::available_parallelism().map_or(1, |n| n.get());
    (0..n)
        .map(|_| {
            Command::new(&exe)
                .args(["bench", "burn", "--seconds", "3600"])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .map_err(anyhow::Error::from)
        })
        .collect()
}

fn table(r: &LlmBenchReport) -> String {
    format!(
        "model {} ({} threads, median of {})\n\
         load                 {:>9.1} ms\n\
         prefill ({:>3} tok)    {:>9.1} tok/s\n\
         decode               {:>9.1} tok/s\n\
         decode, constrained  {:>9.1} tok/s out ({:.1} chosen/s, {:.0}% forced; {:+.1}% per token)\n\
         mask per token       {:>9.1} µs p50, {:.1} µs p99 ({:.2}% of decode time)\n\
         grammar compile      {:>9.1} ms\n\
         peak RSS             {:>9.1} MB",
        r.model,
        r.threads,
        r.runs,
        r.load_ms,
        r.prompt_tokens,
        r.prefill_tok_per_s,
        r.decode_tok_per_s,
        r.constrained_output_tok_per_s,
        r.constrained_decode_tok_per_s,
        r.forced_token_share * 100.0,
        r.constrained_overhead_pct,
        r.mask_us_p50,
        r.mask_us_p99,
        r.mask_share_pct,
        r.grammar_compile_ms,
        r.peak_rss_mb
    )
}
