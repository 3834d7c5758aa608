//! The model's tokenizer, built from the GGUF's own metadata (no tokenizer.json ships with the
//! models): a byte-level BPE (`tokenizer.ggml.model = gpt2`) over `tokenizer.ggml.tokens` and
//! `tokenizer.ggml.merges`, with the pre-tokenizer that `tokenizer.ggml.pre` names, and the
//! control / user-defined tokens (`token_type` 3 / 4) added so that `<|im_start|>` is one id.
//!
//! Supported `pre` values: `smollm` and `starcoder` (each digit split off, then GPT-2's byte-level
//! regex), `qwen2` (NFC, Qwen2's split regex, then byte-level without a regex), `gpt-2` / `default`
//! (GPT-2's byte-level regex); a missing `pre` falls back to `default` as llama.cpp does. Any other
//! value is an error: a wrong pre-tokenizer gives a tokenizer that round-trips text but disagrees
//! with the model's training, which is worse than failing.

use std::collections::BTreeSet;
use std::path::Path;
use std::sync::Arc;

use tokenizers::decoders::byte_level::ByteLevel;
use tokenizers::models::bpe::{Vocab, BPE};
use tokenizers::normalizers::unicode::NFC;
use tokenizers::pre_tokenizers::digits::Digits;
use tokenizers::pre_tokenizers::sequence::Sequence;
use tokenizers::pre_tokenizers::split::{Split, SplitPattern};
use tokenizers::pre_tokenizers::PreTokenizerWrapper;
use tokenizers::processors::template::TemplateProcessing;
use tokenizers::{AddedToken, SplitDelimiterBehavior, Tokenizer};

use super::error::{LlmError, Result};
use super::gguf::{GgufFile, Metadata};

/// Qwen2's pre-tokenizer split pattern (from its published tokenizer configuration): contractions,
/// letter runs with one optional leading non-letter, single digits, punctuation runs, newlines.
const QWEN2_SPLIT: &str = r"(?i:'s|'t|'re|'ve|'m|'ll|'d)|[^\r\n\p{L}\p{N}]?\p{L}+|\p{N}| ?[^\s\p{L}\p{N}]+[\r\n]*|\s*[\r\n]+|\s+(?!\S)|\s+";

/// The `tokenizer.ggml.pre` values this builder knows.
pub const SUPPORTED_PRE: &[&str] = &["smollm", "starcoder", "qwen2", "gpt-2", "default"];

/// llama.cpp token types stored in `tokenizer.ggml.token_type`.
const TYPE_CONTROL: i64 = 3;
const TYPE_USER_DEFINED: i64 = 4;

/// Tokens that end a chat turn in the ChatML family, besides the declared eos.
const CHAT_END_TOKENS: &[&str] = &["<|im_end|>", "<|endoftext|>"];

/// GPT-2's reversible byte-to-symbol map: printable Latin-1 bytes stand for themselves, the
/// others are shifted to code points from 256 upwards, so every byte is a visible character.
pub fn byte_to_unicode() -> [char; 256] {
    let mut out = ['\0'; 256];
    let mut shifted = 0u32;
    for b in 0u32..256 {
        let printable =
            (0x21..=0x7e).contains(&b) || (0xa1..=0xac).contains(&b) || (0xae..=0xff).contains(&b);
        let cp = if printable {
            b
        } else {
            shifted += 1;
            255 + shifted
        };
        // All code points here are below 0x200, valid scalar values.
        out[b as usize] = char::from_u32(cp).unwrap_or('\u{fffd}');
    }
    out
}

/// The inverse of [`byte_to_unicode`], indexed by code point (all symbols are below 0x144).
fn unicode_to_byte() -> Vec<Option<u8>> {
    let map = byte_to_unicode();
    let len = map.iter().map(|&c| c as usize).max().unwrap_or(0) + 1;
    let mut out = vec![None; len];
    for (b, c) in map.iter().enumerate() {
        out[*c as usize] = Some(b as u8);
    }
    out
}

