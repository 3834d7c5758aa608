//! Grammars for the STEP planner's decisions: which actions a grammar may write ([`ActionSet`], at
//! one of three [`Strength`]s), and the three outputs built on it: a decomposition proposal
//! ([`DecomposeGrammar`]), a termination verdict ([`VerdictGrammar`]) and a whole flat plan
//! ([`PlanGrammar`]).
//!
//! Each renders as Lark for llguidance (`to_lark`) and has an independent checker (`parse`): plain
//! string code that shares nothing with llguidance or with the renderer (it asks
//! [`ActionSet::contains`], which reads the spec directly), so tests can prove that every constrained
//! output is what the spec says. The keywords (`subgoal: `, `action: `, `done`, `execute: `,
//! `decompose`, `replan: <cause>: `) are the contract the planner's prompts are written against.
//!
//! Rendering keeps every llguidance row small whatever the scene's size: object lists become single
//! lexemes (upper-case terminals), one rule per verb, and exact two-object lists are grouped by the
//! set of second objects, so no rule is predicted with more alternatives than there are verbs or
//! distinct second-object sets.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::fmt::{self, Write};
use std::str::FromStr;

use crate::action::{parse_action_line, Action, LineSyntax, ObjRef, Verb};

use super::actions::{check_class, check_name, is_text_char, GrammarError, ParseError, VerbSpec, TEXT_CLASS_REGEX};
use super::lark::lark_string;
use super::{MAX_LINES, MAX_TEXT_CHARS, TEXT_CHARS};

/// llguidance's parser refuses a row of more than 2000 Earley items (`max_items_in_row`); a rule
/// rendered here never offers more alternatives than this, or rendering fails with a clear error.
pub const MAX_ALTERNATIVES: usize = 1500;

// ----- strength ---------------------------------------------------------------------------------

/// Which actions a grammar may write (issue 7's three strengths).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Strength {
    /// Any verb with any object of the focus list.
    Format,
    /// Each argument slot limited by the object's properties: no affordance error can be written.
    Typed,
    /// Exactly the actions whose preconditions hold now.
    Feasible,
}

impl Strength {
    pub const ALL: [Strength; 3] = [Strength::Format, Strength::Typed, Strength::Feasible];

    pub fn name(self) -> &'static str {
        match self {
            Strength::Format => "format",
            Strength::Typed => "typed",
            Strength::Feasible => "feasible",
        }
    }
}

impl fmt::Display for Strength {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A grammar strength name that is not one of [`Strength::ALL`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown grammar strength '{0}': use format, typed or feasible")]
pub struct UnknownStrength(pub String);

impl FromStr for Strength {
    type Err = UnknownStrength;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Strength::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| UnknownStrength(s.to_string()))
    }
}

// ----- action sets ------------------------------------------------------------------------------

/// The set of action lines a grammar admits.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ActionSet {
    /// Verbs x per-slot object lists (Format: every object in every slot; Typed: slots filtered by the
    /// object's properties). A verb without `slots` takes any of the objects in every slot; each verb
    /// name must be one of [`Verb::ALL`] with its arity.
    Slots(Vec<VerbSpec>, Vec<ObjRef>),
    /// Exactly these actions (Feasible: two-object verbs need exact pairs).
    Exact(Vec<Action>),
}

impl ActionSet {
    /// The same set without any action of `verbs` (an embodiment narrower than [`Verb::ALL`]).
    pub fn without(self, verbs: &[Verb]) -> ActionSet {
        if verbs.is_empty() {
            return self;
        }
        match self {
            ActionSet::Slots(specs, objects) => ActionSet::Slots(
                specs.into_iter().filter(|s| !verbs.iter().any(|v| v.name() == s.name)).collect(),
                objects,
            ),
            ActionSet::Exact(list) => ActionSet::Exact(list.into_iter().filter(|a| !verbs.contains(&a.verb)).collect()),
        }
    }

    /// Every verb of [`Verb::ALL`] over these objects in every slot.
    pub fn format(objects: &[ObjRef]) -> ActionSet {
        ActionSet::Slots(Verb::ALL.iter().map(|&v| VerbSpec::from(v)).collect(), objects.to_vec())
    }

    /// Whether the set admits `a`. Reads the spec directly (this is the checkers' half, independent
    /// of rendering). For `Slots`, the first spec of a verb name counts.
    pub fn contains(&self, a: &Action) -> bool {
        match self {
            ActionSet::Exact(list) => list.contains(a),
            ActionSet::Slots(verbs, objects) => {
                let Some(spec) = verbs.iter().find(|v| v.name == a.verb.name()) else {
                    return false;
                };
                if spec.arity != a.args.len() || a.verb.arity() != a.args.len() {
                    return false;
                }
                a.args.iter().enumerate().all(|(k, arg)| match &spec.slots {
                    None => objects.contains(arg),
                    Some(slots) => slots.get(k).is_some_and(|s| s.contains(arg)),
                })
            }
        }
    }

