//! The forward pass: a decoder-only transformer (llama and qwen2 GGUF layouts) on the CPU, over our
//! own quantised matrix kernels ([`super::kernels`]) and plain f32 buffers.
//!
//! It is ours rather than candle-transformers' `quantized_llama` for one reason: the planner needs to
//! own the KV cache. Calls share long prompt prefixes, so the cache must be cut back to any length and
//! extended from there ([`Transformer::truncate`]), and appended in place rather than re-concatenated
//! every token. Everything else follows the usual flow: embed → (norm → attention → residual →
//! norm → SwiGLU → residual) × layers → norm → vocabulary projection of the last position.
//!
//! Speed notes: the weights stay in their GGUF blocks (the token embedding too: rows are dequantised
//! when looked up); each matrix input is quantised to 8 bits once and shared by the matrices that read
//! it (q/k/v, gate/up); attention reads the cache directly, each query head from its own kv head,
//! without copying keys and values per head; all buffers live in a scratch area reused across calls.
//! candle is used for reading the file only.
use std::fs::File;
use std::io::BufReader;
use std::sync::Arc;

use candle_core::Device;

use super::gguf::{Arch, GgufFile};
use super::kernels::attn::{AttnOps, Portable, SUMS};
use super::kernels::scores::{self, KeyTiles, Queries, Query, KEYS, MAX_QUERIES};
use super::kernels::{dot_f32, kernel, matmul, matmul_many, pool, Kernel, Q8Acts, QMatrix, SendPtr};
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
    /// The shape of each layer's tiled keys.
    pub(crate) fn key_tiles(&self) -> KeyTiles {
        KeyTiles { nkv: self.n_head_kv, hd: self.head_dim }
    }

    /// Reads the configuration from a validated GGUF file's `<arch>.*` metadata.
    pub fn from_gguf(gguf: &GgufFile) -> Result<Self> {
        let md = gguf.metadata();
        let key = |k: &str| gguf.arch_key(k);
        let bad = |k: &str, detail: String| LlmError::Metadata { path: gguf.path().to_path_buf(), key: key(k), detail };
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
        if !KeyTiles::fits(head_dim) {
            return Err(bad(
                "attention.head_count",
                format!("a head width of {head_dim} ({n_embd} / {n_head} heads): attention takes a multiple of 4 up to 512"),
            ));
        }
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

/// One layer's keys and values, position-major (`[pos][n_head_kv * head_dim]`), grown on demand;
/// the first `len` positions are valid. Attention reads the keys as 16-bit integer tiles (`k16`,
/// scales `ks`: [`scores`]); the f32 keys are what prefix snapshots store, the tiles being made from
/// them.
#[derive(Debug, Clone, Default)]
struct LayerCache {
    k: Vec<f32>,
    v: Vec<f32>,
    k16: Vec<i16>,
    ks: Vec<f32>,
    len: usize,
}

/// The KV cache grows in steps of this many positions, and by at least an eighth of its size:
/// doubling had Qwen's cache at 1024 positions for 545 used (24 MB, 11 of them never written),
/// while a step costs one copy of the cache, rare and small beside the forward passes.
const CACHE_STEP: usize = 128;

impl LayerCache {
    /// Makes room for `n` positions of `shape`'s keys and values, keeping the valid ones.
    fn reserve(&mut self, n: usize, shape: KeyTiles) {
        let width = shape.nkv * shape.hd;
        let have = self.k.len() / width;
        if have < n {
            // A whole number of tiles (CACHE_STEP is a multiple of KEYS).
            let positions = n.max(have + have / 8).next_multiple_of(CACHE_STEP);
            let cap = positions * width;
            for kv in [&mut self.k, &mut self.v] {
                // Exact: `resize` alone would round the capacity up to a power of two.
                kv.reserve_exact(cap - kv.len());
                kv.resize(cap, 0.0);
            }
            let (elements, scales) = shape.sizes(positions);
            self.k16.reserve_exact(elements - self.k16.len());
            self.k16.resize(elements, 0);
            self.ks.reserve_exact(scales - self.ks.len());
            self.ks.resize(scales, 0.0);
        }
    }

    /// Quantises the f32 keys of positions `from..to` into the tiles.
    fn tile_keys(&mut self, from: usize, to: usize, shape: KeyTiles) {
        let width = shape.nkv * shape.hd;
        for p in from..to {
            for h in 0..shape.nkv {
                let x = &self.k[p * width + h * shape.hd..][..shape.hd];
                shape.store(&mut self.k16, &mut self.ks, p, h, x);
            }
        }
    }
}

#[derive(Debug, Clone)]
struct Layer {
    attn_norm: Vec<f32>,
    wq: QMatrix,
    wk: QMatrix,
    wv: QMatrix,
    wo: QMatrix,
    // qwen2 has biases on the q, k, v projections; llama has none.
    bq: Option<Vec<f32>>,
    bk: Option<Vec<f32>>,
    bv: Option<Vec<f32>>,
    ffn_norm: Vec<f32>,
    gate: QMatrix,
    up: QMatrix,
    down: QMatrix,
    cache: LayerCache,
}

/// Buffers of one forward call, kept between calls so that decoding allocates nothing but the logits.
#[derive(Debug, Clone, Default)]
struct Scratch {
    x: Vec<f32>,
    h: Vec<f32>,
    q: Vec<f32>,
    k: Vec<f32>,
    v: Vec<f32>,
    att: Vec<f32>,
    o: Vec<f32>,
    g: Vec<f32>,
    u: Vec<f32>,
    rope: Vec<f32>,
    q8: Q8Acts,
    queries: Queries,
}

/// Sets `v` to `n` elements (contents unspecified), allocating only to grow.
fn fit(v: &mut Vec<f32>, n: usize) -> &mut [f32] {
    if v.len() < n {
        v.resize(n, 0.0);
    }
    &mut v[..n]
}

/// The most tokens one forward pass runs together; longer inputs run in batches of this many.
/// The scratch memory grows with the batch; each batch costs one more pass over the weights.
/// Qwen2.5-0.5B's bench prompt (481 tokens), 2 threads, alternating, medians of 3 rounds: batches
/// of 256 with the FFN whole peaked at 571 MiB and 380 tok/s; 128 with FFN_ROWS 64, at 558 MiB
/// and 365 tok/s, which keeps the peak under the file's size plus 100 MB. A planner node's
/// uncached tail is mostly shorter than one batch anyway.
const MAX_BATCH: usize = 128;

/// The FFN runs this many of a batch's tokens at a time: its two n_ff-wide activations are the
/// largest scratch buffers (39 KB a token for Qwen2.5-0.5B).
const FFN_ROWS: usize = 64;

/// A loaded model and its KV cache: one sequence at a time, the planner's case.
#[derive(Debug, Clone)]
pub struct Transformer {
    cfg: ModelConfig,
    /// (n_vocab, n_embd) in the file's encoding; rows are dequantised on look-up.
    embd: Arc<QMatrix>,
    layers: Vec<Layer>,
    out_norm: Vec<f32>,
    /// The vocabulary projection: the embedding itself when tied (SmolLM2).
    output: Arc<QMatrix>,
    /// Rotary inverse frequencies, one per pair of head dimensions.
    inv_freq: Vec<f32>,
    scratch: Scratch,
}

impl Transformer {
    /// Loads every tensor of a validated GGUF model.
    pub fn load(gguf: &GgufFile) -> Result<Self> {
        let cfg = ModelConfig::from_gguf(gguf)?;
        let dev = Device::Cpu;
        let mut reader = gguf.reader()?;
        let reader = &mut reader;
        let matrix = |reader: &mut BufReader<File>, name: &str| -> Result<QMatrix> {
            QMatrix::from_qtensor(&gguf.tensor(reader, name, &dev)?)
        };
        let plain = |reader: &mut BufReader<File>, name: &str| -> Result<Vec<f32>> {
            Ok(gguf.tensor(reader, name, &dev)?.dequantize(&dev)?.flatten_all()?.to_vec1::<f32>()?)
        };
        let optional = |reader: &mut BufReader<File>, name: &str| -> Result<Option<Vec<f32>>> {
            if gguf.has_tensor(name) {
                plain(reader, name).map(Some)
            } else {
                Ok(None)
            }
        };
        let embd = Arc::new(matrix(reader, "token_embd.weight")?);
        // Tied embeddings (SmolLM2): no output.weight, the embedding matrix projects to the vocabulary.
        let output =
            if gguf.has_tensor("output.weight") { Arc::new(matrix(reader, "output.weight")?) } else { embd.clone() };
        let mut layers = Vec::with_capacity(cfg.n_layer);
        for i in 0..cfg.n_layer {
            let n = |s: &str| format!("blk.{i}.{s}");
            layers.push(Layer {
                attn_norm: plain(reader, &n("attn_norm.weight"))?,
                wq: matrix(reader, &n("attn_q.weight"))?,
                wk: matrix(reader, &n("attn_k.weight"))?,
                wv: matrix(reader, &n("attn_v.weight"))?,
                wo: matrix(reader, &n("attn_output.weight"))?,
                bq: optional(reader, &n("attn_q.bias"))?,
                bk: optional(reader, &n("attn_k.bias"))?,
                bv: optional(reader, &n("attn_v.bias"))?,
                ffn_norm: plain(reader, &n("ffn_norm.weight"))?,
                gate: matrix(reader, &n("ffn_gate.weight"))?,
                up: matrix(reader, &n("ffn_up.weight"))?,
                down: matrix(reader, &n("ffn_down.weight"))?,
                cache: LayerCache::default(),
            });
        }
        let out_norm = plain(reader, "output_norm.weight")?;
        let hd = cfg.head_dim;
        let inv_freq = (0..hd).step_by(2).map(|i| 1.0 / cfg.rope_base.powf(i as f32 / hd as f32)).collect();
        // Start the worker threads now rather than inside the first timed call.
        pool::global();
        Ok(Self { cfg, embd, layers, out_norm, output, inv_freq, scratch: Scratch::default() })
    }

    pub fn config(&self) -> &ModelConfig {
        &self.cfg
    }

    /// Bytes held now: (weights, KV cache, scratch buffers), allocated capacity, for `step::llm::mem`'s
    /// debug lines.
    pub fn memory(&self) -> (usize, usize, usize) {
        let f = |v: &Vec<f32>| v.capacity() * 4;
        let mut weights = self.embd.bytes() + f(&self.out_norm);
        if !Arc::ptr_eq(&self.embd, &self.output) {
            weights += self.output.bytes();
        }
        let mut kv = 0;
        for l in &self.layers {
            let opt = |b: &Option<Vec<f32>>| b.as_ref().map_or(0, f);
            weights += [&l.wq, &l.wk, &l.wv, &l.wo, &l.gate, &l.up, &l.down].iter().map(|m| m.bytes()).sum::<usize>()
                + f(&l.attn_norm)
                + f(&l.ffn_norm)
                + opt(&l.bq)
                + opt(&l.bk)
                + opt(&l.bv);
            kv += f(&l.cache.k) + f(&l.cache.v) + l.cache.k16.capacity() * 2 + f(&l.cache.ks);
        }
        let s = &self.scratch;
        let bufs = [&s.x, &s.h, &s.q, &s.k, &s.v, &s.att, &s.o, &s.g, &s.u, &s.rope];
        let scratch = bufs.iter().map(|v| f(v)).sum::<usize>() + s.q8.bytes();
        (weights, kv, scratch)
    }

    /// Positions currently held in the KV cache.
    pub fn cached_len(&self) -> usize {
        self.layers.first().map_or(0, |l| l.cache.len)
    }

    /// The keys and values of the first `n` cached positions, layer by layer (keys, then values),
    /// each `n × n_head_kv × head_dim` floats: what a prefix snapshot stores ([`super::prefix`]).
    pub fn cache_slices(&self, n: usize) -> Vec<&[f32]> {
        let w = self.cfg.n_head_kv * self.cfg.head_dim;
        let n = n.min(self.cached_len());
        self.layers.iter().flat_map(|l| [&l.cache.k[..n * w], &l.cache.v[..n * w]]).collect()
    }

    /// Replaces the cache by `n` positions that `fill` writes, slice by slice in the order of
    /// [`Transformer::cache_slices`]. On an error the cache is left empty.
    pub fn restore_cache<E>(&mut self, n: usize, mut fill: impl FnMut(&mut [f32]) -> std::result::Result<(), E>) -> std::result::Result<(), E> {
        let shape = self.cfg.key_tiles();
        let w = shape.nkv * shape.hd;
        self.truncate(0);
        for l in &mut self.layers {
            l.cache.reserve(n, shape);
            fill(&mut l.cache.k[..n * w])?;
            fill(&mut l.cache.v[..n * w])?;
        }
        for l in &mut self.layers {
            l.cache.tile_keys(0, n, shape);
            l.cache.len = n;
        }
        Ok(())
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
        let mut logits = Vec::new();
        self.forward_rows(tokens, false, &mut logits)?;
        Ok(logits)
    }

    /// As [`Transformer::forward`], into `logits` (resized to `n_vocab`): the decode loop keeps one
    /// buffer rather than allocating a vocabulary's width of floats per token.
    pub fn forward_into(&mut self, tokens: &[u32], logits: &mut Vec<f32>) -> Result<()> {
        self.forward_rows(tokens, false, logits)
    }

    /// As [`Transformer::forward`], returning the next-token logits after every one of `tokens`
    /// (`tokens.len() × n_vocab`, row by row): what scoring a continuation needs.
    pub fn forward_all(&mut self, tokens: &[u32]) -> Result<Vec<f32>> {
        let mut logits = Vec::new();
        self.forward_rows(tokens, true, &mut logits)?;
        Ok(logits)
    }

    fn forward_rows(&mut self, tokens: &[u32], all: bool, logits: &mut Vec<f32>) -> Result<()> {
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
        let v = self.cfg.n_vocab;
        logits.clear();
        logits.resize(if all { t } else { 1 } * v, 0.0);
        // Long prompts run MAX_BATCH tokens at a time, so that the scratch buffers (sized by the
        // tokens of one pass, and kept) stay bounded; no token's numbers depend on its batch.
        let batches = t.div_ceil(MAX_BATCH);
        for (b, batch) in tokens.chunks(MAX_BATCH).enumerate() {
            let out = if all {
                Some(&mut logits[b * MAX_BATCH * v..][..batch.len() * v])
            } else {
                (b + 1 == batches).then_some(&mut logits[..])
            };
            self.forward_batch(batch, out);
        }
        Ok(())
    }

    /// Runs `tokens` after the cache and appends them to it; writes the logits after the last
    /// `out.len() / n_vocab` of them into `out`, if given.
    fn forward_batch(&mut self, tokens: &[u32], out: Option<&mut [f32]>) {
        let t = tokens.len();
        let pos = self.cached_len();
        let cfg = &self.cfg;
        let d = cfg.n_embd;
        let eps = cfg.rms_eps as f32;
        let s = &mut self.scratch;
        // x and h are passed beside the scratch area, so they leave it for the call.
        let (mut x_buf, mut h_buf) = (std::mem::take(&mut s.x), std::mem::take(&mut s.h));
        let x = fit(&mut x_buf, t * d);
        for (row, &id) in x.chunks_exact_mut(d).zip(tokens) {
            self.embd.dequantize_row(id as usize, row);
        }
        rope_table(&self.inv_freq, pos, t, &mut s.rope);
        for layer in &mut self.layers {
            layer.cache.reserve(pos + t, cfg.key_tiles());
            layer.cache.len = pos;
            let h = fit(&mut h_buf, t * d);
            rms_norm(x, &layer.attn_norm, eps, h);
            layer.attention(h, t, cfg, s);
            add(x, &s.o[..t * d]);
            rms_norm(x, &layer.ffn_norm, eps, h);
            let o = fit(&mut s.o, t * d);
            for (h, o) in h.chunks(FFN_ROWS * d).zip(o.chunks_mut(FFN_ROWS * d)) {
                let r = h.len() / d;
                let (g, u) = (fit(&mut s.g, r * cfg.n_ff), fit(&mut s.u, r * cfg.n_ff));
                s.q8.quantize(h, r, d);
                matmul_many(&[(&layer.gate, &mut *g), (&layer.up, &mut *u)], &s.q8, h, r);
                swiglu(g, u);
                matmul(&layer.down, g, r, &mut s.q8, o);
            }
            add(x, o);
        }
        // Generation uses the last position's logits only: project that row alone.
        if let Some(logits) = out {
            let rows = logits.len() / cfg.n_vocab;
            let h = fit(&mut h_buf, rows * d);
            rms_norm(&x[(t - rows) * d..], &self.out_norm, eps, h);
            matmul(&self.output, h, rows, &mut s.q8, logits);
        }
        (s.x, s.h) = (x_buf, h_buf);
    }
}

impl Layer {
    /// Attention for the `t` new positions in `h` (t × n_embd) over the cache, output projection
    /// included: leaves `scratch.o` (t × n_embd). Appends the new keys and values to the cache.
    fn attention(&mut self, h: &[f32], t: usize, cfg: &ModelConfig, s: &mut Scratch) {
        let (nh, nkv, hd) = (cfg.n_head, cfg.n_head_kv, cfg.head_dim);
        let kvw = nkv * hd;
        let pos = self.cache.len;
        let (q, k, v) = (fit(&mut s.q, t * nh * hd), fit(&mut s.k, t * kvw), fit(&mut s.v, t * kvw));
        s.q8.quantize(h, t, cfg.n_embd);
        matmul_many(&[(&self.wq, &mut *q), (&self.wk, &mut *k), (&self.wv, &mut *v)], &s.q8, h, t);
        for (y, b) in [(&mut *q, &self.bq), (&mut *k, &self.bk), (&mut *v, &self.bv)] {
            if let Some(b) = b {
                y.chunks_exact_mut(b.len()).for_each(|row| add(row, b));
            }
        }
        // llama.cpp stores llama's q/k rows for interleaved (GPT-J style) rotation and qwen2's for
        // the half-split (NeoX) one.
        let interleaved = cfg.arch == Arch::Llama;
        for i in 0..t {
            let cs = &s.rope[i * hd..(i + 1) * hd];
            q[i * nh * hd..(i + 1) * nh * hd].chunks_exact_mut(hd).for_each(|x| rope(x, cs, interleaved));
            k[i * kvw..(i + 1) * kvw].chunks_exact_mut(hd).for_each(|x| rope(x, cs, interleaved));
        }
        self.cache.k[pos * kvw..(pos + t) * kvw].copy_from_slice(k);
        self.cache.v[pos * kvw..(pos + t) * kvw].copy_from_slice(v);
        let shape = cfg.key_tiles();
        self.cache.tile_keys(pos, pos + t, shape);
        self.cache.len = pos + t;
        let scale = 1.0 / (hd as f32).sqrt();
        s.queries.quantize(q, hd, scale);

        // One task per (kv head, sub-group of its query heads, block of queries): the query heads
        // that share a kv head read each tile of its keys and each block of its values together,
        // while it is in L1, instead of each head streaming the whole cache. Sub-groups only when
        // there would otherwise be too few tasks to share out (decoding); every (query, head)
        // result is computed the same way whatever the grouping.
        let kv_len = pos + t;
        let group = nh / nkv;
        let qblock = 16;
        let qblocks = t.div_ceil(qblock);
        let threads = pool::global().threads();
        let subs = (2 * threads).div_ceil(nkv * qblocks).clamp(1, group);
        let per_sub = group.div_ceil(subs);
        let subs = group.div_ceil(per_sub);
        let n_tasks = nkv * subs * qblocks;
        let att = fit(&mut s.att, t * nh * hd);
        att.fill(0.0);
        let out = SendPtr(att.as_mut_ptr());
        let cache = &self.cache;
        let (queries, values) = (&s.queries, &cache.v[..kv_len * kvw]);
        let kernel = kernel();
        let task = |task: usize| {
            let (kvh, sub, qb) = (task % nkv, task / nkv % subs, task / (nkv * subs));
            let first = kvh * group + sub * per_sub;
            let heads = first..(first + per_sub).min((kvh + 1) * group);
            // Each task writes only the (query, head) slices of `att` it owns; the buffer outlives
            // the pool job.
            let job = HeadBlock {
                queries,
                tiles: &cache.k16,
                scales: &cache.ks,
                shape,
                kernel,
                values,
                heads,
                kvh,
                nh,
                pos,
                kv_len,
                out: &out,
            };
            let rows = qb * qblock..((qb + 1) * qblock).min(t);
            // The scores of every (row, head) of the task, in the running thread's own buffer:
            // its size follows the threads, not the tasks.
            SCORES.with_borrow_mut(|buf| {
                let sc = fit(buf, rows.len() * job.heads.len() * job.stride());
                match kernel {
                    // SAFETY: `Kernel::Avx2` is only chosen when the CPU has AVX2 and FMA.
                    Kernel::Avx2 => unsafe { job.run_avx2(rows, sc) },
                    // SAFETY: `Kernel::Avx512` is only chosen when the CPU has AVX-512F/BW/VL/VNNI.
                    Kernel::Avx512 => unsafe { job.run_avx512(rows, sc) },
                    // SAFETY: the portable loops need no CPU feature.
                    Kernel::Scalar => unsafe { job.run::<Portable>(rows, sc) },
                }
            });
        };
        pool::global().run(n_tasks, &task);
        let o = fit(&mut s.o, t * cfg.n_embd);
        matmul(&self.wo, att, t, &mut s.q8, o);
    }
}

/// Query heads sharing one kv head over a block of query rows: scores against every cached key up
/// to each query's own position (causal), softmax, weighted sum of the values, written into `out`.
struct HeadBlock<'a> {
    /// Every (row, query head) of the call, quantised.
    queries: &'a Queries,
    /// The layer's key tiles and their scales.
    tiles: &'a [i16],
    scales: &'a [f32],
    shape: KeyTiles,
    /// Which score loops run.
    kernel: Kernel,
    values: &'a [f32],
    /// The query heads, all of kv head `kvh`.
    heads: std::ops::Range<usize>,
    kvh: usize,
    nh: usize,
    pos: usize,
    kv_len: usize,
    out: &'a SendPtr,
}

