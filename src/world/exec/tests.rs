//! Unit tests of the executor, verb by verb: a precondition that holds (and the effects), one that
//! fails (and its kind and words). Scenes are built here, in code, a few nodes each.

use crate::action::{Action, ObjRef, Verb};
use crate::world::graph::{Edge, Graph, Node};
use crate::world::{FailureKind, Relation, State, World};

use FailureKind::*;
use Relation as R;

/// A small scene: kitchen (1) and bedroom (4) rooms, the character (2) in the kitchen.
struct Scene(Graph);

impl Scene {
    fn new() -> Scene {
        let mut s = Scene(Graph::default());
        s.raw(1, "kitchen", "Rooms", &[], &[]);
        s.raw(4, "bedroom", "Rooms", &[], &[]);
        s.raw(2, "character", "Characters", &[], &[]);
        s.edge(2, "INSIDE", 1)
    }
    fn raw(&mut self, id: u32, class: &str, cat: &str, props: &[&str], states: &[&str]) {
        self.0.nodes.push(Node::new(id, class, cat, props, states));
    }
    /// An object inside the kitchen.
    fn obj(mut self, id: u32, class: &str, props: &[&str], states: &[&str]) -> Scene {
        self.raw(id, class, "Props", props, states);
        self.edge(id, "INSIDE", 1)
    }
    /// An object inside the bedroom.
    fn obj_in_bedroom(mut self, id: u32, class: &str, props: &[&str], states: &[&str]) -> Scene {
        self.raw(id, class, "Props", props, states);
        self.edge(id, "INSIDE", 4)
    }
    fn edge(mut self, f: u32, r: &str, t: u32) -> Scene {
        self.0.edges.push(Edge { from_id: f, relation_type: r.into(), to_id: t });
        self
    }
    /// The robot stands close to `id`.
    fn near(self, id: u32) -> Scene {
        self.edge(2, "CLOSE", id).edge(id, "CLOSE", 2)
    }
    fn holding(self, id: u32) -> Scene {
        self.edge(2, "HOLDS_RH", id).near(id)
    }
    fn world(&self) -> World {
        World::from_graph(&self.0, "test scene").unwrap()
    }
}

fn act(verb: Verb, args: &[(&str, u32)]) -> Action {
    Action::new(verb, args.iter().map(|&(c, i)| ObjRef::new(c, i)).collect()).unwrap()
}

#[track_caller]
fn ok(w: &mut World, verb: Verb, args: &[(&str, u32)]) -> crate::world::Effects {
    let a = act(verb, args);
    assert!(w.check(&a).is_ok(), "check disagrees for {a}");
    w.execute(&a).unwrap_or_else(|e| panic!("{a} failed: {e}"))
}

#[track_caller]
fn fails(w: &World, verb: Verb, args: &[(&str, u32)], kind: FailureKind, words: &str) -> crate::world::ExecFailure {
    let a = act(verb, args);
    let mut w2 = w.clone();
    let e = w2.execute(&a).expect_err("should fail");
    assert_eq!(e.kind, kind, "{}", e.message);
    assert!(e.message.contains(words), "message {:?} lacks {words:?}", e.message);
    assert_eq!(w.check(&a).unwrap_err(), e, "check and execute disagree");
    assert_eq!(w2.edges(), w.edges(), "a failed action changed the state");
    e
}

const APPLE: &[&str] = &["GRABBABLE", "EATABLE", "CUTTABLE", "MOVABLE"];
const FRIDGE: &[&str] = &["CAN_OPEN", "CONTAINERS", "HAS_SWITCH", "HAS_PLUG"];

fn kitchen() -> Scene {
    Scene::new()
        .obj(5, "fridge", FRIDGE, &["CLOSED", "OFF", "PLUGGED_IN"])
        .obj(7, "kitchencounter", &["SURFACES"], &[])
        .obj(8, "mat", &["SURFACES"], &[])
        .edge(7, "ON", 8)
        .obj(12, "apple", APPLE, &[])
        .edge(12, "ON", 7)
        .edge(12, "CLOSE", 7)
        .edge(7, "CLOSE", 12)
        .obj(13, "milk", &["GRABBABLE", "DRINKABLE", "POURABLE"], &[])
        .edge(13, "INSIDE", 5)
        .obj(30, "hands_both", &["BODY_PART"], &[])
}

