//! Our quantised matrix kernels: the weights stay in their GGUF blocks (Q4_1, Q5_0, Q8_0, Q4_K, Q6_K),
//! the activations are quantised once per matrix input to 8-bit blocks of 32 ([`Q8Acts`]), and each
//! output element is an integer dot product per block scaled in f32.
//!
//! Three implementations compute exactly the same numbers: a portable scalar one ([`scalar`]), an
//! AVX2/FMA one ([`avx2`]) and an AVX-512 VNNI one ([`avx512`]), the fastest the CPU has chosen at run
//! time. They agree bit for bit because the integer part is exact
//! and the float part follows the same order: eight lanes (lane `l` holds elements `4l..4l+4` of each
//! 32-block), one fused multiply-add per lane and block, a fixed reduction tree, then the blocks'
//! min terms summed in order. Rows are split across the [`pool`]'s threads; each output element is
//! computed by one thread, so results do not depend on the thread count.

pub mod attn;
pub mod avx2;
pub mod avx512;
pub mod pool;
pub mod scalar;
pub mod scores;

use candle_core::quantized::{GgmlDType, QTensor};
use candle_core::Device;

use super::Result;

/// Values per activation block (and per weight sub-block).
pub const QK: usize = 32;

/// 32 activations quantised to i8 with one f32 scale; `s` is `d * Σ qs` (for the formats with a
/// per-block minimum).
#[derive(Clone, Copy, Debug, Default)]
#[repr(C)]
pub struct Q8Block {
    pub d: f32,
    pub s: f32,
    pub qs: [i8; QK],
}

/// Block `c` of two consecutive tokens for the AVX-512 kernels ([`avx512::dot_pairs`]): each token's
/// 32 values offset to unsigned (`q + 128`), one token per half, and each token's scale repeated over
/// its half's eight lanes, so that one 512-bit load feeds each operand.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub struct PairBlock {
    pub qs: [u8; 64],
    pub d: [f32; 16],
}

impl Default for PairBlock {
    fn default() -> Self {
        Self { qs: [0; 64], d: [0.0; 16] }
    }
}

/// `t` rows of activations, each quantised to `cols / 32` blocks.
#[derive(Clone, Debug, Default)]
pub struct Q8Acts {
    pub blocks: Vec<Q8Block>,
    /// Tokens `2p`, `2p + 1` as [`PairBlock`]s (`pairs[p * nb + c]`), for `t / 2` pairs; empty
    /// unless quantised for the AVX-512 kernel with at least four tokens.
    pub pairs: Vec<PairBlock>,
    /// Beside the pairs: every token's `s` by block, `sums[c * t + k]`, so that the minimum terms
    /// of many tokens are one vector operation.
    pub sums: Vec<f32>,
    pub t: usize,
    pub nb: usize,
}

impl Q8Acts {
    /// Quantises `x` (`t` rows of `cols`, cols a multiple of 32) in place of the previous content,
    /// reusing the allocation, in the layouts the process's kernel reads.
    pub fn quantize(&mut self, x: &[f32], t: usize, cols: usize) {
        self.quantize_for(x, t, cols, kernel())
    }