thread_local! {
    /// Attention scores of the task a thread is running (see [`Layer::attention`]).
    static SCORES: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Values per block that the heads of a group go over together: 64 rows of a 64-wide head are
/// 16 KB, so a block stays in L1 while every head of the group reads it.
const VALUE_BLOCK: usize = 64;

impl HeadBlock<'_> {
    /// The row length of each (row, head)'s scores in the task's buffer: whole tiles.
    fn stride(&self) -> usize {
        self.kv_len.next_multiple_of(KEYS)
    }

    /// The same code over the AVX2 loops, compiled with those features; both loop sets compute the
    /// same bits (see [`super::kernels::attn`]), so both paths give the same results.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2(&self, rows: std::ops::Range<usize>, sc: &mut [f32]) {
        self.run::<super::kernels::attn::Avx2>(rows, sc)
    }

    /// The same code with the AVX-512 softmax and weighted sums, compiled with AVX-512F; the same
    /// bits again.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,avx512f")]
    unsafe fn run_avx512(&self, rows: std::ops::Range<usize>, sc: &mut [f32]) {
        self.run::<super::kernels::attn::Avx512>(rows, sc)
    }

    #[cfg(not(target_arch = "x86_64"))]
    unsafe fn run_avx512(&self, rows: std::ops::Range<usize>, sc: &mut [f32]) {
        self.run::<Portable>(rows, sc)
    }

    #[cfg(not(target_arch = "x86_64"))]
    unsafe fn run_avx2(&self, rows: std::ops::Range<usize>, sc: &mut [f32]) {
        self.run::<Portable>(rows, sc)
    }

    /// # Safety
    /// `O`'s CPU features must be present; `sc` holds `rows.len() × heads.len()` rows of
    /// [`HeadBlock::stride`].
    ///
    /// Tile by tile of keys, then block by block of values, every query row of the task and every
    /// head of the group read it while it is in L1: the cache of one kv head is streamed once per
    /// task rather than once per query row. Each (row, head) still takes its values in order, so
    /// the bits do not depend on the blocking.
    #[inline(always)]
    unsafe fn run<O: AttnOps>(&self, rows: std::ops::Range<usize>, sc: &mut [f32]) {
        let (hd, nh, stride) = (self.shape.hd, self.nh, self.stride());
        let kvw = self.shape.nkv * hd;
        let kv = self.kvh * hd;
        let ng = self.heads.len();
        // Causal: row i sees keys 0..=pos+i.
        let seen = |i: usize| self.pos + i + 1;
        let all = seen(rows.end - 1);
        // Scores, by unit: unit `u = r * ng + g` is row `rows.start + r` with the group's head `g`,
        // its scores at `sc[u * stride..]`. The rows that see a tile are a suffix of the rows
        // (row i sees keys before pos + i + 1), so the units that do are too.
        let units = rows.len() * ng;
        let row_of = |u: usize| rows.start + u / ng;
        let query = |u: usize| self.queries.get(row_of(u) * nh + self.heads.start + u % ng);
        let scp = sc.as_mut_ptr();
        debug_assert!(sc.len() >= units * stride);
        let tl = self.shape.tile_len();
        for j0 in (0..all).step_by(KEYS) {
            let t = self.shape.tile(j0, self.kvh);
            let (tile, scales) = (&self.tiles[t * tl..][..tl], &self.scales[t * KEYS..][..KEYS]);
            let mut u = rows.clone().position(|i| j0 < seen(i)).unwrap_or(rows.len()) * ng;
            while u < units {
                // A few units at a time share each load of the tile; every write is inside a
                // unit's row of `sc` (j0 + KEYS ≤ stride).
                let n = (units - u).min(MAX_QUERIES);
                let qs: [Query; MAX_QUERIES] = std::array::from_fn(|k| query((u + k).min(units - 1)));
                let out: [*mut f32; MAX_QUERIES] = std::array::from_fn(|k| scp.add((u + k).min(units - 1) * stride + j0));
                scores::tile_scores(self.kernel, self.shape, tile, scales, &qs[..n], &out[..n]);
                u += n;
            }
        }
        // Softmax of each (row, head) over the keys it sees.
        for (r, i) in rows.clone().enumerate() {
            for g in 0..ng {
                O::softmax(&mut sc[(r * ng + g) * stride..][..seen(i)]);
            }
        }
        // The weighted sums, a block of values at a time for every row and head: each output
        // element still takes its keys in order (the sum goes through `y` between blocks,
        // exactly). Up to `SUMS` (row, head) pairs that see the same keys of the block go to the
        // loops together, so that one load of a value row serves them all.
        let scp = sc.as_ptr();
        for j0 in (0..all).step_by(VALUE_BLOCK) {
            let vals = &self.values[j0 * kvw + kv..];
            let mut ys = [std::ptr::null_mut::<f32>(); SUMS];
            let mut ps = [std::ptr::null::<f32>(); SUMS];
            let (mut n, mut keys) = (0, 0);
            for (r, i) in rows.clone().enumerate().filter(|&(_, i)| j0 < seen(i)) {
                let k = (j0 + VALUE_BLOCK).min(seen(i)) - j0;
                for (g, head) in self.heads.clone().enumerate() {
                    if n == SUMS || (n > 0 && k != keys) {
                        O::weighted_sums(&ys[..n], &ps[..n], keys, hd, vals, kvw);
                        n = 0;
                    }
                    keys = k;
                    // This (query, head) slice belongs to this task alone (see the caller); the
                    // unit's scores are `seen(i)` floats at its row of `sc`.
                    ys[n] = self.out.get().add((i * nh + head) * hd);
                    ps[n] = scp.add((r * ng + g) * stride + j0);
                    n += 1;
                }
            }
            if n > 0 {
                O::weighted_sums(&ys[..n], &ps[..n], keys, hd, vals, kvw);
            }
        }
    }
}

