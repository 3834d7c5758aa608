//! The forward pass: a decoder-only transformer (llama and qwen2 GGUF layouts) over candle's quantised
//! matmuls, on the CPU.
//!
//! It is ours rather than candle-transformers' `quantized_llama` for one reason: the planner needs to
//! own the KV cache. Calls share long prompt prefixes, so the cache must be cut back to any length and
//! extended from there ([`Transformer::truncate`]), and appended in place rather than re-concatenated
//! every token. Everything else follows the usual flow: embed → (norm → attention → residual →
//! norm → SwiGLU → residual) × layers → norm → vocabulary projection of the last position.

use std::fs::File;
use std::io::BufReader;

use candle_core::quantized::QMatMul;
use candle_core::{DType, Device, Module, Tensor};

use super::gguf::{Arch, GgufFile};
use super::{LlmError, Result};

/// Hyper-parameters read from the GGUF metadata (`<arch>.*` keys).
#[derive(Clone, Debug, PartialEq)]
pub struct ModelConfig {
    pub arch: Arch,
    pub n_layer: usize,
    pub n_embd: usize,
    pub n_head: usize,
    pub n_head_kv: usize,
    pub head_dim: usize,
    pub n_ff: usize,
    pub n_vocab: usize,
    pub context_length: usize,
    pub rope_base: f32,
    pub rms_eps: f64,
}

impl ModelConfig {
    /// Reads the configuration from a validated GGUF file's `<arch>.*` metadata.
    pub fn from_gguf(gguf: &GgufFile) -> Result<Self> {
        let md = gguf.metadata();
        let key = |k: &str| gguf.arch_key(k);
        let bad = |k: &str, detail: String| LlmError::Metadata {
            path: gguf.path().to_path_buf(),
            key: key(k),
            detail,
        };
        let n_embd = md.get_usize(&key("embedding_length"))?;
        let n_head = md.get_usize(&key("attention.head_count"))?;
        let n_head_kv = md.opt_u32(&key("attention.head_count_kv"))?.map_or(n_head, |n| n as usize);
        if n_head == 0 || n_head_kv == 0 || n_embd % n_head != 0 || n_head % n_head_kv != 0 {
            return Err(bad(
                "attention.head_count",
                format!("inconsistent heads: {n_head} heads, {n_head_kv} kv heads, width {n_embd}"),
            ));
        }
        let head_dim = n_embd / n_head;
        if let Some(rope_dim) = md.opt_u32(&key("rope.dimension_count"))? {
            if rope_dim as usize != head_dim {
                return Err(bad(
                    "rope.dimension_count",
                    format!("partial rotary embeddings ({rope_dim} of {head_dim}) are not supported"),
                ));
            }
        }
        let n_vocab = gguf
            .content()
            .tensor_infos
            .get("token_embd.weight")
            .and_then(|t| t.shape.dims().first().copied())
            .ok_or_else(|| LlmError::Metadata {
                path: gguf.path().to_path_buf(),
                key: "token_embd.weight".into(),
                detail: "tensor missing".into(),
            })?;
        Ok(Self {
            arch: gguf.arch(),
            n_layer: md.get_usize(&key("block_count"))?,
            n_embd,
            n_head,
            n_head_kv,
            head_dim,
            n_ff: md.get_usize(&key("feed_forward_length"))?,
            n_vocab,
            context_length: md.opt_u32(&key("context_length"))?.map_or(4096, |n| n as usize),
            rope_base: md.opt_f32(&key("rope.freq_base"))?.unwrap_or(10_000.0),
            rms_eps: md.opt_f32(&key("attention.layer_norm_rms_epsilon"))?.unwrap_or(1e-5) as f64,
        })
    }
}

/// One layer's keys and values, preallocated and appended in place; `len` positions are valid.
#[derive(Debug, Clone)]
struct LayerCache {
    k: Tensor, // (n_head_kv, capacity, head_dim)
    v: Tensor,
    len: usize,
}

impl LayerCache {
    fn new(n_head_kv: usize, head_dim: usize, capacity: usize, dev: &Device) -> Result<Self> {
        let k = Tensor::zeros((n_head_kv, capacity, head_dim), DType::F32, dev)?;
        Ok(Self { v: k.zeros_like()?, k, len: 0 })
    }

