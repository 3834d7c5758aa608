//! Tiny random-weight GGUF models of each supported architecture, written with candle's own GGUF
//! writer, for tests and benches: a real (small) byte-level BPE tokenizer with ChatML control
//! tokens and a ChatML chat template in the metadata, quantised matrices (Q8_0 / Q4_1) so the
//! quantised kernels run, and llama.cpp's tensor names and metadata keys, so the same loader reads
//! them as the real models. Loading one and running a forward pass takes milliseconds; the same
//! spec and seed always give the same bytes.

use std::io::{Seek, Write};
use std::path::Path;

use candle_core::quantized::gguf_file::{self, Value};
use candle_core::quantized::{GgmlDType, QTensor};
use candle_core::{Device, Tensor};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::error::{LlmError, Result};
use super::gguf::Arch;
use super::tokenizer::byte_to_unicode;

/// The shape and initialisation of a tiny model. Build one with [`TinySpec::llama`],
/// [`TinySpec::qwen2`] or [`TinySpec::new`], then adjust fields.
#[derive(Debug, Clone, PartialEq)]
pub struct TinySpec {
    pub arch: Arch,
    pub n_layer: usize,
    /// Hidden size; a multiple of 32 (the quant block size) and of `n_head`.
    pub n_embd: usize,
    pub n_head: usize,
    /// Key/value heads (grouped-query attention); divides `n_head`.
    pub n_head_kv: usize,
    /// Feed-forward width; a multiple of 32.
    pub n_ff: usize,
    pub context_length: usize,
    pub rope_freq_base: f32,
    pub rms_norm_eps: f32,
    pub seed: u64,
    /// Standard deviation of the token embeddings. With tied embeddings the logits are
    /// `h · E` with `h` of unit RMS, so their spread is about `embd_std * sqrt(n_embd)`: the
    /// default 0.3 at width 64 gives logits with a standard deviation near 2.4, a peaked but
    /// non-degenerate distribution.
    pub embd_std: f32,
    /// Matrices other than the embeddings are N(0, (gain / sqrt(fan_in))^2).
    pub weight_gain: f32,
    /// Quantisation of the token embeddings and the output matrix.
    pub embd_dtype: GgmlDType,
    /// Quantisation of the attention matrices.
    pub attn_dtype: GgmlDType,
    /// Quantisation of the feed-forward matrices.
    pub ffn_dtype: GgmlDType,
}

impl TinySpec {
    /// A SmolLM2-like llama model: tied embeddings (no `output.weight`), 4 heads of 16, 2 kv heads.
    pub fn llama() -> Self {
        Self::new(Arch::Llama)
    }

    /// A Qwen2.5-like model: q/k/v biases and a separate `output.weight`.
    pub fn qwen2() -> Self {
        Self::new(Arch::Qwen2)
    }

    /// The default tiny spec for `arch`: 2 layers, width 64, 4 heads of 16 (2 kv heads), ffn 128.
    pub fn new(arch: Arch) -> Self {
        TinySpec {
            arch,
            n_layer: 2,
            n_embd: 64,
            n_head: 4,
            n_head_kv: 2,
            n_ff: 128,
            context_length: 512,
            rope_freq_base: 10_000.0,
            rms_norm_eps: 1e-5,
            seed: 0,
            embd_std: 0.3,
            weight_gain: 1.0,
            embd_dtype: GgmlDType::Q8_0,
            attn_dtype: GgmlDType::Q8_0,
            ffn_dtype: GgmlDType::Q4_1,
        }
    }

    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    pub fn head_dim(&self) -> usize {
        self.n_embd / self.n_head.max(1)
    }

    /// The number of tokens in the tiny vocabulary of this architecture.
    pub fn vocab_size(&self) -> usize {
        tiny_vocab(self.arch).tokens.len()
    }

