//! The local LLM runtime (in progress: issue 3).
pub mod chat;
pub mod constraint;
pub mod engine;
pub mod error;
pub mod gguf;
pub mod locate;
pub mod model;
pub mod sample;
pub mod tiny;
pub mod tokenizer;
pub use error::{LlmError, Result};