/// A model's tokenizer with the ids the decoder needs.
#[derive(Debug, Clone)]
pub struct GgufTokenizer {
    /// Shared with the grammar compiler (llguidance tokenizes some grammar text itself): one copy of
    /// the vocabulary tables, ~31 MB for Qwen2.5's 151k tokens.
    tokenizer: Arc<Tokenizer>,
    vocab_size: usize,
    bos_id: Option<u32>,
    eos_id: u32,
    eos_ids: Vec<u32>,
    pad_id: Option<u32>,
    add_bos: bool,
    pre: String,
    special_ids: BTreeSet<u32>,
    /// Ids of added (control and user-defined) tokens, whose text is literal, not byte symbols.
    added_ids: BTreeSet<u32>,
    /// Byte-level symbol -> byte, by code point.
    sym_to_byte: Vec<Option<u8>>,
}

impl GgufTokenizer {
    /// Builds the tokenizer of a validated GGUF model.
    pub fn from_gguf(gguf: &GgufFile) -> Result<Self> {
        Self::from_metadata(gguf.metadata())
    }

    /// Builds a tokenizer from any GGUF metadata map (also vocabulary-only files).
    pub fn from_metadata(md: Metadata<'_>) -> Result<Self> {
        let path = md.path();
        let model = md.get_str("tokenizer.ggml.model")?;
        if model != "gpt2" {
            return Err(tok_err(
                path,
                format!(
                    "tokenizer.ggml.model is '{model}'; only 'gpt2' (byte-level BPE) is supported, \
                     as used by SmolLM2 and Qwen2.5"
                ),
            ));
        }
        let tokens = md.get_str_array("tokenizer.ggml.tokens")?;
        if tokens.is_empty() {
            return Err(metadata_err(path, "tokenizer.ggml.tokens", "the vocabulary is empty"));
        }
        let n = tokens.len();
        let types = match md.value("tokenizer.ggml.token_type") {
            Some(_) => md.get_i64_array("tokenizer.ggml.token_type")?,
            None => vec![1; n],
        };
        if types.len() != n {
            return Err(metadata_err(
                path,
                "tokenizer.ggml.token_type",
                &format!("{} types for {n} tokens", types.len()),
            ));
        }
        let merges = md.get_str_array("tokenizer.ggml.merges")?;
        let merges = merges
            .iter()
            .enumerate()
            .map(|(i, m)| match m.split_once(' ') {
                Some((a, b)) => Ok((a.to_string(), b.to_string())),
                None => Err(metadata_err(
                    path,
                    &format!("tokenizer.ggml.merges[{i}]"),
                    &format!("{m:?} is not two tokens separated by a space"),
                )),
            })
            .collect::<Result<Vec<_>>>()?;

        // A duplicated token string keeps its first id (the map cannot hold two); the later id
        // then decodes to nothing, which only matters for never-produced padding entries.
        let mut vocab = Vocab::default();
        for (id, t) in tokens.iter().enumerate() {
            vocab.entry(t.to_string()).or_insert(id as u32);
        }
        let bpe = BPE::builder().vocab_and_merges(vocab, merges).build().map_err(|e| {
            tok_err(path, format!("the BPE vocabulary and merges do not fit together: {e}"))
        })?;
        let mut tokenizer = Tokenizer::new(bpe);

        let pre = md.opt_str("tokenizer.ggml.pre")?.unwrap_or("default").to_string();
        match pre.as_str() {
            "smollm" | "starcoder" => {
                let seq = Sequence::new(vec![
                    PreTokenizerWrapper::Digits(Digits::new(true)),
                    PreTokenizerWrapper::ByteLevel(ByteLevel::new(false, true, true)),
                ]);
                tokenizer.with_pre_tokenizer(Some(seq));
            }
            "qwen2" => {
                let split = Split::new(
                    SplitPattern::Regex(QWEN2_SPLIT.to_string()),
                    SplitDelimiterBehavior::Isolated,
                    false,
                )
                .map_err(|e| tok_err(path, format!("Qwen2 split pattern: {e}")))?;
                let seq = Sequence::new(vec![
                    PreTokenizerWrapper::Split(split),
                    PreTokenizerWrapper::ByteLevel(ByteLevel::new(false, false, false)),
                ]);
                tokenizer.with_normalizer(Some(NFC));
                tokenizer.with_pre_tokenizer(Some(seq));
            }
            "gpt-2" | "gpt2" | "default" => {
                tokenizer.with_pre_tokenizer(Some(ByteLevel::new(false, true, true)));
            }
            other => {
                return Err(tok_err(
                    path,
                    format!(
                        "tokenizer.ggml.pre is '{other}', a pre-tokenizer this build does not know \
                         (supported: {}); use a model with one of these, or add its split rules to \
                         src/llm/tokenizer.rs",
                        SUPPORTED_PRE.join(", ")
                    ),
                ))
            }
        }
        tokenizer.with_decoder(Some(ByteLevel::default()));

        // Control tokens are special (skipped when decoding with skip_special); user-defined ones
        // (Qwen's <tool_call>) are matched whole but decode as text, as in the original tokenizers.
        let mut special_ids = BTreeSet::new();
        let mut added_ids = BTreeSet::new();
        let mut control = Vec::new();
        let mut user = Vec::new();
        for (id, (t, ty)) in tokens.iter().zip(&types).enumerate() {
            match *ty {
                TYPE_CONTROL => {
                    special_ids.insert(id as u32);
                    added_ids.insert(id as u32);
                    control.push(AddedToken::from(t.to_string(), true));
                }
                TYPE_USER_DEFINED => {
                    user.push(AddedToken::from(t.to_string(), false).normalized(false))
                }
                _ => {}
            }
        }
        tokenizer.add_special_tokens(&control);
        tokenizer.add_tokens(&user);

        let id_key = |key: &str| -> Result<Option<u32>> {
            match md.opt_u32(key)? {
                Some(id) if (id as usize) >= n => Err(metadata_err(
                    path,
                    key,
                    &format!("token id {id} is outside the vocabulary of {n} tokens"),
                )),
                other => Ok(other),
            }
        };
        let bos_id = id_key("tokenizer.ggml.bos_token_id")?;
        let eos_id = id_key("tokenizer.ggml.eos_token_id")?.ok_or_else(|| {
            metadata_err(
                path,
                "tokenizer.ggml.eos_token_id",
                "missing: the model declares no end token",
            )
        })?;
        let pad_id = id_key("tokenizer.ggml.padding_token_id")?;
        let eot_id = id_key("tokenizer.ggml.eot_token_id")?;
        let add_bos = md.opt_bool("tokenizer.ggml.add_bos_token")?.unwrap_or(false);
        if add_bos {
            let bos = bos_id.ok_or_else(|| {
                metadata_err(
                    path,
                    "tokenizer.ggml.bos_token_id",
                    "missing, but add_bos_token is true",
                )
            })?;
            let bos_str = tokens[bos as usize];
            let template = TemplateProcessing::builder()
                .try_single(format!("{bos_str} $A"))
                .and_then(|b| b.try_pair(format!("{bos_str} $A $B")))
                .map_err(|e| tok_err(path, format!("bos template: {e}")))?
                .special_tokens(vec![(bos_str.to_string(), bos)])
                .build()
                .map_err(|e| tok_err(path, format!("bos template: {e}")))?;
            tokenizer.with_post_processor(Some(template));
        }

        let mut eos: BTreeSet<u32> = [eos_id].into_iter().chain(eot_id).collect();
        for t in CHAT_END_TOKENS {
            if let Some(id) = tokenizer.token_to_id(t) {
                eos.insert(id);
            }
        }
        Ok(GgufTokenizer {
            tokenizer: Arc::new(tokenizer),
            vocab_size: n,
            bos_id,
            eos_id,
            eos_ids: eos.into_iter().collect(),
            pad_id,
            add_bos,
            pre,
            special_ids,
            added_ids,
            sym_to_byte: unicode_to_byte(),
        })
    }

