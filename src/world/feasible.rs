//! Feasible actions: every action, with its objects, that would succeed in the current state.
//!
//! The planner builds grammars from this list, so it must agree exactly with the executor: each
//! candidate is decided by [`World::check`], the executor's own precondition code. The only pruning is
//! a fact the executor enforces first for PUTBACK, PUTIN and POUR (the first object must be held);
//! a test compares the pruned list with the brute-force one over all object pairs.

use crate::action::{Action, ObjRef, Verb};

use super::exec::ExecFailure;
use super::state::World;

impl World {
    /// Every action that would succeed now, over all objects of the scene (the character excluded).
    /// Order: verbs as in [`Verb::ALL`], then objects by id (first object, then second).
    pub fn feasible_actions(&self) -> Vec<Action> {
        self.feasible_among(None)
    }

    /// Like [`World::feasible_actions`], with objects restricted to `ids` (e.g. the task's relevant
    /// objects); ids not in the scene are ignored.
    pub fn feasible_actions_among(&self, ids: &[u32]) -> Vec<Action> {
        self.feasible_among(Some(ids))
    }

    /// Why `action` would not succeed now (`None`: it would).
    pub fn why_not(&self, action: &Action) -> Option<ExecFailure> {
        self.check(action).err()
    }

    /// The runnable action that starts the way to `target`: `target` itself when it can run now;
    /// else the step its failure names ("...; OPEN <fridge> (10) first"), followed the same way
    /// (GRAB needs a WALK first, and so on). `None`: no such step is named (an affordance error, a
    /// tool to find, hands to free) or the chain is longer than a few steps.
    pub fn first_step_towards(&self, target: &Action) -> Option<Action> {
        let mut step = target.clone();
        for _ in 0..6 {
            match self.why_not(&step) {
                None => return Some(step),
                Some(f) => step = self.named_fix(&f.message)?,
            }
        }
        None
    }

    /// Whether following [`World::first_step_towards`] from here (on a copy) ends with `target`
    /// running: a target whose way leads only to an affordance error (SIT on a fridge: walk there,
    /// then fail) or to nothing is not reachable.
    pub fn reaches(&self, target: &Action) -> bool {
        self.after_way_to(target).is_some()
    }

    /// The state after following the way to `target` and running it, on a copy (`None`: see
    /// [`World::reaches`]).
    pub fn after_way_to(&self, target: &Action) -> Option<World> {
        let mut w = self.before_running(target)?;
        w.execute(target).ok()?;
        Some(w)
    }

    /// The state the way to `target` leads to, just before `target` itself runs, on a copy (`None`:
    /// no way within 7 steps).
    pub fn before_running(&self, target: &Action) -> Option<World> {
        self.way_to(target).map(|(_, w)| w)
    }

    /// The steps of the way to `target` (target excluded) and the state they lead to, on a copy
    /// (`None`: no way within 7 steps). A planner limited to some objects checks the steps' objects.
    pub fn way_to(&self, target: &Action) -> Option<(Vec<Action>, World)> {
        let mut w = self.clone();
        let mut steps = Vec::new();
        for _ in 0..8 {
            let step = w.first_step_towards(target)?;
            if step == *target {
                return Some((steps, w));
            }
            w.execute(&step).ok()?;
            steps.push(step);
        }
        None
    }

    /// The action a failure message names as the fix, when it names exactly one: the executor's
    /// messages end with "; VERB [to] <name> (id) first" or "; VERB first" (checks.rs, verbs.rs).
    fn named_fix(&self, message: &str) -> Option<Action> {
        // (a fix that held earlier in the plan carries a note after it: without this, no way led
        // back to an object the robot had walked away from, put down or closed again)
        let message = message.strip_suffix(super::exec::UNDONE_NOTE).unwrap_or(message);
        let fix = message.rsplit("; ").next()?.strip_suffix(" first")?;
        let (verb, rest) = fix.split_once(' ').unwrap_or((fix, ""));
        let verb: Verb = verb.parse().ok()?;
        let rest = rest.trim_start_matches("to ").trim();
        let args = if rest.is_empty() {
            Vec::new()
        } else {
            let id: u32 = rest.rsplit_once('(')?.1.strip_suffix(')')?.parse().ok()?;
            vec![ObjRef::new(self.node(id)?.class_name, id)]
        };
        (args.len() == verb.arity()).then_some(Action { verb, args })
    }