    fn validate(&self) -> Result<()> {
        let bad = |msg: String| Err(LlmError::TinySpec(msg));
        let block = |d: GgmlDType| d.block_size();
        let max_block = [self.embd_dtype, self.attn_dtype, self.ffn_dtype]
            .into_iter()
            .map(block)
            .max()
            .unwrap_or(1);
        if self.n_layer == 0 || self.n_head == 0 || self.n_head_kv == 0 {
            return bad("n_layer, n_head and n_head_kv must be at least 1".into());
        }
        if !self.n_embd.is_multiple_of(self.n_head) {
            return bad(format!(
                "n_embd {} is not a multiple of n_head {}",
                self.n_embd, self.n_head
            ));
        }
        if !self.n_head.is_multiple_of(self.n_head_kv) {
            return bad(format!(
                "n_head {} is not a multiple of n_head_kv {}",
                self.n_head, self.n_head_kv
            ));
        }
        if !self.head_dim().is_multiple_of(2) {
            return bad(format!("head dim {} must be even for rope", self.head_dim()));
        }
        if !self.n_embd.is_multiple_of(max_block) || !self.n_ff.is_multiple_of(max_block) {
            return bad(format!(
                "n_embd {} and n_ff {} must be multiples of the quant block size {max_block}",
                self.n_embd, self.n_ff
            ));
        }
        Ok(())
    }
}

/// The tokenizer stored in a tiny model: GPT-2 byte-level symbols, a few dozen merges for words
/// of the action grammars, and the ChatML control tokens.
#[derive(Debug, Clone, PartialEq)]
pub struct TinyVocab {
    pub tokens: Vec<String>,
    /// llama.cpp token types: 1 normal, 3 control.
    pub token_type: Vec<i32>,
    /// BPE merges, highest priority first, as "left right" in byte-level symbols.
    pub merges: Vec<String>,
    pub bos_id: u32,
    pub eos_id: u32,
    pub pad_id: u32,
    /// `tokenizer.ggml.pre` of the tiny model (the real model's pre-tokenizer of the same arch).
    pub pre: &'static str,
}

/// The ChatML control tokens of the tiny models, in the order they are stored.
pub const TINY_SPECIAL_TOKENS: [&str; 3] = ["<|endoftext|>", "<|im_start|>", "<|im_end|>"];

/// A ChatML template in the style of SmolLM2's: a default system turn when the conversation has
/// none, then one `<|im_start|>role\ncontent<|im_end|>\n` block per message.
pub const TINY_CHAT_TEMPLATE: &str = "{%- for message in messages %}\
{%- if loop.first and message['role'] != 'system' %}\
{{- '<|im_start|>system\\nYou are a robot task planner.<|im_end|>\\n' }}\
{%- endif %}\
{{- '<|im_start|>' + message['role'] + '\\n' + message['content'] + '<|im_end|>\\n' }}\
{%- endfor %}\
{%- if add_generation_prompt %}{{- '<|im_start|>assistant\\n' }}{%- endif %}";

/// Text pieces that get their own multi-byte tokens (each built by merging left to right).
const MERGE_WORDS: &[&str] = &[
    "WALK",
    "RUN",
    "GRAB",
    "FIND",
    "OPEN",
    "CLOSE",
    "PUT",
    "PUTBACK",
    "PUTIN",
    "SWITCHON",
    "SWITCHOFF",
    "LOOKAT",
    "TURNTO",
    "DRINK",
    "WASH",
    "SIT",
    "STANDUP",
    "TOUCH",
    "POUR",
    "WIPE",
    "apple",
    "fridge",
    "kitchen",
    "table",
    "cup",
    "sink",
    "soap",
    "light",
    "door",
    "bedroom",
    "bathroom",
    "plate",
    "water",
    "towel",
    "chair",
    " <",
    "> (",
    " (",
    ")\n",
    "\n\n",
    "\n\n\n",
    "  ",
    "    ",
    " the",
    " to",
    " and",
    "system",
    "user",
    "assistant",
    "Task",
    "Plan",
];

