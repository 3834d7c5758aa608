//! The action-list grammar family: its spec ([`ActionGrammar`]), its Lark rendering, and an
//! independent checker/parser for texts of the family.
//!
//! A sentence is, line by line (separated by `\n`, no trailing newline):
//! - the header fields in order, each `label: value` (a bounded free text or one of fixed choices);
//! - then `min_lines..=max_lines` body lines, each an action exactly as [`Action`]'s `Display` prints
//!   it (`[PUTIN] <apple> (12) <fridge> (5)`, `[STANDUP]`), or, if enabled, a free-text subgoal line
//!   `label: text`.

use std::collections::BTreeSet;
use std::fmt::Write;

use crate::action::{action_line, name_problem, parse_action_line, parse_action_parts, Action, LineSyntax, ObjRef, Verb};

use super::lark::lark_string;

/// Characters a free-text field may use (described in words for prompts and errors).
pub const TEXT_CHARS: &str = "ASCII letters, digits, space and , . ' _ -";
/// The same class as a regex character class, for the Lark rendering.
pub(super) const TEXT_CLASS_REGEX: &str = r"[A-Za-z0-9 ,.'_\-]";
/// Tokens made only of text characters, up to 10 of them: the grammar engine precomputes this slice of
/// the vocabulary and allows it in bulk inside a free-text field with at least 10 characters left,
/// instead of walking the whole vocabulary (about halves the mask time in text on SmolLM2's vocabulary).
pub const TEXT_SLICE: &str = r"[A-Za-z0-9 ,.'_\-]{1,10}";
/// Upper bound on a free-text field's length (keeps grammars and generations small).
pub const MAX_TEXT_CHARS: usize = 1000;
/// Upper bound on the number of body lines.
pub const MAX_LINES: usize = 256;

pub(super) fn is_text_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, ' ' | ',' | '.' | '\'' | '_' | '-')
}

/// A verb as the grammar sees it: a script name, an arity, and optionally per argument slot the
/// objects it may take (a feasibility mask); without a restriction every scene object fits every slot.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VerbSpec {
    pub name: String,
    pub arity: usize,
    /// `Some(slots)`: `slots.len() == arity`, `slots[i]` the objects allowed as argument `i`
    /// (each must be one of the grammar's scene objects).
    pub slots: Option<Vec<Vec<ObjRef>>>,
}

impl VerbSpec {
    pub fn new(name: impl Into<String>, arity: usize) -> Self {
        Self { name: name.into(), arity, slots: None }
    }

    /// Restricts argument `i` to `slots[i]`.
    pub fn restricted(mut self, slots: Vec<Vec<ObjRef>>) -> Self {
        self.slots = Some(slots);
        self
    }
}

impl From<Verb> for VerbSpec {
    fn from(v: Verb) -> Self {
        VerbSpec::new(v.name(), v.arity())
    }
}

/// What a header field's value may be.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FieldKind {
    /// 1..=`max_chars` characters of [`TEXT_CHARS`].
    Text { max_chars: usize },
    /// Exactly one of these strings.
    Choice(Vec<String>),
}

/// A header line `label: value`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Field {
    pub label: String,
    pub kind: FieldKind,
}

/// The spec of one grammar of the family. Build it with [`ActionGrammar::new`] and the chaining
/// methods; [`ActionGrammar::to_lark`] and [`ActionGrammar::parse`] validate it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ActionGrammar {
    pub verbs: Vec<VerbSpec>,
    pub objects: Vec<ObjRef>,
    pub min_lines: usize,
    pub max_lines: usize,
    pub header: Vec<Field>,
    /// Free-text body lines `label: text` allowed among the actions: `(label, max_chars)`.
    pub subgoal: Option<(String, usize)>,
}

