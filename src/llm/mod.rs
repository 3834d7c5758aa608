//! The local LLM runtime (placeholder: issue 3).
pub mod chat;
pub mod constraint;
pub mod error;
pub mod gguf;
pub mod locate;
pub mod tiny;
pub mod tokenizer;
pub use error::{LlmError, Result};
