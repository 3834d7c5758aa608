//! The decode loop: prompt → tokens → (reused prefix + prefill) → per-token mask, choice, forward,
//! until EOS or the grammar is complete. Everything the planner asks of a model goes through
//! [`Generate`], so planner tests can script a model and benches can time the real one.
//!
//! Prefix reuse: the planner's prompts share a long prefix (instructions, scene). The engine keeps the
//! KV cache of the last sequence it ran and, on the next call, cuts it back to the longest common
//! token prefix and prefills only the rest. Outputs are identical with and without reuse.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::chat::{ChatTemplate, Message};
use super::constraint::GrammarCompiler;
use super::gguf::GgufFile;
use super::model::{ModelConfig, Transformer};
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
    /// Time spent computing each token mask and applying it to the logits, in microseconds, one
    /// entry per sampled token.
    pub mask_us: Vec<f64>,
    pub grammar_compile_ms: f64,
    /// The parts of `decode_ms`, so a slow decode can be told apart without a profiler:
    /// forward passes of one chosen token,
    pub forward_ms: f64,
    /// forward passes of grammar-forced tokens (with the chosen token before them, if any),
    pub forced_forward_ms: f64,
    /// grammar work besides the masks (finding forced tokens, committing chosen ones),
    pub grammar_ms: f64,
    /// choosing tokens from the logits,
    pub sample_ms: f64,
    /// and decoding text for the streaming callback. The rest of `decode_ms` is loop overhead.
    pub stream_ms: f64,
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

impl Generation {
    /// Prompt tokens run per second (reused ones excluded: they cost nothing).
    pub fn prefill_tok_per_s(&self) -> f64 {
        per_second(self.prompt_tokens - self.reused_tokens.min(self.prompt_tokens), self.timings.prefill_ms)
    }

    /// Tokens the model chose per second of decoding (forced tokens excluded, though the time to run
    /// them is in): not a speed to compare with unconstrained decoding; see
    /// [`Generation::output_tok_per_s`].
    pub fn decode_tok_per_s(&self) -> f64 {
        per_second(self.tokens.len().saturating_sub(self.forced_tokens), self.timings.decode_ms)
    }

    /// All generated tokens (forced ones included) per second of decoding: the decode speed, with or
    /// without a grammar.
    pub fn output_tok_per_s(&self) -> f64 {
        per_second(self.tokens.len(), self.timings.decode_ms)
    }
}

fn per_second(n: usize, ms: f64) -> f64 {
    if ms > 0.0 {
        n as f64 / (ms / 1e3)
    } else {
        0.0
    }
}

/// How likely one continuation is after a prompt.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Score {
    /// Natural-log probability of the continuation's tokens, summed.
    pub logprob: f64,
    pub tokens: usize,
}

impl Score {
    /// Log probability per token: comparable across continuations of different lengths.
    pub fn mean(&self) -> f64 {
        self.logprob / self.tokens.max(1) as f64
    }
}

/// The scores of a list of continuations, in the order given, with what they cost.
#[derive(Clone, Debug, Serialize)]
pub struct Scoring {
    pub scores: Vec<Score>,
    pub prompt_tokens: usize,
    pub reused_tokens: usize,
    /// Continuation tokens the model ran (shared beginnings run once).
    pub run_tokens: usize,
    pub ms: f64,
}

/// Where a prompt's constant beginning came from when [`Generate::warm`] put it in the cache.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WarmSource {
    /// Nothing done: this model keeps no cache, or no snapshot directory is set.
    #[default]
    None,
    /// Already in the cache (an earlier call of this process).
    Cached,
    /// Read from a snapshot on disk.
    Loaded,
    /// Computed, and written to a snapshot for the next start.
    Computed,
}

/// What [`Generate::warm`] or [`Generate::read`] did (`tokens`: the prefix's, or for `read` the
/// lead's tokens that were not already cached).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Warm {
    pub tokens: usize,
    pub source: WarmSource,
    pub ms: f64,
    /// The snapshot file read or written.
    pub snapshot: Option<PathBuf>,
    /// Why a snapshot could not be read or written (the run goes on: it only costs time).
    pub note: Option<String>,
}

