//! Grammar-constrained decoding: a Lark grammar becomes, at every step of generation, the set of token
//! ids the model may choose next (applied to the logits before sampling), plus the tokens the grammar
//! forces outright (appended without a choice). Built on llguidance.
//!
//! [`GrammarCompiler`] is made once per tokenizer; it compiles a grammar text once and caches it, and
//! every [`GrammarCompiler::compile`] hands out a fresh [`Constraint`] (a clone of the compiled
//! parser). A grammar that cannot be satisfied is an error, never an empty mask that would hang the
//! decode loop, and nothing on this path panics on bad input.
//!
//! The decode loop drives a [`Constraint`] like this:
//! ```text
//! loop {
//!     if c.is_finished() { break }                 // nothing can follow: stop (EOS is implied)
//!     let ff = c.forced_tokens()?;                 // already committed: append, prefill in one pass
//!     if !ff.is_empty() { append(ff); continue }
//!     c.apply_mask(&mut logits)?;                  // EOS is allowed only where the grammar can end
//!     let t = sample(&logits);
//!     if eos.contains(&t) { break }                // (committing it is allowed but not needed)
//!     c.commit(t)?;
//! }
//! ```

use std::collections::{HashMap, VecDeque};
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use llguidance::api::TopLevelGrammar;
use llguidance::toktrie::{
    ApproximateTokEnv, InferenceCapabilities, SimpleVob, TokEnv, TokTrie, TokenId, TokenizerEnv,
};
use llguidance::{Matcher, ParserFactory, TokenParser};
use tokenizers::Tokenizer;
use toktrie_hf_tokenizers::ByteTokenizer;

use super::{LlmError, Result};

/// How many compiled grammars the compiler keeps (the oldest is dropped first). The planner builds
/// grammars per scene and decision; this bounds memory while keeping the hot ones.
const CACHE_CAPACITY: usize = 128;

/// The set of token ids allowed at one position (its length is the model's logits width).
#[derive(Clone, Debug)]
pub struct TokenMask {
    vob: SimpleVob,
}

impl TokenMask {
    /// Whether token `tok` may be chosen (ids beyond the vocabulary never are).
    pub fn is_allowed(&self, tok: u32) -> bool {
        (tok as usize) < self.vob.len() && self.vob.is_allowed(tok)
    }

    /// How many tokens are allowed.
    pub fn count(&self) -> usize {
        self.vob.num_set()
    }

    /// The allowed token ids, ascending.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        self.vob.iter()
    }

    /// The logits width this mask is for.
    pub fn len(&self) -> usize {
        self.vob.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vob.is_zero()
    }

    /// Sets every disallowed logit to `-inf`, leaving the allowed ones untouched. Works a 32-bit word
    /// of the mask at a time, so a mostly-empty or mostly-full mask costs little more than a memset.
    pub fn apply_to_logits(&self, logits: &mut [f32]) -> Result<()> {
        if logits.len() != self.vob.len() {
            return Err(LlmError::Decode(format!(
                "logits have {} entries but the grammar's vocabulary has {}; build the GrammarCompiler with the model's logits width",
                logits.len(),
                self.vob.len()
            )));
        }
        for (chunk, &word) in logits.chunks_mut(32).zip(self.vob.as_slice()) {
            match word {
                u32::MAX => {}
                0 => chunk.fill(f32::NEG_INFINITY),
                w => {
                    // A select rather than a branch per bit: the compiler vectorises it.
                    for (bit, x) in chunk.iter_mut().enumerate() {
                        *x = if (w >> bit) & 1 != 0 { *x } else { f32::NEG_INFINITY };
                    }
                }
            }
        }
        Ok(())
    }
}

/// Compiles Lark grammars against one tokenizer and caches them by grammar text.
pub struct GrammarCompiler {
    factory: ParserFactory,
    eos: Vec<u32>,
    n_vocab: usize,
    cache: Mutex<Cache>,
    compiles: AtomicUsize,
    hits: AtomicUsize,
}

#[derive(Default)]
struct Cache {
    parsers: HashMap<String, TokenParser>,
    order: VecDeque<String>,
}

