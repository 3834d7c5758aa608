//! Plans as text: a [`Program`] is an ordered list of primitive [`Action`]s, read and written in three
//! forms:
//! - **lines**: VirtualHome's script lines, one step a line (`[PUTBACK] <soap> (1002) <sink> (1001)`),
//!   optionally under a title and description as in EAI's `executable_programs/file<id>.txt`;
//! - **json**: a list of `{"verb": "PUTBACK", "args": [{"class_name": "soap", "id": 1002}, …]}`;
//! - **eai**: EAI's LLM-output format, an object of action keys in order (keys repeat), values
//!   `[name, id]`, `[name1, id1, name2, id2]` or `[]`, so plans can be scored by EAI's tools and EAI
//!   outputs run here.
//!
//! Every parse error says where (line and column, or step number) and what was expected.

mod eai;
mod json;
mod lines;

use std::fmt;
use std::str::FromStr;

use crate::action::{Action, UnknownVerb, WrongArity};

pub use lines::parse_step_line;

/// The text forms a plan can take.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PlanFormat {
    /// VirtualHome program lines (`[WALK] <kitchen> (11)`), optionally under a title and description.
    Lines,
    /// A JSON list of `{verb, args: [{class_name, id}]}`.
    Json,
    /// EAI's LLM-output object: `{"WALK": ["kitchen", 11], "STANDUP": [], …}`.
    Eai,
}

impl PlanFormat {
    pub const ALL: [PlanFormat; 3] = [PlanFormat::Lines, PlanFormat::Json, PlanFormat::Eai];

    pub fn name(self) -> &'static str {
        match self {
            PlanFormat::Lines => "lines",
            PlanFormat::Json => "json",
            PlanFormat::Eai => "eai",
        }
    }

    /// Guesses the format from the text: an object (possibly in a ```json fence) is EAI's, a list
    /// whose first element is an object is JSON, anything else is program lines.
    pub fn detect(text: &str) -> PlanFormat {
        let t = strip_bom(text).trim_start();
        let t = t.strip_prefix("```json").or_else(|| t.strip_prefix("```")).unwrap_or(t).trim_start();
        if t.starts_with('{') {
            return PlanFormat::Eai;
        }
        if let Some(rest) = t.strip_prefix('[') {
            let rest = rest.trim_start();
            if rest.starts_with('{') || rest.starts_with(']') {
                return PlanFormat::Json;
            }
        }
        PlanFormat::Lines
    }
}

impl fmt::Display for PlanFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A format name that is not one of `lines`, `json`, `eai`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown plan format '{0}': use lines, json or eai")]
pub struct UnknownFormat(pub String);

impl FromStr for PlanFormat {
    type Err = UnknownFormat;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        PlanFormat::ALL
            .into_iter()
            .find(|f| f.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| UnknownFormat(s.to_string()))
    }
}

/// Where in the text a parse error is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Location {
    /// 1-based line, and 1-based column (in characters) when it helps.
    Line { line: usize, column: Option<usize> },
    /// 1-based step number (for the JSON-shaped formats, whose values carry no position).
    Step { step: usize },
    /// The text as a whole.
    Whole,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line { line, column: Some(c) } => write!(f, "line {line}, column {c}"),
            Location::Line { line, column: None } => write!(f, "line {line}"),
            Location::Step { step } => write!(f, "step {step}"),
            Location::Whole => f.write_str("plan"),
        }
    }
}

/// What is wrong at a [`Location`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PlanParseErrorKind {
    /// The text does not have the expected shape.
    #[error("expected {expected}, found {found}")]
    Syntax { expected: String, found: String },
    #[error("{0}")]
    UnknownVerb(UnknownVerb),
    #[error("{0}")]
    WrongArity(WrongArity),
    /// The text holds no step at all.
    #[error("the plan has no steps")]
    Empty,
}

/// A plan that could not be read: the format, where, and what was expected.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{format} plan, {location}: {kind}")]
pub struct PlanParseError {
    pub format: PlanFormat,
    pub location: Location,
    pub kind: PlanParseErrorKind,
}

