//! `step generate`: one prompt through the local model, optionally under a Lark grammar.
//!
//! Prints the generated text, or with `--json` the text with token counts, the stop reason and
//! timings. The prompt is wrapped in the model's chat template unless `--raw` is given.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use serde_json::json;

use crate::bench::rate;
use crate::llm::chat::Message;
use crate::llm::engine::{Engine, GenOptions, Generate, Prompt};
use crate::llm::locate::{resolve_model, DEFAULT_MODEL};
use crate::llm::sample::Sampling;

#[derive(Args, Debug)]
pub struct GenerateArgs {
    /// The user's message (or the whole prompt with --raw).
    #[arg(long, short)]
    pub prompt: String,
    /// A system message placed before the prompt.
    #[arg(long)]
    pub system: Option<String>,
    /// Feed the prompt as it is, without the model's chat template.
    #[arg(long)]
    pub raw: bool,
    /// A Lark grammar file (llguidance dialect) the output must follow, e.g. grammars/actions.lark.
    #[arg(long, short)]
    pub grammar: Option<PathBuf>,
    /// Model: an installed name (smollm2, qwen2.5-coder-0.5b), a .gguf path, or owner/repo:file.gguf
    /// from the local Hugging Face cache.
    #[arg(long, short, default_value = DEFAULT_MODEL)]
    pub model: String,
    /// Most tokens to generate.
    #[arg(long, default_value_t = 128)]
    pub max_tokens: usize,
    /// Sample with this seed instead of choosing greedily (reproducible for a given seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Sampling temperature (with --seed).
    #[arg(long, default_value_t = 0.8)]
    pub temperature: f64,
    /// Nucleus sampling threshold (with --seed); 1 disables it.
    #[arg(long, default_value_t = 0.95)]
    pub top_p: f64,
    /// Print JSON: text, token counts, stop reason, timings.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &GenerateArgs) -> anyhow::Result<()> {
    let grammar = match &args.grammar {
        Some(p) => Some(
            std::fs::read_to_string(p).with_context(|| format!("reading grammar file {}", p.display()))?,
        ),
        None => None,
    };
    let path = resolve_model(&args.model)?;
    let mut engine = Engine::load(&path)?;
    let prompt = if args.raw {
        Prompt::Text(args.prompt.clone())
    } else {
        let mut m = Vec::new();
        if let Some(s) = &args.system {
            m.push(Message::system(s.clone()));
        }
        m.push(Message::user(args.prompt.clone()));
        Prompt::Chat(m)
    };
    let sampling = match args.seed {
        Some(seed) => Sampling::Sample { temperature: args.temperature, top_p: args.top_p, seed },
        None => Sampling::Greedy,
    };
    let opts = GenOptions { max_tokens: args.max_tokens, sampling, reuse_prefix: true };
    let g = engine
        .generate(&prompt, grammar.as_deref(), &opts)
        .with_context(|| match &args.grammar {
            Some(p) => format!("generating with grammar {}", p.display()),
            None => "generating".to_string(),
        })?;
    if args.json {
        let decode_tokens = g.tokens.len().saturating_sub(g.forced_tokens);
        let out = json!({
            "model": path.display().to_string(),
            "text": g.text,
            "stop": g.stop,
            "prompt_tokens": g.prompt_tokens,
            "generated_tokens": g.tokens.len(),
            "forced_tokens": g.forced_tokens,
            "load_ms": engine.load_ms(),
            "prefill_ms": g.timings.prefill_ms,
            "decode_ms": g.timings.decode_ms,
            "grammar_compile_ms": g.timings.grammar_compile_ms,
            "prefill_tok_per_s": rate(g.prompt_tokens, g.timings.prefill_ms),
            "decode_tok_per_s": rate(decode_tokens, g.timings.decode_ms),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!("{}", g.text);
    }
    Ok(())
}
