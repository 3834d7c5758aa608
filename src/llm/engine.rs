//! The decode loop: prompt → tokens → (reused prefix + prefill) → per-token mask, choice, forward,
//! until EOS or the grammar is complete. Everything the planner asks of a model goes through
//! [`Generate`], so planner tests can script a model and benches can time the real one.
//!
//! Prefix reuse: the planner's prompts share a long prefix (instructions, scene). The engine keeps the
//! KV cache of the last sequence it ran and, on the next call, cuts it back to the longest common
//! token prefix and prefills only the rest. Outputs are identical with and without reuse.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::chat::{ChatTemplate, Message};
use super::constraint::GrammarCompiler;
use super::gguf::GgufFile;
use super::model::Transformer;
use super::sample::{Sampler, Sampling};
use super::tokenizer::GgufTokenizer;
use super::{LlmError, Result};

/// What to feed the model: raw text (special tokens written in it are parsed), or chat messages
/// rendered with the model's own chat template, ending where the assistant's reply begins.
#[derive(Clone, Debug)]
pub enum Prompt {
    Text(String),
    Chat(Vec<Message>),
}

/// Knobs of one generation.
#[derive(Clone, Debug)]
pub struct GenOptions {
    pub max_tokens: usize,
    pub sampling: Sampling,
    /// Keep and reuse the KV cache of the previous call's longest common prefix.
    pub reuse_prefix: bool,
}

impl Default for GenOptions {
    fn default() -> Self {
        Self { max_tokens: 256, sampling: Sampling::Greedy, reuse_prefix: true }
    }
}

/// Why a generation ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The model chose an end-of-sequence token (only allowed where the grammar could end).
    Eos,
    /// The grammar admits nothing more.
    GrammarComplete,
    /// `max_tokens` reached (unconstrained, or with the grammar at an accepting point).
    MaxTokens,
    /// The model's context is full: the text so far is kept, but under a grammar it may be
    /// incomplete. A shorter prompt or a model with a longer context leaves more room.
    Context,
}

/// Where the time went, for the bench and the JSON output.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Timings {
    pub prefill_ms: f64,
    pub decode_ms: f64,
    /// Time spent computing each token mask, in microseconds, one entry per sampled token.
    pub mask_us: Vec<f64>,
    pub grammar_compile_ms: f64,
}

/// One generation's result.
#[derive(Clone, Debug, Serialize)]
pub struct Generation {
    pub text: String,
    pub tokens: Vec<u32>,
    pub prompt_tokens: usize,
    /// Prompt tokens whose KV cache was reused from the previous call (not recomputed).
    pub reused_tokens: usize,
    /// Generated tokens the grammar forced (appended without a choice).
    pub forced_tokens: usize,
    pub stop: StopReason,
    pub timings: Timings,
}

/// The one call the planner makes of a model.
pub trait Generate {
    fn generate(&mut self, prompt: &Prompt, grammar: Option<&str>, opts: &GenOptions) -> Result<Generation>;
}

/// A loaded model with its tokenizer, chat template, grammar compiler and KV cache.
pub struct Engine {
    path: PathBuf,
    model: Transformer,
    tokenizer: GgufTokenizer,
    template: Option<ChatTemplate>,
    grammars: GrammarCompiler,
    /// The tokens whose keys/values are in the model's cache, in order.
    cached: Vec<u32>,
    load_ms: f64,
}