impl PlanParseError {
    fn syntax(format: PlanFormat, location: Location, expected: impl Into<String>, found: impl Into<String>) -> Self {
        PlanParseError {
            format,
            location,
            kind: PlanParseErrorKind::Syntax { expected: expected.into(), found: found.into() },
        }
    }
}

/// A plan: an ordered list of actions, with the title and description a program file may carry.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Program {
    pub title: Option<String>,
    pub description: Option<String>,
    pub actions: Vec<Action>,
}

impl Program {
    pub fn new(actions: Vec<Action>) -> Self {
        Program { title: None, description: None, actions }
    }

    /// Reads a plan in the given format. A leading byte-order mark is ignored.
    pub fn parse(text: &str, format: PlanFormat) -> Result<Program, PlanParseError> {
        let text = strip_bom(text);
        match format {
            PlanFormat::Lines => lines::parse(text),
            PlanFormat::Json => json::parse(text).map(Program::new),
            PlanFormat::Eai => eai::parse(text).map(Program::new),
        }
    }

    /// Reads a plan whose format is guessed with [`PlanFormat::detect`].
    pub fn parse_auto(text: &str) -> Result<Program, PlanParseError> {
        Program::parse(text, PlanFormat::detect(text))
    }

    /// Writes the plan in the given format. Lines carry the title and description when present.
    pub fn write(&self, format: PlanFormat) -> String {
        match format {
            PlanFormat::Lines => lines::write(self),
            PlanFormat::Json => json::write(&self.actions),
            PlanFormat::Eai => eai::write(&self.actions),
        }
    }
}

/// One task's plan out of a file of EAI's LLM outputs, `[{"identifier", "llm_output"}, …]` (what
/// `step eval plan --export-eai` writes and EAI's scorer reads): `None` when `text` is not such a
/// list; an error naming the identifiers it has when none is `task`. The plan is in [`PlanFormat::Eai`].
pub fn exported_plan(text: &str, task: &str) -> Option<Result<String, String>> {
    use serde_json::Value;
    let list: Vec<serde_json::Map<String, Value>> = serde_json::from_str(strip_bom(text)).ok()?;
    if list.is_empty() || !list.iter().all(|e| e.contains_key("identifier") && e.contains_key("llm_output")) {
        return None;
    }
    // EAI writes identifiers as strings; a number is read as its digits.
    let text_of = |v: &Value| match v {
        Value::String(s) => s.clone(),
        other => other.to_string(),
    };
    match list.iter().find(|e| text_of(&e["identifier"]) == task) {
        Some(e) => Some(Ok(text_of(&e["llm_output"]))),
        None => {
            let ids: Vec<String> = list.iter().map(|e| text_of(&e["identifier"])).collect();
            let shown = if ids.len() > 8 { format!("{}, …", ids[..8].join(", ")) } else { ids.join(", ") };
            Some(Err(format!(
                "a list of {} exported plans ({{\"identifier\", \"llm_output\"}}) with none for task '{task}' (it has: {shown}); give --task one of them",
                ids.len()
            )))
        }
    }
}

/// The text without a leading UTF-8 byte-order mark (which editors on Windows add, and which no
/// parser here should see as content).
pub fn strip_bom(text: &str) -> &str {
    text.strip_prefix('\u{feff}').unwrap_or(text)
}

