//! Each kernel against a dequantise-then-f32 reference (candle's own dequantisation, an independent
//! implementation) on random data, and the SIMD kernels against the scalar ones, bit for bit.

use candle_core::quantized::{GgmlDType, QTensor};
use candle_core::{Device, Tensor};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::*;

const FORMATS: [(GgmlDType, Format); 5] = [
    (GgmlDType::Q4_1, Format::Q4_1),
    (GgmlDType::Q5_0, Format::Q5_0),
    (GgmlDType::Q8_0, Format::Q8_0),
    (GgmlDType::Q4K, Format::Q4K),
    (GgmlDType::Q6K, Format::Q6K),
];

fn randn(rng: &mut StdRng, n: usize) -> Vec<f32> {
    // Uniform with a few large values, like real activations.
    (0..n).map(|i| rng.random_range(-1.0f32..1.0) * if i % 97 == 0 { 8.0 } else { 1.0 }).collect()
}

fn quantised(rng: &mut StdRng, dtype: GgmlDType, rows: usize, cols: usize) -> (QMatrix, Vec<f32>) {
    let w = Tensor::from_vec(randn(rng, rows * cols), (rows, cols), &Device::Cpu).unwrap();
    let q = QTensor::quantize(&w, dtype).unwrap();
    let deq = q.dequantize(&Device::Cpu).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    (QMatrix::from_qtensor(&q).unwrap(), deq)
}

/// The activations as the kernels see them: dequantised from their 8-bit blocks.
fn dequantised_acts(q: &Q8Acts) -> Vec<f32> {
    q.blocks.iter().flat_map(|b| b.qs.iter().map(move |&v| b.d * v as f32)).collect()
}

fn run(m: &QMatrix, q: &Q8Acts, x: &[f32], t: usize, kernel: Kernel) -> Vec<f32> {
    let mut y = vec![0f32; t * m.rows()];
    // SAFETY: one thread writes every element of y, which has t * rows elements.
    unsafe { m.compute_rows(0..m.rows(), q, x, y.as_mut_ptr(), m.rows(), kernel) };
    y
}

#[test]
fn kernels_match_the_dequantised_reference() {
    let mut rng = StdRng::seed_from_u64(7);
    let (rows, cols, t) = (19, 512, 6); // t = 6: one four-token tile and two single tokens
    for (dtype, fmt) in FORMATS {
        let (m, w) = quantised(&mut rng, dtype, rows, cols);
        assert_eq!(m.format(), Some(fmt));
        let x = randn(&mut rng, t * cols);
        let mut q = Q8Acts::default();
        q.quantize(&x, t, cols);
        let xq = dequantised_acts(&q);
        let y = run(&m, &q, &x, t, Kernel::Scalar);
        for i in 0..t {
            for r in 0..rows {
                let wr = &w[r * cols..(r + 1) * cols];
                let exact: f64 = wr.iter().zip(&xq[i * cols..]).map(|(&a, &b)| a as f64 * b as f64).sum();
                let unquantised: f64 = wr.iter().zip(&x[i * cols..]).map(|(&a, &b)| a as f64 * b as f64).sum();
                let got = y[i * rows + r] as f64;
                let mag: f64 = wr.iter().zip(&x[i * cols..]).map(|(&a, &b)| (a as f64 * b as f64).abs()).sum();
                // Against the same quantised inputs only float rounding differs; against the f32
                // activations the 8-bit rounding adds up to ~1% of the absolute sum.
                assert!((got - exact).abs() <= 1e-5 * mag, "{fmt:?} row {r} token {i}: {got} vs {exact}");
                assert!((got - unquantised).abs() <= 1e-2 * mag, "{fmt:?} row {r} token {i}: {got} vs {unquantised}");
            }
        }
    }
}

#[test]
fn simd_kernels_equal_the_scalar_ones_bit_for_bit() {
    if !avx2::available() {
        eprintln!("skipped: this CPU has no AVX2/FMA");
        return;
    }
    let mut rng = StdRng::seed_from_u64(11);
    for (dtype, fmt) in FORMATS {
        for (cols, t) in [(256, 1), (768, 3), (768, 5), (1024, 9), (512, 45)] {
            let (m, _) = quantised(&mut rng, dtype, 13, cols);
            let x = randn(&mut rng, t * cols);
            let mut q = Q8Acts::default();
            q.quantize(&x, t, cols);
            let a = run(&m, &q, &x, t, Kernel::Scalar);
            let b = run(&m, &q, &x, t, Kernel::Avx2);
            let same = a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(same, "{fmt:?} cols {cols} t {t}: scalar {a:?}\n avx2 {b:?}");
        }
    }
}

