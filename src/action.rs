//! Primitive actions of the VirtualHome embodiment: the verbs a leaf of the subgoal tree maps to.
//!
//! This is the one place an action is declared (name, arity, what it means in words). The world's
//! executor gives each verb its semantics, the grammar builder turns the table into the only verbs a
//! model may write, and the plan formats print and parse actions through it.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// An object of the scene as an action names it: its class and its node id in the scene graph.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct ObjRef {
    pub class_name: String,
    pub id: u32,
}

/// The longest name (a verb's, an object class's, a grammar's label) a line may hold: a grammar
/// spells every name out.
pub const MAX_NAME_CHARS: usize = 64;

/// Why `name` cannot stand as a name in a line, if it cannot: empty, longer than
/// [`MAX_NAME_CHARS`], or holding a control character or one of `forbidden`, any of which would
/// make the line ambiguous. The grammar builder asks it of every name it spells out.
pub fn name_problem(name: &str, forbidden: &[char]) -> Option<String> {
    if name.is_empty() {
        return Some("it is empty".into());
    }
    if name.chars().count() > MAX_NAME_CHARS {
        return Some(format!("it is longer than {MAX_NAME_CHARS} characters"));
    }
    name.chars()
        .find(|c| c.is_control() || forbidden.contains(c))
        .map(|c| format!("it contains {c:?}, which would make the line ambiguous"))
}

impl ObjRef {
    pub fn new(class_name: impl Into<String>, id: u32) -> Self {
        Self { class_name: class_name.into(), id }
    }

    /// Why `name` cannot be an object's class in an action line (`<name> (id)`), if it cannot
    /// ([`name_problem`], with `<` and `>`). The scene loader and the grammar builder both ask
    /// this, so a scene that loads can always be planned on.
    pub fn class_name_problem(name: &str) -> Option<String> {
        name_problem(name, &['<', '>'])
    }
}

impl fmt::Display for ObjRef {
    /// VirtualHome's script form: `<class> (id)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "<{}> ({})", self.class_name, self.id)
    }
}

macro_rules! verbs {
    ($( $variant:ident = $name:literal, $arity:literal, $doc:literal; )*) => {
        /// Every primitive action the VirtualHome embodiment knows: EAI's 42, plus SLEEP and WAKEUP,
        /// which its gold programs use.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
        #[serde(into = "String", try_from = "String")]
        pub enum Verb { $( $variant, )* }

        impl Verb {
            /// All verbs, in declaration order (the order grammars and listings use).
            pub const ALL: &'static [Verb] = &[ $( Verb::$variant, )* ];

            /// The upper-case script name, e.g. `PUTBACK`.
            pub fn name(self) -> &'static str {
                match self { $( Verb::$variant => $name, )* }
            }

            /// How many objects the action takes (0, 1 or 2).
            pub fn arity(self) -> usize {
                match self { $( Verb::$variant => $arity, )* }
            }

            /// What the action does, in words a model can be prompted with.
            pub fn description(self) -> &'static str {
                match self { $( Verb::$variant => $doc, )* }
            }
        }
    };
}