    fn capacity(&self) -> usize {
        self.k.dim(1).unwrap_or(0)
    }

    /// Appends `k`, `v` of shape (n_head_kv, t, head_dim), growing the buffers by doubling.
    fn append(&mut self, k: &Tensor, v: &Tensor) -> Result<()> {
        let t = k.dim(1)?;
        if self.len + t > self.capacity() {
            let new_cap = (self.len + t).next_power_of_two().max(2 * self.capacity());
            let (h, _, d) = self.k.dims3()?;
            let grow = |old: &Tensor| -> Result<Tensor> {
                let buf = Tensor::zeros((h, new_cap, d), DType::F32, old.device())?;
                buf.slice_set(&old.narrow(1, 0, self.len)?.contiguous()?, 1, 0)?;
                Ok(buf)
            };
            self.k = grow(&self.k)?;
            self.v = grow(&self.v)?;
        }
        self.k.slice_set(&k.contiguous()?, 1, self.len)?;
        self.v.slice_set(&v.contiguous()?, 1, self.len)?;
        self.len += t;
        Ok(())
    }

    fn keys(&self) -> Result<Tensor> {
        Ok(self.k.narrow(1, 0, self.len)?)
    }

    fn values(&self) -> Result<Tensor> {
        Ok(self.v.narrow(1, 0, self.len)?)
    }
}

#[derive(Debug, Clone)]
struct Layer {
    attn_norm: Tensor,
    wq: QMatMul,
    wk: QMatMul,
    wv: QMatMul,
    wo: QMatMul,
    // qwen2 has biases on the q, k, v projections; llama has none.
    bq: Option<Tensor>,
    bk: Option<Tensor>,
    bv: Option<Tensor>,
    ffn_norm: Tensor,
    gate: QMatMul,
    up: QMatMul,
    down: QMatMul,
    cache: LayerCache,
}

/// A loaded model and its KV cache: one sequence at a time, the planner's case.
#[derive(Debug, Clone)]
pub struct Transformer {
    cfg: ModelConfig,
    embd: Tensor, // (n_vocab, n_embd), dequantised once: row look-ups need plain floats
    layers: Vec<Layer>,
    out_norm: Tensor,
    output: QMatMul,
    cos: Tensor,
    sin: Tensor,
    device: Device,
}

/// Initial KV capacity in positions; the cache doubles when a prompt needs more.
const INITIAL_CACHE: usize = 512;

impl Transformer {
    /// Loads every tensor of a validated GGUF model.
    pub fn load(gguf: &GgufFile) -> Result<Self> {
        let cfg = ModelConfig::from_gguf(gguf)?;
        let dev = Device::Cpu;
        let mut reader = gguf.reader()?;
        let reader = &mut reader;
        let tensor = |reader: &mut BufReader<File>, name: &str| gguf.tensor(reader, name, &dev);
        let plain = |reader: &mut BufReader<File>, name: &str| -> Result<Tensor> {
            Ok(tensor(reader, name)?.dequantize(&dev)?)
        };
        let optional = |reader: &mut BufReader<File>, name: &str| -> Result<Option<Tensor>> {
            if gguf.has_tensor(name) {
                plain(reader, name).map(Some)
            } else {
                Ok(None)
            }
        };
        let embd_q = tensor(reader, "token_embd.weight")?;
        let embd = embd_q.dequantize(&dev)?;
        // Tied embeddings (SmolLM2): no output.weight, the embedding matrix projects to the vocabulary.
        let output = if gguf.has_tensor("output.weight") {
            QMatMul::from_qtensor(tensor(reader, "output.weight")?)?
        } else {
            QMatMul::from_qtensor(embd_q)?
        };
        let mut layers = Vec::with_capacity(cfg.n_layer);
        for i in 0..cfg.n_layer {
            let n = |s: &str| format!("blk.{i}.{s}");
            let q = |reader: &mut BufReader<File>, s: &str| -> Result<QMatMul> {
                Ok(QMatMul::from_qtensor(tensor(reader, &n(s))?)?)
            };
            layers.push(Layer {
                attn_norm: plain(reader, &n("attn_norm.weight"))?,
                wq: q(reader, "attn_q.weight")?,
                wk: q(reader, "attn_k.weight")?,
                wv: q(reader, "attn_v.weight")?,
                wo: q(reader, "attn_output.weight")?,
                bq: optional(reader, &n("attn_q.bias"))?,
                bk: optional(reader, &n("attn_k.bias"))?,
                bv: optional(reader, &n("attn_v.bias"))?,
                ffn_norm: plain(reader, &n("ffn_norm.weight"))?,
                gate: q(reader, "ffn_gate.weight")?,
                up: q(reader, "ffn_up.weight")?,
                down: q(reader, "ffn_down.weight")?,
                cache: LayerCache::new(cfg.n_head_kv, cfg.head_dim, INITIAL_CACHE, &dev)?,
            });
        }
        let out_norm = plain(reader, "output_norm.weight")?;
        let (cos, sin) = rope_tables(cfg.head_dim, cfg.rope_base, cfg.context_length, &dev)?;
        Ok(Self { cfg, embd, layers, out_norm, output, cos, sin, device: dev })
    }