/// cos (first half) and sin (second half) of each rotary angle, `head_dim` floats per position.
fn rope_table(inv_freq: &[f32], pos: usize, t: usize, out: &mut Vec<f32>) {
    let half = inv_freq.len();
    let table = fit(out, t * 2 * half);
    for (i, row) in table.chunks_exact_mut(2 * half).enumerate() {
        let p = (pos + i) as f32;
        for (j, &f) in inv_freq.iter().enumerate() {
            let a = p * f;
            row[j] = a.cos();
            row[half + j] = a.sin();
        }
    }
}

/// Rotates one head vector by the angles in `cs` (cos then sin halves).
fn rope(x: &mut [f32], cs: &[f32], interleaved: bool) {
    let half = x.len() / 2;
    let (cos, sin) = cs.split_at(half);
    for j in 0..half {
        let (a, b) = if interleaved { (2 * j, 2 * j + 1) } else { (j, j + half) };
        let (x0, x1) = (x[a], x[b]);
        x[a] = x0 * cos[j] - x1 * sin[j];
        x[b] = x0 * sin[j] + x1 * cos[j];
    }
}

/// RMSNorm of each row of `x` (rows of `w.len()`) into `y`.
fn rms_norm(x: &[f32], w: &[f32], eps: f32, y: &mut [f32]) {
    let d = w.len();
    for (xr, yr) in x.chunks_exact(d).zip(y.chunks_exact_mut(d)) {
        let r = 1.0 / (dot_f32(xr, xr) / d as f32 + eps).sqrt();
        for ((yo, &xi), &wi) in yr.iter_mut().zip(xr).zip(w) {
            *yo = xi * r * wi;
        }
    }
}