verbs! {
    Close = "CLOSE", 1, "close something that is open (a door, a fridge); not 'get close to'";
    Drink = "DRINK", 1, "drink from something held";
    Find = "FIND", 1, "find something and get near to it";
    Walk = "WALK", 1, "walk towards something or into a room and get near to it";
    Grab = "GRAB", 1, "grab something with a free hand";
    LookAt = "LOOKAT", 1, "look at something, face it";
    LookAtShort = "LOOKAT_SHORT", 1, "look at something briefly";
    LookAtLong = "LOOKAT_LONG", 1, "look at something for a long time";
    Open = "OPEN", 1, "open something that is closed";
    PointAt = "POINTAT", 1, "point at something";
    PutBack = "PUTBACK", 2, "put a held object A on object B";
    PutIn = "PUTIN", 2, "put a held object A into object B";
    PutObjBack = "PUTOBJBACK", 1, "put a held object back where it was";
    Run = "RUN", 1, "run towards something and get near to it";
    Sit = "SIT", 1, "sit on something";
    StandUp = "STANDUP", 0, "stand up";
    SwitchOff = "SWITCHOFF", 1, "switch something off";
    SwitchOn = "SWITCHON", 1, "switch something on";
    Touch = "TOUCH", 1, "touch something";
    TurnTo = "TURNTO", 1, "turn to face something";
    Watch = "WATCH", 1, "watch something";
    Wipe = "WIPE", 1, "wipe something clean";
    PutOn = "PUTON", 1, "put on a held piece of clothing";
    PutOff = "PUTOFF", 1, "take off a piece of clothing";
    Greet = "GREET", 1, "greet somebody";
    Drop = "DROP", 1, "drop a held object in the current room";
    Read = "READ", 1, "read something held";
    Lie = "LIE", 1, "lie on something";
    Pour = "POUR", 2, "pour held object A into object B";
    Type = "TYPE", 1, "type on something, e.g. a keyboard";
    Push = "PUSH", 1, "push something";
    Pull = "PULL", 1, "pull something";
    Move = "MOVE", 1, "move something";
    Wash = "WASH", 1, "wash something";
    Rinse = "RINSE", 1, "rinse something";
    Scrub = "SCRUB", 1, "scrub something";
    Squeeze = "SQUEEZE", 1, "squeeze something, e.g. clothes";
    PlugIn = "PLUGIN", 1, "plug something in";
    PlugOut = "PLUGOUT", 1, "unplug something";
    Cut = "CUT", 1, "cut some food";
    Eat = "EAT", 1, "eat some food";
    Release = "RELEASE", 1, "let go of a held object in the current room";
    Sleep = "SLEEP", 0, "go to sleep";
    WakeUp = "WAKEUP", 0, "wake up";
}

impl Verb {
    /// Every verb's name, comma-separated, for an error that says what the robot can do.
    pub fn listing() -> String {
        Verb::ALL.iter().map(|v| v.name()).collect::<Vec<_>>().join(", ")
    }
}

impl fmt::Display for Verb {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A verb name that is not one of [`Verb::ALL`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown action '{0}': the actions are {list}", list = Verb::listing())]
pub struct UnknownVerb(pub String);

impl FromStr for Verb {
    type Err = UnknownVerb;

    /// Accepts the script name in any case (`putback`, `PUTBACK`), with or without brackets.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bare = s.trim().trim_start_matches('[').trim_end_matches(']');
        Verb::ALL
            .iter()
            .copied()
            .find(|v| v.name().eq_ignore_ascii_case(bare))
            .ok_or_else(|| UnknownVerb(s.to_string()))
    }
}

impl From<Verb> for String {
    fn from(v: Verb) -> String {
        v.name().to_string()
    }
}

impl TryFrom<String> for Verb {
    type Error = UnknownVerb;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

/// One primitive action: a verb and exactly `verb.arity()` objects.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Action {
    pub verb: Verb,
    pub args: Vec<ObjRef>,
}

/// An action whose object count does not match its verb.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{verb} takes {expected} object(s), got {got}")]
pub struct WrongArity {
    pub verb: Verb,
    pub expected: usize,
    pub got: usize,
}

impl Action {
    /// Builds an action, checking its arity.
    pub fn new(verb: Verb, args: Vec<ObjRef>) -> Result<Self, WrongArity> {
        if args.len() != verb.arity() {
            return Err(WrongArity { verb, expected: verb.arity(), got: args.len() });
        }
        Ok(Self { verb, args })
    }
}

impl fmt::Display for Action {
    /// VirtualHome's script line: `[PUTBACK] <soap> (1002) <washing_machine> (1001)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_action_line(f, self.verb.name(), &self.args)
    }
}

// ----- the action line: one renderer, one parser, one error type ------------------------------------