    /// The number of distinct action lines admitted.
    pub fn len(&self) -> usize {
        match self {
            ActionSet::Exact(list) => list.iter().collect::<HashSet<_>>().len(),
            ActionSet::Slots(verbs, objects) => {
                let mut seen = HashSet::new();
                let uniq = |l: &[ObjRef]| l.iter().collect::<HashSet<_>>().len();
                verbs
                    .iter()
                    .filter(|v| seen.insert(v.name.as_str()))
                    .filter(|v| Verb::from_str(&v.name).is_ok_and(|x| x.name() == v.name && x.arity() == v.arity))
                    .map(|v| match &v.slots {
                        None => uniq(objects).pow(v.arity as u32),
                        Some(slots) => slots.iter().map(|s| uniq(s)).product(),
                    })
                    .sum()
            }
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The admitted actions, one list per verb in the order of the spec: validates names and
    /// arities, drops verbs that admit nothing.
    fn resolve(&self) -> Result<Vec<VerbEntry>, GrammarError> {
        let check_obj = |o: &ObjRef| check_class(&o.class_name);
        let mut out: Vec<VerbEntry> = Vec::new();
        match self {
            ActionSet::Slots(verbs, objects) => {
                for o in objects {
                    check_obj(o)?;
                }
                let objs = dedup(objects.iter());
                let known: HashSet<&ObjRef> = objs.iter().collect();
                let mut names = BTreeSet::new();
                for spec in verbs {
                    check_name("verb", &spec.name, &['[', ']', ' '])?;
                    if !names.insert(spec.name.as_str()) {
                        return Err(GrammarError::DuplicateVerb(spec.name.clone()));
                    }
                    let verb = Verb::from_str(&spec.name).ok().filter(|v| v.name() == spec.name).ok_or_else(|| {
                        GrammarError::BadName {
                            kind: "verb",
                            name: spec.name.clone(),
                            reason:
                                "it is not one of the embodiment's actions (step::action::Verb), written in upper case"
                                    .into(),
                        }
                    })?;
                    if spec.arity != verb.arity() {
                        return Err(GrammarError::BadArity { verb: spec.name.clone(), arity: spec.arity });
                    }
                    let slots: Vec<Vec<ObjRef>> = match &spec.slots {
                        None => vec![objs.clone(); verb.arity()],
                        Some(slots) => {
                            if slots.len() != verb.arity() {
                                return Err(GrammarError::SlotCount {
                                    verb: spec.name.clone(),
                                    arity: verb.arity(),
                                    got: slots.len(),
                                });
                            }
                            for o in slots.iter().flatten() {
                                if !known.contains(o) {
                                    return Err(GrammarError::UnknownObject {
                                        verb: spec.name.clone(),
                                        object: o.to_string(),
                                    });
                                }
                            }
                            slots.iter().map(|s| dedup(s.iter())).collect()
                        }
                    };
                    let args = match slots.as_slice() {
                        [] => Args::None,
                        [a] => Args::One(a.clone()),
                        [a, b] => Args::Product(a.clone(), b.clone()),
                        _ => unreachable!("verbs have at most two objects"),
                    };
                    if !args.is_empty() {
                        out.push(VerbEntry { verb, args });
                    }
                }
            }
            ActionSet::Exact(actions) => {
                let mut seen = HashSet::new();
                for a in actions {
                    if a.args.len() != a.verb.arity() {
                        return Err(GrammarError::Shape(format!(
                            "action {a} has {} object(s) but {} takes {}; build actions with Action::new",
                            a.args.len(),
                            a.verb,
                            a.verb.arity()
                        )));
                    }
                    for o in &a.args {
                        check_obj(o)?;
                    }
                    if !seen.insert(a) {
                        continue;
                    }
                    let ix = match out.iter().position(|e| e.verb == a.verb) {
                        Some(i) => i,
                        None => {
                            let args = match a.verb.arity() {
                                0 => Args::None,
                                1 => Args::One(Vec::new()),
                                _ => Args::Pairs(Vec::new()),
                            };
                            out.push(VerbEntry { verb: a.verb, args });
                            out.len() - 1
                        }
                    };
                    match (&mut out[ix].args, a.args.as_slice()) {
                        (Args::One(list), [x]) => list.push(x.clone()),
                        (Args::Pairs(pairs), [x, y]) => match pairs.iter_mut().find(|(f, _)| f == x) {
                            Some((_, seconds)) => seconds.push(y.clone()),
                            None => pairs.push((x.clone(), vec![y.clone()])),
                        },
                        _ => {}
                    }
                }
            }
        }
        Ok(out)
    }

    /// Writes the rule `action` (and the rules and terminals it uses) into `g`; `Ok(false)` when the
    /// set admits nothing (no rule written).
    fn write_lark(&self, g: &mut String) -> Result<bool, GrammarError> {
        let entries = self.resolve()?;
        if entries.is_empty() {
            return Ok(false);
        }
        // Object lists as terminals, shared between slots with the same objects.
        let mut terminals: Vec<(String, Vec<String>)> = Vec::new();
        let mut by_content: HashMap<Vec<String>, String> = HashMap::new();
        let mut terminal = |lits: Vec<String>, prefix: &str| -> String {
            if let Some(name) = by_content.get(&lits) {
                return name.clone();
            }
            let name = format!("{prefix}_{}", terminals.len());
            by_content.insert(lits.clone(), name.clone());
            terminals.push((name.clone(), lits));
            name
        };
        let objs = |list: &[ObjRef], suffix: &str| -> Vec<String> {
            let mut v: Vec<String> = list.iter().map(|o| lark_string(&format!("{o}{suffix}"))).collect();
            v.sort();
            v
        };
        let mut verb_rules = Vec::new();
        let mut rules = String::new();
        for (i, e) in entries.iter().enumerate() {
            let name = format!("v_{i}");
            let head = |space: bool| lark_string(&format!("[{}]{}", e.verb.name(), if space { " " } else { "" }));
            let body = match &e.args {
                Args::None => head(false),
                Args::One(list) => format!("{} {}", head(true), terminal(objs(list, ""), "OBJS")),
                Args::Product(a, b) => format!(
                    "{} {} {} {}",
                    head(true),
                    terminal(objs(a, ""), "OBJS"),
                    lark_string(" "),
                    terminal(objs(b, ""), "OBJS")
                ),
                Args::Pairs(pairs) => {
                    // Firsts grouped by their set of seconds: one alternative per distinct set.
                    let mut groups: Vec<(Vec<String>, Vec<&ObjRef>)> = Vec::new();
                    for (first, seconds) in pairs {
                        let key = objs(&dedup(seconds.iter()), "");
                        match groups.iter_mut().find(|(k, _)| *k == key) {
                            Some((_, firsts)) => firsts.push(first),
                            None => groups.push((key, vec![first])),
                        }
                    }
                    if groups.len() > MAX_ALTERNATIVES {
                        return Err(GrammarError::Shape(format!(
                            "{} has {} distinct sets of second objects, more than the grammar engine's {MAX_ALTERNATIVES} \
                             alternatives; narrow the objects",
                            e.verb,
                            groups.len()
                        )));
                    }
                    let alts: Vec<String> = groups
                        .into_iter()
                        .map(|(seconds, firsts)| {
                            let firsts: Vec<ObjRef> = firsts.into_iter().cloned().collect();
                            let f = terminal(objs(&firsts, " "), "FIRST");
                            let s = terminal(seconds, "OBJS");
                            format!("{f} {s}")
                        })
                        .collect();
                    format!("{} ({})", head(true), alts.join(" | "))
                }
            };
            let _ = writeln!(rules, "{name}: {body}");
            verb_rules.push(name);
        }
        let _ = writeln!(g, "action: {}", verb_rules.join(" | "));
        g.push_str(&rules);
        for (name, lits) in &terminals {
            let _ = writeln!(g, "{name}: {}", lits.join(" | "));
        }
        Ok(true)
    }
}

fn dedup<'a>(it: impl Iterator<Item = &'a ObjRef>) -> Vec<ObjRef> {
    let mut seen = HashSet::new();
    it.filter(|o| seen.insert(*o)).cloned().collect()
}

/// One verb's admitted argument lists.
struct VerbEntry {
    verb: Verb,
    args: Args,
}

enum Args {
    None,
    One(Vec<ObjRef>),
    /// Any of the first list, then any of the second.
    Product(Vec<ObjRef>, Vec<ObjRef>),
    /// Exact pairs: each first object with its second objects.
    Pairs(Vec<(ObjRef, Vec<ObjRef>)>),
}

impl Args {
    fn is_empty(&self) -> bool {
        match self {
            Args::None => false,
            Args::One(l) => l.is_empty(),
            Args::Product(a, b) => a.is_empty() || b.is_empty(),
            Args::Pairs(p) => p.is_empty(),
        }
    }
}

// ----- shared pieces of the decision grammars ---------------------------------------------------

const HEADER: &str = "// generated by step::grammar (decision grammars); do not edit by hand\n";

fn text_regex(max_chars: usize) -> String {
    format!("/{TEXT_CLASS_REGEX}{{1,{max_chars}}}/")
}

fn check_text_limit(what: &str, max_chars: usize) -> Result<(), GrammarError> {
    if max_chars == 0 || max_chars > MAX_TEXT_CHARS {
        return Err(GrammarError::Shape(format!("{what} allows {max_chars} characters; use 1..={MAX_TEXT_CHARS}")));
    }
    Ok(())
}

/// A one-line output's checker error (line 1).
fn err1(text: &str, reason: impl Into<String>) -> ParseError {
    ParseError { line: 1, text: text.to_string(), reason: reason.into() }
}

fn spec_error(e: GrammarError) -> ParseError {
    ParseError { line: 0, text: String::new(), reason: e.to_string() }
}

fn check_text(line: &str, value: &str, max: usize) -> Result<(), ParseError> {
    let n = value.chars().count();
    if n == 0 || n > max {
        return Err(err1(line, format!("text has {n} characters; 1..={max} allowed")));
    }
    if let Some(c) = value.chars().find(|&c| !is_text_char(c)) {
        return Err(err1(line, format!("character {c:?} is not allowed in text ({TEXT_CHARS})")));
    }
    Ok(())
}

/// Reads `line` as one action of `set`, in canonical form.
fn check_action(set: &ActionSet, line: &str, body: &str) -> Result<Action, ParseError> {
    let a = parse_action_line(body, LineSyntax::Canonical).map_err(|e| err1(line, e.to_string()))?;
    if !set.contains(&a) {
        return Err(err1(line, format!("{a} is not one of the actions this grammar admits")));
    }
    Ok(a)
}

// ----- decomposition ----------------------------------------------------------------------------

/// Decomposition output: exactly one of
///   `subgoal: <text, 1..=subgoal_chars of TEXT_CHARS>`
///   `action: [VERB] <obj> (id) ...`     (a line from the ActionSet)
///   `done`                               (no more subgoals for this parent)
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DecomposeGrammar {
    pub actions: ActionSet,
    pub subgoal_chars: usize,
    pub allow_subgoal: bool,
    pub allow_done: bool,
    /// When not empty, a subgoal is exactly one of these lines (e.g. a task's goals in words)
    /// instead of free text of at most `subgoal_chars`.
    pub subgoal_menu: Vec<String>,
}

/// A parsed decomposition output.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Proposal {
    Subgoal(String),
    Action(Action),
    Done,
}

