//! AVX2/FMA kernels, used when the CPU reports both features at run time. Each 32-block of weights
//! is expanded to 32 bytes in element order, multiplied with the activation bytes (`maddubs`, signed
//! formats through the sign trick), widened to eight i32 lanes with the per-16 scales (`madd`), and
//! accumulated in f32 with one FMA per block: the same arithmetic, in the same order, as
//! [`super::scalar`]. Several tokens share each decoded weight block.

use super::{Format, Q8Block};

/// Whether this CPU runs these kernels (AVX2 and FMA for the arithmetic, F16C for the block scales).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") && is_x86_feature_detected!("f16c")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `NR × NT` dot products: each of `NR` weight rows with each of `NT` activation rows. Every
/// (row, token) pair keeps its own accumulators and adds its blocks in the same order whatever `NR`
/// and `NT` are, so grouping changes the speed, never the result. Several rows at once serve decoding
/// (one token): their independent sums overlap instead of waiting on one FMA chain, and each
/// activation block is loaded once for all of them.
///
/// # Safety
/// The CPU must support AVX2, FMA and F16C ([`available`]); each `w[r]` must hold `a[k].len()`
/// 32-blocks of `fmt` (every `a[k]` the same length).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
pub unsafe fn dot<const NR: usize, const NT: usize>(
    fmt: Format,
    w: &[&[u8]; NR],
    a: &[&[Q8Block]; NT],
) -> [[f32; NT]; NR] {
    let nb = a[0].len();
    debug_assert!(a.iter().all(|r| r.len() == nb));
    let (bv, bb) = fmt.block();
    debug_assert!(w.iter().all(|w| w.len() >= nb * 32 / bv * bb));
    let mut st = [(); NR].map(|_| x86::State::<NT>::new());
    match fmt {
        Format::Q4_1 => x86::q4_1(w, a, &mut st),
        Format::Q5_0 => x86::q5_0(w, a, &mut st),
        Format::Q8_0 => x86::q8_0(w, a, &mut st),
        Format::Q4K => x86::q4k(w, a, &mut st),
        Format::Q6K => x86::q6k(w, a, &mut st),
    }
    st.map(|s| s.finish())
}

#[cfg(not(target_arch = "x86_64"))]
pub unsafe fn dot<const NR: usize, const NT: usize>(
    _: Format,
    _: &[&[u8]; NR],
    _: &[&[Q8Block]; NT],
) -> [[f32; NT]; NR] {
    unreachable!("the AVX2 kernels are only selected on x86_64")
}

#[cfg(target_arch = "x86_64")]
pub(super) mod x86 {
    //! The helpers are `inline(always)` so that they compile inside `dot`, with its target features.
    use std::arch::x86_64::*;

    use super::super::{q4k_scale_min, Q8Block};

    pub struct State<const NT: usize> {
        acc: [__m256; NT],
        mins: [f32; NT],
    }

    impl<const NT: usize> State<NT> {
        #[inline(always)]
        pub unsafe fn new() -> Self {
            Self { acc: [_mm256_setzero_ps(); NT], mins: [0.0; NT] }
        }

        /// Adds weight block `wq` (32 bytes in element order; signed i8, or unsigned with `signed`
        /// false) times activation block `c` of each token, lanes scaled by the i16s in `scale`, times
        /// `f`, times `d_activation`; and `min * s_activation` to the min sums.
        #[inline(always)]
        unsafe fn add(
            &mut self,
            wq: __m256i,
            signed: bool,
            scale: __m256i,
            a: &[&[Q8Block]; NT],
            c: usize,
            f: f32,
            min: Option<f32>,
        ) {
            let wabs = if signed { _mm256_sign_epi8(wq, wq) } else { wq };
            let fv = _mm256_set1_ps(f);
            for k in 0..NT {
                let b = a[k].get_unchecked(c);
                let av = _mm256_loadu_si256(b.qs.as_ptr() as *const __m256i);
                let av = if signed { _mm256_sign_epi8(av, wq) } else { av };
                let lanes = _mm256_madd_epi16(_mm256_maddubs_epi16(wabs, av), scale);
                // (lanes · f) · d: the weight scale is broadcast once per block for all tokens and
                // the activation scale is broadcast straight from memory.
                let x = _mm256_mul_ps(_mm256_cvtepi32_ps(lanes), fv);
                self.acc[k] = _mm256_fmadd_ps(x, _mm256_set1_ps(b.d), self.acc[k]);
                if let Some(m) = min {
                    self.mins[k] += m * b.s;
                }
            }
        }