#[test]
fn walk_moves_close_to_target_its_support_and_body_parts_and_carries_held_objects() {
    let mut w = kitchen().obj_in_bedroom(40, "bed", &["SURFACES", "SITTABLE", "LIEABLE"], &[]).holding(12).world();
    let fx = ok(&mut w, Verb::Walk, &[("bed", 40)]);
    assert_eq!(w.character_room(), Some(4));
    assert!(w.has_edge(2, R::Close, 40) && w.has_edge(40, R::Close, 2));
    assert!(w.has_edge(2, R::Close, 30), "body parts are always close");
    assert!(w.has_edge(2, R::Close, 12) && w.has_edge(2, R::HoldsRh, 12), "still holding the apple");
    assert!(fx.added.contains(&(2, R::Inside, 4)) && fx.removed.contains(&(2, R::Inside, 1)));
    // To the counter: also close to what it stands on (the mat).
    let mut w = kitchen().world();
    ok(&mut w, Verb::Run, &[("kitchencounter", 7)]);
    assert!(w.has_edge(2, R::Close, 7) && w.has_edge(2, R::Close, 8));
    // A fridge: close to what is inside it.
    let mut w = kitchen().world();
    ok(&mut w, Verb::Walk, &[("fridge", 5)]);
    assert!(w.has_edge(2, R::Close, 13));
    // Into a room: inside it, close to nothing in particular.
    let mut w = kitchen().near(12).world();
    ok(&mut w, Verb::Walk, &[("bedroom", 4)]);
    assert_eq!(w.character_room(), Some(4));
    assert!(!w.has_edge(2, R::Close, 12), "walking away ends closeness");
}

#[test]
fn walk_while_sitting_is_a_missing_standup() {
    let w = kitchen().edge(2, "ON", 7).world();
    let mut w2 = w.clone();
    w2.set_state(w2.char_ix(), State::Sitting, true);
    // The initial state had the robot standing, so this is a wrong order (sitting undid it).
    let e = fails(&w2, Verb::Walk, &[("apple", 12)], WrongOrder, "STANDUP first");
    assert_eq!(e.eai_kind, WrongOrder);
    // Sitting from the start: a missing step.
    let mut g = kitchen();
    g.0.nodes.iter_mut().filter(|n| n.id == 2).for_each(|n| n.states = vec!["SITTING".into()]);
    fails(&g.world(), Verb::Run, &[("apple", 12)], MissingStep, "the robot is sitting; STANDUP first");
}

#[test]
fn find_when_close_only_turns_to_it_otherwise_walks() {
    let mut w = kitchen().near(7).edge(2, "FACING", 5).world();
    let fx = ok(&mut w, Verb::Find, &[("apple", 12)]);
    assert!(w.has_edge(2, R::Close, 12) && !w.has_edge(2, R::Facing, 5));
    assert!(fx.removed.contains(&(2, R::Facing, 5)));
    let mut w = kitchen().obj_in_bedroom(40, "bed", &["LIEABLE"], &[]).world();
    ok(&mut w, Verb::Find, &[("bed", 40)]);
    assert_eq!(w.character_room(), Some(4));
    // A worn item that is not close cannot be found by walking.
    let w = kitchen().obj(50, "shirt", &["CLOTHES", "GRABBABLE"], &[]).edge(50, "ON", 2).world();
    fails(&w, Verb::Find, &[("shirt", 50)], MissingStep, "not close to <shirt> (50)");
}

#[test]
fn grab_takes_a_free_hand_and_lifts_the_object_off_its_support() {
    let mut w = kitchen().near(12).world();
    let fx = ok(&mut w, Verb::Grab, &[("apple", 12)]);
    assert!(w.has_edge(2, R::HoldsRh, 12));
    assert!(!w.has_edge(12, R::On, 7), "no longer on the counter");
    assert!(fx.removed.contains(&(12, R::On, 7)) && fx.added.contains(&(2, R::HoldsRh, 12)));
    assert_eq!(w.held(), vec![(R::HoldsRh, 12)]);
    // Grabbing it again: already held.
    fails(&w, Verb::Grab, &[("apple", 12)], AdditionalStep, "already held");
}