impl DecomposeGrammar {
    /// The one line this grammar admits, when it admits exactly one (a single action, one offered
    /// subgoal, or `done` alone): the caller need not ask a model.
    pub fn only_choice(&self) -> Option<String> {
        match &self.actions {
            ActionSet::Exact(list) if list.len() == 1 && !self.allow_subgoal && !self.allow_done => {
                Some(format!("action: {}", list[0]))
            }
            // One offered line left and nothing else (a root working through a task's goal lines).
            ActionSet::Exact(list)
                if list.is_empty() && self.allow_subgoal && self.subgoal_menu.len() == 1 && !self.allow_done =>
            {
                Some(format!("subgoal: {}", self.subgoal_menu[0]))
            }
            ActionSet::Exact(list) if list.is_empty() && !self.allow_subgoal && self.allow_done => Some("done".to_string()),
            _ => None,
        }
    }

    /// Subgoals, actions from `actions` and `done` all allowed.
    pub fn new(actions: ActionSet, subgoal_chars: usize) -> Self {
        Self { actions, subgoal_chars, allow_subgoal: true, allow_done: true, subgoal_menu: Vec::new() }
    }

    pub fn to_lark(&self) -> Result<String, GrammarError> {
        let mut g = String::from(HEADER);
        let mut rules = String::new();
        let mut alts = Vec::new();
        if self.allow_subgoal && !self.subgoal_menu.is_empty() {
            if let Some(bad) = self.subgoal_menu.iter().find(|l| l.trim().is_empty() || l.contains(['\n', '\r'])) {
                return Err(GrammarError::Shape(format!(
                    "subgoal line {bad:?} is empty or spans lines; give each offered subgoal as one non-empty line"
                )));
            }
            let lines: Vec<String> = self.subgoal_menu.iter().map(|l| lark_string(l)).collect();
            alts.push(format!("{} ({})", lark_string("subgoal: "), lines.join(" | ")));
        } else if self.allow_subgoal {
            check_text_limit("the subgoal", self.subgoal_chars)?;
            alts.push(format!("{} {}", lark_string("subgoal: "), text_regex(self.subgoal_chars)));
        }
        if self.actions.write_lark(&mut rules)? {
            alts.push(format!("{} action", lark_string("action: ")));
        }
        if self.allow_done {
            alts.push(lark_string("done"));
        }
        if alts.is_empty() {
            return Err(GrammarError::Shape(
                "the decomposition grammar can write nothing: no action is admitted and subgoal and done are off; \
                 allow subgoal or done"
                    .into(),
            ));
        }
        let _ = writeln!(g, "start: {}", alts.join(" | "));
        g.push_str(&rules);
        Ok(g)
    }