/// Writes an action line in canonical script form, `[VERB] <class> (id) ...`: the one renderer, used
/// by [`Action`]'s `Display` and by grammars whose verbs are names (which may lie outside [`Verb::ALL`]).
pub fn write_action_line(out: &mut impl fmt::Write, verb: &str, args: &[ObjRef]) -> fmt::Result {
    write!(out, "[{verb}]")?;
    for a in args {
        write!(out, " {a}")?;
    }
    Ok(())
}

/// [`write_action_line`] into a new string.
pub fn action_line(verb: &str, args: &[ObjRef]) -> String {
    let mut s = String::new();
    // Writing into a String cannot fail.
    let _ = write_action_line(&mut s, verb, args);
    s
}

/// How strictly [`parse_action_line`] reads a line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LineSyntax {
    /// Exactly what [`write_action_line`] prints: single spaces, the verb as written in the table,
    /// names verbatim, ids in plain decimal without leading zeros. Grammar outputs are checked in this
    /// form, so a text the checker accepts is one the grammar could have produced.
    Canonical,
    /// What people and EAI's data write: spaces anywhere between the parts, verbs in any case,
    /// object names normalised as VirtualHome does (lower case, spaces as underscores), and EAI's
    /// `(instance.id)` ids such as `(1.1002)`, where only the node id after the dot is kept (the
    /// instance number counts mentions in the original crowd-sourced script; EAI drops it too).
    Lenient,
}

/// What is wrong with an action line.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ActionLineErrorKind {
    /// The line does not have the shape `[VERB] <class> (id) ...`; `found` is a quoted excerpt.
    #[error("expected {expected}, found {found}")]
    Syntax { expected: String, found: String },
    #[error("{0}")]
    UnknownVerb(UnknownVerb),
    #[error("{0}")]
    WrongArity(WrongArity),
}

/// An action line that could not be read: where (1-based character column, when a position helps)
/// and what.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}{kind}", column.map(|c| format!("column {c}: ")).unwrap_or_default())]
pub struct ActionLineError {
    pub column: Option<usize>,
    pub kind: ActionLineErrorKind,
}

/// An action line split into its parts, the verb still a name (not yet looked up in [`Verb::ALL`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ActionLineParts {
    pub verb: String,
    pub args: Vec<ObjRef>,
}

const LINE_EXAMPLE: &str = "an action such as `[WALK] <kitchen> (11)`";

/// The 1-based character column of a byte offset.
pub(crate) fn column_of(line: &str, byte_offset: usize) -> usize {
    line.get(..byte_offset).map_or(1, |s| s.chars().count() + 1)
}

/// A short quoted excerpt of what was found, for error messages.
pub(crate) fn found_excerpt(s: &str) -> String {
    let s = s.trim();
    if s.is_empty() {
        return "the end of the line".to_string();
    }
    let mut out: String = s.chars().take(40).collect();
    if s.chars().count() > 40 {
        out.push('…');
    }
    format!("'{out}'")
}