    /// The underlying `tokenizers` tokenizer.
    pub fn tokenizer(&self) -> &Tokenizer {
        &self.tokenizer
    }

    /// The same, shared: what [`super::constraint::GrammarCompiler`] takes, so that it keeps no copy.
    pub fn shared_tokenizer(&self) -> &Arc<Tokenizer> {
        &self.tokenizer
    }

    pub fn into_tokenizer(self) -> Tokenizer {
        Arc::unwrap_or_clone(self.tokenizer)
    }

    /// The number of token ids (the rows of the embedding matrix), added tokens included.
    pub fn vocab_size(&self) -> usize {
        self.vocab_size
    }

    pub fn bos_id(&self) -> Option<u32> {
        self.bos_id
    }

    /// The declared end-of-sequence token (`tokenizer.ggml.eos_token_id`).
    pub fn eos_id(&self) -> u32 {
        self.eos_id
    }

    /// Every token a chat model stops on: the declared eos and eot, plus `<|im_end|>` and
    /// `<|endoftext|>` where the vocabulary has them. Sorted.
    pub fn eos_ids(&self) -> &[u32] {
        &self.eos_ids
    }

    pub fn is_eos(&self, id: u32) -> bool {
        self.eos_ids.binary_search(&id).is_ok()
    }

    pub fn pad_id(&self) -> Option<u32> {
        self.pad_id
    }