#[test]
fn row_dequantisation_matches_candle() {
    let mut rng = StdRng::seed_from_u64(3);
    for (dtype, fmt) in FORMATS {
        let (m, w) = quantised(&mut rng, dtype, 5, 512);
        let mut row = vec![0f32; 512];
        for r in 0..5 {
            m.dequantize_row(r, &mut row);
            for (c, (&a, &b)) in row.iter().zip(&w[r * 512..]).enumerate() {
                assert!((a - b).abs() <= 1e-6 * (1.0 + b.abs()), "{fmt:?} ({r}, {c}): {a} vs {b}");
            }
        }
    }
}

#[test]
fn pooled_matmul_is_the_same_for_any_thread_count_and_plain_formats_work() {
    let mut rng = StdRng::seed_from_u64(5);
    let (m, _) = quantised(&mut rng, GgmlDType::Q4_1, 300, 256);
    let (f, wf) = quantised(&mut rng, GgmlDType::F32, 40, 256);
    assert_eq!(f.format(), None);
    let x = randn(&mut rng, 3 * 256);
    let mut q = Q8Acts::default();
    q.quantize(&x, 3, 256);
    let one = run(&m, &q, &x, 3, kernel());
    let (mut y, mut yf) = (vec![0f32; 3 * 300], vec![0f32; 3 * 40]);
    matmul_many(&[(&m, &mut y), (&f, &mut yf)], &q, &x, 3);
    assert_eq!(one, y);
    for i in 0..3 {
        for r in 0..40 {
            let want = dot_f32(&wf[r * 256..(r + 1) * 256], &x[i * 256..(i + 1) * 256]);
            assert_eq!(yf[i * 40 + r], want);
        }
    }
}

#[test]
fn activation_blocks_round_trip_within_half_a_step() {
    let mut rng = StdRng::seed_from_u64(9);
    let x = randn(&mut rng, 64);
    let mut q = Q8Acts::default();
    q.quantize(&x, 2, 32);
    let back = dequantised_acts(&q);
    for (b, (a, r)) in q.blocks.iter().zip(x.chunks(32).zip(back.chunks(32))) {
        let isum: i32 = b.qs.iter().map(|&v| v as i32).sum();
        assert_eq!(b.s, b.d * isum as f32);
        assert!(a.iter().zip(r).all(|(a, r)| (a - r).abs() <= b.d * 0.5 + 1e-6));
    }
}

#[test]
fn f16_conversion_is_exact_for_every_bit_pattern() {
    for h in 0..=u16::MAX {
        let want = half::f16::from_bits(h).to_f32();
        let got = f16(h as u8, (h >> 8) as u8);
        assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()), "{h:#06x}: {got} vs {want}");
    }
}

#[test]
fn the_softmax_exponential_is_within_four_ulps_and_exact_at_the_ends() {
    use super::attn::exp_le0;
    assert_eq!(exp_le0(0.0), 1.0);
    assert_eq!(exp_le0(-0.0), 1.0);
    assert_eq!(exp_le0(-87.5), 0.0);
    assert_eq!(exp_le0(f32::NEG_INFINITY), 0.0);
    assert_eq!(exp_le0(f32::NAN), 0.0);
    // Every 97th float from -87 to 0.
    let (lo, hi) = ((-87.0f32).to_bits(), (-0.0f32).to_bits());
    let mut worst = 0f64;
    for b in (hi..=lo).step_by(97) {
        let x = f32::from_bits(b);
        let (got, want) = (exp_le0(x) as f64, (x as f64).exp());
        let ulp = f32::EPSILON as f64 * (want as f32).abs() as f64;
        worst = worst.max((got - want).abs() / ulp);
    }
    assert!(worst <= 4.0, "worst error {worst} ulp");
}