impl GrammarCompiler {
    /// `n_vocab` is the model's logits width (it may exceed the tokenizer's vocabulary: the extra ids
    /// are never allowed); `eos` the ids that end a generation, allowed only where the grammar can end.
    pub fn new(tokenizer: Arc<Tokenizer>, n_vocab: usize, eos: &[u32]) -> Result<Self> {
        Self::with_slices(tokenizer, n_vocab, eos, &[])
    }

    /// As [`GrammarCompiler::new`], with vocabulary slices: regular expressions (e.g. the free-text
    /// class the caller's grammars use) for which llguidance precomputes token sets, so masks inside
    /// such text are cheap. Slices change speed, never which tokens are allowed. The runtime knows no
    /// grammar of its own; the caller passes the classes its grammars use.
    /// The compiler keeps `tokenizer` (llguidance tokenizes some grammar text itself) rather than a
    /// copy of it: pass the engine's own.
    pub fn with_slices(
        tokenizer: Arc<Tokenizer>,
        n_vocab: usize,
        eos: &[u32],
        slices: &[String],
    ) -> Result<Self> {
        let vocab = tokenizer.get_vocab_size(true);
        if vocab == 0 {
            return Err(LlmError::Tokenizer("the tokenizer has an empty vocabulary".into()));
        }
        if n_vocab < vocab {
            return Err(LlmError::Tokenizer(format!(
                "the model's logits width {n_vocab} is smaller than the tokenizer's vocabulary {vocab}; tokenizer and model do not match"
            )));
        }
        if eos.is_empty() {
            return Err(LlmError::Tokenizer(
                "no end-of-sequence token given; constrained decoding needs at least one".into(),
            ));
        }
        if let Some(&bad) = eos.iter().find(|&&t| t as usize >= vocab) {
            return Err(LlmError::Tokenizer(format!(
                "end-of-sequence token {bad} is outside the tokenizer's vocabulary ({vocab} tokens)"
            )));
        }
        // toktrie_hf_tokenizers asserts on a few malformed vocabularies; turn that into an error.
        let build = AssertUnwindSafe(|| SharedTokEnv::build(tokenizer, n_vocab, eos));
        let tok_env: TokEnv = std::panic::catch_unwind(build)
            .map_err(|_| {
                LlmError::Tokenizer("the tokenizer's vocabulary cannot be read as bytes (malformed byte tokens)".into())
            })?
            .map_err(|e| LlmError::Tokenizer(format!("cannot use this tokenizer for constrained decoding: {e:#}")))?;
        // Only the caller's slices, never llguidance's default JSON-string ones, which these grammars
        // do not use.
        let mut factory = ParserFactory::new(&tok_env, InferenceCapabilities::default(), slices)
            .map_err(|e| LlmError::Tokenizer(format!("cannot build the grammar engine for this tokenizer: {e:#}")))?;
        factory.quiet();
        Ok(Self {
            factory,
            eos: eos.to_vec(),
            n_vocab,
            cache: Mutex::new(Cache::default()),
            compiles: AtomicUsize::new(0),
            hits: AtomicUsize::new(0),
        })
    }

    /// A fresh constraint for `lark` (llguidance's Lark dialect). The grammar is compiled the first
    /// time its text is seen and cloned from the cache afterwards. A syntax error names the line and
    /// column; a grammar no token sequence can start is rejected here.
    pub fn compile(&self, lark: &str) -> Result<Constraint> {
        if let Some(p) = self.lock().parsers.get(lark) {
            self.hits.fetch_add(1, Ordering::Relaxed);
            return Ok(self.constraint(p.clone()));
        }
        let parser = self
            .factory
            .create_parser(TopLevelGrammar::from_lark(lark.to_string()))
            .map_err(|e| LlmError::Grammar(describe_compile_error(&e.to_string())))?;
        self.compiles.fetch_add(1, Ordering::Relaxed);
        // A grammar whose language no token of this vocabulary can begin would give an empty first
        // mask: reject it now, with the reason, rather than in the middle of a generation.
        let mut probe = Matcher::new(Ok(parser.clone()));
        if let Err(e) = probe.compute_mask() {
            return Err(LlmError::Grammar(format!(
                "grammar cannot be satisfied: its language is empty or no token of this vocabulary can begin it ({})",
                first_line(&e)
            )));
        }
        let mut cache = self.lock();
        if !cache.parsers.contains_key(lark) {
            if cache.order.len() >= CACHE_CAPACITY {
                if let Some(old) = cache.order.pop_front() {
                    cache.parsers.remove(&old);
                }
            }
            cache.order.push_back(lark.to_string());
            cache.parsers.insert(lark.to_string(), parser.clone());
        }
        Ok(self.constraint(parser))
    }

