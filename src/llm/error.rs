//! The runtime's one error type: every failure names the file, key or grammar at fault and, where
//! there is one, the fix.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum LlmError {
    #[error("model not found: {what}\n  fix: {hint}")]
    ModelNotFound { what: String, hint: String },
    #[error("{path}: not a GGUF model file ({reason})")]
    NotGguf { path: PathBuf, reason: String },
    #[error("{path}: truncated or damaged GGUF file: {detail}")]
    Truncated { path: PathBuf, detail: String },
    #[error("{path}: unsupported model architecture '{arch}' (supported: llama, qwen2)")]
    UnsupportedArch { path: PathBuf, arch: String },
    #[error("{path}: GGUF metadata '{key}' is missing or malformed: {detail}")]
    Metadata { path: PathBuf, key: String, detail: String },
    /// A test model's spec is inconsistent (test support only).
    #[cfg(any(test, feature = "test-support"))]
    #[error("tiny model spec: {0}")]
    TinySpec(String),
    #[error("tokenizer: {0}")]
    Tokenizer(String),
    #[error("chat template: {0}")]
    Template(String),
    #[error("grammar: {0}")]
    Grammar(String),
    #[error("sampling: {0}")]
    Sampling(String),
    #[error("decoding: {0}")]
    Decode(String),
    /// A grammar-constrained generation used all `max_tokens` before the grammar was complete.
    #[error("the grammar was not complete after {max_tokens} tokens (so far: {so_far:?}); raise max tokens")]
    TokenBudget { max_tokens: usize, so_far: String },
    /// The prompt alone does not fit the model's context.
    #[error(
        "the prompt is {prompt_tokens} tokens but the model's context holds {context} positions; shorten the \
         prompt (fewer objects or examples)"
    )]
    PromptTooLong { prompt_tokens: usize, context: usize },
    #[error("{}: {error}", path.display())]
    Io { path: PathBuf, error: std::io::Error },
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

pub type Result<T, E = LlmError> = std::result::Result<T, E>;
