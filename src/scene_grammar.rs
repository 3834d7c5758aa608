//! Where scenes meet grammars: grammars built over a particular scene (the demo kitchen's), above
//! both `world` and `grammar`, so neither depends on the other for it. The tests below this module run
//! the planner's grammar family through the LLM runtime, the one place the two sides are joined in
//! tests.

use crate::action::ObjRef;
use crate::grammar::ActionGrammar;
use crate::world::World;

/// The demo kitchen's action grammar (`grammars/actions.lark`): every verb of the embodiment over
/// the demo scene's objects (the robot excluded), 1..=8 lines (at most ~130 tokens).
pub fn demo_kitchen_grammar() -> ActionGrammar {
    let world = World::demo();
    let objects =
        world.objects().into_iter().filter(|o| o.class_name != "character").map(|o| ObjRef::new(o.class_name, o.id));
    ActionGrammar::for_scene(objects).lines(1, 8)
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod file_tests {
    use super::*;

    /// `grammars/actions.lark` is the builder's output for the demo kitchen (never edited by hand):
    /// the test fails if it drifts; `STEP_UPDATE_GRAMMARS=1 cargo test --lib scene_grammar` rewrites it.
    #[test]
    fn demo_grammar_file_is_the_builders_output() {
        let lark = demo_kitchen_grammar().to_lark().unwrap();
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("grammars/actions.lark");
        if std::env::var_os("STEP_UPDATE_GRAMMARS").is_some() {
            std::fs::write(&path, &lark).unwrap();
        }
        let on_disk = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            on_disk,
            lark,
            "{} is stale: run STEP_UPDATE_GRAMMARS=1 cargo test --lib scene_grammar",
            path.display()
        );
    }
}