#[test]
fn grab_failures_name_the_fix() {
    let w = kitchen().world();
    fails(
        &w,
        Verb::Grab,
        &[("apple", 12)],
        MissingStep,
        "cannot [GRAB] <apple> (12): the robot is not close to <apple> (12); WALK to <apple> (12) first",
    );
    fails(&w, Verb::Grab, &[("kitchencounter", 7)], Affordance, "cannot be grabbed");
    let w = kitchen().near(5).near(13).world();
    fails(
        &w,
        Verb::Grab,
        &[("milk", 13)],
        MissingStep,
        "inside <fridge> (5), which is CLOSED; OPEN <fridge> (5) first",
    );
    let w = kitchen()
        .obj(60, "cup", &["GRABBABLE"], &[])
        .obj(61, "plate", &["GRABBABLE"], &[])
        .edge(2, "HOLDS_RH", 60)
        .edge(2, "HOLDS_LH", 61)
        .near(12)
        .world();
    // The initial state already had both hands full: a missing step, not a wrong order.
    fails(&w, Verb::Grab, &[("apple", 12)], MissingStep, "both hands are full (holding <cup> (60) and <plate> (61))");
}

#[test]
fn grab_with_full_hands_after_having_had_a_free_one_is_wrong_order() {
    let mut w = kitchen()
        .obj(60, "cup", &["GRABBABLE"], &[])
        .obj(61, "plate", &["GRABBABLE"], &[])
        .near(60)
        .near(61)
        .near(12)
        .world();
    ok(&mut w, Verb::Grab, &[("cup", 60)]);
    ok(&mut w, Verb::Grab, &[("plate", 61)]);
    let e = fails(&w, Verb::Grab, &[("apple", 12)], WrongOrder, "both hands are full");
    assert!(e.message.contains("held earlier"), "{}", e.message);
    assert_eq!(w.held(), vec![(R::HoldsRh, 60), (R::HoldsLh, 61)]);
}

#[test]
fn open_and_close() {
    let mut w = kitchen().near(5).world();
    let fx = ok(&mut w, Verb::Open, &[("fridge", 5)]);
    assert_eq!(fx.states_added, vec![(5, State::Open)]);
    assert_eq!(fx.states_removed, vec![(5, State::Closed)]);
    fails(&w, Verb::Open, &[("fridge", 5)], AdditionalStep, "already open");
    ok(&mut w, Verb::Close, &[("fridge", 5)]);
    assert!(w.node(5).unwrap().states.contains(State::Closed));
    fails(&w, Verb::Close, &[("fridge", 5)], AdditionalStep, "is not open");
    fails(&kitchen().world(), Verb::Open, &[("fridge", 5)], MissingStep, "WALK to <fridge> (5) first");
    fails(&kitchen().near(7).world(), Verb::Open, &[("kitchencounter", 7)], Affordance, "lacks CAN_OPEN");
    let on = kitchen().obj(9, "microwave", FRIDGE, &["CLOSED", "ON"]).near(9).world();
    let e = fails(&on, Verb::Open, &[("microwave", 9)], MissingStep, "is ON; SWITCHOFF <microwave> (9) first");
    assert_eq!(e.eai_kind, AdditionalStep);
}

#[test]
fn open_needs_a_free_hand_close_does_not() {
    let g = kitchen().obj(60, "cup", &["GRABBABLE"], &[]).obj(61, "plate", &["GRABBABLE"], &[]);
    let w = g.edge(2, "HOLDS_RH", 60).edge(2, "HOLDS_LH", 61).near(5).world();
    fails(&w, Verb::Open, &[("fridge", 5)], MissingStep, "both hands are full");
    let mut g = kitchen().obj(60, "cup", &["GRABBABLE"], &[]).obj(61, "plate", &["GRABBABLE"], &[]);
    g.0.nodes.iter_mut().filter(|n| n.id == 5).for_each(|n| n.states = vec!["OPEN".into()]);
    let mut w = g.edge(2, "HOLDS_RH", 60).edge(2, "HOLDS_LH", 61).near(5).world();
    ok(&mut w, Verb::Close, &[("fridge", 5)]);
}

