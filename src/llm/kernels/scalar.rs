//! The portable kernels: each weight 32-block decoded to integers, multiplied with the activation
//! block lane by lane exactly as the SIMD code groups it (see the module above), so that both give
//! identical floats. Also the row dequantisation used for embedding look-ups.

use super::{f16, q4k_scale_min, reduce_lanes, Format, Q8Block, QK};

/// One decoded 32-block of weights: `w[e] = f * sc[e / 16] * q[e] + min` (per element), where the
/// integer part `q * sc` is multiplied exactly with the activations.
struct Chunk {
    q: [i32; QK],
    sc: [i32; 2],
    f: f32,
    min: f32,
}

/// Decodes 32-block `c` of a row of `fmt` blocks.
fn decode(fmt: Format, w: &[u8], c: usize) -> Chunk {
    let mut q = [0i32; QK];
    match fmt {
        Format::Q4_1 => {
            let b = &w[c * 20..(c + 1) * 20];
            for j in 0..16 {
                q[j] = (b[4 + j] & 15) as i32;
                q[j + 16] = (b[4 + j] >> 4) as i32;
            }
            Chunk { q, sc: [1, 1], f: f16(b[0], b[1]), min: f16(b[2], b[3]) }
        }
        Format::Q5_0 => {
            let b = &w[c * 22..(c + 1) * 22];
            let qh = u32::from_le_bytes([b[2], b[3], b[4], b[5]]);
            for j in 0..16 {
                q[j] = ((b[6 + j] & 15) as u32 | (((qh >> j) & 1) << 4)) as i32 - 16;
                q[j + 16] = ((b[6 + j] >> 4) as u32 | (((qh >> (j + 16)) & 1) << 4)) as i32 - 16;
            }
            Chunk { q, sc: [1, 1], f: f16(b[0], b[1]), min: 0.0 }
        }
        Format::Q8_0 => {
            let b = &w[c * 34..(c + 1) * 34];
            for j in 0..32 {
                q[j] = b[2 + j] as i8 as i32;
            }
            Chunk { q, sc: [1, 1], f: f16(b[0], b[1]), min: 0.0 }
        }
        Format::Q4K => {
            let (sb, j) = (c / 8, c % 8);
            let b = &w[sb * 144..(sb + 1) * 144];
            let (d, dmin) = (f16(b[0], b[1]), f16(b[2], b[3]));
            let (sc, m) = q4k_scale_min(j, &b[4..16]);
            let qs = &b[16 + 32 * (j / 2)..16 + 32 * (j / 2) + 32];
            for l in 0..32 {
                q[l] = if j % 2 == 0 { qs[l] & 15 } else { qs[l] >> 4 } as i32;
            }
            Chunk { q, sc: [1, 1], f: d * sc as f32, min: -(dmin * m as f32) }
        }
        Format::Q6K => {
            let (sb, k) = (c / 8, c % 8);
            let b = &w[sb * 210..(sb + 1) * 210];
            let (n, kk) = (k / 4, k % 4);
            let ql = &b[64 * n + 32 * (kk & 1)..][..32];
            let qh = &b[128 + 32 * n..][..32];
            let scales = &b[192..208];
            for l in 0..32 {
                let nib = if kk < 2 { ql[l] & 15 } else { ql[l] >> 4 };
                q[l] = (nib | (((qh[l] >> (2 * kk)) & 3) << 4)) as i32 - 32;
            }
            let sc = [scales[8 * n + 2 * kk] as i8 as i32, scales[8 * n + 2 * kk + 1] as i8 as i32];
            Chunk { q, sc, f: f16(b[208], b[209]), min: 0.0 }
        }
    }
}

/// `NT` dot products of one weight row (`w`, whole blocks) with `NT` quantised activation rows.
pub fn dot<const NT: usize>(fmt: Format, w: &[u8], a: &[&[Q8Block]; NT]) -> [f32; NT] {
    let mut lanes = [[0f32; 8]; NT];
    let mut mins = [0f32; NT];
    for c in 0..a[0].len() {
        let ch = decode(fmt, w, c);
        for k in 0..NT {
            let b = &a[k][c];
            for (l, lane) in lanes[k].iter_mut().enumerate() {
                let mut s = 0i32;
                for e in 4 * l..4 * l + 4 {
                    s += ch.q[e] * b.qs[e] as i32 * ch.sc[e / 16];
                }
                // (s · f) rounded, then fused with the activation scale, as the SIMD code does.
                *lane = (s as f32 * ch.f).mul_add(b.d, *lane);
            }
            mins[k] += ch.min * b.s;
        }
    }
    let mut out = [0f32; NT];
    for k in 0..NT {
        out[k] = reduce_lanes(&lanes[k]) + mins[k];
    }
    out
}

/// Dequantises one row (whole blocks of `fmt`) into `out`.
pub fn dequantize_row(fmt: Format, w: &[u8], out: &mut [f32]) {
    for (c, o) in out.chunks_exact_mut(QK).enumerate() {
        let ch = decode(fmt, w, c);
        for (e, v) in o.iter_mut().enumerate() {
            *v = ch.f * (ch.q[e] * ch.sc[e / 16]) as f32 + ch.min;
        }
    }
}