    /// The independent checker: exactly one line of one of the three forms.
    pub fn parse(&self, text: &str) -> Result<Proposal, ParseError> {
        self.actions.resolve().map_err(spec_error)?;
        if text.contains('\n') {
            return Err(err1(text, "a decomposition is one line"));
        }
        if text == "done" {
            return if self.allow_done { Ok(Proposal::Done) } else { Err(err1(text, "'done' is not allowed here")) };
        }
        if let Some(s) = text.strip_prefix("subgoal: ") {
            if !self.allow_subgoal {
                return Err(err1(text, "a subgoal is not allowed here"));
            }
            if self.subgoal_menu.is_empty() {
                check_text(text, s, self.subgoal_chars)?;
            } else if !self.subgoal_menu.iter().any(|l| l == s) {
                return Err(err1(text, "the subgoal is not one of the offered lines"));
            }
            return Ok(Proposal::Subgoal(s.to_string()));
        }
        if let Some(body) = text.strip_prefix("action: ") {
            return check_action(&self.actions, text, body).map(Proposal::Action);
        }
        Err(err1(text, "expected 'subgoal: <text>', 'action: [VERB] <object> (id)' or 'done'"))
    }
}

// ----- termination verdict ----------------------------------------------------------------------

/// Why a subgoal must be replanned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Cause {
    /// The robot cannot do this (no such ability or object property).
    Affordance,
    /// The subgoal does not serve its parent.
    Congruence,
    /// The world does not allow it now.
    Environment,
}

impl Cause {
    pub const ALL: [Cause; 3] = [Cause::Affordance, Cause::Congruence, Cause::Environment];

