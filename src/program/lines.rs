//! VirtualHome program lines: `[VERB] <class> (id) <class> (id)`, one step a line.
//!
//! EAI's gold programs write ids as `(1.1002)`: the part before the dot is the object's instance
//! number in the original crowd-sourced script (1 for the first soap the script mentions, 2 for a
//! second one), the part after it the node id in the scene graph, which is what identifies the object.
//! Both `(1002)` and `(1.1002)` are accepted; the instance number is not kept (EAI drops it too).
//!
//! A file may start with header lines (title, then description), ended by a blank line or by the
//! first step; after the header every non-blank line must be a step, except `#` comment lines. A line
//! that looks like a step (it holds `[VERB]`) is never taken as a title: if it does not parse, the
//! error names it (`Step 1: [WALK] <apple> (12)` is an error at line 1, not a title).

use super::{column_of, excerpt, Location, PlanFormat, PlanParseError, PlanParseErrorKind, Program};
use crate::action::{Action, ObjRef, Verb};

const EXAMPLE: &str = "an action such as `[WALK] <kitchen> (11)`";

pub(super) fn parse(text: &str) -> Result<Program, PlanParseError> {
    let mut lines = text.lines().enumerate().peekable();
    // Header: leading lines that are not steps, up to a blank line or the first step.
    let mut header: Vec<&str> = Vec::new();
    while let Some(&(_, line)) = lines.peek() {
        let t = line.trim();
        if header.is_empty() && t.is_empty() {
            lines.next();
            continue;
        }
        if t.is_empty() || t.starts_with('[') || t.starts_with('#') || looks_like_step(t) {
            break;
        }
        header.push(t);
        lines.next();
    }
    let mut actions = Vec::new();
    for (i, line) in lines {
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        actions.push(parse_at(line, i + 1)?);
    }
    if actions.is_empty() {
        if let Some(first) = header.first() {
            // Only prose: say what was read as the header, and what a step looks like.
            return Err(PlanParseError::syntax(
                PlanFormat::Lines,
                Location::Whole,
                format!("at least one step line such as `[WALK] <kitchen> (11)` (the text was read as a title and {} description line(s))", header.len() - 1),
                excerpt(first),
            ));
        }
        return Err(PlanParseError {
            format: PlanFormat::Lines,
            location: Location::Whole,
            kind: PlanParseErrorKind::Empty,
        });
    }
    let title = header.first().map(|s| s.to_string());
    let description = (header.len() > 1).then(|| header[1..].join("\n"));
    Ok(Program { title, description, actions })
}

/// Parses one step line, e.g. `[PUTBACK] <soap> (1.1002) <sink> (1001)`; errors say line 1.
pub fn parse_step_line(line: &str) -> Result<Action, PlanParseError> {
    parse_at(line, 1)
}

fn parse_at(line: &str, line_no: usize) -> Result<Action, PlanParseError> {
    let err = |at: usize, expected: &str, found: &str| {
        PlanParseError::syntax(
            PlanFormat::Lines,
            Location::Line { line: line_no, column: Some(column_of(line, at)) },
            expected,
            excerpt(found),
        )
    };
    let mut pos = line.len() - line.trim_start().len();
    let rest = &line[pos..];
    if !rest.starts_with('[') {
        if let Some(at) = rest.find('[').filter(|_| looks_like_step(rest)) {
            let before = rest[..at].trim_end();
            return Err(err(
                pos,
                &format!("the line to start with the action ('[' …); remove '{before}' before it"),
                rest,
            ));
        }
        return Err(err(pos, EXAMPLE, rest));
    }
    let Some(close) = rest.find(']') else {
        return Err(err(pos, "']' closing the action name", rest));
    };
    let verb_text = &rest[1..close];
    let verb: Verb = verb_text.parse().map_err(|e| PlanParseError {
        format: PlanFormat::Lines,
        location: Location::Line { line: line_no, column: Some(column_of(line, pos + 1)) },
        kind: PlanParseErrorKind::UnknownVerb(e),
    })?;
    pos += close + 1;
    let mut args = Vec::new();
    loop {
        let rest = &line[pos..];
        let trimmed = rest.trim_start();
        pos += rest.len() - trimmed.len();
        if trimmed.is_empty() {
            break;
        }
        if !trimmed.starts_with('<') {
            return Err(err(pos, "'<' starting an object such as `<soap> (1002)`, or the end of the line", trimmed));
        }
        let Some(gt) = trimmed.find('>') else {
            return Err(err(pos, "'>' closing the object name", trimmed));
        };
        let raw_name = &trimmed[1..gt];
        let name = normalise_name(raw_name);
        if name.is_empty() || raw_name.contains('<') {
            return Err(err(pos, "an object name between '<' and '>'", &trimmed[..=gt]));
        }
        pos += gt + 1;
        let rest = &line[pos..];
        let after = rest.trim_start();
        pos += rest.len() - after.len();
        if !after.starts_with('(') {
            return Err(err(pos, &format!("the id of <{name}> in parentheses, such as (1002) or (1.1002)"), after));
        }
        let Some(paren) = after.find(')') else {
            return Err(err(pos, "')' closing the object id", after));
        };
        let id = parse_id(&after[1..paren])
            .ok_or_else(|| err(pos, "an object id such as (1002) or (1.1002)", &after[..=paren]))?;
        pos += paren + 1;
        args.push(ObjRef::new(name, id));
    }
    Action::new(verb, args).map_err(|e| PlanParseError {
        format: PlanFormat::Lines,
        location: Location::Line { line: line_no, column: None },
        kind: PlanParseErrorKind::WrongArity(e),
    })
}

