//! The closed vocabularies of a VirtualHome scene graph: edge relations, node states and object
//! properties, as the evolving-graph simulator names them (upper-case strings in the JSON).
//!
//! States and properties are small bit sets so that a world state clones cheaply and a check is one
//! AND; the string forms are the ones the graph JSON and the goals use.

use std::fmt;
use std::str::FromStr;

macro_rules! name_enum {
    ($(#[$m:meta])* $ty:ident { $( $variant:ident = $name:literal, )* }) => {
        $(#[$m])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
        #[serde(into = "String", try_from = "String")]
        pub enum $ty { $( $variant, )* }

        impl From<$ty> for String {
            fn from(v: $ty) -> String {
                v.name().to_string()
            }
        }

        impl TryFrom<String> for $ty {
            type Error = String;
            fn try_from(s: String) -> Result<Self, String> {
                s.parse()
            }
        }

        impl $ty {
            /// All values, in declaration order.
            pub const ALL: &'static [$ty] = &[ $( $ty::$variant, )* ];

            /// The upper-case name used in graph JSON.
            pub fn name(self) -> &'static str {
                match self { $( $ty::$variant => $name, )* }
            }

            #[allow(dead_code)] // Relation has no set type
            fn bit(self) -> u32 {
                1u32 << (self as u32)
            }
        }

        impl fmt::Display for $ty {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.name())
            }
        }

        impl FromStr for $ty {
            type Err = String;
            /// Case-insensitive; the error lists the valid names.
            fn from_str(s: &str) -> Result<Self, String> {
                $ty::ALL.iter().copied().find(|v| v.name().eq_ignore_ascii_case(s.trim())).ok_or_else(|| {
                    format!(
                        "unknown {} '{}' (expected one of {})",
                        stringify!($ty).to_lowercase(),
                        s,
                        $ty::ALL.iter().map(|v| v.name()).collect::<Vec<_>>().join(", ")
                    )
                })
            }
        }
    };
}

name_enum! {
    /// A directed edge label of the scene graph.
    Relation {
        On = "ON",
        Inside = "INSIDE",
        Between = "BETWEEN",
        Close = "CLOSE",
        Facing = "FACING",
        HoldsRh = "HOLDS_RH",
        HoldsLh = "HOLDS_LH",
        Sitting = "SITTING",
    }
}

name_enum! {
    /// A state a node can be in.
    State {
        Closed = "CLOSED",
        Open = "OPEN",
        On = "ON",
        Off = "OFF",
        Sitting = "SITTING",
        Dirty = "DIRTY",
        Clean = "CLEAN",
        Lying = "LYING",
        PluggedIn = "PLUGGED_IN",
        PluggedOut = "PLUGGED_OUT",
    }
}

name_enum! {
    /// What an object affords (from the node's `properties`).
    Property {
        Surfaces = "SURFACES",
        Grabbable = "GRABBABLE",
        Sittable = "SITTABLE",
        Lieable = "LIEABLE",
        Hangable = "HANGABLE",
        Drinkable = "DRINKABLE",
        Eatable = "EATABLE",
        Recipient = "RECIPIENT",
        Cuttable = "CUTTABLE",
        Pourable = "POURABLE",
        CanOpen = "CAN_OPEN",
        HasSwitch = "HAS_SWITCH",
        Readable = "READABLE",
        Lookable = "LOOKABLE",
        Containers = "CONTAINERS",
        Clothes = "CLOTHES",
        Person = "PERSON",
        BodyPart = "BODY_PART",
        CoverObject = "COVER_OBJECT",
        HasPlug = "HAS_PLUG",
        HasPaper = "HAS_PAPER",
        Movable = "MOVABLE",
        Cream = "CREAM",
    }
}

impl State {
    /// States no node can be in at once (the executor sets one and clears the other). A scene
    /// giving both is refused: which of the two the executor's checks would see is arbitrary.
    pub const EXCLUSIVE: [(State, State); 5] = [
        (State::Open, State::Closed),
        (State::On, State::Off),
        (State::Clean, State::Dirty),
        (State::PluggedIn, State::PluggedOut),
        (State::Sitting, State::Lying),
    ];

    /// The state this one excludes ([`State::EXCLUSIVE`]), if any.
    pub fn opposite(self) -> Option<State> {
        State::EXCLUSIVE.iter().find_map(|&(a, b)| match self {
            s if s == a => Some(b),
            s if s == b => Some(a),
            _ => None,
        })
    }
}

macro_rules! bit_set {
    ($(#[$m:meta])* $set:ident of $ty:ident) => {
        $(#[$m])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub struct $set(u32);

        impl $set {
            pub const EMPTY: $set = $set(0);

            pub fn contains(self, v: $ty) -> bool {
                self.0 & v.bit() != 0
            }
            pub fn insert(&mut self, v: $ty) {
                self.0 |= v.bit();
            }
            pub fn remove(&mut self, v: $ty) {
                self.0 &= !v.bit();
            }
            pub fn is_empty(self) -> bool {
                self.0 == 0
            }
            /// Members in declaration order (deterministic).
            pub fn iter(self) -> impl Iterator<Item = $ty> {
                $ty::ALL.iter().copied().filter(move |v| self.contains(*v))
            }
        }

        impl FromIterator<$ty> for $set {
            fn from_iter<I: IntoIterator<Item = $ty>>(it: I) -> Self {
                let mut s = $set::EMPTY;
                for v in it {
                    s.insert(v);
                }
                s
            }
        }
    };
}

bit_set!(
    /// A set of [`State`]s.
    StateSet of State
);
bit_set!(
    /// A set of [`Property`]s.
    PropertySet of Property
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back_and_sets_hold_members() {
        for &r in Relation::ALL {
            assert_eq!(r.name().parse::<Relation>().unwrap(), r);
        }
        assert_eq!("holds_rh".parse::<Relation>().unwrap(), Relation::HoldsRh);
        let e = "NEAR".parse::<Relation>().unwrap_err();
        assert!(e.contains("unknown relation 'NEAR'") && e.contains("CLOSE"), "{e}");
        let mut s: StateSet = [State::Open, State::Dirty].into_iter().collect();
        assert!(s.contains(State::Open) && !s.contains(State::Closed));
        assert_eq!((State::Open.opposite(), State::Closed.opposite(), State::Dirty.opposite()), (Some(State::Closed), Some(State::Open), Some(State::Clean)));
        s.remove(State::Open);
        assert_eq!(s.iter().collect::<Vec<_>>(), vec![State::Dirty]);
        assert_eq!(Property::ALL.len(), 23);
    }
}