        #[inline(always)]
        pub unsafe fn finish(self) -> [f32; NT] {
            let mut out = [0f32; NT];
            for k in 0..NT {
                // ((l0+l4)+(l2+l6)) + ((l1+l5)+(l3+l7)), as `reduce_lanes`.
                let s = _mm_add_ps(_mm256_castps256_ps128(self.acc[k]), _mm256_extractf128_ps::<1>(self.acc[k]));
                let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
                let s = _mm_add_ss(s, _mm_shuffle_ps::<1>(s, s));
                // Formats without minimums add 0.0, as the scalar code does.
                out[k] = _mm_cvtss_f32(s) + self.mins[k];
            }
            out
        }
    }

    /// The two f16 values at `p` (unaligned) as f32, exactly (F16C), in one conversion.
    #[inline(always)]
    pub(in crate::llm::kernels) unsafe fn f16_pair(p: *const u8) -> (f32, f32) {
        let v = _mm_cvtph_ps(_mm_cvtsi32_si128(std::ptr::read_unaligned(p as *const i32)));
        (_mm_cvtss_f32(v), _mm_cvtss_f32(_mm_movehdup_ps(v)))
    }

    /// The f16 value at `p` as f32, exactly.
    #[inline(always)]
    pub(in crate::llm::kernels) unsafe fn f16(p: *const u8) -> f32 {
        let v = _mm_cvtph_ps(_mm_cvtsi32_si128(std::ptr::read_unaligned(p as *const u16) as i32));
        _mm_cvtss_f32(v)
    }

    #[inline(always)]
    unsafe fn ones() -> __m256i {
        _mm256_set1_epi16(1)
    }

    /// 16 bytes of nibbles → 32 bytes: low nibbles (elements 0..16), then high nibbles (16..32).
    #[inline(always)]
    pub(in crate::llm::kernels) unsafe fn nibbles(p: *const u8) -> __m256i {
        // The 16 bytes in both halves, the upper half shifted right by 4, then masked: three
        // instructions where splitting and re-joining halves takes five.
        let x = _mm256_broadcastsi128_si256(_mm_loadu_si128(p as *const __m128i));
        let x = _mm256_srlv_epi64(x, _mm256_set_epi64x(4, 4, 0, 0));
        _mm256_and_si256(x, _mm256_set1_epi8(0x0f))
    }

    /// Asks for the weights `PREFETCH_AHEAD` bytes further on when decoding (rows are contiguous,
    /// so that is a few row groups ahead), so that the memory stream runs ahead of the arithmetic.
    /// A hint only: it never faults, even past the end of the matrix.
    #[inline(always)]
    pub(in crate::llm::kernels) unsafe fn prefetch_next<const NR: usize>(w: &[u8], offset: usize) {
        if NR > 1 {
            let p = w.as_ptr().wrapping_add(offset + PREFETCH_AHEAD);
            _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
        }
    }

    /// Far enough to cover the memory latency at the rate the kernel consumes rows, near enough
    /// to stay inside L1. Measured single-thread on SmolLM2 decode: one 4-row group ahead (1.4 KB)
    /// 120 tok/s, four groups 167, 6 KB 170, 12 KB 188 (Qwen decode flat across these).
    const PREFETCH_AHEAD: usize = 12288;

    /// 32 bits → 32 bytes, 0xff where the bit is set.
    #[inline(always)]
    unsafe fn bits_to_bytes(x: u32) -> __m256i {
        let shuf = _mm256_set_epi64x(0x0303030303030303, 0x0202020202020202, 0x0101010101010101, 0);
        let bytes = _mm256_shuffle_epi8(_mm256_set1_epi32(x as i32), shuf);
        let all_but_own_bit = _mm256_set1_epi64x(0x7fbfdfeff7fbfdfe);
        _mm256_cmpeq_epi8(_mm256_or_si256(bytes, all_but_own_bit), _mm256_set1_epi64x(-1))
    }

    // Each format walks the blocks in order and, for every block, each of the `NR` rows in turn.