    /// How many grammars were compiled (cache misses) and how many were served from the cache.
    pub fn cache_stats(&self) -> (usize, usize) {
        (self.compiles.load(Ordering::Relaxed), self.hits.load(Ordering::Relaxed))
    }

    /// The EOS ids this compiler was built with.
    pub fn eos(&self) -> &[u32] {
        &self.eos
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Cache> {
        // A panic while holding the lock cannot leave the map half-updated in a harmful way.
        self.cache.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn constraint(&self, parser: TokenParser) -> Constraint {
        Constraint {
            matcher: Matcher::new(Ok(parser)),
            env: self.factory.tok_env().clone(),
            eos: self.eos.clone(),
            n_vocab: self.n_vocab,
            mask: None,
            tokens: Vec::new(),
        }
    }
}

/// llguidance's view of the tokenizer: the token trie, and the engine's tokenizer for the text
/// llguidance tokenizes itself. It is `toktrie_hf_tokenizers::ByteTokenizerEnv` without the copies
/// that one keeps for its whole life, of the tokenizer and of every token's bytes (31 MB and 8 MB
/// of Qwen2.5's peak memory); it builds the same trie and tokenizes the same way.
struct SharedTokEnv {
    tokenizer: Arc<Tokenizer>,
    trie: TokTrie,
}

impl SharedTokEnv {
    fn build(tokenizer: Arc<Tokenizer>, n_vocab: usize, eos: &[u32]) -> anyhow::Result<TokEnv> {
        // ByteTokenizer works out each token's bytes, but only from a tokenizer of its own, which it
        // may adjust (SentencePiece-style space handling); that copy lives only for this function.
        let mut bt = ByteTokenizer::from_tokenizer((*tokenizer).clone())?;
        bt.set_eos_tokens(eos);
        let (mut info, eos, mut bytes) = (bt.tokrx_info(), bt.eos_tokens(), bt.token_bytes());
        // Where it did adjust the text handling (not byte-level BPE, which has none of that), keep
        // its tokenizer, as ByteTokenizerEnv would.
        let tokenizer =
            if same_text_handling(&bt.hf_tokenizer, &tokenizer) { tokenizer } else { Arc::new(bt.hf_tokenizer) };
        // From here on as ByteTokenizerEnv::new: the logits past the vocabulary are named special
        // tokens (never allowed), and every eos id ends the grammar.
        while bytes.len() < n_vocab {
            let mut name = format!(".<[{}]>", bytes.len()).into_bytes();
            name[0] = TokTrie::SPECIAL_TOKEN_MARKER;
            bytes.push(name);
        }
        info.vocab_size = n_vocab as u32;
        let mut trie = TokTrie::from(&info, &bytes);
        if eos.len() > 1 {
            trie = trie.with_eos_tokens(&eos);
        }
        Ok(Arc::new(SharedTokEnv { tokenizer, trie }))
    }

    fn encode(&self, s: &str) -> Vec<TokenId> {
        // As ByteTokenizerEnv: llguidance hands over text the tokenizer accepts.
        self.tokenizer.encode(s, false).expect("tokenizer error").get_ids().to_vec()
    }
}

/// Whether two tokenizers normalise and split text alike (their vocabularies are the same).
fn same_text_handling(a: &Tokenizer, b: &Tokenizer) -> bool {
    let json = |t: &Tokenizer| {
        (serde_json::to_string(&t.get_normalizer()).ok(), serde_json::to_string(&t.get_pre_tokenizer()).ok())
    };
    let (ja, jb) = (json(a), json(b));
    ja.0.is_some() && ja.1.is_some() && ja == jb
}

impl TokenizerEnv for SharedTokEnv {
    fn tok_trie(&self) -> &TokTrie {
        &self.trie
    }

    fn tokenize_bytes(&self, s: &[u8]) -> Vec<TokenId> {
        self.trie.tokenize_with_greedy_fallback(s, |s| self.encode(s))
    }

    fn tokenize_bytes_special(&self, s: &[u8]) -> Vec<TokenId> {
        self.trie.tokenize_with_greedy_fallback(s, |s| self.trie.tokenize_with_special(s, |s| self.encode(s)))
    }
}

/// The first line of an llguidance error: the reason, without the parser-state dump that follows it
/// (which goes to the debug log).
fn first_line(e: &anyhow::Error) -> String {
    let msg = e.to_string();
    tracing::debug!("llguidance: {msg}");
    msg.lines().next().unwrap_or_default().trim().to_string()
}

/// llguidance reports Lark errors as `LINE(COL): message …` or `at LINE(COL): message …`; say it in
/// words.
fn describe_compile_error(msg: &str) -> String {
    let parsed = msg.strip_prefix("at ").unwrap_or(msg).split_once("): ").and_then(|(pos, rest)| {
        let (line, col) = pos.split_once('(')?;
        Some((line.trim().parse::<usize>().ok()?, col.parse::<usize>().ok()?, rest))
    });
    match parsed {
        Some((line, col, rest)) => {
            format!("invalid Lark grammar at line {line}, column {col}: {rest}")
        }
        None => format!("invalid Lark grammar: {msg}"),
    }
}

/// The most alternatives llguidance's parser holds at one point (its `max_items_in_row`).
pub const MAX_ALTERNATIVES: usize = 2000;

/// Checks a grammar without a model, so a bad grammar is reported before a model loads (seconds)
/// and in words that say what to change: Lark syntax, a rule (or group) with more alternatives than
/// the parser holds at one point, a grammar whose text never ends (a rule that always recurses into
/// itself), and an empty language. It compiles against a one-byte-per-token vocabulary, so a grammar
/// that passes can still be one a particular model's vocabulary cannot write (reported at compile).
pub fn check_grammar(lark: &str) -> Result<()> {
    if let Some((rule, n)) = widest_rule(lark) {
        if n > MAX_ALTERNATIVES {
            return Err(LlmError::Grammar(format!(
                "rule '{rule}' has {n} alternatives, but the grammar engine holds at most {MAX_ALTERNATIVES} at one \
                 point; split it into nested rules (e.g. one rule per verb or per object class) or offer fewer objects"
            )));
        }
    }
    let env = ApproximateTokEnv::single_byte_env();
    let mut factory = ParserFactory::new(&env, InferenceCapabilities::default(), &[])
        .map_err(|e| LlmError::Grammar(format!("cannot build the grammar checker: {e:#}")))?;
    factory.quiet();
    let parser = factory
        .create_parser(TopLevelGrammar::from_lark(lark.to_string()))
        .map_err(|e| LlmError::Grammar(describe_compile_error(&e.to_string())))?;
    let mut m = Matcher::new(Ok(parser));
    let eos = env.tok_trie().eos_token();
    // Walk a few hundred bytes along the first allowed byte: limits the parser hits on the way
    // (too many alternatives, endless forced text) surface here rather than mid-generation.
    for _ in 0..256 {
        if m.is_stopped() {
            break;
        }
        let ff = m.compute_ff_tokens();
        if let Some(e) = m.get_error() {
            return Err(limit_error(&e));
        }
        if !ff.is_empty() {
            m.consume_tokens(&ff).map_err(|e| limit_error(&e.to_string()))?;
            continue;
        }
        let mask = m.compute_mask().map_err(|e| limit_error(&e.to_string()))?;
        if mask.is_allowed(eos) {
            break;
        }
        let Some(t) = (0..256u32).find(|&t| mask.is_allowed(t)) else {
            return Err(LlmError::Grammar("grammar cannot be satisfied: no text can continue it".into()));
        };
        m.consume_token(t).map_err(|e| limit_error(&e.to_string()))?;
    }
    Ok(())
}

/// Whether llguidance stopped on one of its parser limits (rather than on text the grammar rejects).
fn is_limit(msg: &str) -> bool {
    msg.contains("Current row has") || msg.contains("Too many items")
}

/// A parser-limit message in words a grammar author can act on.
fn limit_error(msg: &str) -> LlmError {
    let first = msg.lines().next().unwrap_or_default().trim();
    if first.contains("Current row has") {
        LlmError::Grammar(format!(
            "the grammar offers more than {MAX_ALTERNATIVES} alternatives at one point; split large choices into \
             nested rules (e.g. one rule per verb or per object class) or offer fewer objects ({first})"
        ))
    } else if first.contains("Too many items") {
        LlmError::Grammar(format!(
            "the grammar never ends: from some point every continuation is forced and endless (a rule that always \
             recurses into itself); give each recursive rule a way to finish ({first})"
        ))
    } else {
        LlmError::Grammar(format!("grammar cannot be satisfied: {first}"))
    }
}

/// The rule (or parenthesised group) with the most `|` alternatives, by a plain scan of the Lark
/// text that skips strings, regular expressions and comments.
fn widest_rule(lark: &str) -> Option<(String, usize)> {
    let mut best: Option<(String, usize)> = None;
    let mut rule = String::new();
    // One counter per open group; index 0 is the rule's top level.
    let mut groups: Vec<usize> = vec![1];
    let close = |rule: &str, n: usize, best: &mut Option<(String, usize)>| {
        if best.as_ref().is_none_or(|b| n > b.1) {
            *best = Some((rule.to_string(), n));
        }
    };
    for line in lark.lines() {
        let t = line.trim_start();
        if t.is_empty() || t.starts_with("//") || t.starts_with('%') {
            continue;
        }
        if !t.starts_with('|') {
            let head: String = t.chars().take_while(|c| c.is_alphanumeric() || *c == '_' || *c == '?').collect();
            if !head.is_empty() && t[head.len()..].trim_start().starts_with(':') {
                for n in groups.drain(..) {
                    close(&rule, n, &mut best);
                }
                groups.push(1);
                rule = head;
            }
        }
        let mut chars = t.chars().peekable();
        while let Some(c) = chars.next() {
            match c {
                '"' | '\'' => {
                    while let Some(d) = chars.next() {
                        if d == '\\' {
                            chars.next();
                        } else if d == c {
                            break;
                        }
                    }
                }
                '/' if chars.peek() == Some(&'/') => break,
                '/' => {
                    while let Some(d) = chars.next() {
                        if d == '\\' {
                            chars.next();
                        } else if d == '/' {
                            break;
                        }
                    }
                }
                '(' | '[' => groups.push(1),
                ')' | ']' if groups.len() > 1 => {
                    let n = groups.pop().unwrap_or(1);
                    close(&rule, n, &mut best);
                }
                '|' => {
                    if let Some(g) = groups.last_mut() {
                        *g += 1;
                    }
                }
                _ => {}
            }
        }
    }
    for n in groups {
        close(&rule, n, &mut best);
    }
    best
}

/// One generation's grammar state: which tokens may come next, and which are forced.
pub struct Constraint {
    matcher: Matcher,
    env: TokEnv,
    eos: Vec<u32>,
    n_vocab: usize,
    /// The mask of the current position, once computed (commit checks against it).
    mask: Option<TokenMask>,
    /// Tokens committed so far (forced ones included), for error messages.
    tokens: Vec<u32>,
}

impl Constraint {
    /// The tokens allowed at the next position. EOS ids are in it only where the grammar can end;
    /// once [`Self::is_finished`], only EOS is. A position where nothing is allowed is an error.
    pub fn mask(&mut self) -> Result<TokenMask> {
        self.current_mask().cloned()
    }

    /// Applies [`Self::mask`] to `logits` (see [`TokenMask::apply_to_logits`]): the decode loop's
    /// call, which borrows the mask kept for [`Self::commit`] instead of copying it every token.
    pub fn apply_mask(&mut self, logits: &mut [f32]) -> Result<()> {
        self.current_mask()?.apply_to_logits(logits)
    }

    /// The mask of the current position, computed once per position.
    fn current_mask(&mut self) -> Result<&TokenMask> {
        if self.mask.is_none() {
            let vob = if self.is_finished() {
                let mut v = SimpleVob::alloc(self.n_vocab);
                for &e in &self.eos {
                    v.allow_token(e);
                }
                v
            } else {
                self.matcher.compute_mask().map_err(|e| self.error("no token can continue the text", e))?
            };
            if vob.is_zero() {
                // compute_mask reports this itself; kept so an empty mask can never reach the sampler.
                return Err(LlmError::Decode(format!("no token can continue the text {:?}", self.text_tail())));
            }
            self.mask = Some(TokenMask { vob });
        }
        self.mask.as_ref().ok_or_else(|| LlmError::Decode("the token mask was not computed".into()))
    }

    /// Advances past `token`, which must be in the current mask. After the grammar has finished,
    /// committing an EOS id is a no-op and anything else is an error.
    pub fn commit(&mut self, token: u32) -> Result<()> {
        if token as usize >= self.n_vocab {
            return Err(LlmError::Decode(format!("token {token} is outside the vocabulary ({} ids)", self.n_vocab)));
        }
        if self.is_finished() {
            if self.eos.contains(&token) {
                return Ok(());
            }
            return Err(LlmError::Decode(format!(
                "the grammar is complete; only end-of-sequence may follow, got token {token} {}",
                self.token_dbg(token)
            )));
        }
        if !self.current_mask()?.is_allowed(token) {
            return Err(LlmError::Decode(format!(
                "token {token} {} is not allowed by the grammar after {:?}",
                self.token_dbg(token),
                self.text_tail()
            )));
        }
        self.matcher.consume_token(token).map_err(|e| self.error("cannot commit a token", e))?;
        self.mask = None;
        self.tokens.push(token);
        Ok(())
    }

    /// The tokens the grammar forces from here (possibly none), already committed: the caller
    /// appends them to the sequence without a choice and must not commit them again.
    pub fn forced_tokens(&mut self) -> Result<Vec<u32>> {
        if self.is_finished() {
            return Ok(Vec::new());
        }
        let ff = self.matcher.compute_ff_tokens();
        if let Some(e) = self.matcher.get_error() {
            if is_limit(&e) {
                return Err(limit_error(&e));
            }
            let e = e.lines().next().unwrap_or_default().to_string();
            return Err(LlmError::Decode(format!("computing forced tokens: {e}")));
        }
        if ff.is_empty() {
            return Ok(ff);
        }
        self.matcher.consume_tokens(&ff).map_err(|e| self.error("cannot commit forced tokens", e))?;
        self.mask = None;
        self.tokens.extend_from_slice(&ff);
        Ok(ff)
    }

    /// Whether the text so far is a complete sentence of the grammar (EOS would be allowed now).
    pub fn is_accepting(&mut self) -> bool {
        self.is_finished() || self.matcher.is_accepting().unwrap_or(false)
    }

    /// Whether the grammar is complete and nothing more can follow (or EOS was committed).
    pub fn is_finished(&self) -> bool {
        self.matcher.is_stopped() && !self.matcher.is_error()
    }

    /// The tokens committed so far, forced ones included.
    pub fn tokens(&self) -> &[u32] {
        &self.tokens
    }

    fn error(&self, what: &str, e: anyhow::Error) -> LlmError {
        let msg = e.to_string();
        if is_limit(&msg) {
            return limit_error(&msg);
        }
        LlmError::Decode(format!(
            "{what}: the grammar cannot be satisfied from here (text so far ends {:?}): {}",
            self.text_tail(),
            first_line(&e)
        ))
    }

    fn token_dbg(&self, token: u32) -> String {
        self.env.tok_trie().token_dbg(token)
    }

    /// The last bytes of the committed text, for error messages.
    fn text_tail(&self) -> String {
        let start = self.tokens.len().saturating_sub(16);
        let bytes = self.env.tok_trie().decode_raw(self.tokens.get(start..).unwrap_or(&[]));
        String::from_utf8_lossy(&bytes).into_owned()
    }
}

#[cfg(test)]
pub(crate) mod tests;