    pub fn config(&self) -> &ModelConfig {
        &self.cfg
    }

    /// Positions currently held in the KV cache.
    pub fn cached_len(&self) -> usize {
        self.layers.first().map_or(0, |l| l.cache.len)
    }

    /// Forgets every cached position from `len` on (prefix reuse: keep the shared part).
    pub fn truncate(&mut self, len: usize) {
        for l in &mut self.layers {
            l.cache.len = l.cache.len.min(len);
        }
    }

    /// Runs `tokens` at positions `cached_len()..`, appends them to the cache and returns the
    /// next-token logits after the last one (length `n_vocab`).
    pub fn forward(&mut self, tokens: &[u32]) -> Result<Vec<f32>> {
        let t = tokens.len();
        if t == 0 {
            return Err(LlmError::Decode("forward called with no tokens".into()));
        }
        let pos = self.cached_len();
        if pos + t > self.cfg.context_length {
            return Err(LlmError::Decode(format!(
                "context full: {} cached + {t} new tokens exceed the model's {} positions",
                pos, self.cfg.context_length
            )));
        }
        if let Some(&bad) = tokens.iter().find(|&&id| id as usize >= self.cfg.n_vocab) {
            return Err(LlmError::Decode(format!(
                "token id {bad} is outside the model's vocabulary of {}",
                self.cfg.n_vocab
            )));
        }
        let ids = Tensor::new(tokens, &self.device)?;
        let mut x = self.embd.index_select(&ids, 0)?; // (t, n_embd)
        let cos = self.cos.narrow(0, pos, t)?;
        let sin = self.sin.narrow(0, pos, t)?;
        let mask = if t > 1 { Some(causal_mask(t, pos, &self.device)?) } else { None };
        let cfg = self.cfg.clone();
        for layer in &mut self.layers {
            let h = candle_nn::ops::rms_norm(&x, &layer.attn_norm, cfg.rms_eps as f32)?;
            let a = layer.attention(&h, &cos, &sin, mask.as_ref(), &cfg)?;
            x = (x + a)?;
            let h = candle_nn::ops::rms_norm(&x, &layer.ffn_norm, cfg.rms_eps as f32)?;
            let g = candle_nn::ops::silu(&layer.gate.forward(&h)?)?;
            let u = layer.up.forward(&h)?;
            x = (x + layer.down.forward(&(g * u)?)?)?;
        }
        // Only the last position's logits are ever used: project that row alone.
        let last = x.narrow(0, t - 1, 1)?;
        let last = candle_nn::ops::rms_norm(&last, &self.out_norm, cfg.rms_eps as f32)?;
        let logits = self.output.forward(&last)?.squeeze(0)?;
        Ok(logits.to_vec1::<f32>()?)
    }
}

