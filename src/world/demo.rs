//! The project's own demo scene: a small kitchen and a living room in VirtualHome's graph format,
//! embedded in the binary so that `step plan` runs without the benchmark data.
//!
//! Kitchen: fridge (closed), kitchencounter with an apple, milk, bread, a knife, a rag and the
//! microwave; a kitchencabinet (closed) holding a plate; a kitchentable with a mug; chair, sink,
//! faucet, lightswitch and light. Living room (through an open door, inside the kitchen as a
//! VirtualHome scene puts a door inside one of its rooms, so it can be walked to): sofa facing
//! the television, a coffee_table with the remote_control and a book, a light.

use super::graph::{self, Graph};
use super::state::World;

/// The demo scene's JSON text (a bare graph).
pub const DEMO_KITCHEN_JSON: &str = include_str!("demo_kitchen.json");

/// The demo scene's graph.
pub fn demo_kitchen() -> Graph {
    // The embedded file is checked by the tests below; an empty graph is unreachable in practice.
    graph::parse_scene(DEMO_KITCHEN_JSON, "demo_kitchen.json").map(|s| s.init).unwrap_or_default()
}

impl World {
    /// The demo kitchen as a world (see the module documentation).
    pub fn demo() -> World {
        match World::from_json(DEMO_KITCHEN_JSON, "demo_kitchen.json") {
            Ok(w) => w,
            // Unreachable: the embedded scene is valid (tested). Keep the signature infallible.
            Err(e) => panic!("embedded demo scene is invalid: {e}"),
        }
    }

    /// The demo kitchen with `edit` applied to its JSON: tests of a state it does not have.
    #[cfg(test)]
    pub fn demo_edited(edit: impl FnOnce(&mut serde_json::Value)) -> World {
        let mut g: serde_json::Value = serde_json::from_str(DEMO_KITCHEN_JSON).unwrap();
        edit(&mut g);
        World::from_json(&g.to_string(), "test").unwrap()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::{Action, ObjRef, Verb};
    use crate::world::{FailureKind, Relation, State};

    fn a(verb: Verb, args: &[(&str, u32)]) -> Action {
        Action::new(verb, args.iter().map(|&(c, i)| ObjRef::new(c, i)).collect()).unwrap()
    }

    #[test]
    fn demo_scene_loads_with_the_promised_objects() {
        let w = World::demo();
        for class in [
            "fridge",
            "apple",
            "kitchencounter",
            "microwave",
            "kitchencabinet",
            "kitchentable",
            "chair",
            "sink",
            "faucet",
            "lightswitch",
            "light",
            "sofa",
            "television",
            "living_room",
            "kitchen",
        ] {
            assert!(!w.ids_of_class(class).is_empty(), "missing {class}");
        }
        assert_eq!(w.character_room(), Some(1));
        assert_eq!(demo_kitchen().nodes.len(), w.len());
    }

    #[test]
    fn put_the_apple_in_the_fridge() {
        let mut w = World::demo();
        let plan = [
            a(Verb::Walk, &[("apple", 12)]),
            a(Verb::Grab, &[("apple", 12)]),
            a(Verb::Walk, &[("fridge", 10)]),
            a(Verb::Open, &[("fridge", 10)]),
            a(Verb::PutIn, &[("apple", 12), ("fridge", 10)]),
            a(Verb::Close, &[("fridge", 10)]),
        ];
        for step in &plan {
            w.execute(step).unwrap_or_else(|e| panic!("{step}: {e}"));
        }
        assert!(w.has_edge(12, Relation::Inside, 10));
        assert!(w.node(10).unwrap().states.contains(State::Closed));
        assert!(w.held().is_empty());
    }

    #[test]
    fn putting_the_apple_into_a_closed_fridge_says_open_it() {
        let mut w = World::demo();
        for step in [a(Verb::Walk, &[("apple", 12)]), a(Verb::Grab, &[("apple", 12)]), a(Verb::Walk, &[("fridge", 10)])]
        {
            w.execute(&step).unwrap();
        }
        let e = w.execute(&a(Verb::PutIn, &[("apple", 12), ("fridge", 10)])).unwrap_err();
        assert_eq!(e.kind, FailureKind::MissingStep);
        assert_eq!(e.eai_kind, FailureKind::Affordance);
        assert_eq!(
            e.message,
            "cannot [PUTIN] <apple> (12) <fridge> (10): <fridge> (10) is CLOSED; OPEN <fridge> (10) first"
        );
    }
}