/// Whether a line holds an action name in brackets (`[WALK]`, `[PUTBACK]`): such a line is meant as a
/// step, wherever the bracket is.
fn looks_like_step(line: &str) -> bool {
    line.match_indices('[').any(|(i, _)| {
        let rest = &line[i + 1..];
        let name_len = rest.bytes().take_while(|b| b.is_ascii_alphabetic() || *b == b'_').count();
        name_len > 0 && rest[name_len..].starts_with(']')
    })
}

/// VirtualHome's own normalisation of a script's object name: lower case, spaces as underscores.
fn normalise_name(raw: &str) -> String {
    raw.split_whitespace().collect::<Vec<_>>().join("_").to_lowercase()
}

/// `1002` or `1.1002` (instance.node id) → the node id.
fn parse_id(s: &str) -> Option<u32> {
    let s = s.trim();
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    match s.split_once('.') {
        Some((inst, id)) if digits(inst) && digits(id) => id.parse().ok(),
        None if digits(s) => s.parse().ok(),
        _ => None,
    }
}

pub(super) fn write(p: &Program) -> String {
    let mut out = String::new();
    if let Some(t) = &p.title {
        out.push_str(t);
        out.push('\n');
        if let Some(d) = &p.description {
            out.push_str(d);
            out.push('\n');
        }
        out.push('\n');
    }
    for a in &p.actions {
        out.push_str(&a.to_string());
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn soap() -> ObjRef {
        ObjRef::new("soap", 1002)
    }

    #[test]
    fn reads_an_eai_program_file_with_header() {
        let text = "Wash clothes\nPut the clothes in the machine.\n\n\n[WALK] <bathroom> (1.1)\n\
                    [GRAB] <soap> (1.1002)\n[PUTBACK] <soap> (1.1002) <washing_machine> (2.1001)\n[STANDUP]\n";
        let p = parse(text).unwrap();
        assert_eq!(p.title.as_deref(), Some("Wash clothes"));
        assert_eq!(p.description.as_deref(), Some("Put the clothes in the machine."));
        assert_eq!(p.actions.len(), 4);
        assert_eq!(p.actions[1], Action::new(Verb::Grab, vec![soap()]).unwrap());
        assert_eq!(p.actions[2].args[1], ObjRef::new("washing_machine", 1001));
        assert_eq!(p.actions[3].verb, Verb::StandUp);
        // Written back: the header, a blank line, the steps with plain ids.
        let again = parse(&write(&p)).unwrap();
        assert_eq!(again, p);
    }

    #[test]
    fn plain_ids_comments_case_and_spaces_are_accepted() {
        let p = parse("# a comment\n  [grab]   <Soap>(1002)  \n\n[Walk] <living room> (336)\n").unwrap();
        assert_eq!(p.title, None);
        assert_eq!(p.actions[0], Action::new(Verb::Grab, vec![soap()]).unwrap());
        assert_eq!(p.actions[1].args[0], ObjRef::new("living_room", 336));
    }

    fn err_of(text: &str) -> PlanParseError {
        parse(text).unwrap_err()
    }

    #[test]
    fn unknown_verb_names_line_and_column() {
        let e = err_of("[WALK] <kitchen> (11)\n[FLY] <kitchen> (11)\n");
        assert_eq!(e.location, Location::Line { line: 2, column: Some(2) });
        assert!(matches!(e.kind, PlanParseErrorKind::UnknownVerb(_)));
        let s = e.to_string();
        assert!(s.starts_with("lines plan, line 2, column 2: unknown action 'FLY'"), "{s}");
    }

    #[test]
    fn wrong_arity_names_the_line() {
        let e = err_of("[WALK] <kitchen> (11)\n\n[PUTBACK] <soap> (1002)\n");
        assert_eq!(e.location, Location::Line { line: 3, column: None });
        assert_eq!(e.to_string(), "lines plan, line 3: PUTBACK takes 2 object(s), got 1");
        let e = err_of("[STANDUP] <chair> (5)");
        assert!(matches!(e.kind, PlanParseErrorKind::WrongArity(w) if w.expected == 0 && w.got == 1));
    }

    #[test]
    fn each_malformed_shape_is_a_located_syntax_error() {
        let cases: &[(&str, usize, &str)] = &[
            ("[WALK <kitchen> (11)", 1, "']' closing"),
            ("[WALK] kitchen (11)", 8, "'<' starting an object"),
            ("[WALK] <kitchen (11)", 8, "'>' closing"),
            ("[WALK] <> (11)", 8, "an object name"),
            ("[WALK] <kitchen>", 17, "the end of the line"),
            ("[WALK] <kitchen> 11", 18, "the id of <kitchen>"),
            ("[WALK] <kitchen> (11", 18, "')' closing"),
            ("[WALK] <kitchen> (eleven)", 18, "an object id such as"),
            ("[WALK] <kitchen> (1.)", 18, "an object id such as"),
            ("[WALK] <kitchen> (99999999999)", 18, "an object id such as"),
            ("[WALK] <kitchen> (11) extra", 23, "'<' starting an object"),
        ];
        for &(line, col, needle) in cases {
            // Put the bad step on line 2, after a good one, to check the line number too.
            let e = err_of(&format!("[WALK] <kitchen> (11)\n{line}\n"));
            assert_eq!(e.location, Location::Line { line: 2, column: Some(col) }, "{line}: {e}");
            assert!(matches!(e.kind, PlanParseErrorKind::Syntax { .. }), "{line}: {e}");
            assert!(e.to_string().contains(needle), "{line}: {e}");
        }
    }

    #[test]
    fn a_line_without_brackets_after_the_header_is_an_error() {
        // The header ends at the blank line; the next text line must be a step.
        let e = err_of("Title\n\nWALK kitchen\n");
        assert_eq!(e.location, Location::Line { line: 3, column: Some(1) });
        assert!(
            e.to_string().contains("expected an action such as `[WALK] <kitchen> (11)`, found 'WALK kitchen'"),
            "{e}"
        );
    }

    #[test]
    fn a_plan_without_steps_is_an_error() {
        // A header and no steps: the error says what was read as the header.
        let e = err_of("Title\nDescription\n\n");
        assert!(e.to_string().contains("at least one step line") && e.to_string().contains("'Title'"), "{e}");
        assert_eq!(err_of("").kind, PlanParseErrorKind::Empty);
    }

    #[test]
    fn single_line_parser() {
        let a = parse_step_line("[PUTBACK] <soap> (1.1002) <sink> (1001)").unwrap();
        assert_eq!(a.to_string(), "[PUTBACK] <soap> (1002) <sink> (1001)");
    }

    #[test]
    fn a_title_is_recognised_only_when_it_is_not_a_step() {
        // A title before the steps is kept as the title, and the first step is not lost.
        let p = parse("Put away\n[WALK] <apple> (12)\n[GRAB] <apple> (12)\n").unwrap();
        assert_eq!((p.title.as_deref(), p.actions.len()), (Some("Put away"), 2));
        // A line holding [VERB] is a step, never a title: if it does not parse, the error names it.
        let e = parse("Step 1: [WALK] <apple> (12)\n[GRAB] <apple> (12)\n").unwrap_err();
        assert_eq!(e.location, Location::Line { line: 1, column: Some(1) }, "{e}");
        assert!(e.to_string().contains("remove 'Step 1:' before it"), "{e}");
        let e = parse("1. [WALK] <apple> (12)\n").unwrap_err();
        assert!(e.to_string().contains("line 1"), "{e}");
    }

    #[test]
    fn a_plan_that_is_only_prose_says_what_was_read_and_what_a_step_looks_like() {
        let e = parse("First walk to the apple.\nThen grab it.\n").unwrap_err();
        let m = e.to_string();
        assert!(m.contains("at least one step line") && m.contains("'First walk to the apple.'"), "{m}");
    }
}
