//! The float loops of attention (the softmax of a row of scores, the probability-weighted sum of
//! values; the scores themselves are integer products, [`super::scores`]), written once as portable
//! code and once with AVX2/FMA intrinsics that compute the same bits: both use the same operations
//! in the same order. Left to the auto-vectoriser the sum came out two floats wide, with the output
//! row going through memory for every key; the softmax called the C library's `expf` once a score
//! (a sixth of a planner node's time), whose bits also depend on which C library the robot has and
//! which variant it picks for the CPU. The FFN's SiLU gate (`silu_gate`) is here too: it takes the same
//! exponential.

use super::reduce_lanes;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// The loops; the caller's attention code is generic over the implementation, so the AVX2 one
/// inlines into a function compiled with those features.
pub trait AttnOps {
    /// In place, `row[j] = e_j / Σ e`, where `e_j` is [`exp_le0`] of `row[j] - max(row)` and the sum
    /// runs in eight lanes (lane `l` takes elements `8c + l` in order), reduced as
    /// [`reduce_lanes`], then any tail elements added in order.
    ///
    /// # Safety
    /// The implementation's CPU features must be present; `row` is not empty.
    unsafe fn softmax(row: &mut [f32]);

    /// For every element `e` of `y`: `y[e] = fma(p[j], values[j * stride + e], y[e])` for each `j`
    /// in order.
    ///
    /// # Safety
    /// As [`AttnOps::softmax`]; `values` must hold `(p.len() - 1) * stride + y.len()` floats.
    unsafe fn weighted_sum(y: &mut [f32], p: &[f32], values: &[f32], stride: usize);

    /// [`AttnOps::weighted_sum`] for up to [`SUMS`] outputs over the same `keys` rows of values:
    /// `ys[u]` (`hd` floats) takes `ps[u]` (`keys` floats). Each output's bits are those of its own
    /// `weighted_sum`; an implementation may share each load of a value row between them.
    ///
    /// # Safety
    /// As [`AttnOps::weighted_sum`], for each pair; the outputs do not overlap.
    // Always inlined: called from a function compiled with the CPU's features, the intrinsics of
    // an implementation's `weighted_sum` then inline too. Left a function of its own (no target
    // features), each AVX2 fused multiply-add in it became a call: half of prefill's time on a CPU
    // without AVX-512, whose loops override this one.
    #[inline(always)]
    unsafe fn weighted_sums(ys: &[*mut f32], ps: &[*const f32], keys: usize, hd: usize, values: &[f32], stride: usize) {
        for (&y, &p) in ys.iter().zip(ps) {
            Self::weighted_sum(std::slice::from_raw_parts_mut(y, hd), std::slice::from_raw_parts(p, keys), values, stride);
        }
    }
}

/// The most outputs one [`AttnOps::weighted_sums`] call takes: four 64-wide heads are sixteen
/// 512-bit accumulators, half the registers, leaving room for a value row and the probabilities.
pub const SUMS: usize = 4;

/// Below this the softmax's exponential is 0: `e^-87` is the last power of e that is a normal
/// float, and beside the row's largest term (1) nothing smaller counts.
const EXP_FLOOR: f32 = -87.0;
/// ln 2 in two parts (Cody and Waite): `n · LN2_HI` is exact for every `n` that occurs.
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;
/// The Taylor coefficients 1/k! of eˣ for k = 7 down to 2: on |r| ≤ ln2/2 the first term left out
/// is below 10⁻⁸, under half an ulp.
const EXP_POLY: [f32; 6] = [1.0 / 5040.0, 1.0 / 720.0, 1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5];

