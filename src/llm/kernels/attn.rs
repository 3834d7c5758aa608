//! The two float loops of attention, a query·key dot product and the probability-weighted sum of
//! values, written once as portable code and once with AVX2/FMA intrinsics that compute the same
//! bits: both use fused multiply-adds in the same order. Left to the auto-vectoriser these loops
//! came out two floats wide, with the output row going through memory for every key.

use super::reduce_lanes;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// The loops; the caller's attention code is generic over the implementation, so the AVX2 one
/// inlines into a function compiled with those features.
pub trait AttnOps {
    /// `Σ a·b` (equal lengths): lane `l` accumulates elements `8c + l` with fused multiply-adds,
    /// the lanes reduce as [`reduce_lanes`], then any tail elements are fused in, in order.
    ///
    /// # Safety
    /// The implementation's CPU features must be present.
    unsafe fn dot(a: &[f32], b: &[f32]) -> f32;

    /// Eight [`AttnOps::dot`]s of `a` with `b[0..8]`, each the same bits as alone. One dot is a
    /// single chain of dependent multiply-adds (latency-bound); eight independent chains keep both
    /// FMA pipes busy, and their lane reductions share their shuffles.
    ///
    /// # Safety
    /// As [`AttnOps::dot`].
    unsafe fn dot8(a: &[f32], b: [&[f32]; 8]) -> [f32; 8];

    /// For every element `e` of `y`: `y[e] = fma(p[j], values[j * stride + e], y[e])` for each `j`
    /// in order.
    ///
    /// # Safety
    /// As [`AttnOps::dot`]; `values` must hold `(p.len() - 1) * stride + y.len()` floats.
    unsafe fn weighted_sum(y: &mut [f32], p: &[f32], values: &[f32], stride: usize);
}

/// Plain Rust, for any CPU.
pub struct Portable;

impl AttnOps for Portable {
    #[inline(always)]
    unsafe fn dot(a: &[f32], b: &[f32]) -> f32 {
        let mut acc = [0f32; 8];
        let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
        let (ra, rb) = (ca.remainder(), cb.remainder());
        for (x, y) in ca.zip(cb) {
            for l in 0..8 {
                acc[l] = x[l].mul_add(y[l], acc[l]);
            }
        }
        let mut s = reduce_lanes(&acc);
        for (x, y) in ra.iter().zip(rb) {
            s = x.mul_add(*y, s);
        }
        s
    }

    #[inline(always)]
    unsafe fn dot8(a: &[f32], b: [&[f32]; 8]) -> [f32; 8] {
        b.map(|b| Self::dot(a, b))
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
    /// The lane sums of `a·b[k]` over the whole eight-float chunks (lane `l` takes elements
    /// `8c + l`, fused in order), and the range of tail elements left for the caller.
    #[inline(always)]
    unsafe fn lane_sums<const K: usize>(a: &[f32], b: [&[f32]; K]) -> ([__m256; K], std::ops::Range<usize>) {
        let n = b.iter().fold(a.len(), |n, b| n.min(b.len()));
        let mut acc = [_mm256_setzero_ps(); K];
        let mut c = 0;
        while c + 8 <= n {
            let x = _mm256_loadu_ps(a.as_ptr().add(c));
            for (acc, b) in acc.iter_mut().zip(b) {
                *acc = _mm256_fmadd_ps(x, _mm256_loadu_ps(b.as_ptr().add(c)), *acc);
            }
            c += 8;
        }
        (acc, c..n)
    }

    /// `s` with the tail elements of `a·b` fused in, in order.
    #[inline(always)]
    unsafe fn fuse_tail(mut s: f32, a: &[f32], b: &[f32], tail: std::ops::Range<usize>) -> f32 {
        for e in tail {
            s = a.get_unchecked(e).mul_add(*b.get_unchecked(e), s);
        }
        s
    }
}

#[cfg(target_arch = "x86_64")]
impl AttnOps for Avx2 {
    #[inline(always)]
    unsafe fn dot(a: &[f32], b: &[f32]) -> f32 {
        let ([acc], tail) = Self::lane_sums(a, [b]);
        // ((l0+l4)+(l2+l6)) + ((l1+l5)+(l3+l7)), as `reduce_lanes`.
        let s = _mm_add_ps(_mm256_castps256_ps128(acc), _mm256_extractf128_ps::<1>(acc));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        Self::fuse_tail(_mm_cvtss_f32(_mm_add_ss(s, _mm_shuffle_ps::<1>(s, s))), a, b, tail)
    }

    #[inline(always)]
    unsafe fn dot8(a: &[f32], b: [&[f32]; 8]) -> [f32; 8] {
        let (acc, tail) = Self::lane_sums(a, b);
        // The reductions of `dot`, eight keys side by side; every sum has the same two operands
        // as there. m = lo + hi half of each key: [m(k) | m(k+1)] per pair of keys.
        let m = |k: usize| {
            let lo = _mm256_permute2f128_ps::<0x20>(acc[k], acc[k + 1]);
            let hi = _mm256_permute2f128_ps::<0x31>(acc[k], acc[k + 1]);
            _mm256_add_ps(lo, hi)
        };
        let (m01, m23, m45, m67) = (m(0), m(2), m(4), m(6));
        // n = (m0 + m2, m1 + m3) of each key: [k0 k2 | k1 k3] and [k4 k6 | k5 k7].
        let pairs = |x: __m256, y: __m256| {
            _mm256_add_ps(_mm256_shuffle_ps::<0b01_00_01_00>(x, y), _mm256_shuffle_ps::<0b11_10_11_10>(x, y))
        };
        let (n0, n1) = (pairs(m01, m23), pairs(m45, m67));
        // n0 + n1 of each key: [k0 k2 k4 k6 | k1 k3 k5 k7], then into key order.
        let r = _mm256_add_ps(_mm256_shuffle_ps::<0b10_00_10_00>(n0, n1), _mm256_shuffle_ps::<0b11_01_11_01>(n0, n1));
        let r = _mm256_permutevar8x32_ps(r, _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7));
        let mut out = [0f32; 8];
        _mm256_storeu_ps(out.as_mut_ptr(), r);
        for (s, b) in out.iter_mut().zip(b) {
            *s = Self::fuse_tail(*s, a, b, tail.clone());
        }
        out
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