impl Warm {
    /// How the tokens got into the cache, in words ("computed in 3277 ms, kept for the next run").
    pub fn describe(&self) -> String {
        let ms = self.ms;
        let note = self.note.as_deref().map(|n| format!(" ({n})")).unwrap_or_default();
        match self.source {
            WarmSource::None => "not prepared ahead".into(),
            WarmSource::Cached => "already in the cache".into(),
            WarmSource::Loaded => format!("read from its snapshot in {ms:.0} ms"),
            WarmSource::Computed if self.snapshot.is_some() && self.note.is_none() => {
                format!("computed in {ms:.0} ms, kept for the next run")
            }
            WarmSource::Computed => format!("computed in {ms:.0} ms{note}"),
        }
    }
}

/// The calls the planner makes of a model: generate under a grammar, or rank a closed list of
/// continuations by likelihood (a choice among known options, exact by construction).
pub trait Generate {
    fn generate(&mut self, prompt: &Prompt, grammar: Option<&str>, opts: &GenOptions) -> Result<Generation>;

    /// The log likelihood of each of `continuations` right after `prompt` (where the reply begins).
    fn score(&mut self, prompt: &Prompt, continuations: &[String]) -> Result<Scoring> {
        let _ = (prompt, continuations);
        Err(LlmError::Decode("this model cannot score continuations; choose by generation".into()))
    }

    /// Puts `prefix` in the cache ahead of the calls that start with it: the messages, rendered up
    /// to where the text of a following user turn begins. A model without a cache does nothing.
    fn warm(&mut self, prefix: &[Message]) -> Result<Warm> {
        let _ = prefix;
        Ok(Warm::default())
    }

    /// Puts `lead`, the beginning of the user turn after `prefix`, in the cache too: a run's own
    /// context (a task and its objects) read before its first call, in memory only (no
    /// snapshot: it is this run's). Only the tokens not already cached are computed.
    fn read(&mut self, prefix: &[Message], lead: &str) -> Result<Warm> {
        let _ = (prefix, lead);
        Ok(Warm::default())
    }
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
    /// Where [`Generate::warm`] keeps prefix snapshots (none: it does nothing).
    prefix_dir: Option<PathBuf>,
    load_ms: f64,
}

impl Engine {
    /// Loads a GGUF model file: validates it, reads the weights, builds tokenizer and template.
    pub fn load(path: &Path) -> Result<Self> {
        Self::load_with_slices(path, &[])
    }

