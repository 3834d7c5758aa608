//! AVX-512 VNNI kernels (`vpdpbusd`: four u8·i8 products summed into each i32 lane), used when the
//! CPU reports AVX-512 F/BW/VL/VNNI. A lane of `vpdpbusd` is exactly one lane of the other paths
//! (elements `4l..4l+4` of a 32-block), and the float part is the same multiply then fused
//! multiply-add per lane and block, in block order, so results equal [`super::scalar`] bit for bit.
//!
//! `vpdpbusd` wants one operand unsigned; the offset that makes it so is taken back exactly in the
//! integer accumulator's starting value:
//! - [`dot`] (decoding: one activation block serves several weight rows) makes the *weights*
//!   unsigned (`q + K`, K = 16 for Q5_0's raw 5-bit values, 128 for Q8_0, 0 for the nibble formats)
//!   and starts each lane at `-K · Σ a` over its four activations, computed once per activation block.
//! - [`dot_pairs`] (prompts: one weight block serves many tokens) takes activations already offset
//!   to `a + 128` ([`PairBlock`]) and starts each lane at `-128 · Σ w`, computed once per weight block.
//!   Two tokens share one 512-bit register (one token per 256-bit half), so each instruction does the
//!   work of two tokens while each token's lanes keep their own order. Two weight rows per call
//!   share each activation load (the pair blocks are the bulk of the bytes read).
//!
//! Q6_K has a scale per 16 values inside the lane sums: its pair kernel multiplies bytes to 16-bit
//! pairs (`vpmaddubsw`, never saturating for these ranges) and lets `vpdpwssd` apply the scales while
//! summing into the lanes, starting at `-128 · sc · Σ w`. Its decoding (one token) is left to the
//! AVX2 kernel: with the scale multiply a VNNI version needs as many instructions per block.

use super::{q4k_scale_min, Format, PairBlock, Q8Block};

/// Whether this CPU runs these kernels (AVX-512 F/BW/VL/VNNI, plus the AVX2 set they build on).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        super::avx2::available()
            && is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512bw")
            && is_x86_feature_detected!("avx512vl")
            && is_x86_feature_detected!("avx512vnni")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether [`dot`] handles `fmt` (else the caller uses the AVX2 kernel); [`dot_pairs`] handles all.
pub fn handles(fmt: Format) -> bool {
    fmt != Format::Q6K
}

/// `NR × NT` dot products, as [`super::avx2::dot`] computes them, with 256-bit VNNI.
///
/// # Safety
/// [`available`] must hold and [`handles`]`(fmt)`; each `w[r]` must hold `a[k].len()` 32-blocks of
/// `fmt` (every `a[k]` the same length).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn dot<const NR: usize, const NT: usize>(
    fmt: Format,
    w: &[&[u8]; NR],
    a: &[&[Q8Block]; NT],
) -> [[f32; NT]; NR] {
    debug_assert!(handles(fmt));
    debug_assert!(a.iter().all(|r| r.len() == a[0].len()));
    match fmt {
        Format::Q4_1 => x86::rows::<NR, NT, 20>(w, a, 0, |p| {
            let (d, m) = x86::f16_pair(p);
            (x86::nibbles(p.add(4)), d, Some(m))
        }),
        Format::Q5_0 => x86::rows::<NR, NT, 22>(w, a, 16, |p| {
            use std::arch::x86_64::*;
            // The raw 5-bit values (q + 16): the nibble, plus 16 where the fifth bit is set.
            let qh = std::ptr::read_unaligned(p.add(2) as *const u32);
            let nib = x86::nibbles(p.add(6));
            (_mm256_mask_add_epi8(nib, qh, nib, _mm256_set1_epi8(16)), x86::f16(p), None)
        }),
        Format::Q8_0 => x86::rows::<NR, NT, 34>(w, a, 128, |p| {
            use std::arch::x86_64::*;
            // q + 128 is q with its top bit flipped.
            let q = _mm256_loadu_si256(p.add(2) as *const __m256i);
            (_mm256_xor_si256(q, _mm256_set1_epi8(-128)), x86::f16(p), None)
        }),
        Format::Q4K => x86::q4k::<NR, NT>(w, a),
        Format::Q6K => unreachable!("Q6_K is left to the AVX2 kernel"),
    }
}