/// A spec that cannot become a grammar; the message names the verb, object or field and the fix.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GrammarError {
    #[error("{kind} {name:?} cannot be used in an action grammar: {reason}")]
    BadName { kind: &'static str, name: String, reason: String },
    #[error("verb {0:?} is listed twice; list each verb once")]
    DuplicateVerb(String),
    #[error("verb {verb:?} has arity {arity}; arities are 0, 1 or 2")]
    BadArity { verb: String, arity: usize },
    #[error("verb {verb:?} restricts {got} argument slot(s) but takes {arity}; give one object list per argument")]
    SlotCount { verb: String, arity: usize, got: usize },
    #[error(
        "verb {verb:?} allows object {object} which is not among the scene objects; add it to the objects or drop it"
    )]
    UnknownObject { verb: String, object: String },
    #[error("{0}")]
    Shape(String),
}

/// Why a text is not a sentence of the grammar: the 1-based line, the line itself and the problem.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {reason} (line: {text:?})")]
pub struct ParseError {
    pub line: usize,
    pub text: String,
    pub reason: String,
}

/// One body line of a parsed text.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PlanLine {
    Action { verb: String, args: Vec<ObjRef> },
    Subgoal(String),
}

/// A text of the family, parsed: header values in order, then the body lines.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Parsed {
    pub fields: Vec<(String, String)>,
    pub lines: Vec<PlanLine>,
}

impl Parsed {
    /// The action lines as [`Action`]s (subgoal lines are skipped); a verb that is not one of
    /// [`Verb::ALL`] is an error naming the line.
    pub fn actions(&self) -> Result<Vec<Action>, ParseError> {
        let h = self.fields.len();
        let mut out = Vec::new();
        for (i, l) in self.lines.iter().enumerate() {
            if let PlanLine::Action { verb, args } = l {
                let err = |reason: String| ParseError { line: h + i + 1, text: render(verb, args), reason };
                let v: Verb = verb.parse().map_err(|e: crate::action::UnknownVerb| err(e.to_string()))?;
                out.push(Action::new(v, args.clone()).map_err(|e| err(e.to_string()))?);
            }
        }
        Ok(out)
    }
}

/// The script form of an action line with an arbitrary verb name (as [`Action`]'s `Display`).
fn render(verb: &str, args: &[ObjRef]) -> String {
    action_line(verb, args)
}

/// Parses a plain action list — every line an action of [`Verb::ALL`] with its arity, in canonical
/// form — as the example grammars under `grammars/` produce.
pub fn parse_actions(text: &str) -> Result<Vec<Action>, ParseError> {
    text.split('\n')
        .enumerate()
        .map(|(i, line)| {
            parse_action_line(line, LineSyntax::Canonical).map_err(|e| ParseError {
                line: i + 1,
                text: line.to_string(),
                reason: e.to_string(),
            })
        })
        .collect()
}

/// A name of `kind` the grammar spells out, by [`name_problem`].
pub(super) fn check_name(kind: &'static str, name: &str, forbidden: &[char]) -> Result<(), GrammarError> {
    bad_name(kind, name, name_problem(name, forbidden))
}

/// An object's class, by the rule the scene loader applies too ([`ObjRef::class_name_problem`]).
pub(super) fn check_class(name: &str) -> Result<(), GrammarError> {
    bad_name("object class", name, ObjRef::class_name_problem(name))
}

fn bad_name(kind: &'static str, name: &str, problem: Option<String>) -> Result<(), GrammarError> {
    match problem {
        Some(reason) => Err(GrammarError::BadName { kind, name: name.to_string(), reason }),
        None => Ok(()),
    }
}

fn check_label(label: &str) -> Result<(), GrammarError> {
    check_name("label", label, &[])?;
    if let Some(c) = label.chars().find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | ' '))) {
        return Err(GrammarError::BadName {
            kind: "label",
            name: label.to_string(),
            reason: format!("it contains {c:?}; labels use ASCII letters, digits, '_', '-' and space"),
        });
    }
    Ok(())
}

fn check_text_limit(label: &str, max_chars: usize) -> Result<(), GrammarError> {
    if max_chars == 0 || max_chars > MAX_TEXT_CHARS {
        return Err(GrammarError::Shape(format!(
            "text field {label:?} allows {max_chars} characters; use 1..={MAX_TEXT_CHARS}"
        )));
    }
    Ok(())
}

