//! The local LLM runtime (in progress: issue 3).
pub mod error;
pub mod gguf;
pub mod model;
pub use error::{LlmError, Result};