/// `NR × 2 · NP` dot products of `NR` weight rows with `NP` token pairs (`p[j]`: the pair's
/// blocks; `s`: the same tokens' activation sums, `s[c * stride + k]` for token `2j + k`'s block `c`,
/// for the minimum terms). Returns each row's pairs' two results. The rows share every activation
/// load.
///
/// # Safety
/// [`available`]; every `p[j]` the same number of 32-blocks, each `w[r]` as many of `fmt`, `s` as
/// many rows of `stride` (the last row needs only `2 · NP` values). At most 8 pairs.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn dot_pairs<const NR: usize, const NP: usize>(
    fmt: Format,
    w: &[&[u8]; NR],
    p: &[&[PairBlock]; NP],
    s: &[f32],
    stride: usize,
) -> [[[f32; 2]; NP]; NR] {
    use std::arch::x86_64::*;
    use x86::WBlock;
    debug_assert!(NP <= 8);
    let nb = p[0].len();
    debug_assert!(p.iter().all(|r| r.len() == nb));
    debug_assert!(nb == 0 || s.len() >= (nb - 1) * stride + 2 * NP);
    let a = x86::Sums { s, stride };
    let m4 = _mm256_set1_epi8(0x0f);
    match fmt {
        Format::Q4_1 => x86::pairs::<NR, NP, false>(nb, p, &a, |r, c| {
            let b = w[r].as_ptr().add(c * 20);
            let (d, m) = x86::f16_pair(b);
            WBlock::plain(x86::nibbles(b.add(4)), d, Some(m))
        }),
        Format::Q5_0 => x86::pairs::<NR, NP, false>(nb, p, &a, |r, c| {
            let b = w[r].as_ptr().add(c * 22);
            // q - 16: the nibble where the fifth bit is set, else the nibble minus 16.
            let qh = std::ptr::read_unaligned(b.add(2) as *const u32);
            let nib = x86::nibbles(b.add(6));
            WBlock::plain(_mm256_mask_sub_epi8(nib, !qh, nib, _mm256_set1_epi8(16)), x86::f16(b), None)
        }),
        Format::Q8_0 => x86::pairs::<NR, NP, false>(nb, p, &a, |r, c| {
            let b = w[r].as_ptr().add(c * 34);
            WBlock::plain(_mm256_loadu_si256(b.add(2) as *const __m256i), x86::f16(b), None)
        }),
        Format::Q4K => x86::pairs::<NR, NP, false>(nb, p, &a, |r, c| {
            let (b, j) = (w[r].as_ptr().add(c / 8 * 144), c % 8);
            let (d, dmin) = x86::f16_pair(b);
            let x = _mm256_loadu_si256(b.add(16 + 32 * (j / 2)) as *const __m256i);
            // Even sub-blocks are the low nibbles, odd ones the high.
            let q = _mm256_and_si256(_mm256_srl_epi16(x, _mm_cvtsi32_si128(4 * (j & 1) as i32)), m4);
            let (sc, m) = q4k_scale_min(j, std::slice::from_raw_parts(b.add(4), 12));
            WBlock::plain(q, d * sc as f32, Some(-(dmin * m as f32)))
        }),
        Format::Q6K => x86::pairs::<NR, NP, true>(nb, p, &a, |r, c| {
            let (b, k) = (w[r].as_ptr().add(c / 8 * 210), c % 8);
            let (n, kk) = (k / 4, k % 4);
            let ql = _mm256_loadu_si256(b.add(64 * n + 32 * (kk & 1)) as *const __m256i);
            let nib = _mm256_and_si256(_mm256_srl_epi16(ql, _mm_cvtsi32_si128(4 * (kk / 2) as i32)), m4);
            let qh = _mm256_loadu_si256(b.add(128 + 32 * n) as *const __m256i);
            let hi = _mm256_and_si256(_mm256_srl_epi16(qh, _mm_cvtsi32_si128(2 * kk as i32)), _mm256_set1_epi8(3));
            let q = _mm256_sub_epi8(_mm256_or_si256(nib, _mm256_slli_epi16::<4>(hi)), _mm256_set1_epi8(32));
            // Scale 2k over each token's low eight i16 lanes (elements 0..16), 2k + 1 over the high.
            let scales = _mm512_cvtepi8_epi16(_mm256_zextsi128_si256(_mm_loadu_si128(b.add(192) as *const __m128i)));
            let ones = 0x0001_0001_0001_0001;
            let half = _mm512_set_epi64(ones, ones, 0, 0, ones, ones, 0, 0);
            let sc = _mm512_permutexvar_epi16(_mm512_add_epi16(half, _mm512_set1_epi16(2 * k as i16)), scales);
            WBlock::scaled(q, sc, x86::f16(b.add(208)))
        }),
    }
}

