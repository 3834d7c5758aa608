//! The JSON form of a plan: `[{"verb": "GRAB", "args": [{"class_name": "soap", "id": 1002}]}, …]`.
//!
//! Syntax errors carry serde_json's line and column; a bad verb or arity names the step.

use serde::Deserialize;

use super::{Location, PlanFormat, PlanParseError, PlanParseErrorKind};
use crate::action::{Action, ObjRef, Verb};

/// A step as written, before its verb and arity are checked (so that errors can name the step).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStep {
    verb: String,
    #[serde(default)]
    args: Vec<ObjRef>,
}

pub(super) fn parse(text: &str) -> Result<Vec<Action>, PlanParseError> {
    let raw: Vec<RawStep> = serde_json::from_str(text).map_err(|e| {
        PlanParseError::syntax(
            PlanFormat::Json,
            Location::Line { line: e.line().max(1), column: Some(e.column().max(1)) },
            "a JSON list of steps such as [{\"verb\": \"WALK\", \"args\": [{\"class_name\": \"kitchen\", \"id\": 11}]}]",
            e.to_string(),
        )
    })?;
    if raw.is_empty() {
        return Err(PlanParseError {
            format: PlanFormat::Json,
            location: Location::Whole,
            kind: PlanParseErrorKind::Empty,
        });
    }
    raw.into_iter()
        .enumerate()
        .map(|(i, s)| {
            let at = |kind| PlanParseError { format: PlanFormat::Json, location: Location::Step { step: i + 1 }, kind };
            let verb: Verb = s.verb.parse().map_err(|e| at(PlanParseErrorKind::UnknownVerb(e)))?;
            Action::new(verb, s.args).map_err(|e| at(PlanParseErrorKind::WrongArity(e)))
        })
        .collect()
}

pub(super) fn write(actions: &[Action]) -> String {
    // One step a line: compact enough to read, and diffs stay per step.
    let mut out = String::from("[\n");
    for (i, a) in actions.iter().enumerate() {
        let step = serde_json::json!({ "verb": a.verb.name(), "args": a.args });
        out.push_str("  ");
        out.push_str(&step.to_string());
        out.push_str(if i + 1 < actions.len() { ",\n" } else { "\n" });
    }
    out.push_str("]\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_steps_and_defaults_missing_args() {
        let a = parse(r#"[{"verb":"walk","args":[{"class_name":"kitchen","id":11}]},{"verb":"STANDUP"}]"#).unwrap();
        assert_eq!(a[0].to_string(), "[WALK] <kitchen> (11)");
        assert_eq!(a[1].verb, Verb::StandUp);
    }

    #[test]
    fn errors_name_the_step_or_position() {
        let e = parse(r#"[{"verb":"WALK","args":[]}]"#).unwrap_err();
        assert_eq!(e.location, Location::Step { step: 1 });
        assert_eq!(e.to_string(), "json plan, step 1: WALK takes 1 object(s), got 0");

        let e = parse("[{\"verb\":\"WALK\",\"args\":[{\"class_name\":\"k\",\"id\":1}]},\n {\"verb\":\"FLY\"}]")
            .unwrap_err();
        assert_eq!(e.location, Location::Step { step: 2 });
        assert!(e.to_string().contains("unknown action 'FLY'"), "{e}");

        let e = parse("[\n {\"verb\": \"WALK\", \"args\": [{\"class_name\": \"k\", \"id\": \"x\"}]}]").unwrap_err();
        assert!(matches!(e.location, Location::Line { line: 2, .. }), "{e}");

        let e = parse("[{\"verb\":\"WALK\",\"objects\":[]}]").unwrap_err();
        assert!(e.to_string().contains("unknown field `objects`"), "{e}");

        assert_eq!(parse("[]").unwrap_err().kind, PlanParseErrorKind::Empty);
    }
}