/// The SwiGLU gate is silu(g)·u to a few ulps, at both signs, zero and far out, and the AVX2
/// loop gives the portable bits (with the tail past the last eight).
#[test]
fn the_silu_gate_is_accurate_and_simd_equals_portable_bit_for_bit() {
    let mut rng = StdRng::seed_from_u64(29);
    let mut g: Vec<f32> = randn(&mut rng, 1003).iter().map(|x| x * 6.0).collect();
    g.extend([0.0, -0.0, 1.0, -1.0, 90.0, -90.0, 20.0, -20.0, 1e-30, -1e-30]);
    let u = randn(&mut rng, g.len());
    let mut simd = g.clone();
    attn::silu_gate(&mut simd, &u);
    for ((&x, &u), &y) in g.iter().zip(&u).zip(&simd) {
        let want = x as f64 / (1.0 + (-(x as f64)).exp()) * u as f64;
        assert!((y as f64 - want).abs() <= 8.0 * f32::EPSILON as f64 * want.abs() + 1e-35, "silu({x})·{u} = {y}, want {want}");
    }
    if avx2::available() {
        let mut portable = g.clone();
        // The dispatch took the AVX2 loop on this CPU unless a kernel was forced.
        for (x, u) in portable.iter_mut().zip(&u) {
            let mut one = [*x];
            // A slice of one runs the scalar tail, which is the portable code.
            attn::silu_gate(&mut one, std::slice::from_ref(u));
            *x = one[0];
        }
        assert!(portable.iter().zip(&simd).all(|(a, b)| a.to_bits() == b.to_bits()), "silu gate: AVX2 and portable differ");
    }
}

#[test]
fn attention_loops_simd_equal_portable_bit_for_bit() {
    use super::attn::{AttnOps, Portable};
    if !avx2::available() {
        eprintln!("skipped: this CPU has no AVX2/FMA");
        return;
    }
    let mut rng = StdRng::seed_from_u64(13);
    for hd in [64, 128, 72, 12] {
        // Spreads of ~±30 and ~±120: the second puts many exponentials below the floor (0).
        for (n, spread) in [1, 5, 8, 16, 24, 37, 64, 100, 2000].into_iter().flat_map(|n| [(n, 9.0), (n, 40.0)]) {
            let row: Vec<f32> = randn(&mut rng, n).iter().map(|x| x * spread).collect();
            let (mut x, mut y) = (row.clone(), row.clone());
            // SAFETY: as above.
            unsafe {
                Portable::softmax(&mut x);
                attn::Avx2::softmax(&mut y);
            }
            assert!(x.iter().zip(&y).all(|(a, b)| a.to_bits() == b.to_bits()), "softmax of {n}");
            if avx512::available() {
                let mut z = row.clone();
                // SAFETY: the CPU has AVX-512F.
                unsafe { attn::Avx512::softmax(&mut z) };
                assert!(x.iter().zip(&z).all(|(a, b)| a.to_bits() == b.to_bits()), "AVX-512 softmax of {n}");
            }
            let total: f64 = x.iter().map(|&p| p as f64).sum();
            assert!((total - 1.0).abs() < 1e-5, "softmax of {n} sums to {total}");
        }
        for keys in [1, 7, 40] {
            let stride = hd + 24;
            let values = randn(&mut rng, keys * stride);
            let p = randn(&mut rng, keys);
            let (mut y1, mut y2) = (vec![0f32; hd], vec![0f32; hd]);
            // SAFETY: as above; values holds keys rows of `stride`.
            unsafe {
                Portable::weighted_sum(&mut y1, &p, &values, stride);
                attn::Avx2::weighted_sum(&mut y2, &p, &values, stride);
            }
            assert!(y1.iter().zip(&y2).all(|(a, b)| a.to_bits() == b.to_bits()), "weighted sum, hd {hd}, {keys} keys");
        }
    }
}