    /// Whether the model wants a BOS token in front of a prompt (`tokenizer.ggml.add_bos_token`).
    pub fn add_bos(&self) -> bool {
        self.add_bos
    }

    /// The pre-tokenizer in use (`tokenizer.ggml.pre`, or `default` when absent).
    pub fn pre(&self) -> &str {
        &self.pre
    }

    /// Whether `id` is a control token (`<|im_start|>`, `<|endoftext|>`, …).
    pub fn is_special(&self, id: u32) -> bool {
        self.special_ids.contains(&id)
    }

    /// Encodes `text`; control tokens written in it (a rendered chat prompt) become their single
    /// ids. Adds BOS in front only when the model asks for it (`add_bos_token`).
    pub fn encode(&self, text: &str) -> Result<Vec<u32>> {
        let enc = self.tokenizer.encode(text, true).map_err(|e| {
            LlmError::Tokenizer(format!("encoding {} bytes of text: {e}", text.len()))
        })?;
        Ok(enc.get_ids().to_vec())
    }

    /// Decodes ids to text; `skip_special` drops control tokens.
    pub fn decode(&self, ids: &[u32], skip_special: bool) -> Result<String> {
        if let Some(bad) = ids.iter().find(|&&id| id as usize >= self.vocab_size) {
            return Err(LlmError::Tokenizer(format!(
                "token id {bad} is outside the vocabulary of {} tokens",
                self.vocab_size
            )));
        }
        self.tokenizer
            .decode(ids, skip_special)
            .map_err(|e| LlmError::Tokenizer(format!("decoding {} tokens: {e}", ids.len())))
    }

    /// The id of token string `token` (in the vocabulary's byte-level spelling), if any.
    pub fn token_to_id(&self, token: &str) -> Option<u32> {
        self.tokenizer.token_to_id(token)
    }

    /// The raw bytes token `id` stands for: byte-level symbols mapped back to bytes, an added
    /// token's literal text. A token may hold part of a UTF-8 character, so streaming output
    /// should collect bytes and decode complete characters. `None` for an unknown id.
    pub fn token_bytes(&self, id: u32) -> Option<Vec<u8>> {
        let tok = self.tokenizer.id_to_token(id)?;
        if self.added_ids.contains(&id) {
            return Some(tok.into_bytes());
        }
        // A symbol outside the byte map (never in a well-formed byte-level vocabulary) is kept
        // as its UTF-8 text rather than dropped.
        let mut out = Vec::with_capacity(tok.len());
        for c in tok.chars() {
            match self.sym_to_byte.get(c as usize).copied().flatten() {
                Some(b) => out.push(b),
                None => out.extend_from_slice(c.encode_utf8(&mut [0; 4]).as_bytes()),
            }
        }
        Some(out)
    }

    /// The vocabulary's spelling of token `id`, if any.
    pub fn id_to_token(&self, id: u32) -> Option<String> {
        self.tokenizer.id_to_token(id)
    }
}

fn tok_err(path: &Path, msg: String) -> LlmError {
    LlmError::Tokenizer(format!("{}: {msg}", path.display()))
}

