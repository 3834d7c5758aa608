//! `step bench …`: whole-pipeline benchmarks that print JSON (stdout) and a short table (stderr).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use clap::{Args, Subcommand};

use crate::bench::{burn, run_llm_bench, LlmBenchConfig, LlmBenchReport, TokenTime};
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
    /// Repetitions (at least 1); each figure is the median.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..))]
    pub runs: u64,
    /// Tokens to decode per run.
    #[arg(long, default_value_t = 64)]
    pub decode_tokens: usize,
    /// Measure beside busy neighbours (a shared robot CPU): N processes each keeping a core busy,
    /// `all` for one per core. Without a value, one: the busy neighbour process of a robot PC.
    #[arg(long, value_name = "N|all", num_args = 0..=1, default_missing_value = "1", value_parser = neighbour_count)]
    pub busy_neighbour: Option<usize>,
    #[command(flatten)]
    pub inference: super::args::InferenceArgs,
    /// Also run llama.cpp's `llama-bench` at this path (built by ../shared/tools/llama-bench.sh) on
    /// the same file, prompt length, generated tokens and threads, alternating with ours, and print
    /// the ratios. A measuring stick only.
    #[arg(long, value_name = "LLAMA_BENCH")]
    pub compare: Option<PathBuf>,
    /// Tokens already cached before the timed prompt, as a planner's tree node has (1,000-2,000):
    /// its prefill then attends to them too. With --compare, llama-bench runs with `-d` the same.
    #[arg(long, default_value_t = 0)]
    pub depth: usize,
    /// Alternating rounds for --compare (each side runs once per round; ratios of the medians).
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
}

/// `--busy-neighbour`'s count: a number of processes from 1 to 64, or `all` (one per core).
fn neighbour_count(s: &str) -> Result<usize, String> {
    if s == "all" {
        return Ok(std::thread::available_parallelism().map_or(1, |n| n.get()));
    }
    match s.parse::<usize>() {
        Ok(n) if (1..=64).contains(&n) => Ok(n),
        _ => Err(format!("{s:?} is not a neighbour count: give a number from 1 to 64, or `all` (one per core)")),
    }
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
    a.inference.apply();
    let path = resolve_model(&a.model)?;
    // The neighbours start before the model loads, as on a robot PC where they already run when the
    // planner starts (so `--threads auto` sees them); they are stopped however this ends.
    let _neighbours = match a.busy_neighbour {
        Some(n) => Neighbours::start(n)?,
        None => Neighbours(Vec::new()),
    };
    let mut engine = Engine::load_with_slices(&path, &[crate::grammar::TEXT_SLICE.to_string()])?;
    let deepest = crate::bench::max_depth(&engine, a.decode_tokens)?;
    if a.depth > deepest {
        anyhow::bail!(
            "--depth {}: the model's context cannot hold that many cached tokens before the bench prompt and its \
             decoding; give --depth {deepest} or less",
            a.depth
        );
    }
    if let Some(llama) = &a.compare {
        return compare(a, &mut engine, &path, llama);
    }
    let cfg = LlmBenchConfig { runs: a.runs as usize, decode_tokens: a.decode_tokens, depth: a.depth };
    let report = run_llm_bench(&mut engine, &cfg)?;
    let mut json = serde_json::to_value(&report)?;
    json["busy_neighbours"] = serde_json::json!(a.busy_neighbour.unwrap_or(0));
    eprintln!("{}", table(&report));
    println!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}

/// Ours and llama-bench, alternating, `rounds` times each; prints both sides' medians and the ratios.
fn compare(a: &LlmArgs, engine: &mut Engine, model: &Path, llama: &Path) -> anyhow::Result<()> {
    let threads = crate::llm::kernels::pool::global().threads();
    let cfg = LlmBenchConfig { runs: 1, decode_tokens: a.decode_tokens, depth: a.depth };
    let result = (|| -> anyhow::Result<_> {
        let (mut ours_p, mut ours_d, mut theirs_p, mut theirs_d) = (vec![], vec![], vec![], vec![]);
        let (mut prompt_tokens, mut depth) = (0, 0);
        for round in 0..a.rounds.max(1) {
            let r = run_llm_bench(engine, &cfg)?;
            (prompt_tokens, depth) = (r.prompt_tokens, r.depth);
            let (p, d) = llama_bench(llama, model, threads, r.prompt_tokens, a.decode_tokens, r.depth)?;
            eprintln!(
                "round {round}: ours prefill {:.1} decode {:.1} tok/s | llama.cpp prefill {p:.1} decode {d:.1} tok/s",
                r.prefill_tok_per_s, r.decode_tok_per_s
            );
            ours_p.push(r.prefill_tok_per_s);
            ours_d.push(r.decode_tok_per_s);
            theirs_p.push(p);
            theirs_d.push(d);
        }
        Ok((prompt_tokens, depth, median(ours_p), median(ours_d), median(theirs_p), median(theirs_d)))
    })();
    let (prompt_tokens, depth, op, od, tp, td) = result?;
    let at = if depth > 0 { format!(" after {depth} cached") } else { String::new() };
    eprintln!(
        "{} threads, {prompt_tokens}-token prompt{at}, {} generated, medians of {} rounds{}:\n\
         prefill  ours {op:>8.1}  llama.cpp {tp:>8.1} tok/s  ratio {:.2}x\n\
         decode   ours {od:>8.1}  llama.cpp {td:>8.1} tok/s  ratio {:.2}x",
        threads,
        a.decode_tokens,
        a.rounds.max(1),
        match a.busy_neighbour {
            Some(1) => ", 1 busy neighbour".to_string(),
            Some(n) => format!(", {n} busy neighbours"),
            None => String::new(),
        },
        op / tp.max(1e-9),
        od / td.max(1e-9),
    );
    let json = serde_json::json!({
        "model": model.display().to_string(), "threads": threads, "prompt_tokens": prompt_tokens, "depth": depth,
        "decode_tokens": a.decode_tokens, "rounds": a.rounds.max(1), "busy_neighbours": a.busy_neighbour.unwrap_or(0),
        "ours": { "prefill_tok_per_s": op, "decode_tok_per_s": od },
        "llama_cpp": { "prefill_tok_per_s": tp, "decode_tok_per_s": td },
        "ratio": { "prefill": op / tp.max(1e-9), "decode": od / td.max(1e-9) },
    });
    println!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}