    /// As [`Q8Acts::quantize`], for `kernel`'s layouts.
    pub fn quantize_for(&mut self, x: &[f32], t: usize, cols: usize, kernel: Kernel) {
        debug_assert_eq!(x.len(), t * cols);
        self.t = t;
        // No quantised kernel takes a width that is not whole blocks (those matrices are kept as f32).
        self.nb = if cols % QK == 0 { cols / QK } else { 0 };
        self.blocks.resize(t * self.nb, Q8Block::default());
        let n = self.blocks.len();
        // A prompt's activations are quantised on the pool: done by the caller alone, this was a
        // serial stretch of every layer while the other threads waited.
        const CHUNK: usize = 256;
        if n >= 2 * CHUNK {
            let out = BlockPtr(self.blocks.as_mut_ptr());
            pool::global().run(n.div_ceil(CHUNK), &|k| {
                for b in k * CHUNK..((k + 1) * CHUNK).min(n) {
                    // SAFETY: b < n = blocks.len(), and each task writes its own range of blocks.
                    unsafe { *out.get().add(b) = quantize_block(&x[b * QK..(b + 1) * QK]) };
                }
            });
        } else {
            for (b, xs) in self.blocks.iter_mut().zip(x.chunks_exact(QK)) {
                *b = quantize_block(xs);
            }
        }
        self.pairs.clear();
        self.sums.clear();
        // Decoding (fewer than four tokens) reads the blocks alone.
        if kernel == Kernel::Avx512 && t >= 4 && self.nb > 0 {
            let nb = self.nb;
            let n = t / 2 * nb;
            self.pairs.resize(n, PairBlock::default());
            let (blocks, out) = (&self.blocks, PairPtr(self.pairs.as_mut_ptr()));
            pool::global().run(n.div_ceil(CHUNK), &|k| {
                for i in k * CHUNK..((k + 1) * CHUNK).min(n) {
                    let (p, c) = (i / nb, i % nb);
                    let (b0, b1) = (&blocks[2 * p * nb + c], &blocks[(2 * p + 1) * nb + c]);
                    let mut pb = PairBlock { qs: [0; 64], d: [b0.d; 16] };
                    pb.d[8..].fill(b1.d);
                    for e in 0..QK {
                        // q + 128 as a byte: the sign bit flipped.
                        pb.qs[e] = b0.qs[e] as u8 ^ 0x80;
                        pb.qs[QK + e] = b1.qs[e] as u8 ^ 0x80;
                    }
                    // SAFETY: i < n = pairs.len(), and each task writes its own range.
                    unsafe { *out.get().add(i) = pb };
                }
            });
            self.sums.resize(nb * t, 0.0);
            for (k, row) in self.blocks.chunks_exact(nb).enumerate() {
                for (c, b) in row.iter().enumerate() {
                    self.sums[c * t + k] = b.s;
                }
            }
        }
    }

    /// Bytes allocated.
    pub fn bytes(&self) -> usize {
        use std::mem::size_of;
        self.blocks.capacity() * size_of::<Q8Block>()
            + self.pairs.capacity() * size_of::<PairBlock>()
            + self.sums.capacity() * 4
    }

    /// The pair blocks of tokens `2p` and `2p + 1`.
    pub fn pair(&self, p: usize) -> &[PairBlock] {
        &self.pairs[p * self.nb..(p + 1) * self.nb]
    }

    pub fn row(&self, i: usize) -> &[Q8Block] {
        &self.blocks[i * self.nb..(i + 1) * self.nb]
    }
}

#[derive(Clone, Copy)]
struct BlockPtr(*mut Q8Block);
// SAFETY: used only to write disjoint blocks from pool tasks (see `Q8Acts::quantize`).
unsafe impl Send for BlockPtr {}
unsafe impl Sync for BlockPtr {}

impl BlockPtr {
    fn get(&self) -> *mut Q8Block {
        self.0
    }
}

#[derive(Clone, Copy)]
struct PairPtr(*mut PairBlock);
// SAFETY: used only to write disjoint pair blocks from pool tasks (see `Q8Acts::quantize_for`).
unsafe impl Send for PairPtr {}
unsafe impl Sync for PairPtr {}

impl PairPtr {
    fn get(&self) -> *mut PairBlock {
        self.0
    }
}

/// `v.round()` (halves away from zero) for |v| < 2³¹, in plain arithmetic that vectorises: without
/// SSE4.1 in the baseline, `round()` is a library call per value.
#[inline(always)]
pub(crate) fn round_away(v: f32) -> i32 {
    // Held below 2³¹ (and a NaN made a number: `min` returns the other operand), so the truncation
    // below is a plain `cvttps2dq`: the saturating `as` compiled to scalar code with NaN checks
    // per value. Callers clamp far inside the range, so their results do not change.
    let a = v.abs().min(2_147_483_520.0);
    // SAFETY: 0 ≤ a + 0.5 ≤ 2³¹ - 128, which i32 holds.
    let t: i32 = unsafe { (a + 0.5).to_int_unchecked() };
    // a + 0.5 can round up to the next integer (a = 0.49999997): take it back.
    let t = t - ((t as f32 - 0.5) > a) as i32;
    if v < 0.0 {
        -t
    } else {
        t
    }
}