#[test]
fn putback_and_putin() {
    let mut w = kitchen().holding(12).near(8).world();
    let fx = ok(&mut w, Verb::PutBack, &[("apple", 12), ("mat", 8)]);
    assert!(w.has_edge(12, R::On, 8) && w.held().is_empty());
    assert!(fx.added.contains(&(12, R::On, 8)) && fx.removed.contains(&(2, R::HoldsRh, 12)));
    let mut w = kitchen().holding(12).near(5).world();
    fails(
        &w,
        Verb::PutIn,
        &[("apple", 12), ("fridge", 5)],
        MissingStep,
        "<fridge> (5) is CLOSED; OPEN <fridge> (5) first",
    );
    ok(&mut w, Verb::Open, &[("fridge", 5)]);
    ok(&mut w, Verb::PutIn, &[("apple", 12), ("fridge", 5)]);
    assert!(w.has_edge(12, R::Inside, 5));
    // Closing it again, then trying once more with a new apple: the fridge was open before: wrong order.
    let mut w = kitchen().holding(12).near(5).obj(14, "pear", APPLE, &[]).near(14).world();
    ok(&mut w, Verb::Open, &[("fridge", 5)]);
    ok(&mut w, Verb::Close, &[("fridge", 5)]);
    fails(&w, Verb::PutIn, &[("apple", 12), ("fridge", 5)], WrongOrder, "CLOSED");
    fails(
        &kitchen().near(7).world(),
        Verb::PutBack,
        &[("apple", 12), ("kitchencounter", 7)],
        MissingStep,
        "not holding <apple> (12); GRAB <apple> (12) first",
    );
    fails(
        &kitchen().holding(12).world(),
        Verb::PutBack,
        &[("apple", 12), ("fridge", 5)],
        MissingStep,
        "WALK to <fridge> (5) first",
    );
}

#[test]
fn putobjback_returns_the_object_where_it_was_grabbed() {
    let mut w = kitchen().near(12).world();
    ok(&mut w, Verb::Grab, &[("apple", 12)]);
    ok(&mut w, Verb::PutObjBack, &[("apple", 12)]);
    assert!(w.has_edge(12, R::On, 7) && w.held().is_empty());
    fails(&kitchen().near(12).world(), Verb::PutObjBack, &[("apple", 12)], MissingStep, "was not grabbed");
}

#[test]
fn switch_on_and_off() {
    fails(&kitchen().near(5).world(), Verb::SwitchOff, &[("fridge", 5)], AdditionalStep, "<fridge> (5) is already off");
    let mut w = kitchen().obj(9, "tv", &["HAS_SWITCH", "HAS_PLUG"], &["OFF", "PLUGGED_IN"]).near(9).world();
    fails(&w, Verb::SwitchOff, &[("tv", 9)], AdditionalStep, "already off");
    let fx = ok(&mut w, Verb::SwitchOn, &[("tv", 9)]);
    assert_eq!(fx.states_added, vec![(9, State::On)]);
    fails(&w, Verb::SwitchOn, &[("tv", 9)], AdditionalStep, "already on");
    ok(&mut w, Verb::SwitchOff, &[("tv", 9)]);
    let w = kitchen().obj(9, "tv", &["HAS_SWITCH", "HAS_PLUG"], &["OFF", "PLUGGED_OUT"]).near(9).world();
    let e = fails(&w, Verb::SwitchOn, &[("tv", 9)], MissingStep, "unplugged; PLUGIN <tv> (9) first");
    assert_eq!(e.eai_kind, AdditionalStep);
    fails(&kitchen().near(7).world(), Verb::SwitchOn, &[("kitchencounter", 7)], Affordance, "has no switch");
    fails(&kitchen().world(), Verb::SwitchOn, &[("fridge", 5)], MissingStep, "not close");
}

#[test]
fn plugin_and_plugout() {
    let mut w = kitchen().obj(9, "lamp", &["HAS_SWITCH", "HAS_PLUG"], &["OFF", "PLUGGED_OUT"]).near(9).world();
    fails(&w, Verb::PlugOut, &[("lamp", 9)], AdditionalStep, "already unplugged");
    ok(&mut w, Verb::PlugIn, &[("lamp", 9)]);
    assert!(w.node(9).unwrap().states.contains(State::PluggedIn));
    fails(&w, Verb::PlugIn, &[("lamp", 9)], AdditionalStep, "already plugged in");
    ok(&mut w, Verb::PlugOut, &[("lamp", 9)]);
    assert!(w.node(9).unwrap().states.contains(State::PluggedOut));
    fails(&kitchen().near(7).world(), Verb::PlugIn, &[("kitchencounter", 7)], Affordance, "has no plug");
}

