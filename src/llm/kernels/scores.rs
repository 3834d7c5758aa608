//! Attention scores as integer dot products: keys kept as 16-bit integers with one scale per
//! position and head, each query rounded to 10 bits with one scale per head, so that a score is one
//! exact integer sum turned into a float once. The portable, AVX2 (`vpmaddwd`) and AVX-512 VNNI
//! (`vpdpwssd`) paths compute the same integers, hence the same bits.
//!
//! Why: a planner node prefills ~80 tokens against ~1,200 cached positions, and the f32
//! query·key products were about half of attention's time, itself a third of the node's. VNNI does
//! two elements of 16 keys in one instruction.
//!
//! Why 16-bit keys: with 8 bits (one scale per 32 elements) Qwen2.5's logits moved 20 times
//! further from candle's than the matrices' own 8-bit rounding moves them (normalised squared
//! error 4.3e-2): qwen2's key biases put a few channels far above the others in every key, and
//! a scale set by them leaves the rest a handful of 8-bit steps. At 15 bits they keep hundreds.
//!
//! Range: a query element is at most [`QMAX`] (511, or less for heads wider than 128) and a key
//! element 32767, so a head's sum stays inside an i32.
//!
//! Layout: a layer's keys are kept in tiles of [`KEYS`] positions of one kv head, by pairs of
//! elements: element `32·g + 2·s + b` of a tile is element `2g + b` of the tile's position `s`,
//! so one 64-byte load holds two elements of all 16 keys. Beside each tile, its 16 scales.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::{round_away, symmetric_scale, Kernel};

/// Positions per tile.
pub const KEYS: usize = 16;
/// Queries scored together against a tile: they share its loads.
pub const MAX_QUERIES: usize = 4;
/// The largest key element.
const KMAX: f32 = 32767.0;
/// The largest query element for heads up to 128 wide.
const QMAX: i32 = 511;

/// The largest query element for a head of `hd`: the sum of `hd` products with keys of up to
/// 32767 must fit an i32.
fn qmax(hd: usize) -> i32 {
    QMAX.min((i32::MAX as i64 / (hd as i64 * 32767)) as i32)
}

/// The shape of one layer's tiled keys: kv heads and head width (a multiple of 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KeyTiles {
    pub nkv: usize,
    pub hd: usize,
}

impl KeyTiles {
    /// Whether keys of this head width can be tiled: whole pairs of elements, and a sum that
    /// fits with queries of at least 7 bits.
    pub fn fits(hd: usize) -> bool {
        hd > 0 && hd.is_multiple_of(4) && qmax(hd) >= 127
    }

    pub fn tile_len(self) -> usize {
        KEYS * self.hd
    }

    /// Elements and scales that hold `positions` (whole tiles).
    pub fn sizes(self, positions: usize) -> (usize, usize) {
        let tiles = positions.div_ceil(KEYS) * self.nkv;
        (tiles * self.tile_len(), tiles * KEYS)
    }

    /// The index of the tile holding position `p` of kv head `h`.
    pub fn tile(self, p: usize, h: usize) -> usize {
        p / KEYS * self.nkv + h
    }

    /// Quantises the key `x` (`hd` floats) of position `p`, kv head `h`, into its tile.
    pub fn store(self, keys: &mut [i16], scales: &mut [f32], p: usize, h: usize, x: &[f32]) {
        debug_assert_eq!(x.len(), self.hd);
        let (t, s) = (self.tile(p, h), p % KEYS);
        let (d, id) = symmetric_scale(x, KMAX);
        scales[t * KEYS + s] = d;
        let tile = &mut keys[t * self.tile_len()..][..self.tile_len()];
        for (e, &v) in x.iter().enumerate() {
            tile[e / 2 * 2 * KEYS + 2 * s + e % 2] = round_away(v * id).clamp(-32767, 32767) as i16;
        }
    }
}

/// One query, quantised: its elements (as 16-bit integers) and its scale times the score scale.
#[derive(Clone, Copy, Debug)]
pub struct Query<'a> {
    pub q: &'a [i16],
    pub w: f32,
}

/// Rows of query heads, quantised for scoring.
#[derive(Clone, Debug, Default)]
pub struct Queries {
    q: Vec<i16>,
    w: Vec<f32>,
    hd: usize,
}

impl Queries {
    /// Quantises `x` (heads of `hd` floats, one after the other), each score to be scaled by
    /// `scale`, in place of the previous content: `round(x / d)` with `d = max|x| / qmax`.
    pub fn quantize(&mut self, x: &[f32], hd: usize, scale: f32) {
        let n = x.len() / hd;
        let top = qmax(hd);
        self.hd = hd;
        self.q.resize(n * hd, 0);
        self.w.resize(n, 0.0);
        for (i, xs) in x.chunks_exact(hd).enumerate() {
            let (d, id) = symmetric_scale(xs, top as f32);
            for (q, &v) in self.q[i * hd..][..hd].iter_mut().zip(xs) {
                *q = round_away(v * id).clamp(-top, top) as i16;
            }
            self.w[i] = d * scale;
        }
    }

