//! EAI's LLM-output plan format: a JSON object whose keys are action names in execution order (a key
//! repeats when the action does), each value the action's objects as `[name, id]`,
//! `[name1, id1, name2, id2]` or `[]`:
//!
//! ```text
//! {"WALK": ["bathroom", 1], "GRAB": ["soap", 1002], "PUTBACK": ["soap", 1002, "washing_machine", 1001], "STANDUP": []}
//! ```
//!
//! EAI reads it with a regex; here it is read with a JSON parser that keeps repeated keys in order, so
//! errors have positions. Accepted like EAI: a ```json fence, single quotes instead of double ones,
//! ids as numbers or digit strings, text before the object or after it. Unlike EAI: zero-argument
//! actions (`"STANDUP": []`) are kept, action names in any case are accepted, and malformed text is an
//! error that says where, not a silently shorter plan.

use std::fmt;

use serde::de::{Deserializer, MapAccess, Visitor};
use serde_json::Value;

use super::{Location, PlanFormat, PlanParseError, PlanParseErrorKind};
use crate::action::{Action, ObjRef, Verb};

const SHAPE: &str = "an object of actions such as {\"WALK\": [\"kitchen\", 11], \"STANDUP\": []}";

/// The object's entries in order, repeated keys included (a map type would keep only one).
struct Entries(Vec<(String, Vec<Value>)>);

impl<'de> serde::Deserialize<'de> for Entries {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Entries;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an object whose values are lists of object names and ids")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut m: A) -> Result<Entries, A::Error> {
                let mut out = Vec::new();
                while let Some((k, v)) = m.next_entry::<String, Vec<Value>>()? {
                    out.push((k, v));
                }
                Ok(Entries(out))
            }
        }
        d.deserialize_map(V)
    }
}

/// Removes a Markdown code fence around the object, as LLMs often write one.
fn strip_fence(text: &str) -> &str {
    let t = text.trim();
    let Some(rest) = t.strip_prefix("```") else { return t };
    let rest = rest.strip_prefix("json").unwrap_or(rest);
    rest.strip_suffix("```").unwrap_or(rest).trim()
}

fn read_entries(text: &str) -> Result<Entries, PlanParseError> {
    let body = strip_fence(text);
    let Some(start) = body.find('{') else {
        return Err(PlanParseError::syntax(
            PlanFormat::Eai,
            Location::Line { line: 1, column: Some(1) },
            SHAPE,
            super::excerpt(body),
        ));
    };
    // Lines skipped before the object (prose, the fence) shift serde's positions.
    let skipped = body.as_ptr() as usize - text.as_ptr() as usize; // body is a sub-slice of text
    let line_offset = text[..skipped].matches('\n').count() + body[..start].matches('\n').count();
    let first_col = body[..start].rsplit('\n').next().map_or(0, |s| s.chars().count());
    let attempt = |s: &str| {
        let mut de = serde_json::Deserializer::from_str(s);
        // No `end()` check: text after the closing brace is ignored, as EAI does.
        <Entries as serde::Deserialize>::deserialize(&mut de)
    };
    let object = &body[start..];
    match attempt(object) {
        Ok(e) => Ok(e),
        Err(first) => {
            let retry = object.contains('\'').then(|| attempt(&object.replace('\'', "\"")));
            let err = match retry {
                Some(Ok(e)) => return Ok(e),
                Some(Err(e)) => e,
                None => first,
            };
            let line = err.line().max(1);
            let column = if line == 1 { err.column() + first_col } else { err.column() };
            Err(PlanParseError::syntax(
                PlanFormat::Eai,
                Location::Line { line: line + line_offset, column: Some(column.max(1)) },
                SHAPE,
                err.to_string(),
            ))
        }
    }
}