/// [`quantize_block_with`] as compiled for the CPU: with AVX2 the compiler vectorises it (7% of a
/// Qwen prompt's time as SSE2 code), once its maximum and rounding are written to vectorise (see
/// [`symmetric_scale`], [`round_away`]: as scalar code it was 6% of a planner node). The same IEEE
/// operations in the same order, so the same bits.
fn quantize_block(xs: &[f32]) -> Q8Block {
    #[cfg(target_arch = "x86_64")]
    if avx2::available() {
        // SAFETY: the CPU has AVX2 (checked).
        return unsafe { quantize_block_avx2(xs) };
    }
    quantize_block_with(xs)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn quantize_block_avx2(xs: &[f32]) -> Q8Block {
    quantize_block_with(xs)
}

/// The scale `d = max|x| / top` of a symmetric quantisation of `xs` to `-top..=top`, and its
/// inverse (0 for an all-zero input): the rule of the activation blocks, the attention keys and
/// the queries alike.
#[inline(always)]
pub(crate) fn symmetric_scale(xs: &[f32], top: f32) -> (f32, f32) {
    // The largest |x| as the largest bit pattern with the sign cleared: for numbers the order is the
    // same, and an integer maximum vectorises where `f32::max` (NaN rules) stays a chain of
    // scalar compares. (A NaN input gives a NaN scale.)
    let amax = f32::from_bits(xs.iter().fold(0u32, |m, x| m.max(x.to_bits() & 0x7fff_ffff)));
    let d = amax / top;
    (d, if d > 0.0 { 1.0 / d } else { 0.0 })
}

#[inline(always)]
fn quantize_block_with(xs: &[f32]) -> Q8Block {
    let (d, id) = symmetric_scale(xs, 127.0);
    let mut qs = [0i8; QK];
    let mut sum = 0i32;
    for (q, &x) in qs.iter_mut().zip(xs) {
        *q = round_away(x * id).clamp(-127, 127) as i8;
        sum += *q as i32;
    }
    Q8Block { d, s: d * sum as f32, qs }
}

/// The weight formats with integer kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Q4_1,
    Q5_0,
    Q8_0,
    Q4K,
    Q6K,
}

impl Format {
    fn from_ggml(d: GgmlDType) -> Option<Self> {
        Some(match d {
            GgmlDType::Q4_1 => Format::Q4_1,
            GgmlDType::Q5_0 => Format::Q5_0,
            GgmlDType::Q8_0 => Format::Q8_0,
            GgmlDType::Q4K => Format::Q4K,
            GgmlDType::Q6K => Format::Q6K,
            _ => return None,
        })
    }

    /// (values, bytes) per block.
    pub fn block(self) -> (usize, usize) {
        match self {
            Format::Q4_1 => (32, 20),
            Format::Q5_0 => (32, 22),
            Format::Q8_0 => (32, 34),
            Format::Q4K => (256, 144),
            Format::Q6K => (256, 210),
        }
    }
}

/// How a matrix's rows are stored.
#[derive(Clone, Debug)]
enum Storage {
    /// GGUF blocks, row after row.
    Quant { fmt: Format, data: Vec<u8>, row_bytes: usize },
    /// Plain floats, for formats without a kernel (f32/f16 and the rarer quantisations).
    F32(Vec<f32>),
}

/// A (rows × cols) weight matrix for `y = W x`, in the file's own encoding where a kernel exists.
#[derive(Clone, Debug)]
pub struct QMatrix {
    rows: usize,
    cols: usize,
    storage: Storage,
}