    /// As [`Engine::load`], with vocabulary slices for the grammar compiler (see
    /// [`GrammarCompiler::with_slices`]): pass the free-text classes your grammars use (the planner
    /// passes `grammar::TEXT_SLICE`) so masks inside free text stay cheap.
    pub fn load_with_slices(path: &Path, slices: &[String]) -> Result<Self> {
        let t0 = Instant::now();
        super::mem::stage("start");
        let mut gguf = GgufFile::open(path)?;
        super::mem::stage("gguf header");
        let tokenizer = GgufTokenizer::from_gguf(&gguf)?;
        super::mem::stage("tokenizer");
        // A model without a chat template can still run raw text prompts.
        let template = ChatTemplate::from_gguf(&gguf).ok();
        // Everything built from the tokenizer's metadata comes before the weights: its temporary
        // copies, and the metadata itself, are freed before the weights add the file's size.
        let n_vocab = ModelConfig::from_gguf(&gguf)?.n_vocab;
        let grammars =
            GrammarCompiler::with_slices(tokenizer.shared_tokenizer().clone(), n_vocab, tokenizer.eos_ids(), slices)?;
        super::mem::stage("grammar compiler");
        gguf.drop_tokenizer_metadata();
        let model = Transformer::load(&gguf)?;
        super::mem::stage("weights");
        Ok(Self {
            path: path.to_path_buf(),
            model,
            tokenizer,
            template,
            grammars,
            cached: Vec::new(),
            prefix_dir: None,
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

    /// Keeps prompt-prefix snapshots in `dir` ([`super::prefix`]), read and written by
    /// [`Generate::warm`]; `None` (the default) turns them off.
    pub fn set_prefix_dir(&mut self, dir: Option<PathBuf>) {
        self.prefix_dir = dir;
    }

    /// `messages` and then `lead`, the beginning of a following user turn's text, rendered as
    /// every prompt that continues so writes them.
    pub fn render_lead(&self, messages: &[Message], lead: &str) -> Result<String> {
        const MARK: &str = "\u{1}step: the prefix ends here\u{1}";
        let mut m = messages.to_vec();
        m.push(Message::user(format!("{lead}{MARK}")));
        let text = self.render(&Prompt::Chat(m))?;
        match text.find(MARK) {
            Some(i) => Ok(text[..i].to_string()),
            None => Err(LlmError::Template(format!(
                "{}: the chat template does not write a user message's text as given, so no prompt prefix can be cut",
                self.path.display()
            ))),
        }
    }

    /// The tokens of [`Engine::render_lead`], which must leave room in the context for a prompt's
    /// last token at least.
    fn lead_tokens(&self, messages: &[Message], lead: &str) -> Result<Vec<u32>> {
        let ids = self.tokenizer.encode(&self.render_lead(messages, lead)?)?;
        let context = self.model.config().context_length;
        if ids.len() >= context {
            return Err(LlmError::PromptTooLong { prompt_tokens: ids.len(), context });
        }
        Ok(ids)
    }

    /// Forgets the cached prefix (the next call prefills from scratch).
    pub fn reset(&mut self) {
        self.model.truncate(0);
        self.cached.clear();
    }

    /// Runs `tokens` after the cache, keeping `cached` in step with the model.
    fn forward(&mut self, tokens: &[u32]) -> Result<Vec<f32>> {
        let mut logits = Vec::new();
        self.forward_into(tokens, &mut logits)?;
        Ok(logits)
    }

    /// As [`Engine::forward`], into a buffer the caller keeps.
    fn forward_into(&mut self, tokens: &[u32], logits: &mut Vec<f32>) -> Result<()> {
        self.model.forward_into(tokens, logits)?;
        self.cached.extend_from_slice(tokens);
        Ok(())
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
        self.generate_streaming(prompt, grammar, opts, None)
    }

    /// With a snapshot directory set: reads the prefix's keys and values from its snapshot, or
    /// computes them and writes the snapshot. Without one, the first call computes the prefix as
    /// before.
    fn warm(&mut self, prefix: &[Message]) -> Result<Warm> {
        let t0 = Instant::now();
        let ids = self.lead_tokens(prefix, "")?;
        let mut warm = Warm { tokens: ids.len(), ..Warm::default() };
        if ids.is_empty() {
            return Ok(warm);
        }
        if common_prefix(&self.cached, &ids) == ids.len() {
            warm.source = WarmSource::Cached;
        } else if let Some(dir) = self.prefix_dir.clone() {
            let path = dir.join(format!("{}.kv", super::prefix::key(&self.path, &ids)));
            self.cached.clear();
            match super::prefix::load(&mut self.model, &path, &ids) {
                Ok(true) => {
                    self.cached = ids;
                    warm.source = WarmSource::Loaded;
                }
                found => {
                    warm.note = found.err();
                    self.model.truncate(0);
                    self.forward(&ids)?;
                    if let Err(e) = super::prefix::save(&self.model, &path, &ids) {
                        warm.note = Some(format!("cannot write the prefix snapshot {}: {e}", path.display()));
                    }
                    warm.source = WarmSource::Computed;
                }
            }
            warm.snapshot = Some(path);
        }
        warm.ms = ms(t0);
        Ok(warm)
    }

    fn read(&mut self, prefix: &[Message], lead: &str) -> Result<Warm> {
        let t0 = Instant::now();
        let ids = self.lead_tokens(prefix, lead)?;
        let keep = common_prefix(&self.cached, &ids);
        let mut warm = Warm { tokens: ids.len() - keep, ..Warm::default() };
        if keep == ids.len() {
            warm.source = WarmSource::Cached;
            return Ok(warm);
        }
        self.model.truncate(keep);
        self.cached.truncate(keep);
        self.forward(&ids[keep..])?;
        warm.source = WarmSource::Computed;
        warm.ms = ms(t0);
        Ok(warm)
    }

    /// Runs the prompt once (reusing the cached prefix), then each continuation after it. The
    /// continuations are visited in token order, so one that starts like the previous one reuses
    /// those positions and their log probabilities, and only its own tail runs.
    fn score(&mut self, prompt: &Prompt, continuations: &[String]) -> Result<Scoring> {
        let t0 = Instant::now();
        let text = self.render(prompt)?;
        let prompt_ids = self.tokenizer.encode(&text)?;
        if prompt_ids.is_empty() {
            return Err(LlmError::Decode("the prompt is empty".into()));
        }
        let context = self.model.config().context_length;
        let mut conts = Vec::with_capacity(continuations.len());
        for c in continuations {
            let full = self.tokenizer.encode(&format!("{text}{c}"))?;
            // The prompt must tokenize the same on its own and before the continuation, or the
            // continuation's tokens are not the ones the model would write after it.
            if !full.starts_with(&prompt_ids) || full.len() == prompt_ids.len() {
                return Err(LlmError::Decode(format!(
                    "the continuation {c:?} is empty or merges into the prompt's last token when tokenized; \
                     end the prompt at a token boundary (a newline) or start the continuation with one"
                )));
            }
            if full.len() > context {
                return Err(LlmError::PromptTooLong { prompt_tokens: full.len(), context });
            }
            conts.push(full[prompt_ids.len()..].to_vec());
        }
        let (after_prompt, reused) = self.prefill(&prompt_ids, true)?;
        let base = prompt_ids.len();
        let first = log_softmax_at(&after_prompt, None);
        let mut order: Vec<usize> = (0..conts.len()).collect();
        order.sort_by(|&a, &b| conts[a].cmp(&conts[b]));
        let mut scores = vec![Score { logprob: 0.0, tokens: 0 }; conts.len()];
        let (mut prev, mut prev_lp): (Vec<u32>, Vec<f64>) = (Vec::new(), Vec::new());
        let mut run_tokens = 0;
        for i in order {
            let c = &conts[i];
            let n = c.len();
            let shared = common_prefix(&prev, c);
            let mut lp = Vec::with_capacity(n);
            lp.push(first[c[0] as usize]);
            // Positions 1..shared had the same context and token in the previous continuation.
            lp.extend_from_slice(&prev_lp[1.min(shared)..shared.min(n)]);
            if lp.len() < n {
                // Logits after c[j-1] are needed for j = lp.len()..n: run c[j-1..n-1] after
                // the prompt and c[..j-1] (which stay cached).
                let j = lp.len();
                self.model.truncate(base + j - 1);
                self.cached.truncate(base + j - 1);
                let run = &c[j - 1..n - 1];
                let rows = self.model.forward_all(run)?;
                self.cached.extend_from_slice(run);
                run_tokens += run.len();
                let v = self.model.config().n_vocab;
                for (k, row) in rows.chunks_exact(v).enumerate() {
                    lp.push(log_softmax_at(row, Some(c[j + k]))[0]);
                }
            }
            scores[i] = Score { logprob: lp.iter().sum(), tokens: n };
            prev = c.clone();
            prev_lp = lp;
        }
        Ok(Scoring { scores, prompt_tokens: base, reused_tokens: reused, run_tokens, ms: ms(t0) })
    }
}

/// log softmax of `logits`: at one token (a one-element vector), or at every token.
fn log_softmax_at(logits: &[f32], at: Option<u32>) -> Vec<f64> {
    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64;
    let lse = max + logits.iter().map(|&x| (x as f64 - max).exp()).sum::<f64>().ln();
    match at {
        Some(t) => vec![logits[t as usize] as f64 - lse],
        None => logits.iter().map(|&x| x as f64 - lse).collect(),
    }
}

impl Engine {
    /// [`Generate::generate`], calling `on_text` with each new piece of text as it is decoded (a
    /// piece ends on a character boundary; the pieces concatenate to the final text).
    pub fn generate_streaming(
        &mut self,
        prompt: &Prompt,
        grammar: Option<&str>,
        opts: &GenOptions,
        mut on_text: Option<&mut dyn FnMut(&str)>,
    ) -> Result<Generation> {
        opts.sampling.validate()?;
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
        let mut stream = Stream::default();
        // Tokens in the output but not yet run: the chosen token, then the tokens the grammar forces
        // after it. One forward pass runs them all (cheaper than one pass each, and the kernels give
        // the same bits either way); nothing runs after the last output token.
        let mut pending: Vec<u32> = Vec::new();
        let mut pending_forced = 0;
        let stop = loop {
            if let Some(c) = constraint.as_mut() {
                let t = Instant::now();
                let forced = c.forced_tokens()?;
                timings.grammar_ms += ms(t);
                forced_count += forced.len();
                pending_forced += forced.len();
                out.extend_from_slice(&forced);
                pending.extend_from_slice(&forced);
                if !forced.is_empty() {
                    let t = Instant::now();
                    stream.push(&self.tokenizer, &out, &mut on_text);
                    timings.stream_ms += ms(t);
                }
                if c.is_finished() {
                    break StopReason::GrammarComplete;
                }
            }
            if self.cached.len() + pending.len() > context {
                break StopReason::Context;
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
            if !pending.is_empty() {
                let t = Instant::now();
                self.forward_into(&pending, &mut logits)?;
                if pending_forced > 0 {
                    timings.forced_forward_ms += ms(t);
                } else {
                    timings.forward_ms += ms(t);
                }
                pending.clear();
                pending_forced = 0;
            }
            if let Some(c) = constraint.as_mut() {
                let t = Instant::now();
                c.apply_mask(&mut logits)?;
                timings.mask_us.push(t.elapsed().as_secs_f64() * 1e6);
            }
            let t = Instant::now();
            let tok = sampler.choose(&logits)?;
            timings.sample_ms += ms(t);
            if self.tokenizer.is_eos(tok) {
                break StopReason::Eos;
            }
            if let Some(c) = constraint.as_mut() {
                let t = Instant::now();
                c.commit(tok)?;
                timings.grammar_ms += ms(t);
            }
            out.push(tok);
            let t = Instant::now();
            stream.push(&self.tokenizer, &out, &mut on_text);
            timings.stream_ms += ms(t);
            if constraint.as_ref().is_some_and(|c| c.is_finished()) {
                break StopReason::GrammarComplete;
            }
            // The chosen token is kept; only running it (to choose the next one) needs a position.
            if self.cached.len() + 1 > context {
                break StopReason::Context;
            }
            pending.push(tok);
        };
        timings.decode_ms = ms(t_decode);
        let text = self.tokenizer.decode(&out, true)?;
        stream.finish(&text, &mut on_text);
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

/// What has been streamed so far. Each push decodes only the tokens after the last piece passed on,
/// with the one piece before them as context (a tokenizer may decode a text's first token
/// differently, e.g. without its leading space), so the cost per token stays flat however long the
/// output grows. Only a grown, character-complete text is passed on.
#[derive(Default)]
struct Stream {
    sent: String,
    /// `out[..done]` has been passed on; `out[context..done]` is the last piece's tokens.
    done: usize,
    context: usize,
}

impl Stream {
    fn push(&mut self, tok: &GgufTokenizer, out: &[u32], on_text: &mut Option<&mut dyn FnMut(&str)>) {
        let Some(f) = on_text.as_mut() else { return };
        if out.len() <= self.done {
            return;
        }
        let (Ok(known), Ok(text)) = (tok.decode(&out[self.context..self.done], true), tok.decode(&out[self.context..], true))
        else {
            return;
        };
        // A token may end inside a multi-byte character: wait for the rest of it.
        if text.ends_with('\u{FFFD}') || !text.starts_with(&known) || text.len() == known.len() {
            return;
        }
        let piece = &text[known.len()..];
        f(piece);
        self.sent.push_str(piece);
        (self.context, self.done) = (self.done, out.len());
    }

    fn finish(&mut self, text: &str, on_text: &mut Option<&mut dyn FnMut(&str)>) {
        let Some(f) = on_text.as_mut() else { return };
        if let Some(rest) = text.strip_prefix(self.sent.as_str()) {
            if !rest.is_empty() {
                f(rest);
            }
        } else {
            tracing::warn!("the streamed text differs from the final decoding; the final text is {text:?}");
        }
        self.sent = text.to_string();
    }
}

fn common_prefix(a: &[u32], b: &[u32]) -> usize {
    a.iter().zip(b).take_while(|(x, y)| x == y).count()
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
