//! Lark grammars for the planner, built from data — the embodiment's verbs and the scene's objects —
//! never written by hand per task, so a grammar-constrained model can only write actions that exist,
//! with the right number of objects, naming objects that are in the scene.
//!
//! [`ActionGrammar`] describes the one family of outputs the planner asks for (header fields such as a
//! verdict or a reason, then 1..=N lines that are actions in VirtualHome script form or free-text
//! subgoals) and renders it as Lark for llguidance ([`ActionGrammar::to_lark`]). Its
//! [`ActionGrammar::parse`] is the independent checker for the same family: plain string code that
//! shares nothing with llguidance, so tests can prove that constrained outputs are what the spec says.
//!
//! The planner's decisions use their own grammars ([`decision`]): an [`ActionSet`] at one of three
//! [`Strength`]s (format, typed by `world::affordance`, feasible now), and on it a decomposition proposal
//! ([`DecomposeGrammar`]), a termination verdict ([`VerdictGrammar`]) and a flat plan
//! ([`PlanGrammar`]), each with `to_lark` and an independent `parse`. Action lines are read and
//! written by `crate::action`'s one parser and renderer, in its canonical form.

mod actions;
pub mod decision;
mod lark;

pub use actions::{
    parse_actions, ActionGrammar, Field, FieldKind, GrammarError, ParseError, Parsed, PlanLine, VerbSpec, MAX_LINES,
    MAX_TEXT_CHARS, TEXT_CHARS, TEXT_SLICE,
};
pub use decision::{
    ActionSet, Cause, DecomposeGrammar, PlanGrammar, Proposal, Strength, UnknownStrength, Verdict,
    VerdictGrammar, MAX_ALTERNATIVES,
};
pub use lark::lark_string;