    fn candidates(&self, ids: Option<&[u32]>) -> Vec<ObjRef> {
        let ch = self.character();
        let mut v: Vec<ObjRef> = match ids {
            None => self.nodes().filter(|n| n.id != ch).map(|n| ObjRef::new(n.class_name, n.id)).collect(),
            Some(ids) => ids
                .iter()
                .filter(|&&id| id != ch)
                .filter_map(|&id| self.node(id).map(|n| ObjRef::new(n.class_name, n.id)))
                .collect(),
        };
        v.sort_by_key(|o| o.id);
        v.dedup_by_key(|o| o.id);
        v
    }

    fn feasible_among(&self, ids: Option<&[u32]>) -> Vec<Action> {
        let objs = self.candidates(ids);
        let held: Vec<ObjRef> = {
            let mut h: Vec<u32> = self.held().into_iter().map(|(_, id)| id).collect();
            h.sort_unstable();
            objs.iter().filter(|o| h.binary_search(&o.id).is_ok()).cloned().collect()
        };
        let mut out = Vec::new();
        for &verb in Verb::ALL {
            match verb.arity() {
                0 => push_if_ok(self, &mut out, Action { verb, args: vec![] }),
                1 => {
                    for o in &objs {
                        push_if_ok(self, &mut out, Action { verb, args: vec![o.clone()] });
                    }
                }
                _ => {
                    // PUTBACK, PUTIN, POUR: the executor refuses them unless the first object is held.
                    let firsts = if matches!(verb, Verb::PutBack | Verb::PutIn | Verb::Pour) { &held } else { &objs };
                    for a in firsts {
                        for b in &objs {
                            push_if_ok(self, &mut out, Action { verb, args: vec![a.clone(), b.clone()] });
                        }
                    }
                }
            }
        }
        out
    }
}