    /// Head `i` of the rows quantised (row-major: row `r`, head `h` is `r · heads + h`).
    pub fn get(&self, i: usize) -> Query<'_> {
        Query { q: &self.q[i * self.hd..][..self.hd], w: self.w[i] }
    }
}

/// The scores of `queries` against one tile (`tile_len` elements, `KEYS` scales): for each query
/// `u`, `KEYS` floats at `out[u]`, one per position of the tile, `S · (d_s · w)` with `S` the
/// integer sum and `d_s` the key's scale (positions past the cache's end give finite numbers to be
/// ignored).
///
/// # Safety
/// Each `out[u]` must be valid for `KEYS` writes.
pub unsafe fn tile_scores(kernel: Kernel, shape: KeyTiles, tile: &[i16], scales: &[f32], queries: &[Query], out: &[*mut f32]) {
    debug_assert!(queries.len() <= MAX_QUERIES && queries.len() == out.len());
    debug_assert!(tile.len() >= shape.tile_len() && scales.len() >= KEYS);
    match kernel {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Kernel::Avx512` is chosen only when the CPU has AVX-512 F/BW/VL/VNNI.
        Kernel::Avx512 => match queries.len() {
            4 => vnni::<4>(shape, tile, scales, queries, out),
            3 => vnni::<3>(shape, tile, scales, queries, out),
            2 => vnni::<2>(shape, tile, scales, queries, out),
            _ => vnni::<1>(shape, tile, scales, queries, out),
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Kernel::Avx2` is chosen only when the CPU has AVX2 and FMA.
        Kernel::Avx2 => match queries.len() {
            4 => avx2::<4>(shape, tile, scales, queries, out),
            3 => avx2::<3>(shape, tile, scales, queries, out),
            2 => avx2::<2>(shape, tile, scales, queries, out),
            _ => avx2::<1>(shape, tile, scales, queries, out),
        },
        _ => {
            for (q, &o) in queries.iter().zip(out) {
                portable(shape, tile, scales, q, std::slice::from_raw_parts_mut(o, KEYS));
            }
        }
    }
}

/// The definition, in plain Rust.
fn portable(shape: KeyTiles, tile: &[i16], scales: &[f32], q: &Query, out: &mut [f32]) {
    for (s, out) in out.iter_mut().enumerate() {
        let sum: i32 = (0..shape.hd).map(|e| tile[e / 2 * 2 * KEYS + 2 * s + e % 2] as i32 * q.q[e] as i32).sum();
        *out = sum as f32 * (scales[s] * q.w);
    }
}

/// VNNI: per pair of elements, one load of the tile's 16 keys serves every query, each query's
/// pair broadcast; `vpdpwssd` sums exactly.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,avx512f,avx512bw,avx512vl,avx512vnni")]
unsafe fn vnni<const N: usize>(shape: KeyTiles, tile: &[i16], scales: &[f32], queries: &[Query], out: &[*mut f32]) {
    let mut acc = [_mm512_setzero_si512(); N];
    for g in 0..shape.hd / 2 {
        let k = _mm512_loadu_si512(tile.as_ptr().add(g * 2 * KEYS).cast());
        for u in 0..N {
            let q = queries[u].q.as_ptr().add(2 * g).cast::<i32>().read_unaligned();
            acc[u] = _mm512_dpwssd_epi32(acc[u], k, _mm512_set1_epi32(q));
        }
    }
    let ks = _mm512_loadu_ps(scales.as_ptr());
    for u in 0..N {
        let t = _mm512_mul_ps(ks, _mm512_set1_ps(queries[u].w));
        _mm512_storeu_ps(out[u], _mm512_mul_ps(_mm512_cvtepi32_ps(acc[u]), t));
    }
}

/// AVX2, eight keys a register: `vpmaddwd` of a pair of elements of eight keys with the query's
/// pair, added into each key's lane.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn avx2<const N: usize>(shape: KeyTiles, tile: &[i16], scales: &[f32], queries: &[Query], out: &[*mut f32]) {
    for half in 0..2 {
        let mut acc = [_mm256_setzero_si256(); N];
        for g in 0..shape.hd / 2 {
            let k = _mm256_loadu_si256(tile.as_ptr().add(g * 2 * KEYS + half * KEYS).cast());
            for u in 0..N {
                let q = _mm256_set1_epi32(queries[u].q.as_ptr().add(2 * g).cast::<i32>().read_unaligned());
                acc[u] = _mm256_add_epi32(acc[u], _mm256_madd_epi16(k, q));
            }
        }
        let ks = _mm256_loadu_ps(scales.as_ptr().add(half * 8));
        for u in 0..N {
            let t = _mm256_mul_ps(ks, _mm256_set1_ps(queries[u].w));
            _mm256_storeu_ps(out[u].add(half * 8), _mm256_mul_ps(_mm256_cvtepi32_ps(acc[u]), t));
        }
    }
}
