//! The measurements behind `step bench llm`: load time, prefill and decode throughput (unconstrained
//! and grammar-constrained), per-token mask time, grammar compile time and peak memory, on one model
//! and one thread count, as JSON. Criterion micro-benchmarks live in `benches/`; this is the
//! whole-pipeline figure an engineer compares across machines and against llama.cpp.
//!
//! Constrained against plain decoding is compared per output token, forced tokens included, on the
//! same prompt (`constrained_speed_ratio`): that is what a caller waits for. The grammar's own cost
//! is in `constrained_us_per_token` (mask, grammar), apart from the forward passes, so a fast ratio
//! cannot hide a slow grammar. The plain run decodes `decode_tokens`, the constrained one what the
//! grammar allows (about 100 tokens here); the few extra positions barely change a token's cost.
//!
//! Each figure is the median of `runs` repetitions. With `--busy-neighbour` other processes keep cores
//! busy while we measure, the situation of a robot whose CPU is shared.

use std::time::Instant;

use serde::Serialize;

use crate::llm::chat::Message;
use crate::llm::engine::{Engine, GenOptions, Generate, Generation, Prompt};
use crate::llm::Result;
use crate::world::World;

/// What to measure.
#[derive(Clone, Debug)]
pub struct LlmBenchConfig {
    pub runs: usize,
    pub decode_tokens: usize,
    /// Tokens already in the cache before the timed prompt (0: an empty cache). A planner's tree
    /// node prefills a few hundred new tokens after 1,000-2,000 reused ones, and attention over
    /// that cache is much of its time; llama-bench's `-d` measures the same shape.
    pub depth: usize,
}

impl Default for LlmBenchConfig {
    fn default() -> Self {
        Self { runs: 3, decode_tokens: 64, depth: 0 }
    }
}

/// The figures, all medians over the runs.
#[derive(Clone, Debug, Serialize)]
pub struct LlmBenchReport {
    pub model: String,
    pub threads: usize,
    /// The dot-product kernel this CPU runs (`avx512`, `avx2` or `scalar`; see `STEP_KERNEL`).
    pub kernel: &'static str,
    pub runs: usize,
    pub load_ms: f64,
    /// Tokens the timed prefill computed (after `depth` cached ones).
    pub prompt_tokens: usize,
    /// Tokens reused from the cache before them.
    pub depth: usize,
    pub prefill_tok_per_s: f64,
    pub decode_tok_per_s: f64,
    /// Tokens the model chose per second under the grammar: forced tokens are not counted, but the
    /// time to run them is, so this is not a decode speed to compare with `decode_tok_per_s`.
    pub constrained_decode_tok_per_s: f64,
    /// All output tokens per second under the grammar, forced ones included: the constrained
    /// decode speed, comparable with `decode_tok_per_s` (same prompt, same model).
    pub constrained_output_tok_per_s: f64,
    /// Constrained over unconstrained decode speed per output token (the ratio of the median times
    /// per token; above 1, forced tokens run in batches outweigh the grammar's own cost).
    pub constrained_speed_ratio: f64,
    /// Extra decode time per output token under the grammar, relative to unconstrained decoding
    /// (negative: forced tokens, run in batches, make constrained decoding faster).
    pub constrained_overhead_pct: f64,
    /// Where an output token's decode time goes, unconstrained and constrained.
    pub plain_us_per_token: TokenTime,
    pub constrained_us_per_token: TokenTime,
    /// Share of constrained decode time spent computing masks.
    pub mask_share_pct: f64,
    pub forced_token_share: f64,
    pub mask_us_p50: f64,
    pub mask_us_p99: f64,
    pub grammar_compile_ms: f64,
    pub peak_rss_mb: f64,
}

/// One output token's share of the decode time by part, in microseconds: each field is the median
/// over the runs of that part's time divided by the output tokens (forced ones included).
#[derive(Clone, Debug, Default, Serialize)]
pub struct TokenTime {
    pub total: f64,
    /// One-token forward passes, after each chosen token.
    pub forward: f64,
    /// Forward passes over grammar-forced tokens, a run of them at a time.
    pub forced_forward: f64,
    /// Computing the grammar's masks and applying them to the logits.
    pub mask: f64,
    /// Finding forced tokens and committing chosen ones.
    pub grammar: f64,
    pub sample: f64,
    pub stream: f64,
    /// The rest of the loop.
    pub other: f64,
}

