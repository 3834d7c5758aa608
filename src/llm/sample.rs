//! Choosing the next token from (masked) logits: greedy by default, or seeded sampling.
//!
//! A thin layer over candle-transformers' `LogitsProcessor`, so temperature, top-k and top-p behave
//! as in candle's examples; logits the grammar forbids are -inf and so get zero probability.

use candle_core::{Device, Tensor};
use candle_transformers::generation::{LogitsProcessor, Sampling as CandleSampling};
use serde::{Deserialize, Serialize};

use super::{LlmError, Result};

/// How the next token is chosen.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub enum Sampling {
    /// The most likely token (deterministic; the default).
    #[default]
    Greedy,
    /// Draw from the distribution at `temperature`, restricted to the `top_p` nucleus, with a
    /// seeded generator: the same seed gives the same output.
    Sample { temperature: f64, top_p: f64, seed: u64 },
}

impl Sampling {
    /// Checks the parameters: temperature finite and >= 0 (0 means greedy), top-p in (0, 1]
    /// (1 keeps the whole distribution).
    pub fn validate(&self) -> Result<()> {
        if let Sampling::Sample { temperature, top_p, .. } = *self {
            if !temperature.is_finite() || temperature < 0.0 {
                return Err(LlmError::Sampling(format!(
                    "temperature must be a finite number >= 0 (0 is greedy), got {temperature}"
                )));
            }
            if !(top_p > 0.0 && top_p <= 1.0) {
                return Err(LlmError::Sampling(format!("top-p must be in (0, 1] (1 keeps every token), got {top_p}")));
            }
        }
        Ok(())
    }
}

/// A stateful chooser for one generation.
pub struct Sampler {
    /// `None` for greedy: the argmax is taken on the logits in place, without copying them into a
    /// tensor every token (the same choice: the first of equal maxima).
    inner: Option<LogitsProcessor>,
}

impl Sampler {
    pub fn new(sampling: &Sampling) -> Self {
        let inner = match *sampling {
            Sampling::Greedy => None,
            // Parameters are checked by `Sampling::validate` (the engine calls it); 0 is greedy.
            Sampling::Sample { temperature, top_p, seed } if temperature > 0.0 => {
                let s = if top_p < 1.0 {
                    CandleSampling::TopP { p: top_p, temperature }
                } else {
                    CandleSampling::All { temperature }
                };
                Some(LogitsProcessor::from_sampling(seed, s))
            }
            Sampling::Sample { .. } => None,
        };
        Self { inner }
    }

    /// Picks a token id from `logits` (length = vocabulary).
    pub fn choose(&mut self, logits: &[f32]) -> Result<u32> {
        match &mut self.inner {
            None => argmax(logits).ok_or_else(|| LlmError::Sampling("no logit to choose from (all are NaN)".into())),
            Some(p) => Ok(p.sample(&Tensor::new(logits, &Device::Cpu)?)?),
        }
    }
}

/// Index of the largest logit, the first of equal maxima, NaNs skipped (as
/// [`super::model::argmax`]). Two passes, the first in lanes the compiler can vectorise: a
/// 152k-entry vocabulary every token is worth it.
pub fn argmax(logits: &[f32]) -> Option<u32> {
    const LANES: usize = 16;
    let mut lanes = [f32::NEG_INFINITY; LANES];
    let chunks = logits.chunks_exact(LANES);
    let tail = chunks.remainder();
    for c in chunks {
        for (m, &x) in lanes.iter_mut().zip(c) {
            // `x > m` is false for NaN, so NaNs never win.
            *m = if x > *m { x } else { *m };
        }
    }
    let max = tail.iter().chain(&lanes).fold(f32::NEG_INFINITY, |m, &x| if x > m { x } else { m });
    logits.iter().position(|&x| x == max).map(|i| i as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn argmax_agrees_with_the_plain_loop() {
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 40) as u32
        };
        for n in [1usize, 5, 16, 17, 100, 1000] {
            for _ in 0..50 {
                // Few distinct values, so ties are common; some NaN and infinities.
                let v: Vec<f32> = (0..n)
                    .map(|_| match next() % 10 {
                        0 => f32::NAN,
                        1 => f32::NEG_INFINITY,
                        2 => f32::INFINITY,
                        k => k as f32 - 5.0,
                    })
                    .collect();
                assert_eq!(argmax(&v), crate::llm::model::argmax(&v), "{v:?}");
            }
        }
        assert_eq!(argmax(&[]), None);
        assert_eq!(argmax(&[f32::NAN, f32::NAN]), None);
        assert_eq!(argmax(&[f32::NEG_INFINITY, f32::NAN, f32::NEG_INFINITY]), Some(0));
        assert_eq!(argmax(&[f32::NAN, f32::NEG_INFINITY]), Some(1));
    }

    #[test]
    fn greedy_takes_the_first_maximum() {
        let mut s = Sampler::new(&Sampling::Greedy);
        assert_eq!(s.choose(&[0.0, 2.0, 1.0, 2.0]).unwrap(), 1);
        let mut z = Sampler::new(&Sampling::Sample { temperature: 0.0, top_p: 1.0, seed: 3 });
        assert_eq!(z.choose(&[0.0, 2.0, 1.0, 2.0]).unwrap(), 1);
        assert!(s.choose(&[f32::NAN]).is_err());
    }
}