pub(super) fn parse(text: &str) -> Result<Vec<Action>, PlanParseError> {
    let Entries(entries) = read_entries(text)?;
    if entries.is_empty() {
        return Err(PlanParseError {
            format: PlanFormat::Eai,
            location: Location::Whole,
            kind: PlanParseErrorKind::Empty,
        });
    }
    entries
        .into_iter()
        .enumerate()
        .map(|(i, (key, values))| {
            let at = |kind| PlanParseError { format: PlanFormat::Eai, location: Location::Step { step: i + 1 }, kind };
            let verb: Verb = key.parse().map_err(|e| at(PlanParseErrorKind::UnknownVerb(e)))?;
            if values.len() % 2 != 0 {
                return Err(at(PlanParseErrorKind::Syntax {
                    expected: format!("the objects of \"{key}\" as name, id pairs, e.g. [\"soap\", 1002]"),
                    found: Value::Array(values).to_string(),
                }));
            }
            let args = values
                .chunks(2)
                .map(|pair| {
                    object(&pair[0], &pair[1]).map_err(|what| {
                        at(PlanParseErrorKind::Syntax {
                            expected: format!("{what} in \"{key}\""),
                            found: format!("{}, {}", pair[0], pair[1]),
                        })
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            Action::new(verb, args).map_err(|e| at(PlanParseErrorKind::WrongArity(e)))
        })
        .collect()
}

/// One `name, id` pair; the error says which half is wrong and what was expected.
fn object(name: &Value, id: &Value) -> Result<ObjRef, String> {
    let name = name.as_str().map(str::trim).unwrap_or_default();
    if name.is_empty() {
        return Err("an object name (a non-empty string) before the id".into());
    }
    let range = || format!("an object id from 0 to {} (a scene node id)", u32::MAX);
    let id = match id {
        Value::Number(n) if n.as_u64().is_some() => n.as_u64().and_then(|v| u32::try_from(v).ok()).ok_or_else(range)?,
        Value::Number(_) => return Err("a whole, non-negative object id".into()),
        Value::String(s) => match s.trim().parse::<u64>() {
            Ok(v) => u32::try_from(v).map_err(|_| range())?,
            Err(_) => return Err(format!("an object id (a number) after the name \"{name}\"")),
        },
        _ => return Err(format!("an object id (a number) after the name \"{name}\"")),
    };
    Ok(ObjRef::new(name, id))
}

pub(super) fn write(actions: &[Action]) -> String {
    let quote = |s: &str| Value::String(s.to_string()).to_string();
    let mut out = String::from("{\n");
    for (i, a) in actions.iter().enumerate() {
        let args: Vec<String> = a.args.iter().map(|o| format!("{}, {}", quote(&o.class_name), o.id)).collect();
        out.push_str(&format!("  {}: [{}]", quote(a.verb.name()), args.join(", ")));
        out.push_str(if i + 1 < actions.len() { ",\n" } else { "\n" });
    }
    out.push_str("}\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeated_keys_keep_their_order_and_zero_arg_actions_survive() {
        let a = parse(
            r#"{"WALK": ["bathroom", 1], "GRAB": ["soap", 1002], "STANDUP": [], "WALK": ["kitchen", "11"],
                        "PUTBACK": ["soap", 1002, "washing_machine", 1001]}"#,
        )
        .unwrap();
        let shown: Vec<String> = a.iter().map(|a| a.to_string()).collect();
        assert_eq!(
            shown,
            [
                "[WALK] <bathroom> (1)",
                "[GRAB] <soap> (1002)",
                "[STANDUP]",
                "[WALK] <kitchen> (11)",
                "[PUTBACK] <soap> (1002) <washing_machine> (1001)"
            ]
        );
    }

    #[test]
    fn llm_wrapping_is_tolerated() {
        let fenced = "```json\n{'WALK': ['kitchen', 11],\n 'plugin': ['toaster', 5]}\n```";
        let a = parse(fenced).unwrap();
        assert_eq!(a[1].to_string(), "[PLUGIN] <toaster> (5)");
        let prose = "Here is the plan:\n{\"WALK\": [\"kitchen\", 11]}\nDone.";
        assert_eq!(parse(prose).unwrap().len(), 1);
    }

    #[test]
    fn names_without_ids_wrong_arity_and_unknown_actions_name_the_step() {
        let e = parse(r#"{"WALK": ["kitchen", 11], "GRAB": ["soap"]}"#).unwrap_err();
        assert_eq!(e.location, Location::Step { step: 2 });
        assert!(e.to_string().contains("name, id pairs"), "{e}");

        let e = parse(r#"{"WALK": ["kitchen", 11], "PUTIN": ["soap", 1002]}"#).unwrap_err();
        assert_eq!(e.to_string(), "eai plan, step 2: PUTIN takes 2 object(s), got 1");

        let e = parse(r#"{"TELEPORT": ["kitchen", 11]}"#).unwrap_err();
        assert!(matches!(e.kind, PlanParseErrorKind::UnknownVerb(_)) && e.location == Location::Step { step: 1 });

        let e = parse(r#"{"WALK": [11, "kitchen"]}"#).unwrap_err();
        assert!(e.to_string().contains("an object name (a non-empty string) before the id"), "{e}");
    }

    #[test]
    fn syntax_errors_have_positions() {
        let e = parse("Plan:\n{\"WALK\": [\"kitchen\", 11]\n \"GRAB\": [\"soap\", 1002]}").unwrap_err();
        assert_eq!(e.location, Location::Line { line: 3, column: Some(2) }, "{e}");
        let e = parse("no plan here").unwrap_err();
        assert!(e.to_string().contains("expected an object of actions"), "{e}");
        assert_eq!(parse("{}").unwrap_err().kind, PlanParseErrorKind::Empty);
    }

    #[test]
    fn an_out_of_range_id_is_reported_as_an_id_problem() {
        let e = parse(r#"{"WALK": ["apple", 99999999999]}"#).unwrap_err().to_string();
        assert!(e.contains("an object id from 0 to 4294967295"), "{e}");
        let e = parse(r#"{"WALK": ["apple", -3]}"#).unwrap_err().to_string();
        assert!(e.contains("whole, non-negative object id"), "{e}");
        let e = parse(r#"{"WALK": [12, 12]}"#).unwrap_err().to_string();
        assert!(e.contains("an object name"), "{e}");
    }
}