impl TokenTime {
    fn of(g: &Generation) -> Self {
        let t = &g.timings;
        let per = |ms: f64| ms * 1e3 / g.tokens.len().max(1) as f64;
        let mask_ms = t.mask_us.iter().sum::<f64>() / 1e3;
        let parts = t.forward_ms + t.forced_forward_ms + mask_ms + t.grammar_ms + t.sample_ms + t.stream_ms;
        Self {
            total: per(t.decode_ms),
            forward: per(t.forward_ms),
            forced_forward: per(t.forced_forward_ms),
            mask: per(mask_ms),
            grammar: per(t.grammar_ms),
            sample: per(t.sample_ms),
            stream: per(t.stream_ms),
            other: per((t.decode_ms - parts).max(0.0)),
        }
    }

    fn median(runs: &[Self]) -> Self {
        let m = |f: fn(&Self) -> f64| median(&mut runs.iter().map(f).collect::<Vec<_>>());
        Self {
            total: m(|t| t.total),
            forward: m(|t| t.forward),
            forced_forward: m(|t| t.forced_forward),
            mask: m(|t| t.mask),
            grammar: m(|t| t.grammar),
            sample: m(|t| t.sample),
            stream: m(|t| t.stream),
            other: m(|t| t.other),
        }
    }
}

/// A planner-like prompt of roughly 300 tokens: instructions, the demo scene's objects, a task.
pub fn bench_prompt(world: &World) -> Prompt {
    let mut objects = String::new();
    for o in world.objects() {
        let props: Vec<String> = o.properties.iter().map(|p| format!("{p:?}").to_lowercase()).collect();
        objects.push_str(&format!("<{}> ({}): {}\n", o.class_name, o.id, props.join(", ")));
    }
    // The prompt text lives with the other prompts, where it can be read and edited as text.
    let system = include_str!("../prompts/bench_system.txt").trim();
    Prompt::Chat(vec![
        Message::system(system),
        Message::user(format!("Objects in the scene:\n{objects}\nInstruction: put the apple in the fridge.")),
    ])
}

/// About `depth` tokens of text to put before the timed prompt: its rendered `text` over and
/// over, cut at `depth` tokens (the cut may re-tokenize a token or two differently; the report
/// gives the depth actually reused).
fn filler(engine: &Engine, text: &str, depth: usize) -> Result<String> {
    let tok = engine.tokenizer();
    let per = tok.encode(&text)?.len().max(1);
    let ids = tok.encode(&text.repeat(depth / per + 1))?;
    let cut = tok.decode(&ids[..depth.min(ids.len())], false)?;
    // Start the timed prompt on a line of its own.
    Ok(format!("{cut}\n"))
}

/// The deepest cache that fits before the bench prompt: the model's context less the prompt and
/// the tokens decoded after it (`decode_tokens`; the constrained run may decode up to 256).
pub fn max_depth(engine: &Engine, decode_tokens: usize) -> Result<usize> {
    let prompt = engine.render(&bench_prompt(&World::demo()))?;
    let used = engine.tokenizer().encode(&prompt)?.len() + decode_tokens.max(256);
    Ok(engine.model().config().context_length.saturating_sub(used + 1))
}