/// Splits an action line into verb name and objects, without looking the verb up (grammars check
/// their own verb names). See [`LineSyntax`] for what each mode accepts.
pub fn parse_action_parts(line: &str, syntax: LineSyntax) -> Result<ActionLineParts, ActionLineError> {
    let lenient = syntax == LineSyntax::Lenient;
    let err = |at: usize, expected: &str, found: &str| ActionLineError {
        column: Some(column_of(line, at)),
        kind: ActionLineErrorKind::Syntax { expected: expected.to_string(), found: found_excerpt(found) },
    };
    // Skips spaces at `pos` (lenient only); returns the new position.
    let skip = |pos: usize| if lenient { pos + (line[pos..].len() - line[pos..].trim_start().len()) } else { pos };
    let mut pos = skip(0);
    let rest = &line[pos..];
    if !rest.starts_with('[') {
        return Err(err(pos, LINE_EXAMPLE, rest));
    }
    let Some(close) = rest.find(']') else {
        return Err(err(pos, "']' closing the action name", rest));
    };
    let verb = rest[1..close].to_string();
    if verb.is_empty() {
        return Err(err(pos, "an action name between '[' and ']'", &rest[..=close]));
    }
    pos += close + 1;
    let mut args = Vec::new();
    loop {
        pos = skip(pos);
        if pos == line.len() {
            break;
        }
        // Canonical: exactly one space before each object.
        if !lenient {
            if !line[pos..].starts_with(' ') {
                return Err(err(pos, "' <' starting an object, or the end of the line", &line[pos..]));
            }
            pos += 1;
        }
        let obj = &line[pos..];
        if !obj.starts_with('<') {
            let expected = if lenient {
                "'<' starting an object such as `<soap> (1002)`, or the end of the line"
            } else {
                "' <' starting an object, or the end of the line"
            };
            return Err(err(pos, expected, obj));
        }
        let Some(gt) = obj.find('>') else {
            return Err(err(pos, "'>' closing the object name", obj));
        };
        let raw_name = &obj[1..gt];
        let name = if lenient { normalise_name(raw_name) } else { raw_name.to_string() };
        if name.is_empty() || raw_name.contains('<') {
            return Err(err(pos, "an object name between '<' and '>'", &obj[..=gt]));
        }
        pos += gt + 1;
        if lenient {
            pos = skip(pos);
        } else if line[pos..].starts_with(' ') {
            pos += 1;
        } else {
            return Err(err(pos, &format!("' (' and the id of <{name}>"), &line[pos..]));
        }
        let after = &line[pos..];
        if !after.starts_with('(') {
            let expected = if lenient {
                format!("the id of <{name}> in parentheses, such as (1002) or (1.1002)")
            } else {
                format!("the id of <{name}> in parentheses, such as (1002)")
            };
            return Err(err(pos, &expected, after));
        }
        let Some(paren) = after.find(')') else {
            return Err(err(pos, "')' closing the object id", after));
        };
        let id = parse_id(&after[1..paren], lenient).ok_or_else(|| {
            let expected =
                if lenient { "an object id such as (1002) or (1.1002)" } else { "an object id such as (1002)" };
            err(pos, expected, &after[..=paren])
        })?;
        pos += paren + 1;
        args.push(ObjRef::new(name, id));
    }
    Ok(ActionLineParts { verb, args })
}

/// Parses one action line into an [`Action`]: [`parse_action_parts`], then the verb looked up in
/// [`Verb::ALL`] (canonical: written exactly as its name; lenient: any case) and its arity checked.
pub fn parse_action_line(line: &str, syntax: LineSyntax) -> Result<Action, ActionLineError> {
    let parts = parse_action_parts(line, syntax)?;
    let verb_col = Some(column_of(line, line.find('[').map_or(0, |i| i + 1)));
    let verb: Verb =
        parts.verb.parse().ok().filter(|v: &Verb| syntax == LineSyntax::Lenient || v.name() == parts.verb).ok_or_else(
            || ActionLineError {
                column: verb_col,
                kind: ActionLineErrorKind::UnknownVerb(UnknownVerb(parts.verb.clone())),
            },
        )?;
    Action::new(verb, parts.args)
        .map_err(|e| ActionLineError { column: None, kind: ActionLineErrorKind::WrongArity(e) })
}

/// VirtualHome's own normalisation of a script's object name: lower case, spaces as underscores.
fn normalise_name(raw: &str) -> String {
    raw.split_whitespace().collect::<Vec<_>>().join("_").to_lowercase()
}

