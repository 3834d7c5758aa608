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

impl ObjRef {
    pub fn new(class_name: impl Into<String>, id: u32) -> Self {
        Self { class_name: class_name.into(), id }
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

impl fmt::Display for Verb {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A verb name that is not one of [`Verb::ALL`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown action '{0}': the actions are {list}", list = Verb::ALL.iter().map(|v| v.name()).collect::<Vec<_>>().join(", "))]
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
        write!(f, "[{}]", self.verb)?;
        for a in &self.args {
            write!(f, " {a}")?;
        }
        Ok(())
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
}