fn push_if_ok(w: &World, out: &mut Vec<Action>, a: Action) {
    if w.check(&a).is_ok() {
        out.push(a);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn a(verb: Verb, args: &[(&str, u32)]) -> Action {
        Action::new(verb, args.iter().map(|&(c, i)| ObjRef::new(c, i)).collect()).unwrap()
    }

    /// All actions over all objects, no pruning: the reference.
    fn brute_force(w: &World) -> Vec<Action> {
        let ch = w.character();
        let objs: Vec<ObjRef> = w.nodes().filter(|n| n.id != ch).map(|n| ObjRef::new(n.class_name, n.id)).collect();
        let mut out = Vec::new();
        for &verb in Verb::ALL {
            let lists: Vec<Vec<ObjRef>> = match verb.arity() {
                0 => vec![vec![]],
                1 => objs.iter().map(|o| vec![o.clone()]).collect(),
                _ => objs.iter().flat_map(|x| objs.iter().map(move |y| vec![x.clone(), y.clone()])).collect(),
            };
            for args in lists {
                let act = Action { verb, args };
                // The executor itself decides: execute on a copy.
                if w.clone().execute(&act).is_ok() {
                    out.push(act);
                }
            }
        }
        out
    }

    #[test]
    fn feasible_equals_would_execute_on_the_demo_scene_along_a_plan() {
        let mut w = World::demo();
        let plan = [
            a(Verb::Walk, &[("apple", 12)]),
            a(Verb::Grab, &[("apple", 12)]),
            a(Verb::Grab, &[("knife", 24)]),
            a(Verb::Walk, &[("fridge", 10)]),
            a(Verb::PutBack, &[("knife", 24), ("kitchencounter", 11)]),
            a(Verb::Open, &[("fridge", 10)]),
            a(Verb::Walk, &[("sofa", 30)]),
            a(Verb::Sit, &[("sofa", 30)]),
        ];
        let mut states_checked = 0;
        for step in plan.iter() {
            let feasible = w.feasible_actions();
            assert_eq!(feasible, brute_force(&w), "before {step}");
            assert!(feasible.contains(step), "{step} should be feasible: {:?}", w.why_not(step));
            w.execute(step).unwrap();
            states_checked += 1;
        }
        assert_eq!(w.feasible_actions(), brute_force(&w));
        assert_eq!(states_checked, plan.len());
    }

    #[test]
    fn the_first_step_towards_an_action_follows_the_named_fixes() {
        let mut w = World::demo();
        let target = a(Verb::PutIn, &[("apple", 12), ("fridge", 10)]);
        let mut steps = Vec::new();
        while let Some(s) = w.first_step_towards(&target) {
            w.execute(&s).unwrap();
            steps.push(s.to_string());
            if s == target || steps.len() > 8 {
                break;
            }
        }
        assert_eq!(
            steps,
            // (the apple lies on the counter by the fridge: no second walk)
            ["[WALK] <apple> (12)", "[GRAB] <apple> (12)", "[OPEN] <fridge> (10)", "[PUTIN] <apple> (12) <fridge> (10)"]
        );
        assert!(World::demo().reaches(&target));
        // SIT on a fridge: the way starts with a walk and ends in an affordance error.
        assert!(!World::demo().reaches(&a(Verb::Sit, &[("fridge", 10)])));
        assert!(World::demo().reaches(&a(Verb::Sit, &[("sofa", 30)])));
    }

    /// A way leads back to what the plan had and undid: the fix of a step that held earlier comes
    /// with a note after it ("... GRAB <apple> (12) first (this held earlier in the plan; ...)"),
    /// which once hid the fix, so that no way was found to put an apple back in the fridge after
    /// it was put down, or to an object the robot had walked away from.
    #[test]
    fn a_way_leads_back_to_what_a_later_step_undid() {
        let mut w = World::demo();
        for s in [
            a(Verb::Walk, &[("apple", 12)]),
            a(Verb::Grab, &[("apple", 12)]),
            a(Verb::PutBack, &[("apple", 12), ("kitchencounter", 11)]),
        ] {
            w.execute(&s).unwrap();
        }
        let target = a(Verb::PutIn, &[("apple", 12), ("fridge", 10)]);
        let why = w.why_not(&target).unwrap();
        assert!(why.message.ends_with(crate::world::exec::UNDONE_NOTE), "{}", why.message);
        let (way, _) = w.way_to(&target).expect("a way back to the apple");
        let way: Vec<String> = way.iter().map(|s| s.to_string()).collect();
        assert_eq!(way, ["[GRAB] <apple> (12)", "[OPEN] <fridge> (10)"]);
        // Walked away from the apple: the way starts with a walk back.
        w.execute(&a(Verb::Walk, &[("sofa", 30)])).unwrap();
        let (way, _) = w.way_to(&target).expect("a way back across the house");
        assert_eq!(way.first().map(|s| s.to_string()).as_deref(), Some("[WALK] <apple> (12)"));
    }

    #[test]
    fn feasible_lists_are_deterministic_and_sensible() {
        let w = World::demo();
        let f = w.feasible_actions();
        assert_eq!(f, World::demo().feasible_actions());
        // Standing in the kitchen, far from everything: walking anywhere works, grabbing nothing does.
        assert!(f.contains(&a(Verb::Walk, &[("apple", 12)])));
        assert!(f.contains(&a(Verb::Walk, &[("living_room", 2)])));
        assert!(!f.iter().any(|x| x.verb == Verb::Grab));
        assert!(!f.iter().any(|x| x.args.iter().any(|o| o.id == w.character())));
        let why = w.why_not(&a(Verb::Grab, &[("apple", 12)])).unwrap();
        assert!(why.message.contains("WALK to <apple> (12) first"), "{}", why.message);
        // Restricted to two objects.
        let few = w.feasible_actions_among(&[12, 10, 999]);
        assert!(few.iter().all(|x| x.args.iter().all(|o| o.id == 12 || o.id == 10)));
        assert!(few.contains(&a(Verb::Walk, &[("fridge", 10)])));
    }
}