/// `eˣ` for `x ≤ 0` (0 below [`EXP_FLOOR`], and for NaN): `x = n·ln2 + r`, `eˣ = 2ⁿ·p(r)`, with
/// `p` the degree-7 Taylor polynomial by fused multiply-adds. Within a few ulps of the true value;
/// what matters more is that every CPU and C library gets the same bits, and that the AVX2 loop
/// below computes exactly this.
#[inline(always)]
pub fn exp_le0(x: f32) -> f32 {
    if !(x >= EXP_FLOOR) {
        return 0.0;
    }
    let n = (x * std::f32::consts::LOG2_E).round_ties_even();
    let r = n.mul_add(-LN2_LO, n.mul_add(-LN2_HI, x));
    let mut p = EXP_POLY[0];
    for c in &EXP_POLY[1..] {
        p = p.mul_add(r, *c);
    }
    p = p.mul_add(r, 1.0);
    p = p.mul_add(r, 1.0);
    // 2ⁿ for n in -126..=0, by its bits.
    p * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// SwiGLU's gate in place: `g = silu(g) · u`, with `silu(x) = x · σ(x)` and the logistic σ
/// from [`exp_le0`] of `-|x|` (`1/(1+e)` for `x ≥ 0`, `e/(1+e)` below), so the FFN's bits too are
/// the same on every C library. The AVX2 loop is chosen when the kernels are.
pub fn silu_gate(g: &mut [f32], u: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    if matches!(super::kernel(), super::Kernel::Avx2 | super::Kernel::Avx512) {
        // SAFETY: those kernels are chosen only when the CPU has AVX2 and FMA.
        return unsafe { Avx2::silu_gate(g, u) };
    }
    silu_gate_portable(g, u)
}

#[inline(always)]
fn silu_gate_portable(g: &mut [f32], u: &[f32]) {
    for (x, u) in g.iter_mut().zip(u) {
        // -|x| as `min(x, 0 - x)`: the AVX2 loop's operation (-0.0 for x = 0 either way).
        let e = exp_le0(x.min(0.0 - *x));
        let num = if *x >= 0.0 { 1.0 } else { e };
        *x = *x * (num / (1.0 + e)) * u;
    }
}

/// Plain Rust, for any CPU.
pub struct Portable;

impl AttnOps for Portable {
    #[inline(always)]
    unsafe fn softmax(row: &mut [f32]) {
        let max = row.iter().fold(f32::NEG_INFINITY, |m, &s| m.max(s));
        let mut acc = [0f32; 8];
        let mut chunks = row.chunks_exact_mut(8);
        for x in &mut chunks {
            for l in 0..8 {
                x[l] = exp_le0(x[l] - max);
                acc[l] += x[l];
            }
        }
        let mut sum = reduce_lanes(&acc);
        for x in chunks.into_remainder() {
            *x = exp_le0(*x - max);
            sum += *x;
        }
        let inv = 1.0 / sum;
        row.iter_mut().for_each(|p| *p *= inv);
    }

    #[inline(always)]
    unsafe fn weighted_sum(y: &mut [f32], p: &[f32], values: &[f32], stride: usize) {
        let hd = y.len();
        for (j, &pj) in p.iter().enumerate() {
            for (yo, &v) in y.iter_mut().zip(&values[j * stride..][..hd]) {
                *yo = pj.mul_add(v, *yo);
            }
        }
    }
}

/// AVX2/FMA intrinsics; only to be used where the CPU has both.
#[cfg(target_arch = "x86_64")]
pub struct Avx2;

#[cfg(target_arch = "x86_64")]
impl Avx2 {
    /// [`exp_le0`] of each lane, each operation as there.
    #[inline(always)]
    unsafe fn exp_le0(v: __m256) -> __m256 {
        let k = _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(_mm256_mul_ps(
            v,
            _mm256_set1_ps(std::f32::consts::LOG2_E),
        ));
        let r = _mm256_fmadd_ps(k, _mm256_set1_ps(-LN2_LO), _mm256_fmadd_ps(k, _mm256_set1_ps(-LN2_HI), v));
        let one = _mm256_set1_ps(1.0);
        let mut p = _mm256_set1_ps(EXP_POLY[0]);
        for co in &EXP_POLY[1..] {
            p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(*co));
        }
        p = _mm256_fmadd_ps(p, r, one);
        p = _mm256_fmadd_ps(p, r, one);
        // 2ⁿ by its bits (garbage below the floor, masked next).
        let scale =
            _mm256_castsi256_ps(_mm256_slli_epi32::<23>(_mm256_add_epi32(_mm256_cvtps_epi32(k), _mm256_set1_epi32(127))));
        // 0 where not v ≥ floor (NaN included), as `exp_le0`.
        _mm256_and_ps(_mm256_mul_ps(p, scale), _mm256_cmp_ps::<_CMP_GE_OQ>(v, _mm256_set1_ps(EXP_FLOOR)))
    }

    /// [`silu_gate`] eight at a time, each operation as there.
    #[target_feature(enable = "avx2,fma")]
    unsafe fn silu_gate(g: &mut [f32], u: &[f32]) {
        let n = g.len().min(u.len());
        let (zero, one) = (_mm256_setzero_ps(), _mm256_set1_ps(1.0));
        let mut c = 0;
        while c + 8 <= n {
            let x = _mm256_loadu_ps(g.as_ptr().add(c));
            // -|x|, then the numerator: 1 where x ≥ 0, else e.
            let e = Self::exp_le0(_mm256_min_ps(x, _mm256_sub_ps(zero, x)));
            let num = _mm256_blendv_ps(e, one, _mm256_cmp_ps::<_CMP_GE_OQ>(x, zero));
            let s = _mm256_div_ps(num, _mm256_add_ps(one, e));
            let y = _mm256_mul_ps(_mm256_mul_ps(x, s), _mm256_loadu_ps(u.as_ptr().add(c)));
            _mm256_storeu_ps(g.as_mut_ptr().add(c), y);
            c += 8;
        }
        silu_gate_portable(&mut g[c..n], &u[c..n]);
    }

}