/// Canonical: plain decimal, no sign, no leading zero. Lenient: also spaces around it and EAI's
/// `instance.id` (the node id after the dot).
fn parse_id(s: &str, lenient: bool) -> Option<u32> {
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    if !lenient {
        let canonical = digits(s) && (s == "0" || !s.starts_with('0'));
        return if canonical { s.parse().ok() } else { None };
    }
    let s = s.trim();
    match s.split_once('.') {
        Some((inst, id)) if digits(inst) && digits(id) => id.parse().ok(),
        None if digits(s) => s.parse().ok(),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verb_names_round_trip_and_are_unique() {
        let mut seen = std::collections::HashSet::new();
        for &v in Verb::ALL {
            assert!(seen.insert(v.name()), "duplicate verb name {}", v.name());
            assert_eq!(v.name().parse::<Verb>().unwrap(), v);
            assert_eq!(v.name().to_lowercase().parse::<Verb>().unwrap(), v);
            assert!(v.arity() <= 2);
        }
        assert_eq!(Verb::ALL.len(), 44);
    }

    #[test]
    fn unknown_verb_lists_the_valid_ones() {
        let e = "FLY".parse::<Verb>().unwrap_err().to_string();
        assert!(e.contains("unknown action 'FLY'") && e.contains("PUTBACK"), "{e}");
    }

    #[test]
    fn arity_is_checked_and_display_is_script_form() {
        let soap = ObjRef::new("soap", 1002);
        let wm = ObjRef::new("washing_machine", 1001);
        let a = Action::new(Verb::PutBack, vec![soap.clone(), wm]).unwrap();
        assert_eq!(a.to_string(), "[PUTBACK] <soap> (1002) <washing_machine> (1001)");
        let e = Action::new(Verb::PutBack, vec![soap]).unwrap_err();
        assert_eq!(e.to_string(), "PUTBACK takes 2 object(s), got 1");
        assert_eq!(Action::new(Verb::StandUp, vec![]).unwrap().to_string(), "[STANDUP]");
    }
    #[test]
    fn one_parser_reads_what_display_writes() {
        let a = Action::new(Verb::PutBack, vec![ObjRef::new("soap", 1002), ObjRef::new("sink", 0)]).unwrap();
        for syntax in [LineSyntax::Canonical, LineSyntax::Lenient] {
            assert_eq!(parse_action_line(&a.to_string(), syntax).unwrap(), a);
        }
        assert_eq!(parse_action_line("[STANDUP]", LineSyntax::Canonical).unwrap().verb, Verb::StandUp);
        // Names are verbatim in canonical form (grammars may list any name without '<', '>').
        let p = parse_action_parts("[A\"B] <say \"hi\"> (1)", LineSyntax::Canonical).unwrap();
        assert_eq!((p.verb.as_str(), p.args[0].class_name.as_str()), ("A\"B", "say \"hi\""));
    }

    #[test]
    fn lenient_mode_takes_eai_ids_spaces_and_case() {
        let a = parse_action_line("  [putback]<Soap Dish>( 1.1002 )   <sink>(7) ", LineSyntax::Lenient).unwrap();
        assert_eq!(a.to_string(), "[PUTBACK] <soap_dish> (1002) <sink> (7)");
        for bad in [
            "  [WALK] <sink> (7)",
            "[walk] <sink> (7)",
            "[WALK] <sink> (1.7)",
            "[WALK] <sink> (07)",
            "[WALK]  <sink> (7)",
            "[WALK] <sink>(7)",
            "[WALK] <sink> (7) ",
            "[WALK] <Sink> (7)x",
        ] {
            assert!(parse_action_line(bad, LineSyntax::Canonical).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn errors_say_where_and_what() {
        let e = parse_action_line("[WALK] <sink> (seven)", LineSyntax::Lenient).unwrap_err();
        assert_eq!(e.to_string(), "column 15: expected an object id such as (1002) or (1.1002), found '(seven)'");
        let e = parse_action_line("[FLY] <sink> (7)", LineSyntax::Canonical).unwrap_err();
        assert_eq!(e.column, Some(2));
        assert!(matches!(e.kind, ActionLineErrorKind::UnknownVerb(_)));
        let e = parse_action_line("[GRAB]", LineSyntax::Canonical).unwrap_err();
        assert_eq!(e.to_string(), "GRAB takes 1 object(s), got 0");
        let e = parse_action_line("walk to the sink", LineSyntax::Lenient).unwrap_err();
        assert!(e.to_string().contains("expected an action such as `[WALK] <kitchen> (11)`"), "{e}");
        let e = parse_action_parts("[] <sink> (7)", LineSyntax::Lenient).unwrap_err();
        assert!(e.to_string().contains("an action name between '[' and ']'"), "{e}");
    }
}