    /// The keyword in a verdict.
    pub fn name(self) -> &'static str {
        match self {
            Cause::Affordance => "affordance",
            Cause::Congruence => "congruence",
            Cause::Environment => "environment",
        }
    }
}

impl fmt::Display for Cause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Termination verdict: exactly one of
///   `execute: [VERB] <obj> (id) ...`   (one line from the ActionSet)
///   `decompose`
///   `replan: affordance|congruence|environment: <reason, 1..=reason_chars>`
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VerdictGrammar {
    pub actions: ActionSet,
    pub reason_chars: usize,
    pub allow_decompose: bool,
    /// The causes a replan may give (all three by default). A planner that decides affordance and
    /// environment symbolically offers the model only what the world cannot decide (congruence).
    pub causes: Vec<Cause>,
}

/// A parsed verdict.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Verdict {
    Execute(Action),
    Decompose,
    Replan { cause: Cause, reason: String },
}

impl VerdictGrammar {
    /// All three verdicts allowed.
    pub fn new(actions: ActionSet, reason_chars: usize) -> Self {
        Self { actions, reason_chars, allow_decompose: true, causes: Cause::ALL.to_vec() }
    }

    pub fn to_lark(&self) -> Result<String, GrammarError> {
        check_text_limit("the replan reason", self.reason_chars)?;
        let mut g = String::from(HEADER);
        let mut rules = String::new();
        let mut alts = Vec::new();
        if self.actions.write_lark(&mut rules)? {
            alts.push(format!("{} action", lark_string("execute: ")));
        } else if !self.allow_decompose {
            return Err(GrammarError::Shape(
                "the verdict grammar admits no action to execute and decompose is off, so the only verdict left \
                 would be replan; allow decompose or give actions"
                    .into(),
            ));
        }
        if self.allow_decompose {
            alts.push(lark_string("decompose"));
        }
        if self.causes.is_empty() {
            return Err(GrammarError::Shape("the verdict grammar offers no replan cause; give at least one".into()));
        }
        let causes: Vec<String> = self.causes.iter().map(|c| lark_string(c.name())).collect();
        alts.push(format!(
            "{} ({}) {} {}",
            lark_string("replan: "),
            causes.join(" | "),
            lark_string(": "),
            text_regex(self.reason_chars)
        ));
        let _ = writeln!(g, "start: {}", alts.join(" | "));
        g.push_str(&rules);
        Ok(g)
    }

    /// The independent checker: exactly one line of one of the three forms.
    pub fn parse(&self, text: &str) -> Result<Verdict, ParseError> {
        self.actions.resolve().map_err(spec_error)?;
        check_text_limit("the replan reason", self.reason_chars).map_err(spec_error)?;
        if text.contains('\n') {
            return Err(err1(text, "a verdict is one line"));
        }
        if text == "decompose" {
            return if self.allow_decompose {
                Ok(Verdict::Decompose)
            } else {
                Err(err1(text, "'decompose' is not allowed here"))
            };
        }
        if let Some(body) = text.strip_prefix("execute: ") {
            return check_action(&self.actions, text, body).map(Verdict::Execute);
        }
        if let Some(rest) = text.strip_prefix("replan: ") {
            let (cause, reason) = self
                .causes
                .iter()
                .find_map(|&c| rest.strip_prefix(c.name()).and_then(|r| r.strip_prefix(": ")).map(|r| (c, r)))
                .ok_or_else(|| {
                    let names: Vec<&str> = self.causes.iter().map(|c| c.name()).collect();
                    err1(text, &format!("expected 'replan: {}: <reason>'", names.join("|")))
                })?;
            check_text(text, reason, self.reason_chars)?;
            return Ok(Verdict::Replan { cause, reason: reason.to_string() });
        }
        Err(err1(text, "expected 'execute: [VERB] <object> (id)', 'decompose' or 'replan: <cause>: <reason>'"))
    }
}

// ----- whole plan -------------------------------------------------------------------------------

/// Whole plan (flat baseline): 1..=max_lines action lines from the ActionSet, one a line, no
/// trailing newline.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlanGrammar {
    pub actions: ActionSet,
    pub max_lines: usize,
}

impl PlanGrammar {
    fn check_lines(&self) -> Result<(), GrammarError> {
        if self.max_lines == 0 || self.max_lines > MAX_LINES {
            return Err(GrammarError::Shape(format!(
                "a plan of at most {} lines: use 1..={MAX_LINES}",
                self.max_lines
            )));
        }
        Ok(())
    }

    pub fn to_lark(&self) -> Result<String, GrammarError> {
        self.check_lines()?;
        let mut g = String::from(HEADER);
        let mut rules = String::new();
        if !self.actions.write_lark(&mut rules)? {
            return Err(GrammarError::Shape(
                "the plan grammar admits no action, so no plan can be written; give actions (a wider object list \
                 or a weaker grammar strength)"
                    .into(),
            ));
        }
        if self.max_lines == 1 {
            let _ = writeln!(g, "start: action");
        } else {
            let _ = writeln!(g, "start: action ({} action){{0,{}}}", lark_string("\n"), self.max_lines - 1);
        }
        g.push_str(&rules);
        Ok(g)
    }