impl Engine {
    /// Loads a GGUF model file: validates it, reads the weights, builds tokenizer and template.
    pub fn load(path: &Path) -> Result<Self> {
        let t0 = Instant::now();
        let gguf = GgufFile::open(path)?;
        let tokenizer = GgufTokenizer::from_gguf(&gguf)?;
        // A model without a chat template can still run raw text prompts.
        let template = ChatTemplate::from_gguf(&gguf).ok();
        let model = Transformer::load(&gguf)?;
        let grammars =
            GrammarCompiler::new(tokenizer.tokenizer(), model.config().n_vocab, tokenizer.eos_ids())?;
        Ok(Self {
            path: path.to_path_buf(),
            model,
            tokenizer,
            template,
            grammars,
            cached: Vec::new(),
            load_ms: t0.elapsed().as_secs_f64() * 1e3,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn load_ms(&self) -> f64 {
        self.load_ms
    }

    pub fn tokenizer(&self) -> &GgufTokenizer {
        &self.tokenizer
    }

    pub fn model(&self) -> &Transformer {
        &self.model
    }

    pub fn grammars(&self) -> &GrammarCompiler {
        &self.grammars
    }

    /// The prompt text the model will see.
    pub fn render(&self, prompt: &Prompt) -> Result<String> {
        match prompt {
            Prompt::Text(t) => Ok(t.clone()),
            Prompt::Chat(messages) => match &self.template {
                Some(t) => t.render(messages, true),
                None => Err(LlmError::Template(format!(
                    "{} has no tokenizer.chat_template; pass a raw text prompt instead",
                    self.path.display()
                ))),
            },
        }
    }

    /// Forgets the cached prefix (the next call prefills from scratch).
    pub fn reset(&mut self) {
        self.model.truncate(0);
        self.cached.clear();
    }

    /// Runs `tokens` after the cache, keeping `cached` in step with the model.
    fn forward(&mut self, tokens: &[u32]) -> Result<Vec<f32>> {
        let logits = self.model.forward(tokens)?;
        self.cached.extend_from_slice(tokens);
        Ok(logits)
    }

    /// Cuts the cache back to the longest common prefix with `prompt` and prefills the rest;
    /// returns the logits after the prompt and how many tokens were reused.
    fn prefill(&mut self, prompt: &[u32], reuse: bool) -> Result<(Vec<f32>, usize)> {
        let common = if reuse { common_prefix(&self.cached, prompt) } else { 0 };
        // At least one token must run to produce logits for the next position.
        let keep = common.min(prompt.len().saturating_sub(1));
        self.model.truncate(keep);
        self.cached.truncate(keep);
        let logits = self.forward(&prompt[keep..])?;
        Ok((logits, keep))
    }
}

impl Generate for Engine {
    fn generate(&mut self, prompt: &Prompt, grammar: Option<&str>, opts: &GenOptions) -> Result<Generation> {
        let text = self.render(prompt)?;
        let prompt_ids = self.tokenizer.encode(&text)?;
        if prompt_ids.is_empty() {
            return Err(LlmError::Decode("the prompt is empty".into()));
        }
        let context = self.model.config().context_length;
        if prompt_ids.len() > context {
            return Err(LlmError::PromptTooLong { prompt_tokens: prompt_ids.len(), context });
        }
        let mut timings = Timings::default();
        let t = Instant::now();
        let mut constraint = grammar.map(|g| self.grammars.compile(g)).transpose()?;
        timings.grammar_compile_ms = ms(t);

        let t = Instant::now();
        let (mut logits, reused) = self.prefill(&prompt_ids, opts.reuse_prefix)?;
        timings.prefill_ms = ms(t);

        let t_decode = Instant::now();
        let mut sampler = Sampler::new(&opts.sampling);
        let mut out: Vec<u32> = Vec::new();
        let mut forced_count = 0;
        let stop = loop {
            if let Some(c) = constraint.as_mut() {
                // Fast-forward: tokens the grammar forces are appended and run in one pass.
                let forced = c.forced_tokens()?;
                forced_count += forced.len();
                out.extend_from_slice(&forced);
                if c.is_finished() {
                    break StopReason::GrammarComplete;
                }
                if !forced.is_empty() {
                    if self.cached.len() + forced.len() > context {
                        break StopReason::Context;
                    }
                    logits = self.forward(&forced)?;
                }
            }
            if out.len() >= opts.max_tokens {
                if let Some(c) = constraint.as_mut() {
                    if !c.is_accepting() {
                        let so_far = self.tokenizer.decode(&out, true).unwrap_or_default();
                        return Err(LlmError::TokenBudget { max_tokens: opts.max_tokens, so_far });
                    }
                }
                break StopReason::MaxTokens;
            }
            if let Some(c) = constraint.as_mut() {
                let t = Instant::now();
                let mask = c.mask()?;
                mask.apply_to_logits(&mut logits)?;
                timings.mask_us.push(t.elapsed().as_secs_f64() * 1e6);
            }
            let tok = sampler.choose(&logits)?;
            if self.tokenizer.is_eos(tok) {
                break StopReason::Eos;
            }
            if let Some(c) = constraint.as_mut() {
                c.commit(tok)?;
            }
            out.push(tok);
            if constraint.as_ref().is_some_and(|c| c.is_finished()) {
                break StopReason::GrammarComplete;
            }
            // The chosen token is kept; only running it (to choose the next one) needs a position.
            if self.cached.len() + 1 > context {
                break StopReason::Context;
            }
            logits = self.forward(&[tok])?;
        };
        timings.decode_ms = ms(t_decode);
        let text = self.tokenizer.decode(&out, true)?;
        Ok(Generation {
            text,
            tokens: out,
            prompt_tokens: prompt_ids.len(),
            reused_tokens: reused,
            forced_tokens: forced_count,
            stop,
            timings,
        })
    }
}

fn common_prefix(a: &[u32], b: &[u32]) -> usize {
    a.iter().zip(b).take_while(|(x, y)| x == y).count()
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