/// One llama-bench run (`-r 1`): (prompt tok/s, generation tok/s), after `depth` cached tokens.
fn llama_bench(bin: &Path, model: &Path, threads: usize, prompt: usize, gen: usize, depth: usize) -> anyhow::Result<(f64, f64)> {
    let mut cmd = Command::new(bin);
    cmd.arg("-m").arg(model).args(["-t", &threads.to_string(), "-p", &prompt.to_string(), "-n", &gen.to_string()]);
    if depth > 0 {
        // (llama-bench builds before mid-2025 have no `-d`: they fail, and the error says to run it by hand)
        cmd.args(["-d", &depth.to_string()]);
    }
    let out = cmd
        .args(["-r", "1", "-o", "json"])
        .stderr(Stdio::null())
        .output()
        .map_err(|e| {
            anyhow::anyhow!("cannot run {}: {e} (build it with ../shared/tools/llama-bench.sh)", bin.display())
        })?;
    if !out.status.success() {
        anyhow::bail!("{} failed ({}); run it by hand to see why", bin.display(), out.status);
    }
    let rows: Vec<serde_json::Value> = serde_json::from_slice(&out.stdout)
        .map_err(|e| anyhow::anyhow!("{} printed no JSON list: {e}", bin.display()))?;
    let rate = |prefill: bool| {
        rows.iter().find(|r| (r["n_gen"].as_u64() == Some(0)) == prefill).and_then(|r| r["avg_ts"].as_f64()).ok_or_else(
            || anyhow::anyhow!("{} reported no {} rate", bin.display(), if prefill { "prompt" } else { "generation" }),
        )
    };
    Ok((rate(true)?, rate(false)?))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// Burning processes, one core each, killed when dropped. One is the issue's busy neighbour (on two
/// cores a fair scheduler leaves us one and a half); one per core leaves each of our threads half a
/// core at best, so 0.5x of unloaded throughput is then the ceiling, not a target.
struct Neighbours(Vec<Child>);

impl Neighbours {
    fn start(n: usize) -> anyhow::Result<Neighbours> {
        let exe = std::env::current_exe()?;
        let mut started = Neighbours(Vec::new());
        for _ in 0..n {
            started.0.push(
                Command::new(&exe)
                    .args(["bench", "burn", "--seconds", "3600"])
                    .stdout(Stdio::null())
                    .stderr(Stdio::null())
                    .spawn()?,
            );
        }
        // Let them get going before anything counts the busy cores.
        std::thread::sleep(std::time::Duration::from_millis(300));
        Ok(started)
    }
}

impl Drop for Neighbours {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// One line of where a token's decode time goes.
fn parts(t: &TokenTime) -> String {
    // A part that rounds to zero is printed as 0.0, never as -0.0 (differences of medians can be
    // slightly negative).
    let z = |x: f64| if x.abs() < 0.05 { 0.0 } else { x };
    format!(
        "{:.0} = forward {:.0} + forced {:.0} + mask {:.1} + grammar {:.1} + sample {:.1} + stream {:.1} + other {:.1}",
        z(t.total), z(t.forward), z(t.forced_forward), z(t.mask), z(t.grammar), z(t.sample), z(t.stream), z(t.other)
    )
}

fn table(r: &LlmBenchReport) -> String {
    format!(
        "model {} ({} threads, {} kernels, median of {})\n\
         load                 {:>9.1} ms\n\
         prefill ({:>3} tok)    {:>9.1} tok/s{}\n\
         decode               {:>9.1} tok/s\n\
         decode, constrained  {:>9.1} tok/s out ({:.2}x plain per output token; {:.0}% forced, {:.1} chosen/s)\n\
         µs per token, plain  {}\n\
         µs per token, constr {}\n\
         mask per token       {:>9.1} µs p50, {:.1} µs p99 ({:.2}% of decode time)\n\
         grammar compile      {:>9.1} ms\n\
         peak RSS             {:>9.1} MB",
        r.model,
        r.threads,
        r.kernel,
        r.runs,
        r.load_ms,
        r.prompt_tokens,
        r.prefill_tok_per_s,
        if r.depth > 0 { format!(" (after {} cached tokens)", r.depth) } else { String::new() },
        r.decode_tok_per_s,
        r.constrained_output_tok_per_s,
        r.constrained_speed_ratio,
        r.forced_token_share * 100.0,
        r.constrained_decode_tok_per_s,
        parts(&r.plain_us_per_token),
        parts(&r.constrained_us_per_token),
        r.mask_us_p50,
        r.mask_us_p99,
        r.mask_share_pct,
        r.grammar_compile_ms,
        r.peak_rss_mb
    )
}