#[test]
fn sit_lie_standup_sleep_wakeup() {
    let seat = |g: Scene| {
        g.obj(40, "sofa", &["SITTABLE", "LIEABLE", "SURFACES"], &[])
            .obj(41, "tv", &["LOOKABLE"], &[])
            .edge(40, "FACING", 41)
    };
    let mut w = seat(kitchen()).near(40).world();
    fails(&w, Verb::Sleep, &[], MissingStep, "not lying or sitting");
    fails(&w, Verb::StandUp, &[], AdditionalStep, "not sitting");
    let fx = ok(&mut w, Verb::Sit, &[("sofa", 40)]);
    assert!(w.has_edge(2, R::On, 40) && w.has_edge(2, R::Facing, 41), "sitting faces what the sofa faces");
    assert_eq!(fx.states_added, vec![(2, State::Sitting)]);
    fails(&w, Verb::Sit, &[("sofa", 40)], AdditionalStep, "already sitting");
    ok(&mut w, Verb::Sleep, &[]);
    ok(&mut w, Verb::WakeUp, &[]);
    ok(&mut w, Verb::Lie, &[("sofa", 40)]);
    let s = w.node(2).unwrap().states;
    assert!(s.contains(State::Lying) && !s.contains(State::Sitting));
    fails(&w, Verb::Lie, &[("sofa", 40)], AdditionalStep, "already lying");
    ok(&mut w, Verb::StandUp, &[]);
    assert!(w.node(2).unwrap().states.is_empty());
    // After standing up, sleeping needs lying or sitting again: it held earlier, so wrong order.
    fails(&w, Verb::WakeUp, &[], WrongOrder, "not lying or sitting");
    fails(&kitchen().near(5).world(), Verb::Sit, &[("fridge", 5)], Affordance, "cannot be sat on");
    fails(&kitchen().near(5).world(), Verb::Lie, &[("fridge", 5)], Affordance, "cannot be lain on");
    fails(&seat(kitchen()).world(), Verb::Sit, &[("sofa", 40)], MissingStep, "WALK to <sofa> (40) first");
    // A chair with a box on it is occupied.
    let w = kitchen()
        .obj(42, "chair", &["SITTABLE"], &[])
        .obj(43, "box", &["GRABBABLE"], &[])
        .edge(43, "ON", 42)
        .near(42)
        .world();
    fails(&w, Verb::Sit, &[("chair", 42)], MissingStep, "occupied (<box> (43) on it)");
}

#[test]
fn drink_read_need_the_object_in_hand() {
    let cup =
        |g: Scene| g.obj(60, "cup", &["GRABBABLE", "RECIPIENT"], &[]).obj(61, "book", &["GRABBABLE", "READABLE"], &[]);
    let mut w = cup(kitchen()).holding(60).holding(61).world();
    assert!(ok(&mut w, Verb::Drink, &[("cup", 60)]).is_empty());
    assert!(ok(&mut w, Verb::Read, &[("book", 61)]).is_empty());
    let w = cup(kitchen()).near(60).near(61).world();
    fails(&w, Verb::Drink, &[("cup", 60)], MissingStep, "GRAB <cup> (60) first");
    fails(&w, Verb::Read, &[("book", 61)], MissingStep, "GRAB <book> (61) first");
    fails(&kitchen().holding(12).world(), Verb::Drink, &[("apple", 12)], Affordance, "not something to drink");
    fails(&kitchen().holding(12).world(), Verb::Read, &[("apple", 12)], Affordance, "cannot be read");
}

