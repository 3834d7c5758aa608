//! The local LLM runtime: a quantised GGUF model on the CPU, decoding under a grammar.
//!
//! The flow, one module per step: [`locate`] finds the file, [`gguf`] validates it and reads its
//! metadata, [`tokenizer`] and [`chat`] are rebuilt from that metadata (no tokenizer.json ships with
//! these models), [`model`] is the forward pass with an owned KV cache, [`constraint`] turns a Lark
//! grammar into a token mask per step (llguidance), [`sample`] chooses a token, and [`engine`] runs the
//! loop with prompt-prefix reuse behind the one trait the planner sees, [`engine::Generate`];
//! [`prefix`] keeps a prompt's constant beginning on disk between runs.
//! `tiny` writes random-weight models of each architecture for tests and benches; it is compiled only
//! with the `test-support` feature (this crate's tests and benches enable it), not part of the API.

pub mod chat;
pub mod constraint;
pub mod engine;
pub mod error;
pub mod gguf;
pub mod kernels;
pub mod locate;
pub mod mem;
pub mod model;
pub mod prefix;
pub mod sample;
/// Test support (the `test-support` feature, on for this crate's own tests and benches only).
#[cfg(any(test, feature = "test-support"))]
pub mod tiny;
pub mod tokenizer;

pub use error::{LlmError, Result};
