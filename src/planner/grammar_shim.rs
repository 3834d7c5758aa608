//! TEMPORARY stand-in for helper C's decision grammars (src/grammar/: Strength, ActionSet,
//! DecomposeGrammar, VerdictGrammar), with the agreed names and keywords, so the planner can be
//! built and tested before C's branch is merged. Deleted at that merge.
#![allow(dead_code)]
// TODO(grammar): delete this file and `use crate::grammar::{...}` once the `grammar` branch is merged.

use std::fmt::Write;

use crate::action::{Action, ObjRef, Verb};
use crate::grammar::lark_string;
use crate::world::World;

pub use super::Strength;

const TEXT_CLASS: &str = r"[A-Za-z0-9 ,.'_\-]";

fn is_text_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, ' ' | ',' | '.' | '\'' | '_' | '-')
}

/// The action lines a grammar admits (the stand-in enumerates them all).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ActionSet(pub Vec<Action>);

impl ActionSet {
    pub fn build(strength: Strength, world: &World, ids: &[u32]) -> ActionSet {
        let objs: Vec<ObjRef> = {
            let mut v: Vec<ObjRef> = ids
                .iter()
                .filter(|&&id| id != world.character())
                .filter_map(|&id| world.node(id).map(|n| ObjRef::new(n.class_name, id)))
                .collect();
            v.sort_by_key(|o| o.id);
            v.dedup();
            v
        };
        match strength {
            Strength::Feasible => ActionSet(world.feasible_actions_among(ids)),
            // The stand-in has no property filter: typed is format here.
            Strength::Format | Strength::Typed => {
                let mut out = Vec::new();
                for &verb in Verb::ALL {
                    match verb.arity() {
                        0 => out.push(Action { verb, args: vec![] }),
                        1 => out.extend(objs.iter().map(|o| Action { verb, args: vec![o.clone()] })),
                        _ => {
                            for a in &objs {
                                for b in &objs {
                                    if a != b {
                                        out.push(Action { verb, args: vec![a.clone(), b.clone()] });
                                    }
                                }
                            }
                        }
                    }
                }
                ActionSet(out)
            }
        }
    }

    pub fn exact(actions: Vec<Action>) -> ActionSet {
        ActionSet(actions)
    }

    pub fn contains(&self, a: &Action) -> bool {
        self.0.contains(a)
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    fn rule(&self) -> String {
        let alts: Vec<String> = self.0.iter().map(|a| lark_string(&a.to_string())).collect();
        format!("action: {}\n", alts.join(" | "))
    }

    fn parse(&self, s: &str) -> Result<Action, String> {
        self.0.iter().find(|a| a.to_string() == s).cloned().ok_or_else(|| format!("{s:?} is not an admitted action"))
    }
}

#[derive(Clone, Debug)]
pub struct DecomposeGrammar {
    pub actions: ActionSet,
    pub subgoal_chars: usize,
    pub allow_subgoal: bool,
    pub allow_done: bool,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Proposal {
    Subgoal(String),
    Action(Action),
    Done,
}

impl DecomposeGrammar {
    pub fn to_lark(&self) -> Result<String, String> {
        let mut alts = Vec::new();
        if self.allow_subgoal {
            alts.push(format!("{} /{TEXT_CLASS}{{1,{}}}/", lark_string("subgoal: "), self.subgoal_chars));
        }
        if !self.actions.is_empty() {
            alts.push(format!("{} action", lark_string("action: ")));
        }
        if self.allow_done {
            alts.push(lark_string("done"));
        }
        if alts.is_empty() {
            return Err("the decomposition grammar admits nothing".into());
        }
        let mut g = format!("start: {}\n", alts.join(" | "));
        if !self.actions.is_empty() {
            g.push_str(&self.actions.rule());
        }
        Ok(g)
    }

    pub fn parse(&self, text: &str) -> Result<Proposal, String> {
        if let Some(t) = text.strip_prefix("subgoal: ").filter(|_| self.allow_subgoal) {
            let n = t.chars().count();
            if n == 0 || n > self.subgoal_chars || !t.chars().all(is_text_char) {
                return Err(format!("bad subgoal text {t:?}"));
            }
            return Ok(Proposal::Subgoal(t.to_string()));
        }
        if let Some(a) = text.strip_prefix("action: ") {
            return self.actions.parse(a).map(Proposal::Action);
        }
        if text == "done" && self.allow_done {
            return Ok(Proposal::Done);
        }
        Err(format!("{text:?} is not a decomposition"))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cause {
    Affordance,
    Congruence,
    Environment,
}

impl Cause {
    pub const ALL: [Cause; 3] = [Cause::Affordance, Cause::Congruence, Cause::Environment];
    pub fn name(self) -> &'static str {
        match self {
            Cause::Affordance => "affordance",
            Cause::Congruence => "congruence",
            Cause::Environment => "environment",
        }
    }
}

impl std::fmt::Display for Cause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Verdict {
    Execute(Action),
    Decompose,
    Replan { cause: Cause, reason: String },
}

#[derive(Clone, Debug)]
pub struct VerdictGrammar {
    pub actions: ActionSet,
    pub reason_chars: usize,
    pub allow_decompose: bool,
}

impl VerdictGrammar {
    pub fn to_lark(&self) -> Result<String, String> {
        let mut alts = Vec::new();
        if !self.actions.is_empty() {
            alts.push(format!("{} action", lark_string("execute: ")));
        }
        if self.allow_decompose {
            alts.push(lark_string("decompose"));
        }
        let causes: Vec<String> = Cause::ALL.iter().map(|c| lark_string(c.name())).collect();
        alts.push(format!(
            "{} ({}) {} /{TEXT_CLASS}{{1,{}}}/",
            lark_string("replan: "),
            causes.join(" | "),
            lark_string(": "),
            self.reason_chars
        ));
        let mut g = String::new();
        let _ = writeln!(g, "start: {}", alts.join(" | "));
        if !self.actions.is_empty() {
            g.push_str(&self.actions.rule());
        }
        Ok(g)
    }

    pub fn parse(&self, text: &str) -> Result<Verdict, String> {
        if let Some(a) = text.strip_prefix("execute: ") {
            return self.actions.parse(a).map(Verdict::Execute);
        }
        if text == "decompose" && self.allow_decompose {
            return Ok(Verdict::Decompose);
        }
        if let Some(rest) = text.strip_prefix("replan: ") {
            for c in Cause::ALL {
                if let Some(r) = rest.strip_prefix(c.name()).and_then(|r| r.strip_prefix(": ")) {
                    let n = r.chars().count();
                    if n == 0 || n > self.reason_chars || !r.chars().all(is_text_char) {
                        return Err(format!("bad reason {r:?}"));
                    }
                    return Ok(Verdict::Replan { cause: c, reason: r.to_string() });
                }
            }
        }
        Err(format!("{text:?} is not a verdict"))
    }
}