#[test]
fn turnto_then_lookat_pointat_watch() {
    let mut w = kitchen().obj(9, "tv", &["LOOKABLE", "HAS_SWITCH"], &["OFF"]).world();
    for v in [Verb::LookAt, Verb::LookAtShort, Verb::LookAtLong, Verb::PointAt, Verb::Watch] {
        fails(&w, v, &[("tv", 9)], MissingStep, "not facing <tv> (9); TURNTO <tv> (9) first");
    }
    let fx = ok(&mut w, Verb::TurnTo, &[("tv", 9)]);
    assert_eq!(fx.added, vec![(2, R::Facing, 9)]);
    for v in [Verb::LookAt, Verb::LookAtShort, Verb::LookAtLong, Verb::PointAt, Verb::Watch] {
        assert!(ok(&mut w, v, &[("tv", 9)]).is_empty());
    }
    fails(&kitchen().world(), Verb::Watch, &[("apple", 12)], Affordance, "cannot be watched");
    let far = kitchen().obj_in_bedroom(9, "tv", &["LOOKABLE"], &[]).edge(2, "FACING", 9).world();
    let e = fails(&far, Verb::Watch, &[("tv", 9)], MissingStep, "not in the robot's room (it is in <bedroom> (4))");
    assert_eq!(e.eai_kind, Affordance);
}

#[test]
fn wipe_wash_rinse_scrub_clean_things() {
    let g = || kitchen().obj(70, "table", &["SURFACES"], &["DIRTY"]).obj(71, "rag", &["GRABBABLE"], &[]);
    let mut w = g().near(70).holding(71).world();
    let fx = ok(&mut w, Verb::Wipe, &[("table", 70)]);
    assert_eq!((fx.states_added, fx.states_removed), (vec![(70, State::Clean)], vec![(70, State::Dirty)]));
    fails(&g().near(70).world(), Verb::Wipe, &[("table", 70)], MissingStep, "holds nothing to wipe with");
    // (a cloth to take is named, so the way to a WIPE can be found)
    fails(&g().near(70).world(), Verb::Wipe, &[("table", 70)], MissingStep, "GRAB <rag> (71) first");
    let bare = kitchen().obj(70, "table", &["SURFACES"], &["DIRTY"]).near(70).world();
    fails(&bare, Verb::Wipe, &[("table", 70)], MissingStep, "GRAB a cloth (e.g. a rag or towel) first");
    fails(&g().world(), Verb::Wipe, &[("table", 70)], MissingStep, "not close");
    for v in [Verb::Wash, Verb::Rinse, Verb::Scrub] {
        let mut w = g().near(70).world();
        ok(&mut w, v, &[("table", 70)]);
        assert!(w.node(70).unwrap().states.contains(State::Clean));
        fails(&g().world(), v, &[("table", 70)], MissingStep, "WALK to <table> (70) first");
    }
}

#[test]
fn puton_putoff_clothes() {
    let g = || kitchen().obj(50, "shirt", &["CLOTHES", "GRABBABLE"], &[]);
    let mut w = g().holding(50).world();
    ok(&mut w, Verb::PutOn, &[("shirt", 50)]);
    assert!(w.has_edge(50, R::On, 2) && w.held().is_empty());
    ok(&mut w, Verb::PutOff, &[("shirt", 50)]);
    assert!(!w.has_edge(50, R::On, 2));
    fails(&g().near(50).world(), Verb::PutOn, &[("shirt", 50)], MissingStep, "GRAB <shirt> (50) first");
    fails(&g().world(), Verb::PutOff, &[("shirt", 50)], MissingStep, "not wearing <shirt> (50)");
    fails(&kitchen().holding(12).world(), Verb::PutOn, &[("apple", 12)], Affordance, "is not clothing");
}

#[test]
fn drop_and_release_leave_it_in_the_room() {
    for v in [Verb::Drop, Verb::Release] {
        let mut w = kitchen().holding(12).world();
        let fx = ok(&mut w, v, &[("apple", 12)]);
        assert!(w.held().is_empty() && w.has_edge(12, R::Inside, 1));
        assert!(fx.removed.contains(&(2, R::HoldsRh, 12)));
        fails(&kitchen().near(12).world(), v, &[("apple", 12)], MissingStep, "GRAB <apple> (12) first");
    }
}

