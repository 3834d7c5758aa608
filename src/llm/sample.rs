//! Choosing the next token from (masked) logits: greedy by default, or seeded sampling.
//!
//! A thin layer over candle-transformers' `LogitsProcessor`, so temperature, top-k and top-p behave
//! as in candle's examples; logits the grammar forbids are -inf and so get zero probability.

use candle_core::{Device, Tensor};
use candle_transformers::generation::{LogitsProcessor, Sampling as CandleSampling};
use serde::{Deserialize, Serialize};

use super::{LlmError, Result};

/// How the next token is chosen.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Sampling {
    /// The most likely token (deterministic; the default).
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

impl Default for Sampling {
    fn default() -> Self {
        Sampling::Greedy
    }
}

/// A stateful chooser for one generation.
pub struct Sampler {
    inner: LogitsProcessor,
}

impl Sampler {
    pub fn new(sampling: &Sampling) -> Self {
        let (seed, s) = match *sampling {
            Sampling::Greedy => (0, CandleSampling::ArgMax),
            // Parameters are checked by `Sampling::validate` (the engine calls it); 0 is greedy.
            Sampling::Sample { temperature, top_p, seed } if temperature > 0.0 => {
                if top_p < 1.0 {
                    (seed, CandleSampling::TopP { p: top_p, temperature })
                } else {
                    (seed, CandleSampling::All { temperature })
                }
            }
            Sampling::Sample { seed, .. } => (seed, CandleSampling::ArgMax),
        };
        Self { inner: LogitsProcessor::from_sampling(seed, s) }
    }

    /// Picks a token id from `logits` (length = vocabulary).
    pub fn choose(&mut self, logits: &[f32]) -> Result<u32> {
        let t = Tensor::new(logits, &Device::Cpu)?;
        Ok(self.inner.sample(&t)?)
    }
}