fn metadata_err(path: &Path, key: &str, detail: &str) -> LlmError {
    LlmError::Metadata {
        path: path.to_path_buf(),
        key: key.to_string(),
        detail: detail.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::llm::gguf::test_models::{real_model, real_tokenizer, QWEN, SMOLLM2};
    use crate::llm::gguf::Arch;
    use crate::llm::tiny::{tiny_gguf_bytes, TinySpec, TINY_SPECIAL_TOKENS};
    use candle_core::quantized::gguf_file::{Content, Value};
    use std::collections::HashMap;

    fn tiny_metadata(arch: Arch) -> HashMap<String, Value> {
        let bytes = tiny_gguf_bytes(&TinySpec::new(arch)).unwrap();
        Content::read(&mut std::io::Cursor::new(bytes)).unwrap().metadata
    }

    fn build(map: &HashMap<String, Value>) -> Result<GgufTokenizer> {
        GgufTokenizer::from_metadata(Metadata::new(Path::new("tiny.gguf"), map))
    }

    /// Texts of the kind the planner sends, plus the hard cases of byte-level BPE.
    const TEXTS: &[&str] = &[
        "[WALK] <kitchen> (11)\n[OPEN] <fridge> (1001)\n[GRAB] <apple> (1002)\n",
        "Task: put the apple in the fridge.\nPlan:\n",
        "  leading spaces,\ttabs\tand trailing  \n\n\n",
        "digits 1234567890 and 3.14159 and -42",
        "Ünïcödé: naïve café, Straße, Ελληνικά, русский, 中文字符, 日本語のテキスト",
        "emoji 🤖🍎 and symbols ∑ ≤ → ©",
        "code: fn main() { println!(\"{}\", x?); } // done",
        "it's we're they've I'm you'll he'd",
        "",
    ];

    #[test]
    fn tiny_tokenizers_round_trip_and_use_merges() {
        for arch in [Arch::Llama, Arch::Qwen2] {
            let tok = build(&tiny_metadata(arch)).unwrap();
            assert_eq!(tok.vocab_size(), TinySpec::new(arch).vocab_size());
            for text in TEXTS {
                let ids = tok.encode(text).unwrap();
                assert_eq!(tok.decode(&ids, false).unwrap(), *text, "{arch}");
            }
            let walk = tok.token_to_id("WALK").unwrap();
            let ids = tok.encode("WALK").unwrap();
            assert_eq!(ids, vec![walk], "{arch}: merges should make WALK one token");
            let apple = tok.token_to_id("apple").unwrap();
            assert!(tok.encode("[GRAB] <apple> (1)").unwrap().contains(&apple));
        }
    }

    #[test]
    fn byte_map_is_a_bijection_onto_visible_chars() {
        let m = byte_to_unicode();
        let set: std::collections::BTreeSet<char> = m.iter().copied().collect();
        assert_eq!(set.len(), 256);
        assert!(m.iter().all(|c| !c.is_whitespace() && !c.is_control()));
        assert_eq!(m[b' ' as usize], 'Ġ');
        assert_eq!(m[b'\n' as usize], 'Ċ');
        assert_eq!(m[b'A' as usize], 'A');
    }

    #[test]
    fn token_bytes_reassemble_the_text() {
        for arch in [Arch::Llama, Arch::Qwen2] {
            let tok = build(&tiny_metadata(arch)).unwrap();
            for text in TEXTS.iter().chain(&["<|im_start|>user\n🤖<|im_end|>"]) {
                let ids = tok.encode(text).unwrap();
                let bytes: Vec<u8> =
                    ids.iter().flat_map(|&id| tok.token_bytes(id).unwrap()).collect();
                assert_eq!(bytes, text.as_bytes(), "{arch}: {text:?}");
            }
            assert_eq!(tok.token_bytes(tok.token_to_id("Ġ<").unwrap()).unwrap(), b" <");
            assert_eq!(tok.token_bytes(1_000_000), None);
        }
        for file in [SMOLLM2, QWEN] {
            let Some(tok) = real(file) else { continue };
            let text = TEXTS.concat();
            let ids = tok.encode(&text).unwrap();
            let bytes: Vec<u8> = ids.iter().flat_map(|&id| tok.token_bytes(id).unwrap()).collect();
            assert_eq!(String::from_utf8(bytes).unwrap(), text, "{file}");
        }
    }

    #[test]
    fn tiny_special_tokens_are_single_ids() {
        for arch in [Arch::Llama, Arch::Qwen2] {
            let map = tiny_metadata(arch);
            let tok = build(&map).unwrap();
            let ids: Vec<u32> =
                TINY_SPECIAL_TOKENS.iter().map(|t| tok.token_to_id(t).unwrap()).collect();
            let text = "<|im_start|>user\nWALK<|im_end|>\n<|endoftext|>";
            let enc = tok.encode(text).unwrap();
            assert_eq!(enc[0], ids[1], "{arch}");
            assert!(enc.contains(&ids[2]) && *enc.last().unwrap() == ids[0], "{arch}: {enc:?}");
            assert_eq!(tok.decode(&enc, false).unwrap(), text);
            assert_eq!(tok.decode(&enc, true).unwrap(), "user\nWALK\n");
            assert!(tok.is_special(ids[1]) && !tok.is_special(tok.token_to_id("WALK").unwrap()));
            // eos set: declared eos (<|im_end|>) plus <|endoftext|>.
            let mut want = vec![ids[0], ids[2]];
            want.sort();
            assert_eq!(tok.eos_ids(), want.as_slice(), "{arch}");
            assert_eq!(tok.eos_id(), ids[2]);
            assert!(tok.is_eos(ids[0]) && !tok.is_eos(ids[1]));
            assert!(!tok.add_bos());
        }
    }

    #[test]
    fn unsupported_tokenizers_are_clear_errors() {
        let mut map = tiny_metadata(Arch::Llama);
        map.insert("tokenizer.ggml.pre".into(), Value::String("deepseek-llm".into()));
        let msg = build(&map).unwrap_err().to_string();
        assert!(msg.contains("deepseek-llm") && msg.contains("supported: smollm"), "{msg}");

        let mut map = tiny_metadata(Arch::Llama);
        map.insert("tokenizer.ggml.model".into(), Value::String("llama".into()));
        let msg = build(&map).unwrap_err().to_string();
        assert!(msg.contains("'llama'") && msg.contains("only 'gpt2'"), "{msg}");

        let mut map = tiny_metadata(Arch::Qwen2);
        map.insert("tokenizer.ggml.eos_token_id".into(), Value::U32(99_999));
        let err = build(&map).unwrap_err();
        assert!(
            err.to_string().contains("tokenizer.ggml.eos_token_id")
                && err.to_string().contains("99999"),
            "{err}"
        );

        let mut map = tiny_metadata(Arch::Qwen2);
        map.insert(
            "tokenizer.ggml.merges".into(),
            Value::Array(vec![Value::String("nospace".into())]),
        );
        let msg = build(&map).unwrap_err().to_string();
        assert!(msg.contains("tokenizer.ggml.merges[0]"), "{msg}");

        let mut map = tiny_metadata(Arch::Qwen2);
        map.remove("tokenizer.ggml.tokens");
        let msg = build(&map).unwrap_err().to_string();
        assert!(msg.contains("tokenizer.ggml.tokens") && msg.contains("missing"), "{msg}");

        let tok = build(&tiny_metadata(Arch::Qwen2)).unwrap();
        assert!(tok.decode(&[1_000_000], false).is_err());
    }

    /// The pre-tokenizer's pieces of `text`, in byte-level spelling.
    fn pieces(tok: &GgufTokenizer, text: &str) -> Vec<String> {
        use tokenizers::{OffsetReferential, OffsetType, PreTokenizedString, PreTokenizer};
        let mut pts = PreTokenizedString::from(text);
        tok.tokenizer().get_pre_tokenizer().unwrap().pre_tokenize(&mut pts).unwrap();
        pts.get_splits(OffsetReferential::Original, OffsetType::Byte)
            .into_iter()
            .map(|(s, _, _)| s.to_string())
            .collect()
    }

    #[test]
    fn missing_pre_falls_back_to_gpt2_and_qwen2_normalises_to_nfc() {
        let mut map = tiny_metadata(Arch::Llama);
        map.remove("tokenizer.ggml.pre");
        let tok = build(&map).unwrap();
        assert_eq!(tok.pre(), "default");
        // GPT-2's regex keeps a digit run together; smollm splits each digit; qwen2 too.
        let smol = build(&tiny_metadata(Arch::Llama)).unwrap();
        assert_eq!(pieces(&tok, "x 123"), ["x", "Ġ123"]);
        assert_eq!(pieces(&smol, "x 123"), ["x", "Ġ", "1", "2", "3"]);
        assert_eq!(tok.decode(&tok.encode(TEXTS[4]).unwrap(), false).unwrap(), TEXTS[4]);
        // Qwen2 normalises to NFC first: a decomposed "é" encodes as the composed one.
        let qwen = build(&tiny_metadata(Arch::Qwen2)).unwrap();
        assert_eq!(pieces(&qwen, "x 123 <apple>"), ["x", "Ġ", "1", "2", "3", "Ġ<", "apple", ">"]);
        assert_eq!(qwen.encode("cafe\u{301}").unwrap(), qwen.encode("caf\u{e9}").unwrap());
        assert_ne!(smol.encode("cafe\u{301}").unwrap(), smol.encode("caf\u{e9}").unwrap());
    }

    #[test]
    fn add_bos_token_prepends_bos() {
        let mut map = tiny_metadata(Arch::Llama);
        map.insert("tokenizer.ggml.add_bos_token".into(), Value::Bool(true));
        let tok = build(&map).unwrap();
        let ids = tok.encode("WALK").unwrap();
        assert_eq!(ids, vec![1, tok.token_to_id("WALK").unwrap()]);
    }

    fn real(file: &'static str) -> Option<&'static GgufTokenizer> {
        real_tokenizer(file)
    }

    /// Reference ids for Qwen2's vocabulary (shared by Qwen2.5), taken from llama.cpp's test
    /// vectors `models/ggml-vocab-qwen2.gguf.{inp,out}`, whose ids were produced by Hugging Face
    /// `tokenizers` from Qwen2's tokenizer.json — an implementation independent of this one.
    #[test]
    fn qwen_ids_match_reference() {
        let Some(tok) = real(QWEN) else { return };
        let cases: &[(&str, &[u32])] = &[
            ("ied 4 ½ months", &[1122, 220, 19, 220, 26062, 3951]),
            ("Äpfel", &[86975, 15897, 301]),
            ("\t\n", &[1572]),
            (" Hello World", &[21927, 4337]),
            (" Hello, world!", &[21927, 11, 1879, 0]),
            (" this is 🦙.cpp", &[419, 374, 11162, 99, 247, 13, 10821]),
            ("    Hello\n    Hello", &[262, 21927, 198, 262, 21927]),
            ("\n =", &[198, 284]),
            ("33333", &[18, 18, 18, 18, 18]),
        ];
        for (text, want) in cases {
            assert_eq!(tok.encode(text).unwrap(), *want, "{text:?}");
        }
    }

    /// Reference ids for SmolLM2, produced by llama.cpp's own tokenizer (`llama_tokenize`, from the
    /// llama.cpp vendored in the llama-cpp-python 0.3.36 sdist, parse_special on, no BOS) on the
    /// installed SmolLM2-135M-Instruct.Q4_1.gguf: an implementation independent of this one. The
    /// same tool agreed with this tokenizer on all 58 texts of the one-off check (see
    /// `vocab_test_vectors`), and on the Qwen2.5 file too.
    #[test]
    fn smollm2_ids_match_reference() {
        let Some(tok) = real(SMOLLM2) else { return };
        let cases: &[(&str, &[u32])] = &[
            (
                "Task: put the apple in the fridge.\nPlan:\n",
                &[22188, 42, 1830, 260, 11977, 281, 260, 28867, 30, 198, 23296, 42, 198],
            ),
            (
                "[PUTBACK] <soap> (1002) <sink> (1001)",
                &[75, 21348, 32910, 77, 2067, 559, 512, 46, 365, 33, 32, 32, 34, 25, 2067, 99, 900, 46, 365, 33, 32, 32, 33, 25],
            ),
            (
                "digits 1234567890 and 3.14159 and -42",
                &[37307, 216, 33, 34, 35, 36, 37, 38, 39, 40, 41, 32, 284, 216, 35, 30, 33, 36, 33, 37, 41, 284, 731, 36, 34],
            ),
            (
                "emoji 🤖🍎 and symbols ∑ ≤ → ©",
                &[391, 33777, 15107, 114, 240, 10813, 231, 232, 284, 7349, 19995, 235, 38599, 17822, 11435],
            ),
            (
                "<|im_start|>system\nYou are a robot task planner.<|im_end|>\n<|im_start|>assistant\n",
                &[1, 9690, 198, 2683, 359, 253, 8085, 3856, 34830, 30, 2, 198, 1, 520, 9531, 198],
            ),
            ("Hello world", &[19556, 905]),
            (" Hello world", &[38699, 905]),
            ("Äpfel", &[142, 222, 96, 34520]),
            ("\n\n", &[1116]),
            (" this is 🦙.cpp", &[451, 314, 15107, 116, 243, 30, 35392]),
        ];
        for (text, want) in cases {
            assert_eq!(tok.encode(text).unwrap(), *want, "{text:?}");
        }
    }

    #[test]
    fn real_tokenizers_round_trip() {
        for file in [SMOLLM2, QWEN] {
            let Some(tok) = real(file) else { continue };
            for text in TEXTS {
                let ids = tok.encode(text).unwrap();
                assert_eq!(tok.decode(&ids, false).unwrap(), *text, "{file}");
            }
            // Real vocabularies compress ordinary English well below one token per 3 bytes.
            let text = "Task: put the apple in the fridge and close the door of the kitchen.";
            let n = tok.encode(text).unwrap().len();
            assert!(n * 3 < text.len(), "{file}: {n} tokens for {} bytes", text.len());
        }
    }

    #[test]
    fn real_chat_tokens_are_single_ids() {
        for (file, start, end, eos) in
            [(SMOLLM2, 1, 2, vec![0, 2]), (QWEN, 151644, 151645, vec![151643, 151645])]
        {
            let Some(tok) = real(file) else { continue };
            let ids = tok.encode("<|im_start|>user\nhello<|im_end|>\n").unwrap();
            assert_eq!(ids.first(), Some(&start), "{file}: {ids:?}");
            assert!(ids.contains(&end), "{file}: {ids:?}");
            assert_eq!(tok.eos_ids(), eos.as_slice(), "{file}");
            assert!(!tok.add_bos());
        }
    }

    /// One-off check against reference ids: for every `X.gguf` in `$STEP_VOCAB_TESTS_DIR` that has
    /// `X.gguf.inp` (texts separated by `\n__ggml_vocab_test__\n`) and `X.gguf.out` (one line of
    /// ids per text), the ids this tokenizer gives must equal the file's. llama.cpp's
    /// `models/ggml-vocab-*.gguf` test vectors have this layout (their ids come from Hugging Face
    /// `tokenizers`); so do files made with llama.cpp's own tokenizer. Not run by default: those
    /// files are not ours to ship. Run with
    /// `STEP_VOCAB_TESTS_DIR=<dir> cargo test --lib vocab_test_vectors -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn vocab_test_vectors() {
        let Ok(dir) = std::env::var("STEP_VOCAB_TESTS_DIR") else {
            panic!("set STEP_VOCAB_TESTS_DIR to a folder of X.gguf, X.gguf.inp, X.gguf.out");
        };
        let mut ggufs: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "gguf"))
            .filter(|p| p.with_extension("gguf.out").exists())
            .collect();
        ggufs.sort();
        assert!(!ggufs.is_empty(), "no X.gguf with X.gguf.out in {dir}");
        let mut failures = Vec::new();
        for gguf in ggufs {
            let inp = std::fs::read_to_string(gguf.with_extension("gguf.inp")).unwrap();
            let out = std::fs::read_to_string(gguf.with_extension("gguf.out")).unwrap();
            let mut f = std::io::BufReader::new(std::fs::File::open(&gguf).unwrap());
            let content = Content::read(&mut f).unwrap();
            let tok =
                GgufTokenizer::from_metadata(Metadata::new(&gguf, &content.metadata)).unwrap();
            let texts: Vec<&str> = inp.split("\n__ggml_vocab_test__\n").collect();
            let outs: Vec<&str> = out.lines().collect();
            let mut ok = 0;
            for (text, want) in texts.iter().zip(&outs) {
                let want: Vec<u32> = want.split_whitespace().map(|x| x.parse().unwrap()).collect();
                let got = tok.encode(text).unwrap();
                if got == want {
                    ok += 1;
                } else {
                    failures
                        .push(format!("{}: {text:?}: want {want:?} got {got:?}", gguf.display()));
                }
            }
            let name = gguf.file_name().unwrap().to_string_lossy();
            eprintln!("{name} (pre={}): {ok}/{} reference encodings match", tok.pre(), outs.len());
        }
        assert!(failures.is_empty(), "{}", failures.join("\n"));
    }

    /// Prints how long opening each real model's GGUF header and building its tokenizer take.
    /// A measurement, not a check: `cargo test --release --lib tokenizer_build_time -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn tokenizer_build_time() {
        for file in [SMOLLM2, QWEN] {
            let Some(p) = real_model(file) else { continue };
            let t0 = std::time::Instant::now();
            let g = GgufFile::open(&p).unwrap();
            let t1 = std::time::Instant::now();
            let tok = GgufTokenizer::from_gguf(&g).unwrap();
            let t2 = std::time::Instant::now();
            let text = TEXTS.concat().repeat(20);
            let ids = tok.encode(&text).unwrap();
            let t3 = std::time::Instant::now();
            eprintln!(
                "{file}: open+validate {:.0} ms, tokenizer build {:.0} ms (vocab {}), encode {} bytes -> {} ids in {:.2} ms",
                (t1 - t0).as_secs_f64() * 1e3,
                (t2 - t1).as_secs_f64() * 1e3,
                tok.vocab_size(),
                text.len(),
                ids.len(),
                (t3 - t2).as_secs_f64() * 1e3
            );
        }
    }
}