/// A verb ready to render: name, and per slot the indices (into the deduplicated objects) allowed.
struct ResolvedVerb<'a> {
    name: &'a str,
    slots: Vec<Vec<usize>>,
}

/// A validated spec: deduplicated objects and per-verb slot sets.
struct Resolved<'a> {
    objects: Vec<&'a ObjRef>,
    verbs: Vec<ResolvedVerb<'a>>,
}

impl ActionGrammar {
    /// A grammar over these verbs and scene objects, 1..=16 action lines, no header, no subgoals.
    pub fn new(verbs: impl IntoIterator<Item = VerbSpec>, objects: impl IntoIterator<Item = ObjRef>) -> Self {
        Self {
            verbs: verbs.into_iter().collect(),
            objects: objects.into_iter().collect(),
            min_lines: 1,
            max_lines: 16,
            header: Vec::new(),
            subgoal: None,
        }
    }

    /// All of the embodiment's verbs ([`Verb::ALL`]) over these objects.
    pub fn for_scene(objects: impl IntoIterator<Item = ObjRef>) -> Self {
        Self::new(Verb::ALL.iter().map(|&v| VerbSpec::from(v)), objects)
    }

    /// Between `min` and `max` body lines.
    pub fn lines(mut self, min: usize, max: usize) -> Self {
        self.min_lines = min;
        self.max_lines = max;
        self
    }

    /// Adds a header field `label: <text>` of 1..=`max_chars` characters of [`TEXT_CHARS`].
    pub fn header_text(mut self, label: impl Into<String>, max_chars: usize) -> Self {
        self.header.push(Field { label: label.into(), kind: FieldKind::Text { max_chars } });
        self
    }

    /// Adds a header field `label: <one of choices>`.
    pub fn header_choice<S: Into<String>>(
        mut self,
        label: impl Into<String>,
        choices: impl IntoIterator<Item = S>,
    ) -> Self {
        let choices = choices.into_iter().map(Into::into).collect();
        self.header.push(Field { label: label.into(), kind: FieldKind::Choice(choices) });
        self
    }

    /// Allows free-text body lines `label: <text>` (1..=`max_chars` of [`TEXT_CHARS`]) among the actions.
    pub fn subgoals(mut self, label: impl Into<String>, max_chars: usize) -> Self {
        self.subgoal = Some((label.into(), max_chars));
        self
    }

    fn resolve(&self) -> Result<Resolved<'_>, GrammarError> {
        let mut objects: Vec<&ObjRef> = Vec::new();
        let mut seen = BTreeSet::new();
        for o in &self.objects {
            check_class(&o.class_name)?;
            if seen.insert(o) {
                objects.push(o);
            }
        }
        let index = |o: &ObjRef| objects.iter().position(|x| *x == o);
        let mut names = BTreeSet::new();
        let mut verbs = Vec::new();
        for v in &self.verbs {
            check_name("verb", &v.name, &['[', ']', ' '])?;
            if !names.insert(v.name.as_str()) {
                return Err(GrammarError::DuplicateVerb(v.name.clone()));
            }
            if v.arity > 2 {
                return Err(GrammarError::BadArity { verb: v.name.clone(), arity: v.arity });
            }
            let slots: Vec<Vec<usize>> = match &v.slots {
                None => vec![(0..objects.len()).collect(); v.arity],
                Some(slots) => {
                    if slots.len() != v.arity {
                        return Err(GrammarError::SlotCount { verb: v.name.clone(), arity: v.arity, got: slots.len() });
                    }
                    let mut out = Vec::new();
                    for slot in slots {
                        let mut idx = BTreeSet::new();
                        for o in slot {
                            let i = index(o).ok_or_else(|| GrammarError::UnknownObject {
                                verb: v.name.clone(),
                                object: o.to_string(),
                            })?;
                            idx.insert(i);
                        }
                        out.push(idx.into_iter().collect());
                    }
                    out
                }
            };
            // A verb with an empty slot cannot be written: it is left out of the grammar (this is
            // what a feasibility mask asks for), not an error.
            if slots.iter().all(|s| !s.is_empty()) {
                verbs.push(ResolvedVerb { name: &v.name, slots });
            }
        }