#[cfg(target_arch = "x86_64")]
impl AttnOps for Avx2 {
    #[inline(always)]
    unsafe fn softmax(row: &mut [f32]) {
        let (n, x) = (row.len(), row.as_mut_ptr());
        // The maximum: any order gives the same value, so four independent chains (one chain
        // waited on each max's latency: a tenth of attention's float time).
        let mut m = [_mm256_set1_ps(f32::NEG_INFINITY); 4];
        let mut c = 0;
        while c + 32 <= n {
            for (u, mu) in m.iter_mut().enumerate() {
                *mu = _mm256_max_ps(*mu, _mm256_loadu_ps(x.add(c + 8 * u)));
            }
            c += 32;
        }
        while c + 8 <= n {
            m[0] = _mm256_max_ps(m[0], _mm256_loadu_ps(x.add(c)));
            c += 8;
        }
        let m8 = _mm256_max_ps(_mm256_max_ps(m[0], m[1]), _mm256_max_ps(m[2], m[3]));
        let mut lanes = [0f32; 8];
        _mm256_storeu_ps(lanes.as_mut_ptr(), m8);
        let max = row[c..].iter().chain(&lanes).fold(f32::NEG_INFINITY, |m, &s| m.max(s));
        let maxv = _mm256_set1_ps(max);
        let mut acc = _mm256_setzero_ps();
        let mut c = 0;
        while c + 8 <= n {
            let e = Self::exp_le0(_mm256_sub_ps(_mm256_loadu_ps(x.add(c)), maxv));
            _mm256_storeu_ps(x.add(c), e);
            acc = _mm256_add_ps(acc, e);
            c += 8;
        }
        _mm256_storeu_ps(lanes.as_mut_ptr(), acc);
        let mut sum = reduce_lanes(&lanes);
        for e in row[c..].iter_mut() {
            *e = exp_le0(*e - max);
            sum += *e;
        }
        let inv = _mm256_set1_ps(1.0 / sum);
        let mut c = 0;
        while c + 8 <= n {
            _mm256_storeu_ps(x.add(c), _mm256_mul_ps(_mm256_loadu_ps(x.add(c)), inv));
            c += 8;
        }
        let inv = 1.0 / sum;
        row[c..].iter_mut().for_each(|p| *p *= inv);
    }

    #[inline(always)]
    unsafe fn weighted_sum(y: &mut [f32], p: &[f32], values: &[f32], stride: usize) {
        debug_assert!(p.is_empty() || values.len() >= (p.len() - 1) * stride + y.len());
        let (hd, v) = (y.len(), values.as_ptr());
        let mut e = 0;
        // 64 outputs at a time stay in eight registers across all the keys.
        while e + 64 <= hd {
            let mut acc: [__m256; 8] = std::array::from_fn(|c| _mm256_loadu_ps(y.as_ptr().add(e + 8 * c)));
            for (j, &pj) in p.iter().enumerate() {
                let pv = _mm256_set1_ps(pj);
                let row = v.add(j * stride + e);
                for (c, a) in acc.iter_mut().enumerate() {
                    *a = _mm256_fmadd_ps(pv, _mm256_loadu_ps(row.add(8 * c)), *a);
                }
            }
            for (c, a) in acc.iter().enumerate() {
                _mm256_storeu_ps(y.as_mut_ptr().add(e + 8 * c), *a);
            }
            e += 64;
        }
        while e + 8 <= hd {
            let mut acc = _mm256_loadu_ps(y.as_ptr().add(e));
            for (j, &pj) in p.iter().enumerate() {
                acc = _mm256_fmadd_ps(_mm256_set1_ps(pj), _mm256_loadu_ps(v.add(j * stride + e)), acc);
            }
            _mm256_storeu_ps(y.as_mut_ptr().add(e), acc);
            e += 8;
        }
        for (e, yo) in y.iter_mut().enumerate().skip(e) {
            for (j, &pj) in p.iter().enumerate() {
                *yo = pj.mul_add(*v.add(j * stride + e), *yo);
            }
        }
    }
}

