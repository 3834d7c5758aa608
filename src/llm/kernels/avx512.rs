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
//!   work of two tokens while each token's lanes keep their own order.
//!
//! Q6_K has a scale per 16 values inside the lane sums: its pair kernel multiplies bytes to 16-bit
//! pairs (`vpmaddubsw`, never saturating for these ranges) and lets `vpdpwssd` apply the scales while
//! summing into the lanes, starting at `-128 · sc · Σ w`. Its decoding (one token) is left to the
//! AVX2 kernel: with the scale multiply a VNNI version needs as many instructions per block.

use super::{Format, PairBlock, Q8Block};

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

/// `2 · NP` dot products of one weight row with `NP` token pairs (`p[j]`: the pair's blocks; `s`:
/// the same tokens' activation sums, `s[c * stride + k]` for token `2j + k`'s block `c`, for the
/// minimum terms). Returns each pair's two results.
///
/// # Safety
/// [`available`]; each `w` must hold `p[j].len()` 32-blocks of `fmt`, every `p[j]` the same number of blocks as `w` holds, `s` as many rows of `stride`
/// (the last row needs only `2 · NP` values). At most 8 pairs.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn dot_pairs<const NP: usize>(
    fmt: Format,
    w: &[u8],
    p: &[&[PairBlock]; NP],
    s: &[f32],
    stride: usize,
) -> [[f32; 2]; NP] {
    use std::arch::x86_64::*;
    debug_assert!(NP <= 8);
    debug_assert!(p.iter().all(|r| r.len() == p[0].len()));
    debug_assert!(p[0].is_empty() || s.len() >= (p[0].len() - 1) * stride + 2 * NP);
    let a = x86::Sums { s, stride };
    match fmt {
        Format::Q4_1 => x86::pairs::<NP, 20>(w, p, &a, |p| {
            let (d, m) = x86::f16_pair(p);
            (x86::nibbles(p.add(4)), d, Some(m))
        }),
        Format::Q5_0 => x86::pairs::<NP, 22>(w, p, &a, |p| {
            // q - 16: the nibble where the fifth bit is set, else the nibble minus 16.
            let qh = std::ptr::read_unaligned(p.add(2) as *const u32);
            let nib = x86::nibbles(p.add(6));
            (_mm256_mask_sub_epi8(nib, !qh, nib, _mm256_set1_epi8(16)), x86::f16(p), None)
        }),
        Format::Q8_0 => {
            x86::pairs::<NP, 34>(w, p, &a, |p| (_mm256_loadu_si256(p.add(2) as *const __m256i), x86::f16(p), None))
        }
        Format::Q4K => x86::q4k_pairs::<NP>(w, p, &a),
        Format::Q6K => x86::q6k_pairs::<NP>(w, p),
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
pub unsafe fn dot_pairs<const NP: usize>(_: Format, _: &[u8], _: &[&[PairBlock]; NP], _: &[f32], _: usize) -> [[f32; 2]; NP] {
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

    /// Accumulators for `NP` token pairs: the lanes (one token per 256-bit half) and the minimum
    /// terms (token `k` in lane `k`: each is the same product then sum per block as elsewhere).
    pub struct Pairs<const NP: usize> {
        acc: [__m512; NP],
        mins: __m512,
    }

    impl<const NP: usize> Pairs<NP> {
        #[inline(always)]
        unsafe fn new() -> Self {
            Self { acc: [_mm512_setzero_ps(); NP], mins: _mm512_setzero_ps() }
        }

        /// Adds signed weight block `q` (element order) times block `c` of every pair.
        #[inline(always)]
        unsafe fn add(&mut self, q: __m256i, p: &[&[PairBlock]; NP], a: &Sums, c: usize, f: f32, min: Option<f32>) {
            let wz = _mm512_broadcast_i64x4(q);
            // The activations are a + 128: start each lane at -128 · Σ w over its four weights.
            let corr = _mm512_dpbusd_epi32(_mm512_setzero_si512(), _mm512_set1_epi8(-128), wz);
            let start = _mm512_sub_epi32(_mm512_setzero_si512(), corr);
            let fv = _mm512_set1_ps(f);
            for j in 0..NP {
                let b = p[j].get_unchecked(c);
                let av = _mm512_load_si512(b.qs.as_ptr() as *const _);
                let lanes = _mm512_dpbusd_epi32(start, av, wz);
                let x = _mm512_mul_ps(_mm512_cvtepi32_ps(lanes), fv);
                self.acc[j] = _mm512_fmadd_ps(x, _mm512_load_ps(b.d.as_ptr()), self.acc[j]);
            }
            if let Some(m) = min {
                // The masked-off lanes are not read.
                let s = _mm512_maskz_loadu_ps(((1u32 << (2 * NP)) - 1) as u16, a.s.as_ptr().add(c * a.stride));
                self.mins = _mm512_add_ps(self.mins, _mm512_mul_ps(_mm512_set1_ps(m), s));
            }
        }

        /// Adds a block with a scale per 16 values: `q` signed (element order, both halves), `sc`
        /// the i16 scale of each 16-bit pair (one token per half), `start` each lane's
        /// `-128 · sc · Σ q` over its four weights (the activations are a + 128).
        #[inline(always)]
        unsafe fn add_scaled(&mut self, q: __m512i, sc: __m512i, start: __m512i, p: &[&[PairBlock]; NP], c: usize, f: f32) {
            let fv = _mm512_set1_ps(f);
            for j in 0..NP {
                let b = p[j].get_unchecked(c);
                let av = _mm512_load_si512(b.qs.as_ptr() as *const _);
                // (a + 128) · q pairs: at most 2 · 255 · 32 in magnitude, inside i16.
                let pairs = _mm512_maddubs_epi16(av, q);
                let lanes = _mm512_dpwssd_epi32(start, pairs, sc);
                let x = _mm512_mul_ps(_mm512_cvtepi32_ps(lanes), fv);
                self.acc[j] = _mm512_fmadd_ps(x, _mm512_load_ps(b.d.as_ptr()), self.acc[j]);
            }
        }

        #[inline(always)]
        unsafe fn finish(self) -> [[f32; 2]; NP] {
            let mut out = [[0f32; 2]; NP];
            let mut mins = [0f32; 16];
            _mm512_storeu_ps(mins.as_mut_ptr(), self.mins);
            for j in 0..NP {
                let lo = _mm512_castps512_ps256(self.acc[j]);
                let hi = _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(_mm512_castps_pd(self.acc[j])));
                // Formats without minimums add 0.0, as the scalar code does.
                out[j] = [reduce(lo) + mins[2 * j], reduce(hi) + mins[2 * j + 1]];
            }
            out
        }
    }

    /// One row of 32-blocks of `BB` bytes against `NP` pairs; `decode` gives a block's signed
    /// weights (element order), scale and minimum.
    #[inline(always)]
    pub unsafe fn pairs<const NP: usize, const BB: usize>(
        w: &[u8],
        p: &[&[PairBlock]; NP],
        a: &Sums,
        decode: impl Fn(*const u8) -> (__m256i, f32, Option<f32>),
    ) -> [[f32; 2]; NP] {
        let mut st = Pairs::<NP>::new();
        for c in 0..p[0].len() {
            let (q, f, min) = decode(w.as_ptr().add(c * BB));
            st.add(q, p, a, c, f, min);
        }
        st.finish()
    }

    #[inline(always)]
    pub unsafe fn q4k_pairs<const NP: usize>(w: &[u8], p: &[&[PairBlock]; NP], a: &Sums) -> [[f32; 2]; NP] {
        let m4 = _mm256_set1_epi8(0x0f);
        let mut st = Pairs::<NP>::new();
        for sb in 0..p[0].len() / 8 {
            let b = std::slice::from_raw_parts(w.as_ptr().add(sb * 144), 144);
            let (d, dmin) = f16_pair(b.as_ptr());
            for jj in 0..4 {
                let x = _mm256_loadu_si256(b.as_ptr().add(16 + 32 * jj) as *const __m256i);
                let halves = [_mm256_and_si256(x, m4), _mm256_and_si256(_mm256_srli_epi16::<4>(x), m4)];
                for (h, q) in halves.into_iter().enumerate() {
                    let j = 2 * jj + h;
                    let (sc, m) = q4k_scale_min(j, &b[4..16]);
                    st.add(q, p, a, sb * 8 + j, d * sc as f32, Some(-(dmin * m as f32)));
                }
            }
        }
        st.finish()
    }

    #[inline(always)]
    pub unsafe fn q6k_pairs<const NP: usize>(w: &[u8], p: &[&[PairBlock]; NP]) -> [[f32; 2]; NP] {
        let m4 = _mm256_set1_epi8(0x0f);
        let m2 = _mm256_set1_epi8(0x03);
        // Scale pair k's i16 lanes in each token's half: 2k in the low eight (elements 0..16 of
        // the block), 2k + 1 in the high eight.
        let half = _mm512_set_epi64(0x0001_0001_0001_0001, 0x0001_0001_0001_0001, 0, 0, 0x0001_0001_0001_0001, 0x0001_0001_0001_0001, 0, 0);
        let mut st = Pairs::<NP>::new();
        for sb in 0..p[0].len() / 8 {
            let b = w.as_ptr().add(sb * 210);
            let d = f16(b.add(208));
            let scales = _mm512_cvtepi8_epi16(_mm256_zextsi128_si256(_mm_loadu_si128(b.add(192) as *const __m128i)));
            for n in 0..2 {
                let qh = _mm256_loadu_si256(b.add(128 + 32 * n) as *const __m256i);
                for kk in 0..4 {
                    let k = 4 * n + kk;
                    let ql = _mm256_loadu_si256(b.add(64 * n + 32 * (kk & 1)) as *const __m256i);
                    let nib = if kk < 2 { _mm256_and_si256(ql, m4) } else { _mm256_and_si256(_mm256_srli_epi16::<4>(ql), m4) };
                    let hi = _mm256_and_si256(_mm256_srl_epi16(qh, _mm_cvtsi32_si128(2 * kk as i32)), m2);
                    let q = _mm256_sub_epi8(_mm256_or_si256(nib, _mm256_slli_epi16::<4>(hi)), _mm256_set1_epi8(32));
                    let qz = _mm512_broadcast_i64x4(q);
                    let sc = _mm512_permutexvar_epi16(_mm512_add_epi16(half, _mm512_set1_epi16(2 * k as i16)), scales);
                    // -128 · sc · Σ q per lane: 128 · (q + q') pairs (|·| ≤ 8192) times -sc (≤ 128).
                    let q128 = _mm512_maddubs_epi16(_mm512_set1_epi8(-128), qz);
                    let start = _mm512_dpwssd_epi32(_mm512_setzero_si512(), q128, _mm512_sub_epi16(_mm512_setzero_si512(), sc));
                    st.add_scaled(qz, sc, start, p, sb * 8 + k, d);
                }
            }
        }
        st.finish()
    }
}