impl QMatrix {
    /// Takes a GGUF tensor of shape (rows, cols). Formats without a kernel, or widths that are not
    /// whole blocks, are dequantised to f32 once.
    pub fn from_qtensor(t: &QTensor) -> Result<Self> {
        let (rows, cols) = t.shape().dims2()?;
        if let Some(fmt) = Format::from_ggml(t.dtype()) {
            let (bv, bb) = fmt.block();
            if cols % bv == 0 {
                let data = t.data()?.into_owned();
                let row_bytes = cols / bv * bb;
                debug_assert_eq!(data.len(), rows * row_bytes);
                return Ok(Self { rows, cols, storage: Storage::Quant { fmt, data, row_bytes } });
            }
        }
        let w = t.dequantize(&Device::Cpu)?.flatten_all()?.to_vec1::<f32>()?;
        Ok(Self { rows, cols, storage: Storage::F32(w) })
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Bytes of weights held.
    pub fn bytes(&self) -> usize {
        match &self.storage {
            Storage::Quant { data, .. } => data.capacity(),
            Storage::F32(w) => w.capacity() * 4,
        }
    }

    pub fn cols(&self) -> usize {
        self.cols
    }

    /// The format of the integer kernel used, if any.
    pub fn format(&self) -> Option<Format> {
        match &self.storage {
            Storage::Quant { fmt, .. } => Some(*fmt),
            Storage::F32(_) => None,
        }
    }

    /// Whether this matrix multiplies quantised activations (else it wants the f32 input).
    pub fn wants_q8(&self) -> bool {
        self.format().is_some()
    }

    /// Row `r` dequantised into `out` (length `cols`): the embedding look-up.
    pub fn dequantize_row(&self, r: usize, out: &mut [f32]) {
        match &self.storage {
            Storage::Quant { fmt, data, row_bytes } => {
                scalar::dequantize_row(*fmt, &data[r * row_bytes..(r + 1) * row_bytes], out)
            }
            Storage::F32(w) => out.copy_from_slice(&w[r * self.cols..(r + 1) * self.cols]),
        }
    }

    /// Computes output rows `rows` for every token: `y[i * ld + r] = W[r] · x_i`, with x the
    /// quantised activations `q` (quantised kernels) or the floats `x` (plain storage).
    ///
    /// # Safety
    /// `y` must be valid for writes at every `i * ld + r` (i < t, r in `rows`), and no other thread
    /// may write those elements at the same time.
    pub unsafe fn compute_rows(
        &self,
        rows: std::ops::Range<usize>,
        q: &Q8Acts,
        x: &[f32],
        y: *mut f32,
        ld: usize,
        kernel: Kernel,
    ) {
        match &self.storage {
            Storage::Quant { fmt, data, row_bytes } => {
                let t = q.t;
                let row = |r: usize| &data[r * row_bytes..(r + 1) * row_bytes];
                let mut r = rows.start;
                // Few tokens (decoding): four rows at a time, so four independent sums overlap and
                // share each activation block. Results are the same as one row at a time. Not for
                // the 256-blocks: four rows of their unpacking spill registers and ran 3x slower.
                if t < 4 && !matches!(fmt, Format::Q4K | Format::Q6K) {
                    while r + 4 <= rows.end {
                        let w = [row(r), row(r + 1), row(r + 2), row(r + 3)];
                        for i in 0..t {
                            let out = dot::<4, 1>(kernel, *fmt, &w, &[q.row(i)]);
                            for (k, [v]) in out.into_iter().enumerate() {
                                *y.add(i * ld + r + k) = v;
                            }
                        }
                        r += 4;
                    }
                }
                let first = r;
                let pairs = kernel == Kernel::Avx512 && !q.pairs.is_empty();
                let group = if pairs { PAIR_GROUP } else { TOKEN_GROUP };
                // Prompts: tokens in groups, so that a group's activations stay in cache while
                // every row of the range passes over them.
                for i0 in (0..t).step_by(group) {
                    let end = (i0 + group).min(t);
                    let mut r = first;
                    while r < rows.end {
                        // AVX-512: two rows at a time share the activation loads; pairs of tokens,
                        // 16 then 8 then 2 at a time (i0 is even, so token i starts pair i / 2).
                        let nr = if pairs && r + 2 <= rows.end { 2 } else { 1 };
                        let mut i = i0;
                        if pairs {
                            i = if nr == 2 {
                                self.pairs_avx512(*fmt, &[row(r), row(r + 1)], q, i, end, r, y, ld)
                            } else {
                                self.pairs_avx512(*fmt, &[row(r)], q, i, end, r, y, ld)
                            };
                        }
                        for r in r..r + nr {
                            self.tokens(*fmt, row(r), q, i, end, r, y, ld, kernel);
                        }
                        r += nr;
                    }
                }
            }
            Storage::F32(w) => {
                let t = x.len() / self.cols;
                for r in rows {
                    let wr = &w[r * self.cols..(r + 1) * self.cols];
                    for i in 0..t {
                        *y.add(i * ld + r) = dot_f32(wr, &x[i * self.cols..(i + 1) * self.cols]);
                    }
                }
            }
        }
    }
}

impl QMatrix {
    /// Row `r` (`w`) times tokens `i..end`, eight, then four, then one at a time.
    ///
    /// # Safety
    /// As [`QMatrix::compute_rows`].
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    unsafe fn tokens(&self, fmt: Format, w: &[u8], q: &Q8Acts, mut i: usize, end: usize, r: usize, y: *mut f32, ld: usize, kernel: Kernel) {
        let w = [w];
        // Eight (then four) tokens at a time share each decoded weight block.
        while i + 8 <= end {
            let a = std::array::from_fn::<_, 8, _>(|k| q.row(i + k));
            let [out] = dot::<1, 8>(kernel, fmt, &w, &a);
            for (k, v) in out.into_iter().enumerate() {
                *y.add((i + k) * ld + r) = v;
            }
            i += 8;
        }
        while i + 4 <= end {
            let a = [q.row(i), q.row(i + 1), q.row(i + 2), q.row(i + 3)];
            let [out] = dot::<1, 4>(kernel, fmt, &w, &a);
            for (k, v) in out.into_iter().enumerate() {
                *y.add((i + k) * ld + r) = v;
            }
            i += 4;
        }
        while i < end {
            let [[v]] = dot::<1, 1>(kernel, fmt, &w, &[q.row(i)]);
            *y.add(i * ld + r) = v;
            i += 1;
        }
    }