        let mut labels = BTreeSet::new();
        for f in &self.header {
            check_label(&f.label)?;
            if !labels.insert(f.label.as_str()) {
                return Err(GrammarError::Shape(format!("label {:?} is used twice; labels must differ", f.label)));
            }
            match &f.kind {
                FieldKind::Text { max_chars } => check_text_limit(&f.label, *max_chars)?,
                FieldKind::Choice(choices) => {
                    if choices.is_empty() {
                        return Err(GrammarError::Shape(format!(
                            "choice field {:?} has no choices; give at least one",
                            f.label
                        )));
                    }
                    for c in choices {
                        check_name("choice", c, &[])?;
                    }
                }
            }
        }
        if let Some((label, max_chars)) = &self.subgoal {
            check_label(label)?;
            if label.starts_with('[') || !labels.insert(label.as_str()) {
                return Err(GrammarError::Shape(format!(
                    "subgoal label {label:?} is also a header label; labels must differ"
                )));
            }
            check_text_limit(label, *max_chars)?;
        }

        if self.max_lines > MAX_LINES || self.min_lines > self.max_lines {
            return Err(GrammarError::Shape(format!(
                "lines {}..={}: need min <= max <= {MAX_LINES}",
                self.min_lines, self.max_lines
            )));
        }
        if self.header.is_empty() && self.min_lines == 0 {
            return Err(GrammarError::Shape(
                "without header fields at least one line is needed (min_lines >= 1)".into(),
            ));
        }
        if self.min_lines > 0 && verbs.is_empty() && self.subgoal.is_none() {
            return Err(GrammarError::Shape(
                "no line can be written: no verb has objects for all its arguments and subgoal lines are off".into(),
            ));
        }
        Ok(Resolved { objects, verbs })
    }

    /// Checks the spec without rendering it.
    pub fn validate(&self) -> Result<(), GrammarError> {
        self.resolve().map(|_| ())
    }

    /// The Lark grammar (llguidance dialect) whose sentences are exactly those [`Self::parse`] accepts.
    pub fn to_lark(&self) -> Result<String, GrammarError> {
        let r = self.resolve()?;
        let mut g = String::new();
        let text_rx = |k: usize| format!("/{TEXT_CLASS_REGEX}{{1,{k}}}/");
        // Writing into a String cannot fail; `let _ =` below drops an always-Ok result.
        let _ = writeln!(g, "// generated by step::grammar::ActionGrammar; do not edit by hand");

        let has_line = !r.verbs.is_empty() || self.subgoal.is_some();
        // start: header fields, then the body lines.
        let mut start: Vec<String> = Vec::new();
        for i in 0..self.header.len() {
            if i > 0 {
                start.push(lark_string("\n"));
            }
            start.push(format!("field_{i}"));
        }
        let rep = |lo: usize, hi: usize| -> String {
            // Lark ranges cannot end at 0; callers never ask for {0,0}.
            if lo == hi {
                format!("{{{lo}}}")
            } else {
                format!("{{{lo},{hi}}}")
            }
        };
        if has_line && self.max_lines > 0 {
            let sep_line = format!("({} line)", lark_string("\n"));
            if self.header.is_empty() {
                start.push("line".into());
                if self.max_lines > 1 {
                    start.push(format!("{sep_line}{}", rep(self.min_lines.saturating_sub(1), self.max_lines - 1)));
                }
            } else {
                start.push(format!("{sep_line}{}", rep(self.min_lines, self.max_lines)));
            }
        }
        let _ = writeln!(g, "start: {}", start.join(" "));

        for (i, f) in self.header.iter().enumerate() {
            let prefix = lark_string(&format!("{}: ", f.label));
            let value = match &f.kind {
                FieldKind::Text { max_chars } => text_rx(*max_chars),
                FieldKind::Choice(choices) => {
                    let uniq: BTreeSet<&String> = choices.iter().collect();
                    let alts: Vec<String> = uniq.into_iter().map(|c| lark_string(c)).collect();
                    format!("({})", alts.join(" | "))
                }
            };
            let _ = writeln!(g, "field_{i}: {prefix} {value}");
        }

        if has_line && self.max_lines > 0 {
            let mut alts = Vec::new();
            if !r.verbs.is_empty() {
                alts.push("action".to_string());
            }
            if let Some((label, k)) = &self.subgoal {
                alts.push(format!("{} {}", lark_string(&format!("{label}: ")), text_rx(*k)));
            }
            let _ = writeln!(g, "line: {}", alts.join(" | "));
        }

        // Object sets shared between slots with the same allowed objects.
        let mut sets: Vec<&Vec<usize>> = Vec::new();
        let mut action_alts = Vec::new();
        // Without body lines the action rules would be unreachable: leave them out.
        let verbs: &[ResolvedVerb] = if self.max_lines > 0 { &r.verbs } else { &[] };
        for v in verbs {
            if v.slots.is_empty() {
                action_alts.push(lark_string(&format!("[{}]", v.name)));
                continue;
            }
            let mut parts = vec![lark_string(&format!("[{}] ", v.name))];
            for (k, slot) in v.slots.iter().enumerate() {
                if k > 0 {
                    parts.push(lark_string(" "));
                }
                let id = match sets.iter().position(|x| **x == *slot) {
                    Some(id) => id,
                    None => {
                        sets.push(slot);
                        sets.len() - 1
                    }
                };
                parts.push(format!("objs_{id}"));
            }
            action_alts.push(parts.join(" "));
        }
        if !action_alts.is_empty() {
            let _ = writeln!(g, "action: {}", action_alts.join("\n      | "));
        }
        for (id, set) in sets.iter().enumerate() {
            let alts: Vec<String> =
                set.iter().filter_map(|&i| r.objects.get(i)).map(|o| lark_string(&o.to_string())).collect();
            let _ = writeln!(g, "objs_{id}: {}", alts.join(" | "));
        }
        Ok(g)
    }

    /// Parses `text` as a sentence of this grammar, checking everything the spec says: the header
    /// fields in order, the number of lines, each verb and its arity, each object against the verb's
    /// allowed objects, each free text's characters and length. Independent of llguidance.
    pub fn parse(&self, text: &str) -> Result<Parsed, ParseError> {
        let r = self.resolve().map_err(|e| ParseError { line: 0, text: String::new(), reason: e.to_string() })?;
        let lines: Vec<&str> = text.split('\n').collect();
        let err = |i: usize, reason: String| ParseError {
            line: i + 1,
            text: lines.get(i).map(|s| s.to_string()).unwrap_or_default(),
            reason,
        };
        let check_text = |i: usize, value: &str, max: usize| -> Result<(), ParseError> {
            let n = value.chars().count();
            if n == 0 || n > max {
                return Err(err(i, format!("text has {n} characters; 1..={max} allowed")));
            }
            if let Some(c) = value.chars().find(|&c| !is_text_char(c)) {
                return Err(err(i, format!("character {c:?} is not allowed in text ({TEXT_CHARS})")));
            }
            Ok(())
        };

        let mut fields = Vec::new();
        for (i, f) in self.header.iter().enumerate() {
            let line = lines.get(i).copied().ok_or_else(|| err(i, format!("missing field {:?}", f.label)))?;
            let value = line
                .strip_prefix(f.label.as_str())
                .and_then(|v| v.strip_prefix(": "))
                .ok_or_else(|| err(i, format!("expected field '{}: …'", f.label)))?;
            match &f.kind {
                FieldKind::Text { max_chars } => check_text(i, value, *max_chars)?,
                FieldKind::Choice(choices) => {
                    if !choices.iter().any(|c| c == value) {
                        return Err(err(i, format!("{value:?} is not one of {choices:?}")));
                    }
                }
            }
            fields.push((f.label.clone(), value.to_string()));
        }

        let h = self.header.len();
        // With a header and no body, the text ends after the last field: no body lines at all.
        let body: &[&str] = if h > 0 && lines.len() == h { &[] } else { lines.get(h..).unwrap_or(&[]) };
        if body.len() < self.min_lines || body.len() > self.max_lines {
            return Err(err(
                lines.len().saturating_sub(1),
                format!("{} body line(s); {}..={} allowed", body.len(), self.min_lines, self.max_lines),
            ));
        }
        let mut out = Vec::new();
        for (j, line) in body.iter().enumerate() {
            let i = h + j;
            if line.starts_with('[') {
                let (verb, args) = parse_action_parts(line, LineSyntax::Canonical)
                    .map(|p| (p.verb, p.args))
                    .map_err(|e| err(i, e.to_string()))?;
                let v = r
                    .verbs
                    .iter()
                    .find(|v| v.name == verb)
                    .ok_or_else(|| err(i, format!("verb {verb:?} is not allowed here")))?;
                if args.len() != v.slots.len() {
                    return Err(err(i, format!("{verb} takes {} object(s), got {}", v.slots.len(), args.len())));
                }
                for (k, a) in args.iter().enumerate() {
                    let ok = v.slots.get(k).is_some_and(|slot| slot.iter().any(|&o| r.objects.get(o) == Some(&a)));
                    if !ok {
                        return Err(err(i, format!("object {a} is not allowed as argument {} of {verb}", k + 1)));
                    }
                }
                out.push(PlanLine::Action { verb, args });
            } else if let Some((label, max)) = &self.subgoal {
                let value = line
                    .strip_prefix(label.as_str())
                    .and_then(|v| v.strip_prefix(": "))
                    .ok_or_else(|| err(i, format!("expected an action or '{label}: …'")))?;
                check_text(i, value, *max)?;
                out.push(PlanLine::Subgoal(value.to_string()));
            } else {
                return Err(err(i, "expected an action line '[VERB] <object> (id)'".into()));
            }
        }
        Ok(Parsed { fields, lines: out })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kitchen() -> Vec<ObjRef> {
        vec![ObjRef::new("apple", 12), ObjRef::new("fridge", 5), ObjRef::new("kitchen_counter", 7)]
    }

    #[test]
    fn renders_verbs_by_arity_and_objects_from_the_list_only() {
        let g = ActionGrammar::new(
            [VerbSpec::new("GRAB", 1), VerbSpec::new("PUTIN", 2), VerbSpec::new("STANDUP", 0)],
            kitchen(),
        );
        let lark = g.to_lark().unwrap();
        assert!(lark.contains(r#""[GRAB] " objs_0"#), "{lark}");
        assert!(lark.contains(r#""[PUTIN] " objs_0 " " objs_0"#), "{lark}");
        assert!(lark.contains(r#""[STANDUP]""#), "{lark}");
        assert!(lark.contains(r#"objs_0: "<apple> (12)" | "<fridge> (5)" | "<kitchen_counter> (7)""#), "{lark}");
        assert!(lark.contains(r#"start: line ("\n" line){0,15}"#), "{lark}");

        let p = g.parse("[GRAB] <apple> (12)\n[PUTIN] <apple> (12) <fridge> (5)\n[STANDUP]").unwrap();
        assert_eq!(p.lines.len(), 3);
        let acts = p.actions().unwrap();
        assert_eq!(acts[1].to_string(), "[PUTIN] <apple> (12) <fridge> (5)");
    }

    #[test]
    fn checker_rejects_what_the_spec_forbids() {
        let g = ActionGrammar::new([VerbSpec::new("GRAB", 1), VerbSpec::new("STANDUP", 0)], kitchen()).lines(1, 2);
        let bad = [
            ("", "expected an action line"),
            ("[GRAB] <banana> (3)", "not allowed as argument 1"),
            ("[GRAB] <apple> (5)", "not allowed as argument 1"),
            ("[GRAB]", "takes 1 object"),
            ("[STANDUP] <apple> (12)", "takes 0 object"),
            ("[FLY] <apple> (12)", "verb \"FLY\" is not allowed"),
            ("[GRAB] <apple> (012)", "column 16: expected an object id such as (1002), found '(012)'"),
            ("[GRAB]  <apple> (12)", "expected ' <'"),
            ("[GRAB] <apple> (12)\n", "expected an action line"),
            ("[STANDUP]\n[STANDUP]\n[STANDUP]", "3 body line(s); 1..=2"),
        ];
        for (text, why) in bad {
            let e = g.parse(text).unwrap_err().to_string();
            assert!(e.contains(why), "{text:?}: {e}");
        }
    }

    #[test]
    fn per_verb_restriction_limits_each_slot() {
        let apple = ObjRef::new("apple", 12);
        let fridge = ObjRef::new("fridge", 5);
        let g = ActionGrammar::new(
            [
                VerbSpec::new("PUTIN", 2).restricted(vec![vec![apple.clone()], vec![fridge.clone()]]),
                VerbSpec::new("OPEN", 1).restricted(vec![vec![fridge.clone()]]),
                VerbSpec::new("EAT", 1).restricted(vec![vec![]]),
            ],
            kitchen(),
        );
        let lark = g.to_lark().unwrap();
        assert!(!lark.contains("EAT"), "a verb with no allowed object is dropped:\n{lark}");
        assert!(lark.contains(r#"objs_0: "<apple> (12)""#) && lark.contains(r#"objs_1: "<fridge> (5)""#), "{lark}");
        assert!(g.parse("[PUTIN] <apple> (12) <fridge> (5)\n[OPEN] <fridge> (5)").is_ok());
        assert!(g.parse("[PUTIN] <fridge> (5) <apple> (12)").unwrap_err().reason.contains("argument 1"));
        assert!(g.parse("[EAT] <apple> (12)").is_err());

        let unknown =
            ActionGrammar::new([VerbSpec::new("OPEN", 1).restricted(vec![vec![ObjRef::new("door", 1)]])], kitchen());
        assert!(matches!(unknown.to_lark(), Err(GrammarError::UnknownObject { .. })));
        let slots = ActionGrammar::new([VerbSpec::new("OPEN", 1).restricted(vec![])], kitchen());
        assert!(matches!(slots.to_lark(), Err(GrammarError::SlotCount { .. })));
    }

    #[test]
    fn awkward_names_are_escaped_and_ambiguous_ones_rejected() {
        let objs = vec![ObjRef::new("say \"hi\"", 1), ObjRef::new(r"back\slash", 22), ObjRef::new("tv_2", 3)];
        let g = ActionGrammar::new([VerbSpec::new("A\"B", 1)], objs);
        let lark = g.to_lark().unwrap();
        assert!(lark.contains(r#""<say \"hi\"> (1)""#), "{lark}");
        assert!(lark.contains(r#""<back\\slash> (22)""#), "{lark}");
        assert!(lark.contains(r#""[A\"B] ""#), "{lark}");
        assert!(g.parse("[A\"B] <say \"hi\"> (1)").is_ok());

        for bad in ["a<b", "a>b", "", "new\nline"] {
            let g = ActionGrammar::new([VerbSpec::new("GRAB", 1)], [ObjRef::new(bad, 1)]);
            assert!(matches!(g.to_lark(), Err(GrammarError::BadName { kind: "object class", .. })), "{bad:?}");
        }
        for bad in ["A]", "[A", "A B", ""] {
            let g = ActionGrammar::new([VerbSpec::new(bad, 0)], kitchen());
            assert!(matches!(g.to_lark(), Err(GrammarError::BadName { kind: "verb", .. })), "{bad:?}");
        }
        let dup = ActionGrammar::new([VerbSpec::new("A", 0), VerbSpec::new("A", 1)], kitchen());
        assert_eq!(dup.to_lark().unwrap_err(), GrammarError::DuplicateVerb("A".into()));
        let arity = ActionGrammar::new([VerbSpec::new("A", 3)], kitchen());
        assert!(matches!(arity.to_lark(), Err(GrammarError::BadArity { arity: 3, .. })));
    }

    #[test]
    fn header_fields_and_subgoal_lines() {
        let g = ActionGrammar::new([VerbSpec::new("WALK", 1)], kitchen())
            .header_choice("verdict", ["decompose", "primitive"])
            .header_text("reason", 10)
            .subgoals("subgoal", 12)
            .lines(0, 3);
        let lark = g.to_lark().unwrap();
        assert!(lark.contains(r#"field_0: "verdict: " ("decompose" | "primitive")"#), "{lark}");
        assert!(lark.contains(r#"field_1: "reason: " /[A-Za-z0-9 ,.'_\-]{1,10}/"#), "{lark}");
        assert!(lark.contains(r#"line: action | "subgoal: " /[A-Za-z0-9 ,.'_\-]{1,12}/"#), "{lark}");
        assert!(lark.contains(r#"start: field_0 "\n" field_1 ("\n" line){0,3}"#), "{lark}");

        let p = g.parse("verdict: primitive\nreason: it's done").unwrap();
        assert_eq!(p.fields[1], ("reason".to_string(), "it's done".to_string()));
        assert!(p.lines.is_empty());
        let p = g.parse("verdict: decompose\nreason: x\nsubgoal: open fridge\n[WALK] <fridge> (5)").unwrap();
        assert_eq!(p.lines[0], PlanLine::Subgoal("open fridge".into()));
        assert_eq!(p.actions().unwrap().len(), 1);

        assert!(g.parse("verdict: maybe\nreason: x").unwrap_err().reason.contains("not one of"));
        assert!(g.parse("verdict: primitive\nreason: 12345678901").unwrap_err().reason.contains("11 characters"));
        assert!(g.parse("verdict: primitive\nreason: a;b").unwrap_err().reason.contains("';'"));
        assert!(g.parse("verdict: primitive").unwrap_err().reason.contains("missing field"));
        assert!(g.parse("verdict: primitive\nreason: x\n").is_err(), "a trailing newline is an empty line");

        let no_lines = ActionGrammar::new([VerbSpec::new("WALK", 1)], kitchen()).lines(0, 3);
        assert!(matches!(no_lines.to_lark(), Err(GrammarError::Shape(_))));
        let bad_label = ActionGrammar::new([VerbSpec::new("WALK", 1)], kitchen()).header_text("a:b", 3);
        assert!(matches!(bad_label.to_lark(), Err(GrammarError::BadName { kind: "label", .. })));
        let zero = ActionGrammar::new([VerbSpec::new("WALK", 1)], kitchen()).subgoals("sub", 0);
        assert!(matches!(zero.to_lark(), Err(GrammarError::Shape(_))));
    }

    #[test]
    fn no_writable_line_is_an_error() {
        let g = ActionGrammar::new([VerbSpec::new("GRAB", 1)], Vec::<ObjRef>::new());
        let e = g.to_lark().unwrap_err().to_string();
        assert!(e.contains("no line can be written"), "{e}");
    }

    #[test]
    fn parse_actions_reads_real_verbs_only() {
        let acts = parse_actions("[WALK] <fridge> (5)\n[OPEN] <fridge> (5)\n[STANDUP]").unwrap();
        assert_eq!(acts.len(), 3);
        assert_eq!(acts[2].to_string(), "[STANDUP]");
        let e = parse_actions("[WALK] <fridge> (5)\n[FLY] <fridge> (5)").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(parse_actions("[walk] <fridge> (5)").unwrap_err().reason.contains("WALK"));
        assert!(parse_actions("[WALK]").unwrap_err().reason.contains("takes 1"));
    }
}