/// The AVX2 and AVX-512 weighted sums, one to five outputs at a time over the same keys, give
/// each output the portable loop's bits, for head widths with and without a 64-, 16- or 8-wide part.
#[test]
fn batched_weighted_sums_equal_the_portable_loop_bit_for_bit() {
    use super::attn::{AttnOps, Portable};
    if !avx2::available() {
        eprintln!("skipped: this CPU has no AVX2");
        return;
    }
    let mut rng = StdRng::seed_from_u64(31);
    for hd in [64, 128, 80, 72, 40, 16, 12] {
        for keys in [0, 1, 7, 64] {
            let stride = 3 * hd + 8;
            let values = randn(&mut rng, keys.max(1) * stride);
            for n in 1..=5 {
                let ps: Vec<Vec<f32>> = (0..n).map(|_| randn(&mut rng, keys)).collect();
                let start: Vec<Vec<f32>> = (0..n).map(|_| randn(&mut rng, hd)).collect();
                let mut want = start.clone();
                let mut got = start.clone();
                let yp: Vec<*mut f32> = got.iter_mut().map(|y| y.as_mut_ptr()).collect();
                let pp: Vec<*const f32> = ps.iter().map(|p| p.as_ptr()).collect();
                // SAFETY: AVX2 checked above, AVX-512 before its call; each output holds `hd`
                // floats and each probability row `keys`; values holds `keys` rows of `stride`.
                unsafe {
                    for (y, p) in want.iter_mut().zip(&ps) {
                        Portable::weighted_sum(y, p, &values, stride);
                    }
                    attn::Avx2::weighted_sums(&yp, &pp, keys, hd, &values, stride);
                }
                let same = want.iter().flatten().zip(got.iter().flatten()).all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "AVX2: hd {hd}, {keys} keys, {n} outputs");
                if avx512::available() {
                    let mut got = start.clone();
                    let yp: Vec<*mut f32> = got.iter_mut().map(|y| y.as_mut_ptr()).collect();
                    // SAFETY: as above, AVX-512 checked.
                    unsafe { attn::Avx512::weighted_sums(&yp, &pp, keys, hd, &values, stride) };
                    let same = want.iter().flatten().zip(got.iter().flatten()).all(|(a, b)| a.to_bits() == b.to_bits());
                    assert!(same, "AVX-512: hd {hd}, {keys} keys, {n} outputs");
                }
            }
        }
    }
}