    /// Rows `r..r + NR` (`w`) times tokens `i..` in pairs, as far as whole pairs before `end` go;
    /// returns the first token not done.
    ///
    /// # Safety
    /// As [`QMatrix::compute_rows`], and the AVX-512 kernel must be available; `q` has its pairs.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    unsafe fn pairs_avx512<const NR: usize>(
        &self,
        fmt: Format,
        w: &[&[u8]; NR],
        q: &Q8Acts,
        mut i: usize,
        end: usize,
        r: usize,
        y: *mut f32,
        ld: usize,
    ) -> usize {
        debug_assert!(i % 2 == 0);
        // Row r + k's results for tokens i..
        let store = |i: usize, k: usize, out: &[[f32; 2]]| {
            for (j, v) in out.iter().flatten().enumerate() {
                *y.add((i + j) * ld + r + k) = *v;
            }
        };
        let (s, t) = (&q.sums, q.t);
        while i + 16 <= end {
            let p = std::array::from_fn::<_, 8, _>(|j| q.pair(i / 2 + j));
            for (k, out) in avx512::dot_pairs::<NR, 8>(fmt, w, &p, &s[i..], t).iter().enumerate() {
                store(i, k, out);
            }
            i += 16;
        }
        while i + 8 <= end {
            let p = std::array::from_fn::<_, 4, _>(|j| q.pair(i / 2 + j));
            for (k, out) in avx512::dot_pairs::<NR, 4>(fmt, w, &p, &s[i..], t).iter().enumerate() {
                store(i, k, out);
            }
            i += 8;
        }
        while i + 2 <= end {
            for (k, out) in avx512::dot_pairs::<NR, 1>(fmt, w, &[q.pair(i / 2)], &s[i..], t).iter().enumerate() {
                store(i, k, out);
            }
            i += 2;
        }
        i
    }
}

/// Tokens whose activations one pass over a task's rows reuses (a multiple of 8): 32 rows of 4864
/// columns of activation blocks are ~190 KB, well inside L2 beside the rows' weights.
const TOKEN_GROUP: usize = 32;