    /// The independent checker: 1..=max_lines lines, each an admitted action in canonical form.
    pub fn parse(&self, text: &str) -> Result<Vec<Action>, ParseError> {
        self.actions.resolve().map_err(spec_error)?;
        self.check_lines().map_err(spec_error)?;
        let lines: Vec<&str> = text.split('\n').collect();
        if lines.len() > self.max_lines {
            return Err(ParseError {
                line: lines.len(),
                text: lines.last().map(|s| s.to_string()).unwrap_or_default(),
                reason: format!("{} lines; 1..={} allowed", lines.len(), self.max_lines),
            });
        }
        lines
            .iter()
            .enumerate()
            .map(|(i, line)| check_action(&self.actions, line, line).map_err(|e| ParseError { line: i + 1, ..e }))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_choice_is_the_one_admissible_answer() {
        let one = |list: Vec<Action>, sub: bool, done: bool, menu: &[&str]| {
            DecomposeGrammar {
                actions: ActionSet::Exact(list),
                subgoal_chars: 20,
                allow_subgoal: sub,
                allow_done: done,
                subgoal_menu: menu.iter().map(|s| s.to_string()).collect(),
            }
            .only_choice()
        };
        let walk = Action::new(Verb::Walk, vec![ObjRef::new("apple", 12)]).unwrap();
        assert_eq!(one(vec![walk.clone()], false, false, &[]).as_deref(), Some("action: [WALK] <apple> (12)"));
        assert_eq!(one(vec![walk.clone()], false, true, &[]), None);
        assert_eq!(one(vec![], true, false, &["fridge is OPEN"]).as_deref(), Some("subgoal: fridge is OPEN"));
        assert_eq!(one(vec![], true, false, &["fridge is OPEN", "apple is ON"]), None);
        assert_eq!(one(vec![], true, false, &[]), None, "free text is no single answer");
        assert_eq!(one(vec![walk.clone()], true, false, &["fridge is OPEN"]), None);
        assert_eq!(one(vec![], false, true, &[]).as_deref(), Some("done"), "nothing left but done");
        assert_eq!(one(vec![walk], false, true, &[]), None);
    }

    fn o(c: &str, id: u32) -> ObjRef {
        ObjRef::new(c, id)
    }
    fn act(v: Verb, args: &[(&str, u32)]) -> Action {
        Action::new(v, args.iter().map(|&(c, i)| o(c, i)).collect()).unwrap()
    }
    fn kitchen() -> Vec<ObjRef> {
        vec![o("apple", 12), o("fridge", 10), o("kitchencounter", 11)]
    }

    #[test]
    fn strength_names_round_trip() {
        for s in Strength::ALL {
            assert_eq!(s.to_string().parse::<Strength>().unwrap(), s);
        }
        assert_eq!("Typed".parse::<Strength>().unwrap(), Strength::Typed);
        let e = "strong".parse::<Strength>().unwrap_err().to_string();
        assert!(e.contains("'strong'") && e.contains("format, typed or feasible"), "{e}");
    }

    #[test]
    fn format_set_admits_every_verb_over_every_object() {
        let set = ActionSet::format(&kitchen());
        let arity = |k: usize| Verb::ALL.iter().filter(|v| v.arity() == k).count();
        assert_eq!(set.len(), arity(0) + 3 * arity(1) + 9 * arity(2));
        assert!(set.contains(&act(Verb::PutIn, &[("fridge", 10), ("apple", 12)])));
        assert!(!set.contains(&act(Verb::Grab, &[("banana", 3)])));
        let lark = DecomposeGrammar::new(set, 40).to_lark().unwrap();
        assert!(
            lark.contains(r#"start: "subgoal: " /[A-Za-z0-9 ,.'_\-]{1,40}/ | "action: " action | "done""#),
            "{lark}"
        );
        assert!(lark.contains(r#""[PUTIN] " OBJS_0 " " OBJS_0"#), "{lark}");
        assert!(lark.contains(r#"OBJS_0: "<apple> (12)" | "<fridge> (10)" | "<kitchencounter> (11)""#), "{lark}");
        assert!(lark.contains(r#""[STANDUP]""#), "{lark}");
    }

    #[test]
    fn exact_set_groups_pairs_by_their_second_objects() {
        let set = ActionSet::Exact(vec![
            act(Verb::Walk, &[("fridge", 10)]),
            act(Verb::PutIn, &[("apple", 12), ("fridge", 10)]),
            act(Verb::PutIn, &[("knife", 24), ("fridge", 10)]),
            act(Verb::PutBack, &[("apple", 12), ("kitchencounter", 11)]),
            act(Verb::Walk, &[("fridge", 10)]),
            act(Verb::StandUp, &[]),
        ]);
        assert_eq!(set.len(), 5);
        let lark = PlanGrammar { actions: set.clone(), max_lines: 3 }.to_lark().unwrap();
        assert!(lark.contains(r#"start: action ("\n" action){0,2}"#), "{lark}");
        assert!(lark.contains(r#"action: v_0 | v_1 | v_2 | v_3"#), "{lark}");
        // Both PUTIN firsts share one second set: one alternative.
        assert!(lark.contains(r#"v_1: "[PUTIN] " (FIRST_1 OBJS_0)"#), "{lark}");
        assert!(lark.contains(r#"FIRST_1: "<apple> (12) " | "<knife> (24) ""#), "{lark}");
        assert!(!lark.contains("GRAB"), "verbs without actions are absent:\n{lark}");
        let g = PlanGrammar { actions: set, max_lines: 3 };
        let plan = g.parse("[WALK] <fridge> (10)\n[PUTIN] <knife> (24) <fridge> (10)\n[STANDUP]").unwrap();
        assert_eq!(plan.len(), 3);
        let e = g.parse("[WALK] <fridge> (10)\n[PUTIN] <knife> (24) <kitchencounter> (11)").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.reason.contains("not one of the actions"), "{e}");
        assert!(g.parse("[STANDUP]\n[STANDUP]\n[STANDUP]\n[STANDUP]").unwrap_err().reason.contains("4 lines"));
        assert!(g.parse("[STANDUP]\n").is_err(), "a trailing newline is an empty line");
        assert!(g.parse("[STANDUP]  ").is_err());
    }

    #[test]
    fn decompose_checker_reads_the_three_forms() {
        let g = DecomposeGrammar::new(ActionSet::format(&kitchen()), 20);
        assert_eq!(g.parse("done").unwrap(), Proposal::Done);
        assert_eq!(g.parse("subgoal: open the fridge").unwrap(), Proposal::Subgoal("open the fridge".into()));
        assert_eq!(
            g.parse("action: [OPEN] <fridge> (10)").unwrap(),
            Proposal::Action(act(Verb::Open, &[("fridge", 10)]))
        );
        let bad = [
            ("Done", "expected 'subgoal"),
            ("done\n", "one line"),
            ("subgoal: ", "0 characters"),
            ("subgoal: put the apple in the fridge", "27 characters"),
            ("subgoal: a;b", "';'"),
            ("action: [OPEN] <fridge> (11)", "not one of the actions"),
            ("action: [open] <fridge> (10)", "unknown action 'open'"),
            ("action: [OPEN]  <fridge> (10)", "' <'"),
            ("action: [OPEN] <fridge> (010)", "object id"),
            ("action:[OPEN] <fridge> (10)", "expected 'subgoal"),
        ];
        for (text, why) in bad {
            let e = g.parse(text).unwrap_err().to_string();
            assert!(e.contains(why), "{text:?}: {e}");
        }
        let only_actions = DecomposeGrammar { allow_subgoal: false, allow_done: false, ..g.clone() };
        assert!(only_actions.parse("done").is_err());
        assert!(only_actions.parse("subgoal: x").is_err());
        let lark = only_actions.to_lark().unwrap();
        assert!(lark.contains(r#"start: "action: " action"#) && !lark.contains("subgoal"), "{lark}");
    }

    #[test]
    fn an_offered_subgoal_is_one_of_the_lines_exactly() {
        let g = DecomposeGrammar {
            subgoal_menu: vec!["apple is INSIDE to fridge".into(), "tv is ON".into()],
            ..DecomposeGrammar::new(ActionSet::Exact(vec![act(Verb::Open, &[("fridge", 10)])]), 20)
        };
        // Longer than subgoal_chars, still accepted: the lines are given, not written.
        assert_eq!(g.parse("subgoal: apple is INSIDE to fridge").unwrap(), Proposal::Subgoal("apple is INSIDE to fridge".into()));
        let e = g.parse("subgoal: tv is OFF").unwrap_err().to_string();
        assert!(e.contains("not one of the offered lines"), "{e}");
        let lark = g.to_lark().unwrap();
        assert!(lark.contains(r#""subgoal: " ("apple is INSIDE to fridge" | "tv is ON")"#), "{lark}");
        let bad = DecomposeGrammar { subgoal_menu: vec!["two\nlines".into()], ..g.clone() };
        assert!(bad.to_lark().unwrap_err().to_string().contains("spans lines"));
        // Without subgoals allowed, the menu is not offered.
        let off = DecomposeGrammar { allow_subgoal: false, ..g };
        assert!(!off.to_lark().unwrap().contains("subgoal") && off.parse("subgoal: tv is ON").is_err());
    }

    #[test]
    fn an_empty_action_set_leaves_subgoal_and_done_or_is_a_clear_error() {
        let empty = ActionSet::Exact(vec![]);
        assert_eq!(empty.len(), 0);
        let d = DecomposeGrammar::new(empty.clone(), 30);
        let lark = d.to_lark().unwrap();
        assert!(lark.contains(r#"start: "subgoal: " /[A-Za-z0-9 ,.'_\-]{1,30}/ | "done""#), "{lark}");
        assert!(!lark.contains("action"), "{lark}");
        assert!(d.parse("action: [STANDUP]").is_err());
        let none = DecomposeGrammar { allow_subgoal: false, allow_done: false, ..d };
        assert!(none.to_lark().unwrap_err().to_string().contains("can write nothing"));

        let e = PlanGrammar { actions: empty.clone(), max_lines: 4 }.to_lark().unwrap_err().to_string();
        assert!(e.contains("admits no action"), "{e}");
        let v = VerdictGrammar { actions: empty.clone(), reason_chars: 30, allow_decompose: false, causes: Cause::ALL.to_vec() };
        let e = v.to_lark().unwrap_err().to_string();
        assert!(e.contains("allow decompose"), "{e}");
        let v = VerdictGrammar::new(empty, 30);
        let lark = v.to_lark().unwrap();
        assert!(!lark.contains("execute"), "{lark}");
        assert_eq!(v.parse("decompose").unwrap(), Verdict::Decompose);
    }

    #[test]
    fn verdict_checker_reads_the_three_forms() {
        let g = VerdictGrammar::new(ActionSet::Exact(vec![act(Verb::Open, &[("fridge", 10)])]), 25);
        let lark = g.to_lark().unwrap();
        assert!(
            lark.contains(
                r#"start: "execute: " action | "decompose" | "replan: " ("affordance" | "congruence" | "environment") ": " /[A-Za-z0-9 ,.'_\-]{1,25}/"#
            ),
            "{lark}"
        );
        assert_eq!(
            g.parse("execute: [OPEN] <fridge> (10)").unwrap(),
            Verdict::Execute(act(Verb::Open, &[("fridge", 10)]))
        );
        assert_eq!(g.parse("decompose").unwrap(), Verdict::Decompose);
        assert_eq!(
            g.parse("replan: environment: the fridge is locked").unwrap(),
            Verdict::Replan { cause: Cause::Environment, reason: "the fridge is locked".into() }
        );
        for (text, why) in [
            ("execute: [CLOSE] <fridge> (10)", "not one of the actions"),
            ("replan: mood: tired", "affordance|congruence|environment"),
            ("replan: affordance:", "affordance|congruence"),
            ("replan: affordance: ", "0 characters"),
            ("replan: congruence: this reason is far too long", "characters; 1..=25"),
            ("decompose now", "expected 'execute"),
        ] {
            let e = g.parse(text).unwrap_err().to_string();
            assert!(e.contains(why), "{text:?}: {e}");
        }
        let no_dec = VerdictGrammar { allow_decompose: false, ..g };
        assert!(no_dec.parse("decompose").is_err());
        assert!(!no_dec.to_lark().unwrap().contains("\"decompose\""));
    }

    #[test]
    fn bad_specs_are_errors_naming_the_problem() {
        let bad_obj = ActionSet::format(&[o("a<b", 1)]);
        assert!(matches!(
            DecomposeGrammar::new(bad_obj.clone(), 10).to_lark(),
            Err(GrammarError::BadName { kind: "object class", .. })
        ));
        assert_eq!(DecomposeGrammar::new(bad_obj, 10).parse("done").unwrap_err().line, 0);
        let unknown_verb = ActionSet::Slots(vec![VerbSpec::new("FLY", 1)], kitchen());
        let e = PlanGrammar { actions: unknown_verb, max_lines: 2 }.to_lark().unwrap_err().to_string();
        assert!(e.contains("\"FLY\"") && e.contains("not one of the embodiment's actions"), "{e}");
        let arity = ActionSet::Slots(vec![VerbSpec::new("GRAB", 2)], kitchen());
        assert!(matches!(PlanGrammar { actions: arity, max_lines: 2 }.to_lark(), Err(GrammarError::BadArity { .. })));
        let stranger =
            ActionSet::Slots(vec![VerbSpec::from(Verb::Grab).restricted(vec![vec![o("door", 1)]])], kitchen());
        assert!(matches!(
            PlanGrammar { actions: stranger, max_lines: 2 }.to_lark(),
            Err(GrammarError::UnknownObject { .. })
        ));
        let malformed = ActionSet::Exact(vec![Action { verb: Verb::Grab, args: vec![] }]);
        assert!(PlanGrammar { actions: malformed, max_lines: 2 }
            .to_lark()
            .unwrap_err()
            .to_string()
            .contains("Action::new"));
        let set = ActionSet::format(&kitchen());
        assert!(PlanGrammar { actions: set.clone(), max_lines: 0 }.to_lark().is_err());
        assert!(DecomposeGrammar::new(set.clone(), 0).to_lark().is_err());
        assert!(VerdictGrammar::new(set, MAX_TEXT_CHARS + 1).to_lark().is_err());
    }


    #[test]
    fn without_drops_the_verbs_from_both_kinds_of_set() {
        let objs = [ObjRef::new("apple", 12), ObjRef::new("fridge", 10)];
        let ActionSet::Slots(specs, _) = ActionSet::format(&objs).without(&[Verb::Grab, Verb::Sleep]) else {
            panic!("slots expected")
        };
        assert_eq!(specs.len(), Verb::ALL.len() - 2);
        assert!(specs.iter().all(|s| s.name != "GRAB" && s.name != "SLEEP"));
        let grab = Action::new(Verb::Grab, vec![objs[0].clone()]).unwrap();
        let walk = Action::new(Verb::Walk, vec![objs[1].clone()]).unwrap();
        let ActionSet::Exact(list) = ActionSet::Exact(vec![grab, walk.clone()]).without(&[Verb::Grab]) else {
            panic!("exact expected")
        };
        assert_eq!(list, [walk]);
    }
}