impl Layer {
    /// Grouped-query attention over the cache plus the `t` new positions of `h` (t, n_embd).
    fn attention(
        &mut self,
        h: &Tensor,
        cos: &Tensor,
        sin: &Tensor,
        mask: Option<&Tensor>,
        cfg: &ModelConfig,
    ) -> Result<Tensor> {
        let t = h.dim(0)?;
        let (nh, nkv, hd) = (cfg.n_head, cfg.n_head_kv, cfg.head_dim);
        let proj = |w: &QMatMul, b: &Option<Tensor>| -> Result<Tensor> {
            let y = w.forward(h)?;
            Ok(match b {
                Some(b) => y.broadcast_add(b)?,
                None => y,
            })
        };
        // (t, heads*hd) → (1, heads, t, hd), the layout the rope kernels take.
        let heads = |y: Tensor, n: usize| -> Result<Tensor> {
            Ok(y.reshape((1, t, n, hd))?.transpose(1, 2)?.contiguous()?)
        };
        let q = heads(proj(&self.wq, &self.bq)?, nh)?;
        let k = heads(proj(&self.wk, &self.bk)?, nkv)?;
        let v = heads(proj(&self.wv, &self.bv)?, nkv)?;
        // llama.cpp stores llama's q/k rows for interleaved (GPT-J style) rotation and qwen2's for
        // the half-split (NeoX) one.
        let (q, k) = match cfg.arch {
            Arch::Llama => {
                (candle_nn::rotary_emb::rope_i(&q, cos, sin)?, candle_nn::rotary_emb::rope_i(&k, cos, sin)?)
            }
            Arch::Qwen2 => {
                (candle_nn::rotary_emb::rope(&q, cos, sin)?, candle_nn::rotary_emb::rope(&k, cos, sin)?)
            }
        };
        self.cache.append(&k.squeeze(0)?, &v.squeeze(0)?)?;
        let keys = self.cache.keys()?; // (nkv, kv_len, hd)
        let values = self.cache.values()?;
        // Grouped-query attention: each kv head serves `group` consecutive query heads.
        let group = nh / nkv;
        let rep = |x: Tensor| -> Result<Tensor> {
            let (h, l, d) = x.dims3()?;
            Ok(x.unsqueeze(1)?.expand((h, group, l, d))?.reshape((h * group, l, d))?)
        };
        let keys = rep(keys.contiguous()?)?;
        let values = rep(values.contiguous()?)?;
        let q = q.squeeze(0)?; // (nh, t, hd)
        let scale = 1.0 / (hd as f64).sqrt();
        let att = (q.matmul(&keys.t()?)? * scale)?; // (nh, t, kv_len)
        let att = match mask {
            Some(m) => att.broadcast_add(m)?,
            None => att,
        };
        let att = candle_nn::ops::softmax_last_dim(&att)?;
        let y = att.matmul(&values)?; // (nh, t, hd)
        let y = y.transpose(0, 1)?.reshape((t, nh * hd))?;
        Ok(self.wo.forward(&y)?)
    }
}

/// cos/sin tables (positions × head_dim/2) for rotary embeddings.
fn rope_tables(head_dim: usize, base: f32, n_pos: usize, dev: &Device) -> Result<(Tensor, Tensor)> {
    let inv: Vec<f32> =
        (0..head_dim).step_by(2).map(|i| 1.0 / base.powf(i as f32 / head_dim as f32)).collect();
    let inv = Tensor::new(inv.as_slice(), dev)?.reshape((1, head_dim / 2))?;
    let pos = Tensor::arange(0u32, n_pos as u32, dev)?.to_dtype(DType::F32)?.reshape((n_pos, 1))?;
    let angles = pos.matmul(&inv)?;
    Ok((angles.cos()?, angles.sin()?))
}

/// Additive mask (t, pos + t): query i (absolute pos + i) sees keys 0..=pos + i.
fn causal_mask(t: usize, pos: usize, dev: &Device) -> Result<Tensor> {
    let kv = pos + t;
    let data: Vec<f32> = (0..t)
        .flat_map(|i| (0..kv).map(move |j| if j <= pos + i { 0.0 } else { f32::NEG_INFINITY }))
        .collect();
    Ok(Tensor::from_vec(data, (t, kv), dev)?)
}

/// Index of the largest logit (ties: the lowest id), the greedy choice.
pub fn argmax(logits: &[f32]) -> Option<u32> {
    let mut best: Option<(usize, f32)> = None;
    for (i, &x) in logits.iter().enumerate() {
        if x.is_nan() {
            continue;
        }
        if best.is_none_or(|(_, b)| x > b) {
            best = Some((i, x));
        }
    }
    best.map(|(i, _)| i as u32)
}
