//! Opening and validating a GGUF model file: the architecture from `general.architecture`, clear
//! errors for non-GGUF, truncated or unsupported files, and typed metadata getters that name the
//! missing key.

/// The model architectures the runtime can run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Arch {
    /// llama.cpp's LLAMA (SmolLM2): interleaved rope, usually tied embeddings.
    Llama,
    /// Qwen2 (Qwen2.5): q/k/v biases, NeoX-style rope, separate output matrix.
    Qwen2,
}

impl Arch {
    /// The value of `general.architecture` and the prefix of the architecture's metadata keys.
    pub fn gguf_name(self) -> &'static str {
        match self {
            Arch::Llama => "llama",
            Arch::Qwen2 => "qwen2",
        }
    }

    /// Parses a `general.architecture` value; `None` for an architecture we do not run.
    pub fn from_gguf_name(name: &str) -> Option<Arch> {
        match name {
            "llama" => Some(Arch::Llama),
            "qwen2" => Some(Arch::Qwen2),
            _ => None,
        }
    }
}

impl std::fmt::Display for Arch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.gguf_name())
    }
}
