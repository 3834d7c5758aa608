//! The local LLM runtime (placeholder: issue 3).
pub mod constraint;
pub mod error;
pub use error::{LlmError, Result};