/// The integer attention scores: every kernel this CPU has computes the portable definition's
/// bits, for one to four queries a tile and head widths of 12 to 256; and each score is the f32
/// query·key product within the rounding, keys with a few channels far above the rest (as
/// qwen2's key biases make them) included.
#[test]
fn tile_scores_every_kernel_equals_the_definition_and_the_float_product() {
    use super::scores::{tile_scores, KeyTiles, Queries, KEYS};
    let mut rng = StdRng::seed_from_u64(29);
    let kernels: Vec<Kernel> = [Kernel::Avx2, Kernel::Avx512]
        .into_iter()
        .filter(|k| match k {
            Kernel::Avx2 => avx2::available(),
            _ => avx512::available(),
        })
        .collect();
    if kernels.len() < 2 {
        eprintln!("only {kernels:?} of the SIMD score kernels checked: this CPU has no more");
    }
    for hd in [16, 64, 80, 128, 12, 256] {
        let (nkv, positions) = (2, 40);
        let shape = KeyTiles { nkv, hd };
        assert!(KeyTiles::fits(hd));
        let (ne, ns) = shape.sizes(positions);
        let (mut tiles, mut scales) = (vec![0i16; ne], vec![0f32; ns]);
        // Two channels 60 times the others in every key.
        let keys: Vec<Vec<f32>> = (0..positions * nkv)
            .map(|_| randn(&mut rng, hd).into_iter().enumerate().map(|(e, x)| if e == 3 || e == hd / 2 + 3 { 60.0 + x } else { x }).collect())
            .collect();
        for p in 0..positions {
            for h in 0..nkv {
                shape.store(&mut tiles, &mut scales, p, h, &keys[p * nkv + h]);
            }
        }
        let raw = randn(&mut rng, 4 * hd);
        let scale = 1.0 / (hd as f32).sqrt();
        let mut queries = Queries::default();
        queries.quantize(&raw, hd, scale);
        let qs: Vec<_> = (0..4).map(|i| queries.get(i)).collect();
        for h in 0..nkv {
            for p0 in (0..positions).step_by(KEYS) {
                let t = shape.tile(p0, h);
                let tile = &tiles[t * shape.tile_len()..][..shape.tile_len()];
                let sc = &scales[t * KEYS..][..KEYS];
                for n in 1..=4 {
                    let mut want = vec![0f32; n * KEYS];
                    let out: Vec<*mut f32> = (0..n).map(|u| want[u * KEYS..].as_mut_ptr()).collect();
                    // SAFETY: each pointer has KEYS floats after it.
                    unsafe { tile_scores(Kernel::Scalar, shape, tile, sc, &qs[..n], &out) };
                    for &k in &kernels {
                        let mut got = vec![f32::NAN; n * KEYS];
                        let out: Vec<*mut f32> = (0..n).map(|u| got[u * KEYS..].as_mut_ptr()).collect();
                        // SAFETY: `kernels` holds only what this CPU runs; KEYS floats after each pointer.
                        unsafe { tile_scores(k, shape, tile, sc, &qs[..n], &out) };
                        let same = want.iter().zip(&got).all(|(a, b)| a.to_bits() == b.to_bits());
                        assert!(same, "{k:?}, hd {hd}, {n} queries, tile at {p0}");
                    }
                    for u in 0..n {
                        for s in 0..KEYS.min(positions - p0) {
                            let (q, k) = (&raw[u * hd..][..hd], &keys[(p0 + s) * nkv + h]);
                            let exact: f32 = q.iter().zip(k).map(|(a, b)| a * b).sum::<f32>() * scale;
                            // The query's rounding, against the part of the key off the outliers.
                            let bulk = k.iter().enumerate().filter(|&(e, _)| e != 3 && e != hd / 2 + 3).map(|(_, b)| b * b).sum::<f32>().sqrt();
                            let size = q.iter().map(|a| a * a).sum::<f32>().sqrt() * (bulk + 120.0) * scale;
                            let err = (want[u * KEYS + s] - exact).abs();
                            assert!(err <= 0.004 * size, "hd {hd}: score {} against {exact} (size {size})", want[u * KEYS + s]);
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn rounding_matches_round_half_away_from_zero() {
    let mut rng = StdRng::seed_from_u64(17);
    let special = [0.0f32, -0.0, 0.5, -0.5, 1.5, 2.5, -2.5, 126.5, -126.5, 127.0, 0.49999997, -0.49999997, 2.4999998];
    let random = (0..100_000).map(|_| rng.random_range(-130.0f32..130.0));
    for v in special.into_iter().chain(random) {
        assert_eq!(round_away(v), v.round() as i32, "{v}");
    }
    // Every half step in range, and its neighbours.
    for i in -300..=300 {
        let h = i as f32 * 0.5;
        for v in [h, f32::from_bits(h.to_bits() + 1), f32::from_bits(h.to_bits().saturating_sub(1))] {
            assert_eq!(round_away(v), v.round() as i32, "{v}");
        }
    }
}

/// A matrix of random raw blocks: every byte random except the f16 scales (kept finite and small,
/// so that sums stay finite), so that extremes the quantiser never writes (Q8_0's -128, every Q5_0
/// high-bit pattern, large 6-bit Q4_K scales) are exercised too.
fn random_blocks(rng: &mut StdRng, fmt: Format, rows: usize, cols: usize) -> QMatrix {
    let (bv, bb) = fmt.block();
    let nblocks = rows * cols / bv;
    let mut data: Vec<u8> = (0..nblocks * bb).map(|_| rng.random()).collect();
    // Byte offsets of the f16 scales inside a block.
    let scales: &[usize] = match fmt {
        Format::Q4_1 | Format::Q4K => &[0, 2],
        Format::Q5_0 | Format::Q8_0 => &[0],
        Format::Q6K => &[208],
    };
    for b in data.chunks_exact_mut(bb) {
        for &o in scales {
            let v = half::f16::from_f32(rng.random_range(-0.05f32..0.05));
            b[o..o + 2].copy_from_slice(&v.to_bits().to_le_bytes());
        }
    }
    QMatrix { rows, cols, storage: Storage::Quant { fmt, data, row_bytes: cols / bv * bb } }
}

#[test]
fn avx512_kernels_equal_the_scalar_ones_bit_for_bit() {
    if !avx512::available() {
        eprintln!("skipped: this CPU has no AVX-512 VNNI");
        return;
    }
    let mut rng = StdRng::seed_from_u64(19);
    // t = 1 and 3: decoding (four rows at a time, then single rows: 13 rows); 45 and 64: whole
    // 32-token groups, then 16-, 8- and 2-token pair groups and a single token.
    for (_, fmt) in FORMATS {
        for (cols, t) in [(256, 1), (768, 3), (768, 5), (1024, 9), (512, 45), (256, 64), (256, 27)] {
            for raw in [false, true] {
                let m = if raw {
                    random_blocks(&mut rng, fmt, 13, cols)
                } else {
                    quantised(&mut rng, FORMATS.iter().find(|f| f.1 == fmt).unwrap().0, 13, cols).0
                };
                let mut x = randn(&mut rng, t * cols);
                // A block at full scale both ways: activations of exactly ±127.
                x[..QK].iter_mut().enumerate().for_each(|(e, v)| *v = if e % 3 == 0 { -4.0 } else { 4.0 });
                let mut q = Q8Acts::default();
                q.quantize_for(&x, t, cols, Kernel::Avx512);
                assert_eq!(q.pairs.is_empty(), t < 4);
                let want = run(&m, &q, &x, t, Kernel::Scalar);
                // With the pair blocks (prompts), and without them (every token through the
                // 256-bit kernel).
                let with_pairs = run(&m, &q, &x, t, Kernel::Avx512);
                q.pairs.clear();
                let without = run(&m, &q, &x, t, Kernel::Avx512);
                for (name, got) in [("pairs", with_pairs), ("rows", without)] {
                    let same = want.iter().zip(&got).all(|(x, y)| x.to_bits() == y.to_bits());
                    assert!(same, "{fmt:?} raw {raw} cols {cols} t {t} {name}: scalar {want:?}\n avx512 {got:?}");
                }
            }
        }
    }
}

#[test]
fn avx512_q6k_equals_scalar_at_the_extremes() {
    if !avx512::available() {
        eprintln!("skipped: this CPU has no AVX-512 VNNI");
        return;
    }
    // Weights of -32 and 31 under scales of -128 and 127, against activations of ±127: the largest
    // 16-bit pair products (2 · 255 · 32 with the +128 offset) and lane sums the pair kernel makes.
    let (rows, cols) = (6, 512);
    let mut rng = StdRng::seed_from_u64(23);
    let mut m = random_blocks(&mut rng, Format::Q6K, rows, cols);
    if let Storage::Quant { data, .. } = &mut m.storage {
        for (i, b) in data.chunks_exact_mut(210).enumerate() {
            let low = i % 2 == 0;
            b[..192].fill(if low { 0x00 } else { 0xff });
            b[192..208].fill(if (i / 2) % 2 == 0 { 0x80 } else { 0x7f });
        }
    }
    for t in [4, 6, 16, 34] {
        let x: Vec<f32> = (0..t * cols).map(|e| if (e / 7) % 2 == 0 { -1.0 } else { 1.0 }).collect();
        let mut q = Q8Acts::default();
        q.quantize_for(&x, t, cols, Kernel::Avx512);
        let want = run(&m, &q, &x, t, Kernel::Scalar);
        let got = run(&m, &q, &x, t, Kernel::Avx512);
        assert!(want.iter().zip(&got).all(|(a, b)| a.to_bits() == b.to_bits()), "t {t}: {want:?}\n{got:?}");
    }
}

#[test]
fn activation_quantisation_with_avx2_equals_the_portable_code() {
    if !avx2::available() {
        eprintln!("skipped: this CPU has no AVX2/FMA");
        return;
    }
    let mut rng = StdRng::seed_from_u64(29);
    for k in 0..2000 {
        let mut xs = randn(&mut rng, QK);
        // Values on the rounding halves, and all-zero blocks.
        match k % 4 {
            0 => xs.iter_mut().enumerate().for_each(|(e, v)| *v = (e as f32 - 15.5) * 0.5),
            1 => xs.fill(0.0),
            _ => {}
        }
        let a = quantize_block_with(&xs);
        // SAFETY: AVX2 is present (checked above).
        let b = unsafe { quantize_block_avx2(&xs) };
        assert!(a.d.to_bits() == b.d.to_bits() && a.s.to_bits() == b.s.to_bits() && a.qs == b.qs, "{xs:?}");
    }
}