    #[inline(always)]
    pub unsafe fn q4_1<const NR: usize, const NT: usize>(w: &[&[u8]; NR], a: &[&[Q8Block]; NT], st: &mut [State<NT>; NR]) {
        for c in 0..a[0].len() {
            for r in 0..NR {
                prefetch_next::<NR>(w[r], c * 20);
                let p = w[r].as_ptr().add(c * 20);
                let (d, m) = f16_pair(p);
                st[r].add(nibbles(p.add(4)), false, ones(), a, c, d, Some(m));
            }
        }
    }

    #[inline(always)]
    pub unsafe fn q5_0<const NR: usize, const NT: usize>(w: &[&[u8]; NR], a: &[&[Q8Block]; NT], st: &mut [State<NT>; NR]) {
        for c in 0..a[0].len() {
            for r in 0..NR {
                prefetch_next::<NR>(w[r], c * 22);
                let p = w[r].as_ptr().add(c * 22);
                let d = f16(p);
                let qh = std::ptr::read_unaligned(p.add(2) as *const u32);
                // Without the fifth bit the value is nibble - 16, i.e. the nibble with 0xf0 or-ed in.
                let high = _mm256_andnot_si256(bits_to_bytes(qh), _mm256_set1_epi8(0xf0u8 as i8));
                st[r].add(_mm256_or_si256(nibbles(p.add(6)), high), true, ones(), a, c, d, None);
            }
        }
    }

    #[inline(always)]
    pub unsafe fn q8_0<const NR: usize, const NT: usize>(w: &[&[u8]; NR], a: &[&[Q8Block]; NT], st: &mut [State<NT>; NR]) {
        for c in 0..a[0].len() {
            for r in 0..NR {
                prefetch_next::<NR>(w[r], c * 34);
                let p = w[r].as_ptr().add(c * 34);
                let d = f16(p);
                st[r].add(_mm256_loadu_si256(p.add(2) as *const __m256i), true, ones(), a, c, d, None);
            }
        }
    }

    #[inline(always)]
    pub unsafe fn q4k<const NR: usize, const NT: usize>(w: &[&[u8]; NR], a: &[&[Q8Block]; NT], st: &mut [State<NT>; NR]) {
        let m4 = _mm256_set1_epi8(0x0f);
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
                        st[r].add(q, false, ones(), a, sb * 8 + j, d * sc as f32, Some(-(dmin * m as f32)));
                    }
                }
            }
        }
    }

    #[inline(always)]
    pub unsafe fn q6k<const NR: usize, const NT: usize>(w: &[&[u8]; NR], a: &[&[Q8Block]; NT], st: &mut [State<NT>; NR]) {
        let m4 = _mm256_set1_epi8(0x0f);
        let m2 = _mm256_set1_epi8(0x03);
        let off = _mm256_set1_epi8(32);
        for sb in 0..a[0].len() / 8 {
            for r in 0..NR {
                let b = w[r].as_ptr().add(sb * 210);
                let d = f16(b.add(208));
                let scales = b.add(192) as *const i8;
                for n in 0..2 {
                    let qh = _mm256_loadu_si256(b.add(128 + 32 * n) as *const __m256i);
                    for kk in 0..4 {
                        let ql = _mm256_loadu_si256(b.add(64 * n + 32 * (kk & 1)) as *const __m256i);
                        let nib = if kk < 2 {
                            _mm256_and_si256(ql, m4)
                        } else {
                            _mm256_and_si256(_mm256_srli_epi16::<4>(ql), m4)
                        };
                        let hi = _mm256_and_si256(_mm256_srl_epi16(qh, _mm_cvtsi32_si128(2 * kk as i32)), m2);
                        let q = _mm256_sub_epi8(_mm256_or_si256(nib, _mm256_slli_epi16::<4>(hi)), off);
                        let s0 = *scales.add(8 * n + 2 * kk) as i16;
                        let s1 = *scales.add(8 * n + 2 * kk + 1) as i16;
                        let scale = _mm256_set_m128i(_mm_set1_epi16(s1), _mm_set1_epi16(s0));
                        st[r].add(q, true, scale, a, sb * 8 + 4 * n + kk, d, None);
                    }
                }
            }
        }
    }
}