/// The same for the AVX-512 pair kernels (one 16-token call per row): their pair blocks are twice
/// the size, and 16 tokens of a 896-wide input (28 KB) stay in L1 from row to row where 32 did not.
/// One thread, 481 tokens, 896-column Q5_0 matrices: 150 -> 183..209 Gop/s (Qwen2.5-0.5B prefill
/// CPU time -14%); AVX2 with 16: no gain.
const PAIR_GROUP: usize = 16;

/// Which implementation runs the dot products.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    Scalar,
    Avx2,
    /// AVX-512 VNNI where it has a kernel for the format, else AVX2.
    Avx512,
}

impl Kernel {
    /// The fastest implementation this CPU runs. `STEP_KERNEL=scalar` forces the portable one and
    /// `STEP_KERNEL=avx2` the AVX2 one (where the CPU has it), so every path can be run on one machine.
    pub fn detect() -> Kernel {
        let forced = std::env::var("STEP_KERNEL").ok();
        match forced.as_deref() {
            Some("scalar") => return Kernel::Scalar,
            Some("avx2") if avx2::available() => return Kernel::Avx2,
            _ => {}
        }
        if avx512::available() {
            Kernel::Avx512
        } else if avx2::available() {
            Kernel::Avx2
        } else {
            Kernel::Scalar
        }
    }

    /// The name `STEP_KERNEL` takes for this kernel.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Scalar => "scalar",
            Kernel::Avx2 => "avx2",
            Kernel::Avx512 => "avx512",
        }
    }
}

/// `NR × NT` dot products: each of `NR` weight rows with each of `NT` activation rows.
#[inline]
fn dot<const NR: usize, const NT: usize>(
    kernel: Kernel,
    fmt: Format,
    w: &[&[u8]; NR],
    a: &[&[Q8Block]; NT],
) -> [[f32; NT]; NR] {
    match kernel {
        // SAFETY: `Kernel::Avx2` is only chosen when the CPU has AVX2, FMA and F16C.
        Kernel::Avx2 => unsafe { avx2::dot::<NR, NT>(fmt, w, a) },
        // SAFETY: `Kernel::Avx512` is only chosen when the CPU has AVX-512 F/BW/VL/VNNI besides
        // the AVX2 set.
        Kernel::Avx512 if avx512::handles(fmt) => unsafe { avx512::dot::<NR, NT>(fmt, w, a) },
        Kernel::Avx512 => unsafe { avx2::dot::<NR, NT>(fmt, w, a) },
        Kernel::Scalar => w.map(|w| scalar::dot::<NT>(fmt, w, a)),
    }
}

/// A float dot product with eight independent partial sums (vectorisable, fixed order).
#[inline(always)]
pub fn dot_f32(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..8 {
            acc[l] += x[l] * y[l];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[2] + acc[6])) + ((acc[1] + acc[5]) + (acc[3] + acc[7]));
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// The final reduction of the eight lanes, in the order the SIMD code adds them.
#[inline(always)]
pub(crate) fn reduce_lanes(l: &[f32; 8]) -> f32 {
    let s = [l[0] + l[4], l[1] + l[5], l[2] + l[6], l[3] + l[7]];
    (s[0] + s[2]) + (s[1] + s[3])
}

/// f16 bits → f32 (exact), by arithmetic alone: a library call here, even on the rare path, would
/// make the compiler keep the kernels' float accumulators on the stack around it.
#[inline(always)]
pub(crate) fn f16(lo: u8, hi: u8) -> f32 {
    let h = u16::from_le_bytes([lo, hi]) as u32;
    let (sign, exp, man) = ((h & 0x8000) << 16, (h >> 10) & 0x1f, h & 0x3ff);
    if exp == 0 {
        // Zero and subnormals: man · 2⁻²⁴, exact in f32.
        let v = man as f32 * (1.0 / 16_777_216.0);
        return f32::from_bits(v.to_bits() | sign);
    }
    if exp == 31 {
        // Infinities, and NaNs made quiet (as `half` does).
        let quiet = if man != 0 { 0x0040_0000 } else { 0 };
        return f32::from_bits(sign | 0x7f80_0000 | quiet | (man << 13));
    }
    f32::from_bits(sign | ((exp + 112) << 23) | (man << 13))
}