/// `g = silu(g) · u`, element by element; on the pool for prompts (an exp per element is a
/// stretch the other threads would otherwise wait through).
fn swiglu(g: &mut [f32], u: &[f32]) {
    const CHUNK: usize = 8192;
    let f = super::kernels::attn::silu_gate;
    let n = g.len();
    if n < 2 * CHUNK {
        return f(g, u);
    }
    let out = SendPtr(g.as_mut_ptr());
    pool::global().run(n.div_ceil(CHUNK), &|k| {
        let (s, e) = (k * CHUNK, ((k + 1) * CHUNK).min(n));
        // SAFETY: each task owns elements s..e of g (length n), which outlives the pool job.
        f(unsafe { std::slice::from_raw_parts_mut(out.get().add(s), e - s) }, &u[s..e]);
    });
}

fn add(x: &mut [f32], y: &[f32]) {
    x.iter_mut().zip(y).for_each(|(a, b)| *a += b);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Long inputs run in batches of MAX_BATCH and the KV cache grows in steps: whatever the pieces a
    /// sequence is fed in (one call, pieces across batch and cache-step boundaries, one token at a
    /// time), every position's logits are the same bits; and the cache holds what was asked for
    /// rounded up to a step, not the next power of two.
    #[test]
    fn batches_and_cache_growth_leave_the_logits_unchanged() {
        use super::super::tiny::{write_tiny_gguf, TinySpec};
        let dir = tempfile::tempdir().unwrap();
        for spec in [TinySpec::llama(), TinySpec::qwen2()] {
            let path = dir.path().join(format!("{}.gguf", spec.arch));
            write_tiny_gguf(&TinySpec { context_length: 1024, ..spec.clone() }, &path).unwrap();
            let mut m = Transformer::load(&GgufFile::open(&path).unwrap()).unwrap();
            let n = 2 * MAX_BATCH + 45;
            let ids: Vec<u32> = (0..n as u32).map(|i| (i * 7 + 3) % spec.vocab_size() as u32).collect();
            let whole = m.forward_all(&ids).unwrap();
            assert_eq!(m.forward_all(&ids[..0]).err().map(|e| e.to_string().contains("no tokens")), Some(true));
            let width = m.cfg.n_head_kv * m.cfg.head_dim;
            assert_eq!(m.layers[0].cache.k.len(), n.next_multiple_of(CACHE_STEP) * width);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            for pieces in [vec![1, 100, 57, MAX_BATCH + 1, n - 159 - MAX_BATCH], vec![1; n]] {
                m.truncate(0);
                let (mut at, mut rows) = (0, Vec::new());
                for p in pieces {
                    rows.extend(m.forward_all(&ids[at..at + p]).unwrap());
                    at += p;
                }
                assert_eq!(bits(&rows), bits(&whole), "{}", spec.arch);
            }
            m.truncate(0);
            let last = m.forward(&ids).unwrap();
            assert_eq!(bits(&last), bits(&whole[(n - 1) * m.cfg.n_vocab..]), "{}", spec.arch);
        }
    }

    /// The attention of one query head as it was computed before heads were grouped: every key's
    /// score on its own (the portable definition), softmax, one weighted sum over all values.
    fn one_head<O: AttnOps>(q: Query, tiles: (&[i16], &[f32]), shape: KeyTiles, kvh: usize, seen: usize, values: &[f32], y: &mut [f32]) {
        let (hd, kvw) = (shape.hd, shape.nkv * shape.hd);
        let mut sc = vec![0f32; seen.next_multiple_of(KEYS)];
        for j0 in (0..seen).step_by(KEYS) {
            let t = shape.tile(j0, kvh);
            let tile = (&tiles.0[t * shape.tile_len()..][..shape.tile_len()], &tiles.1[t * KEYS..][..KEYS]);
            // SAFETY: KEYS floats after the pointer; the portable loops need no CPU feature.
            unsafe { scores::tile_scores(Kernel::Scalar, shape, tile.0, tile.1, &[q], &[sc[j0..].as_mut_ptr()]) };
        }
        sc.truncate(seen);
        // SAFETY: callers pass `O` only where its CPU features are present.
        unsafe {
            O::softmax(&mut sc);
            O::weighted_sum(y, &sc, &values[kvh * hd..], kvw);
        }
    }

    /// Grouped heads over tiles of keys and blocks of values give exactly the per-head results,
    /// for groups of one, part of and all of a kv head's query heads, over several tiles and a
    /// partial one, with every kernel this CPU has.
    #[test]
    fn grouped_attention_equals_one_head_at_a_time_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(23);
        // A few rows far into the cache, and rows that straddle tiles and value blocks.
        for (pos, t) in [(150, 3), (70, 21)] {
            let (nh, nkv, hd) = (6, 2, 64);
            let (kvw, kv_len, group) = (nkv * hd, pos + t, nh / nkv);
            let shape = KeyTiles { nkv, hd };
            let mut r = |n: usize| (0..n).map(|_| rng.random_range(-2.0f32..2.0)).collect::<Vec<_>>();
            let (q, keys, values) = (r(t * nh * hd), r(kv_len * kvw), r(kv_len * kvw));
            let (nb, ns) = shape.sizes(kv_len);
            let (mut tiles, mut scales) = (vec![0i16; nb], vec![0f32; ns]);
            for p in 0..kv_len {
                for h in 0..nkv {
                    shape.store(&mut tiles, &mut scales, p, h, &keys[p * kvw + h * hd..][..hd]);
                }
            }
            let mut queries = Queries::default();
            queries.quantize(&q, hd, 0.125);
            let avx2 = super::super::kernels::avx2::available();
            let avx512 = super::super::kernels::avx512::available();
            for (simd, kernel) in [(false, Kernel::Scalar), (true, Kernel::Avx2), (true, Kernel::Avx512)] {
                if (kernel == Kernel::Avx2 && !avx2) || (kernel == Kernel::Avx512 && !avx512) {
                    eprintln!("skipped {kernel:?}: this CPU does not have it");
                    continue;
                }
                let mut want = vec![0f32; t * nh * hd];
                for i in 0..t {
                    let seen = pos + i + 1;
                    for h in 0..nh {
                        let (qi, y) = (queries.get(i * nh + h), &mut want[(i * nh + h) * hd..][..hd]);
                        let v = &values[..seen * kvw];
                        #[cfg(target_arch = "x86_64")]
                        if simd {
                            one_head::<super::super::kernels::attn::Avx2>(qi, (&tiles, &scales), shape, h / group, seen, v, y);
                            continue;
                        }
                        one_head::<Portable>(qi, (&tiles, &scales), shape, h / group, seen, v, y);
                    }
                }
                // Row blocks as the model makes them (16 rows) and smaller ones, odd and even.
                for (per_sub, rows_per_job) in [(1, 16), (2, 16), (3, 16), (3, 5), (2, 4)] {
                    let mut got = vec![0f32; t * nh * hd];
                    let out = SendPtr(got.as_mut_ptr());
                    for kvh in 0..nkv {
                        for first in (kvh * group..(kvh + 1) * group).step_by(per_sub) {
                            let heads = first..(first + per_sub).min((kvh + 1) * group);
                            let job = HeadBlock {
                                queries: &queries,
                                tiles: &tiles,
                                scales: &scales,
                                shape,
                                kernel,
                                values: &values,
                                heads,
                                kvh,
                                nh,
                                pos,
                                kv_len,
                                out: &out,
                            };
                            for r0 in (0..t).step_by(rows_per_job) {
                                let rows = r0..(r0 + rows_per_job).min(t);
                                let mut sc = vec![0f32; rows.len() * per_sub * job.stride()];
                                // SAFETY: the kernel's features checked above; `got` outlives the
                                // calls, one writer.
                                unsafe {
                                    if kernel == Kernel::Avx512 {
                                        job.run_avx512(rows, &mut sc)
                                    } else if simd {
                                        job.run_avx2(rows, &mut sc)
                                    } else {
                                        job.run::<Portable>(rows, &mut sc)
                                    }
                                };
                            }
                        }
                    }
                    let same = want.iter().zip(&got).all(|(a, b)| a.to_bits() == b.to_bits());
                    assert!(same, "{kernel:?}, {per_sub} heads and {rows_per_job} rows per task, {t} rows after {pos}");
                }
            }
        }
    }
}
