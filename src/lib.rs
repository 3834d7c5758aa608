//! `step`: an offline, embedded task planner for robots, after the STEP paper (subgoal trees).
//!
//! An instruction becomes the root of a subgoal tree; a small quantised LLM running on the robot's CPU
//! decomposes each node into ordered children, a termination model decides for each new subgoal whether
//! it is a primitive action (execute it), needs decomposing further, or is inconsistent (replan the
//! parent), and every model output is grammar-constrained so it parses by construction.
//!
//! The modules follow the data flow, one way:
//! - [`action`]: the embodiment's primitive actions (verbs, arities).
//! - [`world`]: the symbolic VirtualHome world: scene graphs, the executor, observations. No LLM.
//! - [`program`]: plans as text: VirtualHome program lines, JSON, and EAI's LLM-output format.
//! - [`eval`]: task sets (EAI's VirtualHome set, a user's own file), goal checks, metrics.
//! - [`grammar`]: Lark grammars built from the embodiment and the scene.
//! - [`planner`]: the STEP planner: subgoal tree, decomposition and termination, closed loop.
//! - [`llm`]: the local runtime: GGUF loading, tokenizer and chat template from the GGUF, forward pass,
//!   sampling, grammar-constrained decoding, prompt-prefix reuse.
//! - [`bench`]: whole-pipeline measurements behind `step bench` (JSON).
//! - [`cli`]: the `step` command's subcommands; a thin layer over the library.

pub mod action;
pub mod bench;
pub mod cli;
pub mod eval;
pub mod grammar;
pub mod llm;
pub mod planner;
pub mod program;
pub mod world;