/// Scale and minimum of sub-block `j` (0..8) of a Q4_K block from its 12 packed 6-bit bytes.
#[inline(always)]
pub(crate) fn q4k_scale_min(j: usize, s: &[u8]) -> (u8, u8) {
    if j < 4 {
        (s[j] & 63, s[j + 4] & 63)
    } else {
        ((s[j + 4] & 0xF) | ((s[j - 4] >> 6) << 4), (s[j + 4] >> 4) | ((s[j] >> 6) << 4))
    }
}

/// y (t × m.rows) = x (t × m.cols) · mᵀ for up to four matrices sharing one input, rows split across
/// the pool. `q` must hold `x` quantised when any matrix wants it.
pub fn matmul_many(mats: &[(&QMatrix, &mut [f32])], q: &Q8Acts, x: &[f32], t: usize) {
    assert!(mats.len() <= 4, "matmul_many takes at most four matrices");
    let kernel = kernel();
    let pool = pool::global();
    let threads = pool.threads();
    // Chunks of rows: enough tasks to balance a few threads (and a busy core), few enough to keep
    // the per-task overhead low. No allocation: task k maps to (matrix, chunk) arithmetically.
    let mut per = [0usize; 4];
    let mut first = [0usize; 5];
    let mut outs = [SendPtr(std::ptr::null_mut()); 4];
    for (mi, (m, y)) in mats.iter().enumerate() {
        assert_eq!(y.len(), t * m.rows, "output buffer does not match {t} tokens x {} rows", m.rows);
        per[mi] = if threads == 1 { m.rows.max(1) } else { (m.rows / (threads * 4)).max(16).div_ceil(8) * 8 };
        first[mi + 1] = first[mi] + m.rows.div_ceil(per[mi]);
        outs[mi] = SendPtr(y.as_ptr() as *mut f32);
    }
    let n_tasks = first[mats.len()];
    let run = |k: usize| {
        let mi = (0..mats.len()).find(|&i| k < first[i + 1]).unwrap_or(0);
        let m = mats[mi].0;
        let s = (k - first[mi]) * per[mi];
        let e = (s + per[mi]).min(m.rows);
        // SAFETY: tasks cover disjoint row ranges of each output, every (token, row) element of
        // `outs[mi]` lies inside its slice (checked above), and each task runs exactly once.
        unsafe { m.compute_rows(s..e, q, x, outs[mi].get(), m.rows, kernel) };
    };
    pool.run(n_tasks, &run);
}

/// One matrix: `y = x · mᵀ` (quantising `x` into `q`).
pub fn matmul(m: &QMatrix, x: &[f32], t: usize, q: &mut Q8Acts, y: &mut [f32]) {
    if m.wants_q8() {
        q.quantize(x, t, m.cols);
    }
    matmul_many(&[(m, y)], q, x, t);
}

#[derive(Clone, Copy)]
pub(crate) struct SendPtr(pub(crate) *mut f32);
// SAFETY: used only to write disjoint elements from pool tasks (see `matmul_many`).
unsafe impl Send for SendPtr {}
unsafe impl Sync for SendPtr {}

impl SendPtr {
    // A method (not a field access) so closures capture the whole Sync wrapper.
    pub(crate) fn get(&self) -> *mut f32 {
        self.0
    }
}

/// What on this CPU decides the bits of a forward pass: the kernel path, and the features the C
/// library picks its variants of `sinf` and `cosf` by (the rotary table; the exponentials are
/// ours). Prefix snapshots are keyed by it.
pub(crate) fn cpu_signature() -> String {
    #[cfg(target_arch = "x86_64")]
    let features = format!("fma={} avx512f={}", is_x86_feature_detected!("fma"), is_x86_feature_detected!("avx512f"));
    #[cfg(not(target_arch = "x86_64"))]
    let features = String::new();
    format!("{:?} {} {features}", kernel(), std::env::consts::ARCH)
}

/// The kernel chosen for this process (detected once).
pub(crate) fn kernel() -> Kernel {
    static K: std::sync::OnceLock<Kernel> = std::sync::OnceLock::new();
    *K.get_or_init(Kernel::detect)
}

#[cfg(test)]
mod tests;
