//! Where scenes meet grammars: grammars built over a particular scene (the demo kitchen's), above
//! both `world` and `grammar`, so neither depends on the other for it. The tests below this module run
//! the planner's grammar family through the LLM runtime, the one place the two sides are joined in
//! tests.

use crate::action::{Action, ObjRef, Verb};
use crate::grammar::{ActionGrammar, ActionSet, Strength, VerbSpec};
use crate::world::affordance::SlotRequirement;
use crate::world::World;

/// The scene objects with these ids, the character and unknown ids left out, by id, once each (the
/// objects [`World::feasible_actions_among`] ranges over).
pub fn scene_objects(world: &World, ids: &[u32]) -> Vec<ObjRef> {
    let ch = world.character();
    let mut v: Vec<ObjRef> = ids
        .iter()
        .filter(|&&id| id != ch)
        .filter_map(|&id| world.node(id).map(|n| ObjRef::new(n.class_name, n.id)))
        .collect();
    v.sort_by_key(|o| o.id);
    v.dedup_by_key(|o| o.id);
    v
}

/// `typed`: each slot of each verb limited to the objects among `ids` whose properties fit it
/// ([`SlotRequirement::of`]); verbs with a slot nothing fits are left out.
pub fn typed_set(world: &World, ids: &[u32]) -> ActionSet {
    let objects = scene_objects(world, ids);
    let mut verbs = Vec::new();
    for &v in Verb::ALL {
        let slots: Vec<Vec<ObjRef>> = (0..v.arity()).map(|i| fitting(world, &objects, v, i)).collect();
        if slots.iter().all(|s: &Vec<ObjRef>| !s.is_empty()) {
            verbs.push(VerbSpec::from(v).restricted(slots));
        }
    }
    ActionSet::Slots(verbs, objects)
}

/// Every action of the `typed` set over `ids`, listed one by one (verbs as in [`Verb::ALL`], then
/// objects by id), without actions naming one object twice. The planner offers those that cannot
/// run yet as subgoals ("make this action possible, then do it"); verbs without objects are left out.
pub fn typed_actions(world: &World, ids: &[u32]) -> Vec<Action> {
    let objects = scene_objects(world, ids);
    let fits = |v: Verb, i: usize| fitting(world, &objects, v, i);
    let mut out = Vec::new();
    for &verb in Verb::ALL {
        match verb.arity() {
            1 => out.extend(fits(verb, 0).into_iter().map(|o| Action { verb, args: vec![o] })),
            2 => {
                let second = fits(verb, 1);
                for a in fits(verb, 0) {
                    for b in second.iter().filter(|b| b.id != a.id) {
                        out.push(Action { verb, args: vec![a.clone(), b.clone()] });
                    }
                }
            }
            _ => {}
        }
    }
    out
}

/// The `objects` whose properties fit slot `i` of `verb` ([`SlotRequirement::of`]).
fn fitting(world: &World, objects: &[ObjRef], verb: Verb, i: usize) -> Vec<ObjRef> {
    let need = SlotRequirement::of(verb, i);
    objects.iter().filter(|o| world.node(o.id).is_some_and(|n| need.admits(world, &n))).cloned().collect()
}

/// `feasible`: exactly the actions over `ids` that would succeed now ([`World::feasible_actions_among`]),
/// less those that name one object twice (a toothbrush put on itself): the executor, like EAI's,
/// lets them run, but no robot can do them, and a tiny model was seen writing them.
pub fn feasible_set(world: &World, ids: &[u32]) -> ActionSet {
    let mut list = world.feasible_actions_among(ids);
    list.retain(|a| !(a.args.len() == 2 && a.args[0].id == a.args[1].id));
    ActionSet::Exact(list)
}

/// The action set of the given strength over the objects `ids` of `world`.
pub fn action_set(strength: Strength, world: &World, ids: &[u32]) -> ActionSet {
    match strength {
        Strength::Format => ActionSet::format(&scene_objects(world, ids)),
        Strength::Typed => typed_set(world, ids),
        Strength::Feasible => feasible_set(world, ids),
    }
}

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
    use crate::action::Action;
    use crate::grammar::{DecomposeGrammar, PlanGrammar, VerdictGrammar};

    fn act(v: Verb, args: &[(&str, u32)]) -> Action {
        Action::new(v, args.iter().map(|&(c, i)| ObjRef::new(c, i)).collect()).unwrap()
    }

    #[test]
    fn typed_and_feasible_sets_on_the_demo_scene() {
        let w = World::demo();
        let ids: Vec<u32> = w.nodes().map(|n| n.id).collect();
        let typed = typed_set(&w, &ids);
        assert!(typed.contains(&act(Verb::Grab, &[("apple", 12)])));
        assert!(!typed.contains(&act(Verb::Grab, &[("sofa", 30)])), "the sofa is not GRABBABLE");
        assert!(!typed.contains(&act(Verb::Sit, &[("fridge", 10)])));
        assert!(typed.contains(&act(Verb::Sit, &[("sofa", 30)])));
        assert!(!typed.contains(&act(Verb::Open, &[("apple", 12)])));
        assert!(!typed.contains(&act(Verb::SwitchOn, &[("apple", 12)])));
        assert!(typed.contains(&act(Verb::PutIn, &[("apple", 12), ("fridge", 10)])));
        assert!(!typed.contains(&act(Verb::PutIn, &[("fridge", 10), ("apple", 12)])), "a fridge cannot be held");
        assert!(!typed.contains(&act(Verb::Walk, &[("character", 3)])), "the robot is never an object");
        let feasible = feasible_set(&w, &ids);
        assert_eq!(feasible.len(), w.feasible_actions().len());
        assert!(feasible.contains(&act(Verb::Walk, &[("apple", 12)])));
        assert!(!feasible.contains(&act(Verb::Grab, &[("apple", 12)])), "too far");
        for s in Strength::ALL {
            let set = action_set(s, &w, &ids);
            assert!(!set.is_empty(), "{s}");
            for lark in [
                DecomposeGrammar::new(set.clone(), 40).to_lark().unwrap(),
                VerdictGrammar::new(set.clone(), 40).to_lark().unwrap(),
                PlanGrammar { actions: set.clone(), max_lines: 8 }.to_lark().unwrap(),
            ] {
                assert!(lark.contains("action: "), "{s}: {lark}");
            }
        }
        let sizes: Vec<usize> = Strength::ALL.iter().map(|&s| action_set(s, &w, &ids).len()).collect();
        assert!(sizes[0] > sizes[1] && sizes[1] > sizes[2], "format > typed > feasible: {sizes:?}");
    }

    #[test]
    fn a_typed_set_whose_objects_fit_no_slot_keeps_only_verbs_they_fit() {
        let t = typed_set(&World::demo(), &[1]);
        assert!(t.contains(&act(Verb::StandUp, &[])));
        assert!(!t.contains(&act(Verb::Grab, &[("kitchen", 1)])));
        assert!(t.contains(&act(Verb::Walk, &[("kitchen", 1)])));
    }


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