/// The tiny vocabulary of `arch`. The llama vocabulary puts the control tokens first (as SmolLM2:
/// `<|endoftext|>` 0, `<|im_start|>` 1 = bos, `<|im_end|>` 2 = eos); the qwen2 one puts them last
/// (as Qwen2.5: bos = pad = `<|endoftext|>`, eos = `<|im_end|>`), so both layouts are exercised.
pub fn tiny_vocab(arch: Arch) -> TinyVocab {
    let b2u = byte_to_unicode();
    let mut tokens: Vec<String> = Vec::new();
    let mut token_type: Vec<i32> = Vec::new();
    let specials_first = arch == Arch::Llama;
    if specials_first {
        for s in TINY_SPECIAL_TOKENS {
            tokens.push(s.to_string());
            token_type.push(3);
        }
    }
    for c in b2u {
        tokens.push(c.to_string());
        token_type.push(1);
    }
    let mut merges = Vec::new();
    let mut known: std::collections::BTreeSet<String> = tokens.iter().cloned().collect();
    for word in MERGE_WORDS {
        let symbols: Vec<String> = word.bytes().map(|b| b2u[b as usize].to_string()).collect();
        let mut cur = match symbols.first() {
            Some(s) => s.clone(),
            None => continue,
        };
        for next in &symbols[1..] {
            let joined = format!("{cur}{next}");
            if known.insert(joined.clone()) {
                merges.push(format!("{cur} {next}"));
                tokens.push(joined.clone());
                token_type.push(1);
            }
            cur = joined;
        }
    }
    let first_special = tokens.len() as u32;
    if !specials_first {
        for s in TINY_SPECIAL_TOKENS {
            tokens.push(s.to_string());
            token_type.push(3);
        }
    }
    let (bos_id, eos_id, pad_id, pre) = if specials_first {
        (1, 2, 2, "smollm")
    } else {
        (first_special, first_special + 2, first_special, "qwen2")
    };
    TinyVocab { tokens, token_type, merges, bos_id, eos_id, pad_id, pre }
}

/// Standard normal samples by Box-Muller (no extra dependency for a distribution crate).
fn randn(rng: &mut StdRng, n: usize, std: f32) -> Vec<f32> {
    let mut out = Vec::with_capacity(n + 1);
    while out.len() < n {
        let u1: f32 = rng.random::<f32>().max(f32::MIN_POSITIVE);
        let u2: f32 = rng.random::<f32>();
        let r = (-2.0 * u1.ln()).sqrt() * std;
        let t = std::f32::consts::TAU * u2;
        out.push(r * t.cos());
        out.push(r * t.sin());
    }
    out.truncate(n);
    out
}

fn qtensor(data: Vec<f32>, shape: &[usize], dtype: GgmlDType) -> Result<QTensor> {
    let t = Tensor::from_vec(data, shape, &Device::Cpu)?;
    Ok(QTensor::quantize(&t, dtype)?)
}

/// Metadata entries and named tensors, in file order.
type TinyParts = (Vec<(String, Value)>, Vec<(String, QTensor)>);