// Columns and excerpts in error messages are the action-line parser's, so every plan error reads alike.
pub(crate) use crate::action::{column_of, found_excerpt as excerpt};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::{ObjRef, Verb};

    fn sample() -> Program {
        Program::new(vec![
            Action::new(Verb::Walk, vec![ObjRef::new("kitchen", 11)]).unwrap(),
            Action::new(Verb::Grab, vec![ObjRef::new("soap", 1002)]).unwrap(),
            Action::new(Verb::PutBack, vec![ObjRef::new("soap", 1002), ObjRef::new("washing_machine", 1001)]).unwrap(),
            Action::new(Verb::StandUp, vec![]).unwrap(),
            Action::new(Verb::Grab, vec![ObjRef::new("soap", 1002)]).unwrap(),
            Action::new(Verb::PlugIn, vec![ObjRef::new("washing_machine", 1001)]).unwrap(),
        ])
    }

    #[test]
    fn every_format_round_trips_and_is_detected() {
        let p = sample();
        for f in PlanFormat::ALL {
            let text = p.write(f);
            assert_eq!(PlanFormat::detect(&text), f, "{f}: {text}");
            assert_eq!(Program::parse(&text, f).unwrap(), p, "{f}: {text}");
            assert_eq!(Program::parse_auto(&text).unwrap(), p, "{f}: {text}");
        }
    }

    fn arb_action() -> impl proptest::strategy::Strategy<Value = Action> {
        use proptest::prelude::*;
        let obj = ("[a-z][a-z_]{0,12}", 0u32..100_000).prop_map(|(n, id)| ObjRef::new(n, id));
        (0..Verb::ALL.len(), proptest::collection::vec(obj, 2)).prop_map(|(v, objs)| {
            let verb = Verb::ALL[v];
            Action::new(verb, objs.into_iter().take(verb.arity()).collect()).unwrap()
        })
    }

    proptest::proptest! {
        // A fixed seed keeps the suite deterministic; no regression files are written.
        #![proptest_config(proptest::test_runner::Config {
            cases: 200,
            rng_seed: proptest::test_runner::RngSeed::Fixed(0x5e9),
            failure_persistence: None,
            ..proptest::test_runner::Config::default()
        })]
        #[test]
        fn any_plan_round_trips_through_every_format(actions in proptest::collection::vec(arb_action(), 1..20)) {
            let p = Program::new(actions);
            for f in PlanFormat::ALL {
                let text = p.write(f);
                proptest::prop_assert_eq!(&Program::parse(&text, f).unwrap(), &p);
                proptest::prop_assert_eq!(PlanFormat::detect(&text), f);
            }
        }
    }

    #[test]
    fn a_task_plan_is_taken_out_of_a_file_of_exported_plans() {
        let p = sample();
        let file = serde_json::json!([
            {"identifier": "3_1", "llm_output": "{\"WALK\": [\"kitchen\", 11]}"},
            {"identifier": "27_2", "llm_output": p.write(PlanFormat::Eai)},
        ])
        .to_string();
        let plan = exported_plan(&file, "27_2").unwrap().unwrap();
        assert_eq!(Program::parse(&plan, PlanFormat::Eai).unwrap(), p);
        let e = exported_plan(&file, "9_9").unwrap().unwrap_err();
        assert!(e.contains("2 exported plans") && e.contains("task '9_9'") && e.contains("it has: 3_1, 27_2"), "{e}");
        // Plans in the other forms, and other lists, are not such a file.
        for f in PlanFormat::ALL {
            assert!(exported_plan(&p.write(f), "27_2").is_none(), "{f}");
        }
        assert!(exported_plan(r#"[{"identifier": "3_1"}]"#, "3_1").is_none());
    }

    #[test]
    fn format_names_parse() {
        assert_eq!("EAI".parse::<PlanFormat>().unwrap(), PlanFormat::Eai);
        let e = "yaml".parse::<PlanFormat>().unwrap_err().to_string();
        assert!(e.contains("'yaml'") && e.contains("lines, json or eai"), "{e}");
    }

    #[test]
    fn a_byte_order_mark_is_stripped_in_every_format() {
        let bom = |s: &str| format!("\u{feff}{s}");
        let lines = Program::parse(&bom("[WALK] <apple> (12)\n[GRAB] <apple> (12)\n"), PlanFormat::Lines).unwrap();
        assert_eq!((lines.title, lines.actions.len()), (None, 2), "the BOM line is not a title");
        let json = bom(r#"[{"verb": "WALK", "args": [{"class_name": "apple", "id": 12}]}]"#);
        assert_eq!(PlanFormat::detect(&json), PlanFormat::Json);
        assert_eq!(Program::parse_auto(&json).unwrap().actions.len(), 1);
        let eai = bom(r#"{"WALK": ["apple", 12]}"#);
        assert_eq!(Program::parse_auto(&eai).unwrap().actions.len(), 1);
    }
}