#[cfg(not(target_arch = "x86_64"))]
pub unsafe fn dot<const NR: usize, const NT: usize>(
    _: Format,
    _: &[&[u8]; NR],
    _: &[&[Q8Block]; NT],
) -> [[f32; NT]; NR] {
    unreachable!("the AVX-512 kernels are only selected on x86_64")
}

#[cfg(not(target_arch = "x86_64"))]
pub unsafe fn dot_pairs<const NR: usize, const NP: usize>(
    _: Format,
    _: &[&[u8]; NR],
    _: &[&[PairBlock]; NP],
    _: &[f32],
    _: usize,
) -> [[[f32; 2]; NP]; NR] {
    unreachable!("the AVX-512 kernels are only selected on x86_64")
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    //! The helpers are `inline(always)` so that they compile inside the callers, with their
    //! target features.
    use std::arch::x86_64::*;

    use super::super::{q4k_scale_min, PairBlock, Q8Block};

    // The small helpers are the AVX2 kernels' own (inlined here, under these target features).
    pub(in crate::llm::kernels) use super::super::avx2::x86::{f16, f16_pair, nibbles};
    use super::super::avx2::x86::prefetch_next;

    /// `((l0+l4)+(l2+l6)) + ((l1+l5)+(l3+l7))`, as `reduce_lanes`.
    #[inline(always)]
    unsafe fn reduce(acc: __m256) -> f32 {
        let s = _mm_add_ps(_mm256_castps256_ps128(acc), _mm256_extractf128_ps::<1>(acc));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        _mm_cvtss_f32(_mm_add_ss(s, _mm_shuffle_ps::<1>(s, s)))
    }

    /// The lane starting values `-k · Σ a` (four activations per lane) of each token's block `c`.
    #[inline(always)]
    unsafe fn offsets<const NT: usize>(a: &[&[Q8Block]; NT], c: usize, k: i32) -> [__m256i; NT] {
        // A plain loop: a closure (`array::from_fn`) would not inherit the caller's target
        // features, and the intrinsic in it became a function call.
        let mut off = [_mm256_setzero_si256(); NT];
        if k != 0 {
            for t in 0..NT {
                let av = _mm256_loadu_si256(a[t].get_unchecked(c).qs.as_ptr() as *const __m256i);
                // Σ (-k)·a needs the unsigned operand non-negative: k · Σ (-a) (|a| ≤ 127 negates).
                let neg = _mm256_sub_epi8(_mm256_setzero_si256(), av);
                off[t] = _mm256_dpbusd_epi32(_mm256_setzero_si256(), _mm256_set1_epi8(k as i8), neg);
            }
        }
        off
    }

    /// Rows of 32-blocks of `BB` bytes; `decode` gives a block's weights plus `k` (unsigned, in
    /// element order), its scale and its minimum.
    #[inline(always)]
    pub unsafe fn rows<const NR: usize, const NT: usize, const BB: usize>(
        w: &[&[u8]; NR],
        a: &[&[Q8Block]; NT],
        k: i32,
        decode: impl Fn(*const u8) -> (__m256i, f32, Option<f32>),
    ) -> [[f32; NT]; NR] {
        let mut acc = [[_mm256_setzero_ps(); NT]; NR];
        let mut mins = [[0f32; NT]; NR];
        for c in 0..a[0].len() {
            let off = offsets(a, c, k);
            for r in 0..NR {
                prefetch_next::<NR>(w[r], c * BB);
                let (q, f, min) = decode(w[r].as_ptr().add(c * BB));
                block(&mut acc[r], &mut mins[r], q, &off, a, c, f, min);
            }
        }
        finish(acc, mins)
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn block<const NT: usize>(
        acc: &mut [__m256; NT],
        mins: &mut [f32; NT],
        q: __m256i,
        off: &[__m256i; NT],
        a: &[&[Q8Block]; NT],
        c: usize,
        f: f32,
        min: Option<f32>,
    ) {
        let fv = _mm256_set1_ps(f);
        for t in 0..NT {
            let b = a[t].get_unchecked(c);
            let av = _mm256_loadu_si256(b.qs.as_ptr() as *const __m256i);
            let lanes = _mm256_dpbusd_epi32(off[t], q, av);
            let x = _mm256_mul_ps(_mm256_cvtepi32_ps(lanes), fv);
            acc[t] = _mm256_fmadd_ps(x, _mm256_set1_ps(b.d), acc[t]);
            if let Some(m) = min {
                mins[t] += m * b.s;
            }
        }
    }

    #[inline(always)]
    unsafe fn finish<const NR: usize, const NT: usize>(acc: [[__m256; NT]; NR], mins: [[f32; NT]; NR]) -> [[f32; NT]; NR] {
        let mut out = [[0f32; NT]; NR];
        for r in 0..NR {
            for t in 0..NT {
                // Formats without minimums add 0.0, as the scalar code does.
                out[r][t] = reduce(acc[r][t]) + mins[r][t];
            }
        }
        out
    }

    #[inline(always)]
    pub unsafe fn q4k<const NR: usize, const NT: usize>(w: &[&[u8]; NR], a: &[&[Q8Block]; NT]) -> [[f32; NT]; NR] {
        let m4 = _mm256_set1_epi8(0x0f);
        let mut acc = [[_mm256_setzero_ps(); NT]; NR];
        let mut mins = [[0f32; NT]; NR];
        let off = [_mm256_setzero_si256(); NT];
        for sb in 0..a[0].len() / 8 {
            for r in 0..NR {
                let b = std::slice::from_raw_parts(w[r].as_ptr().add(sb * 144), 144);
                let (d, dmin) = f16_pair(b.as_ptr());
                for jj in 0..4 {
                    let x = _mm256_loadu_si256(b.as_ptr().add(16 + 32 * jj) as *const __m256i);
                    let halves = [_mm256_and_si256(x, m4), _mm256_and_si256(_mm256_srli_epi16::<4>(x), m4)];
                    for (h, q) in halves.into_iter().enumerate() {
                        let j = 2 * jj + h;
                        let (sc, m) = q4k_scale_min(j, &b[4..16]);
                        block(&mut acc[r], &mut mins[r], q, &off, a, sb * 8 + j, d * sc as f32, Some(-(dmin * m as f32)));
                    }
                }
            }
        }
        finish(acc, mins)
    }

    /// The activation sums of the tokens of a pair group (see [`super::dot_pairs`]).
    pub struct Sums<'a> {
        pub s: &'a [f32],
        pub stride: usize,
    }

    /// A weight block as the pair kernels take it: signed values `q` (element order) in both
    /// halves, each lane's starting value `start` (which takes back the activations' +128), for
    /// formats with a scale per 16 values the i16 scale of each 16-bit pair `sc`, the block's
    /// float scale `f` and its minimum.
    #[derive(Clone, Copy)]
    pub struct WBlock {
        q: __m512i,
        sc: __m512i,
        start: __m512i,
        f: f32,
        min: Option<f32>,
    }

    impl WBlock {
        #[inline(always)]
        unsafe fn zero() -> Self {
            let z = _mm512_setzero_si512();
            Self { q: z, sc: z, start: z, f: 0.0, min: None }
        }

        /// A block without inner scales: each lane starts at `-128 · Σ q` over its four weights.
        #[inline(always)]
        pub unsafe fn plain(q: __m256i, f: f32, min: Option<f32>) -> Self {
            let q = _mm512_broadcast_i64x4(q);
            let corr = _mm512_dpbusd_epi32(_mm512_setzero_si512(), _mm512_set1_epi8(-128), q);
            Self { q, sc: _mm512_setzero_si512(), start: _mm512_sub_epi32(_mm512_setzero_si512(), corr), f, min }
        }

        /// A block with the i16 scales `sc` per 16-bit pair: each lane starts at `-128 · sc · Σ q`.
        #[inline(always)]
        pub unsafe fn scaled(q: __m256i, sc: __m512i, f: f32) -> Self {
            let q = _mm512_broadcast_i64x4(q);
            // 128 · (q + q') pairs (|·| ≤ 8192) times -sc (≤ 128).
            let q128 = _mm512_maddubs_epi16(_mm512_set1_epi8(-128), q);
            let start = _mm512_dpwssd_epi32(_mm512_setzero_si512(), q128, _mm512_sub_epi16(_mm512_setzero_si512(), sc));
            Self { q, sc, start, f, min: None }
        }
    }

    /// `NR` rows of `nb` 32-blocks against `NP` pairs; `decode(r, c)` gives row `r`'s block `c`.
    /// `SCALED`: the blocks have scales per 16 values ([`WBlock::scaled`]). Per row and pair: the
    /// lanes (one token per 256-bit half); per row: the minimum terms (token `k` in lane `k`: each
    /// is the same product then sum per block as elsewhere).
    #[inline(always)]
    pub unsafe fn pairs<const NR: usize, const NP: usize, const SCALED: bool>(
        nb: usize,
        p: &[&[PairBlock]; NP],
        a: &Sums,
        decode: impl Fn(usize, usize) -> WBlock,
    ) -> [[[f32; 2]; NP]; NR] {
        let mut acc = [[_mm512_setzero_ps(); NP]; NR];
        let mut mins = [_mm512_setzero_ps(); NR];
        for c in 0..nb {
            // A plain loop: a closure (`array::from_fn`) would not inherit the target features.
            let mut wb = [WBlock::zero(); NR];
            for r in 0..NR {
                wb[r] = decode(r, c);
            }
            for j in 0..NP {
                let b = p[j].get_unchecked(c);
                let av = _mm512_load_si512(b.qs.as_ptr() as *const _);
                let d = _mm512_load_ps(b.d.as_ptr());
                for r in 0..NR {
                    let lanes = if SCALED {
                        // (a + 128) · q pairs: at most 2 · 255 · 32 in magnitude, inside i16.
                        _mm512_dpwssd_epi32(wb[r].start, _mm512_maddubs_epi16(av, wb[r].q), wb[r].sc)
                    } else {
                        _mm512_dpbusd_epi32(wb[r].start, av, wb[r].q)
                    };
                    let x = _mm512_mul_ps(_mm512_cvtepi32_ps(lanes), _mm512_set1_ps(wb[r].f));
                    acc[r][j] = _mm512_fmadd_ps(x, d, acc[r][j]);
                }
            }
            if wb.iter().any(|b| b.min.is_some()) {
                // The masked-off lanes are not read.
                let s = _mm512_maskz_loadu_ps(((1u32 << (2 * NP)) - 1) as u16, a.s.as_ptr().add(c * a.stride));
                for r in 0..NR {
                    if let Some(m) = wb[r].min {
                        mins[r] = _mm512_add_ps(mins[r], _mm512_mul_ps(_mm512_set1_ps(m), s));
                    }
                }
            }
        }
        let mut out = [[[0f32; 2]; NP]; NR];
        for r in 0..NR {
            let mut m = [0f32; 16];
            _mm512_storeu_ps(m.as_mut_ptr(), mins[r]);
            for j in 0..NP {
                let lo = _mm512_castps512_ps256(acc[r][j]);
                let hi = _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(_mm512_castps_pd(acc[r][j])));
                // Formats without minimums add 0.0, as the scalar code does.
                out[r][j] = [reduce(lo) + m[2 * j], reduce(hi) + m[2 * j + 1]];
            }
        }
        out
    }
}