#[test]
fn touch_and_type() {
    let mut w = kitchen().near(7).obj(80, "keyboard", &["GRABBABLE"], &[]).near(80).world();
    assert!(ok(&mut w, Verb::Touch, &[("apple", 12)]).is_empty());
    assert!(ok(&mut w, Verb::Type, &[("keyboard", 80)]).is_empty());
    fails(&w, Verb::Type, &[("apple", 12)], Affordance, "cannot be typed on");
    fails(&kitchen().world(), Verb::Touch, &[("apple", 12)], MissingStep, "not close");
    fails(&kitchen().near(5).near(13).world(), Verb::Touch, &[("milk", 13)], MissingStep, "OPEN <fridge> (5) first");
    fails(&kitchen().world(), Verb::Type, &[("fridge", 5)], MissingStep, "not close");
}

#[test]
fn pour_from_held_into_recipient() {
    let g = || kitchen().obj(60, "cup", &["GRABBABLE", "RECIPIENT"], &[]).obj(61, "water", &["POURABLE"], &[]);
    let mut w = g().near(60).edge(2, "HOLDS_RH", 13).near(13).world();
    ok(&mut w, Verb::Pour, &[("milk", 13), ("cup", 60)]);
    assert!(w.has_edge(13, R::Inside, 60) && w.has_edge(2, R::HoldsRh, 13));
    let mut w = g().near(60).edge(2, "HOLDS_RH", 61).world();
    ok(&mut w, Verb::Pour, &[("water", 61), ("cup", 60)]);
    assert!(w.held().is_empty(), "poured water leaves the hand");
    fails(&g().near(60).world(), Verb::Pour, &[("milk", 13), ("cup", 60)], MissingStep, "GRAB <milk> (13) first");
    fails(&g().holding(13).world(), Verb::Pour, &[("milk", 13), ("cup", 60)], MissingStep, "WALK to <cup> (60) first");
    fails(&g().holding(12).near(60).world(), Verb::Pour, &[("apple", 12), ("cup", 60)], Affordance, "cannot be poured");
    fails(
        &g().holding(13).near(7).world(),
        Verb::Pour,
        &[("milk", 13), ("kitchencounter", 7)],
        Affordance,
        "lacks RECIPIENT",
    );
}

#[test]
fn push_pull_move() {
    for v in [Verb::Push, Verb::Pull, Verb::Move] {
        let mut w = kitchen().near(12).world();
        assert!(ok(&mut w, v, &[("apple", 12)]).is_empty());
        fails(&kitchen().world(), v, &[("apple", 12)], MissingStep, "not close");
    }
    fails(&kitchen().near(7).world(), Verb::Pull, &[("kitchencounter", 7)], Affordance, "lacks MOVABLE");
    // As in EAI, PUSH does not require MOVABLE.
    assert!(kitchen().near(7).world().check(&act(Verb::Push, &[("kitchencounter", 7)])).is_ok());
}

#[test]
fn squeeze_cut_eat() {
    let g = || {
        kitchen().obj(90, "towel", &["GRABBABLE"], &[]).obj(91, "knife", &["GRABBABLE"], &[]).obj(
            92,
            "plate",
            &["SURFACES"],
            &[],
        )
    };
    let mut w = g().near(90).near(12).holding(91).world();
    ok(&mut w, Verb::Squeeze, &[("towel", 90)]);
    ok(&mut w, Verb::Cut, &[("apple", 12)]);
    ok(&mut w, Verb::Eat, &[("apple", 12)]);
    fails(&w, Verb::Squeeze, &[("apple", 12)], Affordance, "cannot be squeezed");
    // (the knife to take is named, so the way to a CUT can be found)
    fails(&g().near(12).world(), Verb::Cut, &[("apple", 12)], MissingStep, "GRAB <knife> (91) first");
    fails(&kitchen().near(12).world(), Verb::Cut, &[("apple", 12)], MissingStep, "GRAB a knife first (the scene has none)");
    fails(&g().holding(91).near(7).world(), Verb::Cut, &[("kitchencounter", 7)], Affordance, "is not food");
    fails(&g().world(), Verb::Eat, &[("apple", 12)], MissingStep, "not close");
    // A plate with food on it can be eaten from; an empty one cannot.
    let mut w = g().edge(14, "ON", 92).obj(14, "bread", &["EATABLE"], &[]).near(92).world();
    ok(&mut w, Verb::Eat, &[("plate", 92)]);
    fails(&g().near(92).world(), Verb::Eat, &[("plate", 92)], Affordance, "no food on it");
}