/// All metadata and tensors of the tiny model, in file order.
fn build(spec: &TinySpec) -> Result<TinyParts> {
    spec.validate()?;
    let vocab = tiny_vocab(spec.arch);
    let n_vocab = vocab.tokens.len();
    let arch = spec.arch.gguf_name();
    let u32v = |x: usize| Value::U32(x as u32);
    let mut md: Vec<(String, Value)> = vec![
        ("general.architecture".into(), Value::String(arch.into())),
        ("general.name".into(), Value::String(format!("step-tiny-{arch}"))),
        (format!("{arch}.block_count"), u32v(spec.n_layer)),
        (format!("{arch}.context_length"), u32v(spec.context_length)),
        (format!("{arch}.embedding_length"), u32v(spec.n_embd)),
        (format!("{arch}.feed_forward_length"), u32v(spec.n_ff)),
        (format!("{arch}.attention.head_count"), u32v(spec.n_head)),
        (format!("{arch}.attention.head_count_kv"), u32v(spec.n_head_kv)),
        (format!("{arch}.rope.freq_base"), Value::F32(spec.rope_freq_base)),
        (format!("{arch}.attention.layer_norm_rms_epsilon"), Value::F32(spec.rms_norm_eps)),
        (format!("{arch}.rope.dimension_count"), u32v(spec.head_dim())),
        (format!("{arch}.vocab_size"), u32v(n_vocab)),
        ("tokenizer.ggml.model".into(), Value::String("gpt2".into())),
        ("tokenizer.ggml.pre".into(), Value::String(vocab.pre.into())),
        (
            "tokenizer.ggml.tokens".into(),
            Value::Array(vocab.tokens.iter().map(|t| Value::String(t.clone())).collect()),
        ),
        (
            "tokenizer.ggml.token_type".into(),
            Value::Array(vocab.token_type.iter().map(|&t| Value::I32(t)).collect()),
        ),
        (
            "tokenizer.ggml.merges".into(),
            Value::Array(vocab.merges.iter().map(|m| Value::String(m.clone())).collect()),
        ),
        ("tokenizer.ggml.bos_token_id".into(), Value::U32(vocab.bos_id)),
        ("tokenizer.ggml.eos_token_id".into(), Value::U32(vocab.eos_id)),
        ("tokenizer.ggml.padding_token_id".into(), Value::U32(vocab.pad_id)),
        ("tokenizer.ggml.add_bos_token".into(), Value::Bool(false)),
        ("tokenizer.chat_template".into(), Value::String(TINY_CHAT_TEMPLATE.into())),
    ];
    if spec.arch == Arch::Llama {
        md.push(("tokenizer.ggml.unknown_token_id".into(), Value::U32(0)));
    }

    let mut rng = StdRng::seed_from_u64(spec.seed);
    let (d, ff) = (spec.n_embd, spec.n_ff);
    let kv = spec.n_head_kv * spec.head_dim();
    let gain = spec.weight_gain;
    let mut tensors: Vec<(String, QTensor)> = Vec::new();
    // A matrix stored as llama.cpp does: candle shape (out, in), GGUF dims reversed by the writer.
    let matrix = |rng: &mut StdRng, out: usize, inp: usize, dtype: GgmlDType| {
        let std = gain / (inp as f32).sqrt();
        qtensor(randn(rng, out * inp, std), &[out, inp], dtype)
    };
    let norm = |rng: &mut StdRng, n: usize| -> Result<QTensor> {
        let v = randn(rng, n, 0.05).into_iter().map(|x| 1.0 + x).collect();
        qtensor(v, &[n], GgmlDType::F32)
    };
    let bias = |rng: &mut StdRng, n: usize| qtensor(randn(rng, n, 0.1), &[n], GgmlDType::F32);

    let embd =
        qtensor(randn(&mut rng, n_vocab * d, spec.embd_std), &[n_vocab, d], spec.embd_dtype)?;
    tensors.push(("token_embd.weight".into(), embd));
    for i in 0..spec.n_layer {
        let p = format!("blk.{i}");
        tensors.push((format!("{p}.attn_norm.weight"), norm(&mut rng, d)?));
        tensors.push((format!("{p}.attn_q.weight"), matrix(&mut rng, d, d, spec.attn_dtype)?));
        tensors.push((format!("{p}.attn_k.weight"), matrix(&mut rng, kv, d, spec.attn_dtype)?));
        tensors.push((format!("{p}.attn_v.weight"), matrix(&mut rng, kv, d, spec.attn_dtype)?));
        if spec.arch == Arch::Qwen2 {
            tensors.push((format!("{p}.attn_q.bias"), bias(&mut rng, d)?));
            tensors.push((format!("{p}.attn_k.bias"), bias(&mut rng, kv)?));
            tensors.push((format!("{p}.attn_v.bias"), bias(&mut rng, kv)?));
        }
        tensors.push((format!("{p}.attn_output.weight"), matrix(&mut rng, d, d, spec.attn_dtype)?));
        tensors.push((format!("{p}.ffn_norm.weight"), norm(&mut rng, d)?));
        tensors.push((format!("{p}.ffn_gate.weight"), matrix(&mut rng, ff, d, spec.ffn_dtype)?));
        tensors.push((format!("{p}.ffn_up.weight"), matrix(&mut rng, ff, d, spec.ffn_dtype)?));
        tensors.push((format!("{p}.ffn_down.weight"), matrix(&mut rng, d, ff, spec.ffn_dtype)?));
    }
    tensors.push(("output_norm.weight".into(), norm(&mut rng, d)?));
    if spec.arch == Arch::Qwen2 {
        let out =
            qtensor(randn(&mut rng, n_vocab * d, spec.embd_std), &[n_vocab, d], spec.embd_dtype)?;
        tensors.push(("output.weight".into(), out));
    }
    Ok((md, tensors))
}