/// AVX-512 (F): the softmax sixteen lanes wide, its sum still in the AVX2 loop's eight lanes and
/// order (each sixteen exponentials are added as their first eight, then their last eight), and
/// weighted sums that share each value row between up to
/// [`SUMS`] (row, head) pairs: per key, four 16-wide loads feed sixteen fused multiply-adds, where
/// the AVX2 loop loads a row once for every eight. Each element is still one chain of fmas over the
/// keys in order, so the bits are the portable loop's. Only to be used where the CPU has AVX-512F.
#[cfg(target_arch = "x86_64")]
pub struct Avx512;

#[cfg(target_arch = "x86_64")]
impl Avx512 {
    /// [`Avx2::exp_le0`] on sixteen lanes, each operation as there.
    #[inline(always)]
    unsafe fn exp_le0(v: __m512) -> __m512 {
        let k = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(_mm512_mul_ps(
            v,
            _mm512_set1_ps(std::f32::consts::LOG2_E),
        ));
        let r = _mm512_fmadd_ps(k, _mm512_set1_ps(-LN2_LO), _mm512_fmadd_ps(k, _mm512_set1_ps(-LN2_HI), v));
        let one = _mm512_set1_ps(1.0);
        let mut p = _mm512_set1_ps(EXP_POLY[0]);
        for co in &EXP_POLY[1..] {
            p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(*co));
        }
        p = _mm512_fmadd_ps(p, r, one);
        p = _mm512_fmadd_ps(p, r, one);
        let scale =
            _mm512_castsi512_ps(_mm512_slli_epi32::<23>(_mm512_add_epi32(_mm512_cvtps_epi32(k), _mm512_set1_epi32(127))));
        // +0 where not v ≥ floor (NaN included), as the AVX2 mask.
        _mm512_maskz_mul_ps(_mm512_cmp_ps_mask::<_CMP_GE_OQ>(v, _mm512_set1_ps(EXP_FLOOR)), p, scale)
    }

    /// `N` outputs over `keys` rows: 64 elements at a time in four registers each, then 16 at a
    /// time, then the tail element by element.
    #[inline(always)]
    unsafe fn sums<const N: usize>(ys: &[*mut f32], ps: &[*const f32], keys: usize, hd: usize, values: &[f32], stride: usize) {
        debug_assert!(ys.len() == N && ps.len() == N);
        debug_assert!(keys == 0 || values.len() >= (keys - 1) * stride + hd);
        let v = values.as_ptr();
        let mut e = 0;
        while e + 64 <= hd {
            Self::block::<N, 4>(ys, ps, keys, v, stride, e);
            e += 64;
        }
        while e + 16 <= hd {
            Self::block::<N, 1>(ys, ps, keys, v, stride, e);
            e += 16;
        }
        for u in 0..N {
            for e in e..hd {
                let y = ys[u].add(e);
                for j in 0..keys {
                    *y = (*ps[u].add(j)).mul_add(*v.add(j * stride + e), *y);
                }
            }
        }
    }

    /// Elements `e..e + 16·C` of the `N` outputs, in `C` registers each, over every key.
    /// No closures here (`array::from_fn`): a closure does not inherit the caller's target
    /// features, and each intrinsic inside one became a call.
    #[inline(always)]
    unsafe fn block<const N: usize, const C: usize>(ys: &[*mut f32], ps: &[*const f32], keys: usize, v: *const f32, stride: usize, e: usize) {
        let mut acc = [[_mm512_setzero_ps(); C]; N];
        for u in 0..N {
            for c in 0..C {
                acc[u][c] = _mm512_loadu_ps(ys[u].add(e + 16 * c));
            }
        }
        let mut vr = [_mm512_setzero_ps(); C];
        for j in 0..keys {
            let row = v.add(j * stride + e);
            for c in 0..C {
                vr[c] = _mm512_loadu_ps(row.add(16 * c));
            }
            for u in 0..N {
                let pv = _mm512_set1_ps(*ps[u].add(j));
                for c in 0..C {
                    acc[u][c] = _mm512_fmadd_ps(pv, vr[c], acc[u][c]);
                }
            }
        }
        for u in 0..N {
            for c in 0..C {
                _mm512_storeu_ps(ys[u].add(e + 16 * c), acc[u][c]);
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl AttnOps for Avx512 {
    #[inline(always)]
    unsafe fn softmax(row: &mut [f32]) {
        let (n, x) = (row.len(), row.as_mut_ptr());
        let mut m = [_mm512_set1_ps(f32::NEG_INFINITY); 4];
        let mut c = 0;
        while c + 64 <= n {
            for (u, mu) in m.iter_mut().enumerate() {
                *mu = _mm512_max_ps(*mu, _mm512_loadu_ps(x.add(c + 16 * u)));
            }
            c += 64;
        }
        while c + 16 <= n {
            m[0] = _mm512_max_ps(m[0], _mm512_loadu_ps(x.add(c)));
            c += 16;
        }
        let mut lanes = [0f32; 16];
        _mm512_storeu_ps(lanes.as_mut_ptr(), _mm512_max_ps(_mm512_max_ps(m[0], m[1]), _mm512_max_ps(m[2], m[3])));
        let max = row[c..].iter().chain(&lanes).fold(f32::NEG_INFINITY, |m, &s| m.max(s));
        let maxv = _mm512_set1_ps(max);
        let mut acc = _mm256_setzero_ps();
        let mut c = 0;
        while c + 16 <= n {
            let e = Self::exp_le0(_mm512_sub_ps(_mm512_loadu_ps(x.add(c)), maxv));
            _mm512_storeu_ps(x.add(c), e);
            acc = _mm256_add_ps(acc, _mm512_castps512_ps256(e));
            acc = _mm256_add_ps(acc, _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(_mm512_castps_pd(e))));
            c += 16;
        }
        if c + 8 <= n {
            let e = Avx2::exp_le0(_mm256_sub_ps(_mm256_loadu_ps(x.add(c)), _mm256_set1_ps(max)));
            _mm256_storeu_ps(x.add(c), e);
            acc = _mm256_add_ps(acc, e);
            c += 8;
        }
        let mut lanes = [0f32; 8];
        _mm256_storeu_ps(lanes.as_mut_ptr(), acc);
        let mut sum = reduce_lanes(&lanes);
        for e in row[c..].iter_mut() {
            *e = exp_le0(*e - max);
            sum += *e;
        }
        let inv = 1.0 / sum;
        let invv = _mm512_set1_ps(inv);
        let mut c = 0;
        while c + 16 <= n {
            _mm512_storeu_ps(x.add(c), _mm512_mul_ps(_mm512_loadu_ps(x.add(c)), invv));
            c += 16;
        }
        row[c..].iter_mut().for_each(|p| *p *= inv);
    }

    #[inline(always)]
    unsafe fn weighted_sum(y: &mut [f32], p: &[f32], values: &[f32], stride: usize) {
        Self::sums::<1>(&[y.as_mut_ptr()], &[p.as_ptr()], p.len(), y.len(), values, stride)
    }

    #[inline(always)]
    unsafe fn weighted_sums(ys: &[*mut f32], ps: &[*const f32], keys: usize, hd: usize, values: &[f32], stride: usize) {
        match ys.len() {
            4 => Self::sums::<4>(ys, ps, keys, hd, values, stride),
            3 => Self::sums::<3>(ys, ps, keys, hd, values, stride),
            2 => Self::sums::<2>(ys, ps, keys, hd, values, stride),
            1 => Self::sums::<1>(ys, ps, keys, hd, values, stride),
            // Not by recursion: a recursive function is not inlined into the caller compiled with
            // the CPU's features, and its intrinsics become calls.
            _ => {
                for (y, p) in ys.iter().zip(ps) {
                    Self::sums::<1>(std::slice::from_ref(y), std::slice::from_ref(p), keys, hd, values, stride);
                }
            }
        }
    }
}
