//! `step generate`: one prompt through the local model, optionally under a Lark grammar.
//!
//! Prints the text as it is generated, or with `--json` the text with token counts, the stop reason
//! and timings at the end. The prompt is wrapped in the model's chat template unless `--raw` is given.
//! A grammar is checked before the model loads, so a bad one fails in milliseconds.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Args;
use serde_json::json;

use super::args::{read_input, InferenceArgs};
use crate::llm::chat::Message;
use crate::llm::constraint::check_grammar;
use crate::llm::engine::{Engine, GenOptions, Prompt, StopReason};
use crate::llm::locate::{resolve_model, DEFAULT_MODEL};
use crate::llm::sample::Sampling;

#[derive(Args, Debug)]
#[command(after_help = "\
Limits: the prompt and the output together must fit the model's context (its positions, read from the \
GGUF and printed as context_length by --json); when the context fills, generation stops with stop reason \
'context' and the text so far. Under a grammar, output that is not complete within --max-tokens is an error \
(raise --max-tokens).

Exit codes: 0 done; 1 error (model, grammar, prompt or options); 2 usage error.")]
pub struct GenerateArgs {
    /// The user's message (or the whole prompt with --raw).
    #[arg(long, short, required_unless_present = "prompt_file", conflicts_with = "prompt_file")]
    pub prompt: Option<String>,
    /// Read the prompt from a file, or from standard input with `-`.
    #[arg(long, value_name = "FILE")]
    pub prompt_file: Option<PathBuf>,
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
    #[arg(long, default_value_t = 128, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_tokens: u64,
    /// Sample with this seed instead of choosing greedily (reproducible for a given seed).
    /// --temperature and --top-p apply only with it.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Sampling temperature, finite and >= 0 (0 is greedy); needs --seed [default: 0.8].
    #[arg(long, requires = "seed", value_parser = parse_temperature, allow_hyphen_values = true)]
    pub temperature: Option<f64>,
    /// Nucleus sampling threshold in (0, 1] (1 keeps every token); needs --seed [default: 0.95].
    #[arg(long, requires = "seed", value_parser = parse_top_p, allow_hyphen_values = true)]
    pub top_p: Option<f64>,
    /// Print JSON at the end: text, token counts, stop reason, timings (no streaming).
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub inference: InferenceArgs,
}

fn parse_temperature(s: &str) -> Result<f64, String> {
    let t: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !t.is_finite() || t < 0.0 {
        return Err(format!("the temperature must be a finite number >= 0 (0 is greedy), got {s}"));
    }
    Ok(t)
}

fn parse_top_p(s: &str) -> Result<f64, String> {
    let p: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !(p > 0.0 && p <= 1.0) {
        return Err(format!("top-p must be in (0, 1] (1 keeps every token), got {s}"));
    }
    Ok(p)
}

pub fn run(args: &GenerateArgs) -> anyhow::Result<()> {
    let user = match (&args.prompt, &args.prompt_file) {
        (Some(p), _) => p.clone(),
        (None, Some(f)) => read_input(f, "prompt file")?,
        (None, None) => bail!("give a prompt with --prompt TEXT or --prompt-file FILE"),
    };
    let grammar = match &args.grammar {
        Some(p) => {
            let g = read_input(p, "grammar file")?;
            check_grammar(&g).with_context(|| format!("grammar file {}", p.display()))?;
            Some(g)
        }
        None => None,
    };
    args.inference.apply();
    let path = resolve_model(&args.model)?;
    let slices = [crate::grammar::TEXT_SLICE.to_string()];
    let mut engine = Engine::load_with_slices(&path, &slices)?;
    let prompt = if args.raw {
        Prompt::Text(user)
    } else {
        let mut m = Vec::new();
        if let Some(s) = &args.system {
            m.push(Message::system(s.clone()));
        }
        m.push(Message::user(user));
        Prompt::Chat(m)
    };
    let sampling = match args.seed {
        Some(seed) => {
            Sampling::Sample { temperature: args.temperature.unwrap_or(0.8), top_p: args.top_p.unwrap_or(0.95), seed }
        }
        None => Sampling::Greedy,
    };
    let opts = GenOptions { max_tokens: args.max_tokens as usize, sampling, reuse_prefix: true };
    let context = |r: crate::llm::Result<_>| {
        r.with_context(|| match &args.grammar {
            Some(p) => format!("generating with grammar {}", p.display()),
            None => "generating".to_string(),
        })
    };
    if args.json {
        let g = context(engine.generate_streaming(&prompt, grammar.as_deref(), &opts, None))?;
        let out = json!({
            "model": path.display().to_string(),
            "context_length": engine.model().config().context_length,
            "text": g.text,
            "stop": g.stop,
            "prompt_tokens": g.prompt_tokens,
            "generated_tokens": g.tokens.len(),
            "forced_tokens": g.forced_tokens,
            "load_ms": engine.load_ms(),
            "prefill_ms": g.timings.prefill_ms,
            "decode_ms": g.timings.decode_ms,
            "grammar_compile_ms": g.timings.grammar_compile_ms,
            "prefill_tok_per_s": g.prefill_tok_per_s(),
            "decode_tok_per_s": g.decode_tok_per_s(),
            "output_tok_per_s": g.output_tok_per_s(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    // Stream: each piece is written and flushed as it is decoded.
    let stdout = std::io::stdout();
    let mut write_err: Option<std::io::Error> = None;
    let mut emit = |piece: &str| {
        if write_err.is_none() {
            let mut lock = stdout.lock();
            if let Err(e) = lock.write_all(piece.as_bytes()).and_then(|_| lock.flush()) {
                write_err = Some(e);
            }
        }
    };
    let g = context(engine.generate_streaming(
        &prompt,
        grammar.as_deref(),
        &opts,
        Some(&mut emit as &mut dyn FnMut(&str)),
    ))?;
    if let Some(e) = write_err {
        return Err(e).context("writing the output");
    }
    println!();
    if g.stop == StopReason::Context {
        eprintln!(
            "note: stopped because the model's context ({} positions) is full; the text above is what fit",
            engine.model().config().context_length
        );
    }
    Ok(())
}