/// Writes the tiny model of `spec` as GGUF to any seekable writer.
pub fn write_tiny_gguf_to<W: Write + Seek>(spec: &TinySpec, w: &mut W) -> Result<()> {
    let (md, tensors) = build(spec)?;
    let md_refs: Vec<(&str, &Value)> = md.iter().map(|(k, v)| (k.as_str(), v)).collect();
    let t_refs: Vec<(&str, &QTensor)> = tensors.iter().map(|(k, t)| (k.as_str(), t)).collect();
    gguf_file::write(w, &md_refs, &t_refs)?;
    Ok(())
}

/// The tiny model of `spec` as GGUF bytes (for in-memory loading).
pub fn tiny_gguf_bytes(spec: &TinySpec) -> Result<Vec<u8>> {
    let mut cur = std::io::Cursor::new(Vec::new());
    write_tiny_gguf_to(spec, &mut cur)?;
    Ok(cur.into_inner())
}

/// Writes the tiny model of `spec` to `path` (created or replaced).
pub fn write_tiny_gguf(spec: &TinySpec, path: &Path) -> Result<()> {
    let io_err = |error| LlmError::Io { path: path.to_path_buf(), error };
    let bytes = tiny_gguf_bytes(spec)?;
    let mut f = std::fs::File::create(path).map_err(io_err)?;
    f.write_all(&bytes).map_err(io_err)?;
    f.sync_all().map_err(io_err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::quantized::gguf_file::Content;

    fn read(spec: &TinySpec) -> (Content, std::io::Cursor<Vec<u8>>) {
        let bytes = tiny_gguf_bytes(spec).expect("write tiny");
        let mut cur = std::io::Cursor::new(bytes);
        let content = Content::read(&mut cur).expect("read back");
        (content, cur)
    }

    #[test]
    fn vocab_has_merged_words_and_specials() {
        for arch in [Arch::Llama, Arch::Qwen2] {
            let v = tiny_vocab(arch);
            assert_eq!(v.tokens.len(), v.token_type.len());
            for w in ["WALK", "GRAB", "Ġ<", ">Ġ(", "apple", "fridge", "ĊĊ"] {
                assert!(v.tokens.iter().any(|t| t == w), "{arch}: missing token {w}");
            }
            assert!(v.merges.len() >= 40, "{arch}: only {} merges", v.merges.len());
            // Every merge joins two existing tokens into a token that exists.
            for m in &v.merges {
                let (a, b) = m.split_once(' ').expect("merge has a space");
                assert!(v.tokens.iter().any(|t| t == a) && v.tokens.iter().any(|t| t == b));
                assert!(v.tokens.iter().any(|t| *t == format!("{a}{b}")));
            }
            assert_eq!(v.tokens[v.eos_id as usize], "<|im_end|>");
            let n_control = v.token_type.iter().filter(|&&t| t == 3).count();
            assert_eq!(n_control, 3);
        }
    }

    #[test]
    fn tiny_models_read_back_with_llama_cpp_names() {
        for spec in [TinySpec::llama(), TinySpec::qwen2()] {
            let (c, mut cur) = read(&spec);
            let arch = c.metadata["general.architecture"].to_string().expect("arch");
            assert_eq!(arch, spec.arch.gguf_name());
            let n_layer = c.metadata[&format!("{arch}.block_count")].to_u32().expect("u32");
            assert_eq!(n_layer as usize, spec.n_layer);
            assert!(c.metadata.contains_key("tokenizer.chat_template"));
            let emb = &c.tensor_infos["token_embd.weight"];
            assert_eq!(emb.shape.dims(), &[spec.vocab_size(), spec.n_embd]);
            assert_eq!(emb.ggml_dtype, GgmlDType::Q8_0);
            assert_eq!(c.tensor_infos["blk.1.ffn_down.weight"].ggml_dtype, GgmlDType::Q4_1);
            assert_eq!(c.tensor_infos["blk.0.attn_k.weight"].shape.dims(), &[32, 64]);
            assert_eq!(c.tensor_infos["output_norm.weight"].ggml_dtype, GgmlDType::F32);
            let has_output = c.tensor_infos.contains_key("output.weight");
            let has_bias = c.tensor_infos.contains_key("blk.0.attn_q.bias");
            assert_eq!(has_output, spec.arch == Arch::Qwen2);
            assert_eq!(has_bias, spec.arch == Arch::Qwen2);
            // Tensor data is readable and dequantises to finite, non-constant values.
            let q = c.tensor(&mut cur, "blk.0.ffn_up.weight", &Device::Cpu).expect("tensor");
            let v: Vec<f32> =
                q.dequantize(&Device::Cpu).unwrap().flatten_all().unwrap().to_vec1().unwrap();
            assert!(v.iter().all(|x| x.is_finite()));
            let mean = v.iter().sum::<f32>() / v.len() as f32;
            let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f32>() / v.len() as f32;
            let want = 1.0 / (spec.n_embd as f32); // (gain / sqrt(fan_in))^2
            assert!(var > 0.5 * want && var < 2.0 * want, "variance {var}, want ~{want}");
        }
    }

    #[test]
    fn same_seed_same_bytes_other_seed_other_bytes() {
        let a = tiny_gguf_bytes(&TinySpec::llama().with_seed(7)).unwrap();
        let b = tiny_gguf_bytes(&TinySpec::llama().with_seed(7)).unwrap();
        let c = tiny_gguf_bytes(&TinySpec::llama().with_seed(8)).unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_eq!(a.len(), c.len());
    }

    #[test]
    fn bad_spec_is_an_error_not_a_panic() {
        let mut s = TinySpec::llama();
        s.n_embd = 60;
        assert!(matches!(tiny_gguf_bytes(&s), Err(LlmError::TinySpec(_))));
        let mut s = TinySpec::qwen2();
        s.n_head_kv = 3;
        assert!(matches!(tiny_gguf_bytes(&s), Err(LlmError::TinySpec(_))));
    }

    /// candle's reference model code loads the tiny files and gives finite, varied logits: the
    /// file is a usable model, not only a readable one.
    #[test]
    fn candle_reference_models_run_the_tiny_files() {
        use candle_transformers::models::{quantized_llama, quantized_qwen2};
        for spec in [TinySpec::llama(), TinySpec::qwen2()] {
            let (c, mut cur) = read(&spec);
            let ids = Tensor::new(&[[5u32, 60, 61, 62, 100]], &Device::Cpu).unwrap();
            let logits = match spec.arch {
                Arch::Llama => quantized_llama::ModelWeights::from_gguf(c, &mut cur, &Device::Cpu)
                    .unwrap()
                    .forward(&ids, 0)
                    .unwrap(),
                Arch::Qwen2 => quantized_qwen2::ModelWeights::from_gguf(c, &mut cur, &Device::Cpu)
                    .unwrap()
                    .forward(&ids, 0)
                    .unwrap(),
            };
            let v: Vec<f32> = logits.flatten_all().unwrap().to_vec1().unwrap();
            assert_eq!(v.len(), spec.vocab_size());
            assert!(v.iter().all(|x| x.is_finite()));
            let mean = v.iter().sum::<f32>() / v.len() as f32;
            let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / v.len() as f32).sqrt();
            // Spread enough that sampling and argmax are meaningful, not a flat distribution.
            assert!(sd > 0.5 && sd < 20.0, "{}: logit sd {sd}", spec.arch);
        }
    }

    #[test]
    fn writes_to_a_path() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tiny.gguf");
        write_tiny_gguf(&TinySpec::qwen2(), &p).unwrap();
        let len = std::fs::metadata(&p).unwrap().len();
        assert!(len > 10_000 && len < 1_000_000, "size {len}");
    }
}