#[test]
fn greet_only_people() {
    let mut w = kitchen().obj(95, "child", &["PERSON"], &[]).world();
    ok(&mut w, Verb::Greet, &[("child", 95)]);
    fails(&w, Verb::Greet, &[("apple", 12)], Affordance, "is not a person");
}

#[test]
fn hallucinated_objects_and_wrong_arity() {
    let w = kitchen().world();
    fails(&w, Verb::Grab, &[("apple", 99)], UnknownObject, "no object with id 99; the <apple> in the scene: (12)");
    fails(&w, Verb::Grab, &[("banana", 99)], UnknownObject, "no object with id 99 and no <banana>");
    fails(&w, Verb::Grab, &[("pear", 12)], UnknownObject, "object 12 is a <apple>, not a <pear>");
    let bad = Action { verb: Verb::PutIn, args: vec![ObjRef::new("apple", 12)] };
    let e = w.check(&bad).unwrap_err();
    assert_eq!(e.kind, WrongArity);
    assert_eq!(e.message, "cannot [PUTIN] <apple> (12): PUTIN takes 2 object(s), got 1");
}

#[test]
fn every_verb_has_a_test_above() {
    // Guards this file against a verb added to `action.rs` without executor tests: the list must
    // match the verbs exercised here.
    let tested = [
        "WALK",
        "RUN",
        "FIND",
        "GRAB",
        "OPEN",
        "CLOSE",
        "PUTBACK",
        "PUTIN",
        "PUTOBJBACK",
        "SWITCHON",
        "SWITCHOFF",
        "PLUGIN",
        "PLUGOUT",
        "SIT",
        "LIE",
        "STANDUP",
        "SLEEP",
        "WAKEUP",
        "DRINK",
        "READ",
        "TURNTO",
        "LOOKAT",
        "LOOKAT_SHORT",
        "LOOKAT_LONG",
        "POINTAT",
        "WATCH",
        "WIPE",
        "WASH",
        "RINSE",
        "SCRUB",
        "PUTON",
        "PUTOFF",
        "DROP",
        "RELEASE",
        "TOUCH",
        "TYPE",
        "POUR",
        "PUSH",
        "PULL",
        "MOVE",
        "SQUEEZE",
        "CUT",
        "EAT",
        "GREET",
    ];
    let mut all: Vec<&str> = Verb::ALL.iter().map(|v| v.name()).collect();
    let mut t = tested.to_vec();
    all.sort();
    t.sort();
    assert_eq!(all, t);
}

#[test]
fn walking_away_then_grabbing_is_wrong_order() {
    let mut w = kitchen().world();
    ok(&mut w, Verb::Walk, &[("apple", 12)]);
    ok(&mut w, Verb::Walk, &[("fridge", 5)]);
    let e = fails(&w, Verb::Grab, &[("apple", 12)], WrongOrder, "WALK to <apple> (12) first");
    assert_eq!(e.eai_kind, WrongOrder);
    assert_eq!(e.missing.len(), 1);
}

mod never_panics {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
        /// Random action sequences (any verb, any id, any class name, any arity) never panic, and a
        /// failed step leaves the state as it was.
        #[test]
        fn random_plans_on_the_demo_scene(steps in proptest::collection::vec(
            (0usize..44, proptest::collection::vec((0u32..40, 0usize..3), 0..3)), 1..40)) {
            let mut w = World::demo();
            let classes = ["apple", "fridge", "nothing"];
            for (v, args) in steps {
                let verb = Verb::ALL[v % Verb::ALL.len()];
                let args: Vec<ObjRef> = args
                    .into_iter()
                    .map(|(id, c)| {
                        // Mostly the object's true class, sometimes a wrong one.
                        let class = if c == 0 { classes[id as usize % 3].to_string() } else {
                            w.node(id).map(|n| n.class_name.to_string()).unwrap_or_else(|| "ghost".into())
                        };
                        ObjRef::new(class, id)
                    })
                    .collect();
                let a = Action { verb, args };
                let before = w.edges();
                let checked = w.check(&a);
                match w.execute(&a) {
                    Ok(_) => prop_assert!(checked.is_ok()),
                    Err(e) => {
                        prop_assert_eq!(Err(e), checked);
                        prop_assert_eq!(before, w.edges());
                    }
                }
            }
        }
    }
}
