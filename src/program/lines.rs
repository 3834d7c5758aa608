//! VirtualHome program lines: `[VERB] <class> (id) <class> (id)`, one step a line.
//!
//! EAI's gold programs write ids as `(1.1002)`: the part before the dot is the object's instance
//! number in the original crowd-sourced script (1 for the first soap the script mentions, 2 for a
//! second one), the part after it the node id in the scene graph, which is what identifies the object.
//! Both `(1002)` and `(1.1002)` are accepted; the instance number is not kept (EAI drops it too).
//!
//! A file may start with header lines (title, then description), ended by a blank line or by the
//! first step; after the header every non-blank line must be a step, except `#` comment lines.

use super::{Location, ParseError, ParseErrorKind, PlanFormat, Program};
use crate::action::{parse_action_line, Action, ActionLineErrorKind, LineSyntax};

pub(super) fn parse(text: &str) -> Result<Program, ParseError> {
    let mut lines = text.lines().enumerate().peekable();
    // Header: leading lines that are not steps, up to a blank line or the first step.
    let mut header: Vec<&str> = Vec::new();
    while let Some(&(_, line)) = lines.peek() {
        let t = line.trim();
        if header.is_empty() && t.is_empty() {
            lines.next();
            continue;
        }
        if t.is_empty() || t.starts_with('[') || t.starts_with('#') {
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
        return Err(ParseError { format: PlanFormat::Lines, location: Location::Whole, kind: ParseErrorKind::Empty });
    }
    let title = header.first().map(|s| s.to_string());
    let description = (header.len() > 1).then(|| header[1..].join("\n"));
    Ok(Program { title, description, actions })
}

/// Parses one step line, e.g. `[PUTBACK] <soap> (1.1002) <sink> (1001)`; errors say line 1.
pub fn parse_step_line(line: &str) -> Result<Action, ParseError> {
    parse_at(line, 1)
}

/// The one action-line parser in its lenient mode (spaces, verb case, EAI's `(1.1002)` ids), its
/// error placed at `line_no`.
fn parse_at(line: &str, line_no: usize) -> Result<Action, ParseError> {
    parse_action_line(line, LineSyntax::Lenient).map_err(|e| ParseError {
        format: PlanFormat::Lines,
        location: Location::Line { line: line_no, column: e.column },
        kind: match e.kind {
            ActionLineErrorKind::Syntax { expected, found } => ParseErrorKind::Syntax { expected, found },
            ActionLineErrorKind::UnknownVerb(v) => ParseErrorKind::UnknownVerb(v),
            ActionLineErrorKind::WrongArity(w) => ParseErrorKind::WrongArity(w),
        },
    })
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
    use crate::action::{ObjRef, Verb};

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

    fn err_of(text: &str) -> ParseError {
        parse(text).unwrap_err()
    }

    #[test]
    fn unknown_verb_names_line_and_column() {
        let e = err_of("[WALK] <kitchen> (11)\n[FLY] <kitchen> (11)\n");
        assert_eq!(e.location, Location::Line { line: 2, column: Some(2) });
        assert!(matches!(e.kind, ParseErrorKind::UnknownVerb(_)));
        let s = e.to_string();
        assert!(s.starts_with("lines plan, line 2, column 2: unknown action 'FLY'"), "{s}");
    }

    #[test]
    fn wrong_arity_names_the_line() {
        let e = err_of("[WALK] <kitchen> (11)\n\n[PUTBACK] <soap> (1002)\n");
        assert_eq!(e.location, Location::Line { line: 3, column: None });
        assert_eq!(e.to_string(), "lines plan, line 3: PUTBACK takes 2 object(s), got 1");
        let e = err_of("[STANDUP] <chair> (5)");
        assert!(matches!(e.kind, ParseErrorKind::WrongArity(w) if w.expected == 0 && w.got == 1));
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
            assert!(matches!(e.kind, ParseErrorKind::Syntax { .. }), "{line}: {e}");
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
        assert_eq!(err_of("Title\nDescription\n\n").kind, ParseErrorKind::Empty);
        assert_eq!(err_of("").kind, ParseErrorKind::Empty);
    }

    #[test]
    fn single_line_parser() {
        let a = parse_step_line("[PUTBACK] <soap> (1.1002) <sink> (1001)").unwrap();
        assert_eq!(a.to_string(), "[PUTBACK] <soap> (1002) <sink> (1001)");
    }
}