/// Runs the measurements on a loaded engine.
pub fn run_llm_bench(engine: &mut Engine, cfg: &LlmBenchConfig) -> Result<LlmBenchReport> {
    let world = World::demo();
    let prompt = bench_prompt(&world);
    let lark = crate::scene_grammar::demo_kitchen_grammar()
        .to_lark()
        .map_err(|e| crate::llm::LlmError::Grammar(e.to_string()))?;
    let runs = cfg.runs.max(1);

    // Grammar compile: a fresh text each time defeats the cache (a trailing comment changes it).
    let mut compile = Vec::new();
    for i in 0..runs {
        let t = Instant::now();
        engine.grammars().compile(&format!("{lark}\n// run {i}\n"))?;
        compile.push(t.elapsed().as_secs_f64() * 1e3);
    }

    let fresh = |max: usize| GenOptions { max_tokens: max, reuse_prefix: false, ..Default::default() };
    // At a depth, every timed call first computes the filler (untimed), then the prompt after it
    // with the filler reused.
    let (deep, prompt) = match cfg.depth {
        0 => (None, prompt),
        d => {
            let text = engine.render(&prompt)?;
            let f = filler(engine, &text, d)?;
            let after = Prompt::Text(format!("{f}{text}"));
            (Some(f), after)
        }
    };
    let timed = |engine: &mut Engine, grammar: Option<&str>, max: usize| -> Result<Generation> {
        match &deep {
            Some(f) => {
                engine.generate(&Prompt::Text(f.clone()), None, &fresh(1))?;
                engine.generate(&prompt, grammar, &GenOptions { reuse_prefix: true, ..fresh(max) })
            }
            None => engine.generate(&prompt, grammar, &fresh(max)),
        }
    };
    let mut depth = 0;
    let mut prefill = Vec::new();
    let mut decode = Vec::new();
    let mut cdecode = Vec::new();
    let mut coutput = Vec::new();
    let mut per_tok_plain = Vec::new();
    let mut per_tok_constrained = Vec::new();
    let (mut parts_plain, mut parts_constrained) = (Vec::new(), Vec::new());
    let mut mask_share = Vec::new();
    let mut forced_share = Vec::new();
    let mut masks = Vec::new();
    let mut prompt_tokens = 0;
    for _ in 0..runs {
        let g = timed(engine, None, cfg.decode_tokens)?;
        prompt_tokens = g.prompt_tokens - g.reused_tokens;
        depth = g.reused_tokens;
        prefill.push(rate(prompt_tokens, g.timings.prefill_ms));
        decode.push(rate(g.tokens.len(), g.timings.decode_ms));
        per_tok_plain.push(g.timings.decode_ms / g.tokens.len().max(1) as f64);
        parts_plain.push(TokenTime::of(&g));
        // The grammar decides the length here (up to 8 action lines); the cap only guards it.
        let c = timed(engine, Some(&lark), cfg.decode_tokens.max(256))?;
        let chosen = c.tokens.len() - c.forced_tokens;
        cdecode.push(rate(chosen, c.timings.decode_ms));
        coutput.push(rate(c.tokens.len(), c.timings.decode_ms));
        per_tok_constrained.push(c.timings.decode_ms / c.tokens.len().max(1) as f64);
        parts_constrained.push(TokenTime::of(&c));
        mask_share.push(c.timings.mask_us.iter().sum::<f64>() / 1e3 / c.timings.decode_ms.max(1e-9) * 100.0);
        forced_share.push(c.forced_tokens as f64 / c.tokens.len().max(1) as f64);
        masks.extend_from_slice(&c.timings.mask_us);
    }
    crate::llm::mem::stage("after the runs");
    crate::llm::mem::model("after the runs", engine.model());
    let plain = median(&mut per_tok_plain);
    let constrained = median(&mut per_tok_constrained);
    Ok(LlmBenchReport {
        model: engine.path().display().to_string(),
        threads: crate::llm::kernels::pool::global().threads(),
        kernel: crate::llm::kernels::kernel().name(),
        runs,
        load_ms: engine.load_ms(),
        prompt_tokens,
        depth,
        prefill_tok_per_s: median(&mut prefill),
        decode_tok_per_s: median(&mut decode),
        constrained_decode_tok_per_s: median(&mut cdecode),
        constrained_output_tok_per_s: median(&mut coutput),
        constrained_speed_ratio: if constrained > 0.0 { plain / constrained } else { 0.0 },
        constrained_overhead_pct: if plain > 0.0 { (constrained / plain - 1.0) * 100.0 } else { 0.0 },
        plain_us_per_token: TokenTime::median(&parts_plain),
        constrained_us_per_token: TokenTime::median(&parts_constrained),
        mask_share_pct: median(&mut mask_share),
        forced_token_share: median(&mut forced_share),
        mask_us_p50: percentile(&mut masks, 0.50),
        mask_us_p99: percentile(&mut masks, 0.99),
        grammar_compile_ms: median(&mut compile),
        peak_rss_mb: peak_rss_mb(),
    })
}

/// Items per second for `n` items in `ms` milliseconds (0 for no time).
pub fn rate(n: usize, ms: f64) -> f64 {
    if ms > 0.0 {
        n as f64 / (ms / 1e3)
    } else {
        0.0
    }
}

fn median(v: &mut [f64]) -> f64 {
    percentile(v, 0.5)
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let i = ((v.len() - 1) as f64 * q).round() as usize;
    v[i.min(v.len() - 1)]
}

/// Peak resident memory of this process (Linux `VmHWM`), in MB; 0 where unknown.
pub fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
}

/// Keeps one core busy until `seconds` pass: the busy neighbour of `step bench llm --busy-neighbour`,
/// run in its own process so that it competes as another program would.
pub fn burn(seconds: f64) {
    let end = Instant::now() + std::time::Duration::from_secs_f64(seconds);
    let mut x: u64 = 1;
    while Instant::now() < end {
        for _ in 0..100_000 {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        }
        std::hint::black_box(x);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_pick_ranked_values() {
        let mut v = vec![5.0, 1.0, 3.0, 2.0, 4.0];
        assert_eq!(percentile(&mut v, 0.5), 3.0);
        assert_eq!(percentile(&mut v, 0.99), 5.0);
        assert_eq!(percentile(&mut v, 0.0), 1.0);
        assert_eq!(percentile(&mut [], 0.5), 0.0);
    }

    #[test]
    fn bench_prompt_lists_the_demo_scene() {
        let w = World::demo();
        match bench_prompt(&w) {
            Prompt::Chat(m) => assert!(m[1].content.contains("<apple> (12)")),
            Prompt::Text(_) => panic!("expected a chat prompt"),
        }
    }
}
