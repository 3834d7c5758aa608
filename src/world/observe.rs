//! Observations for the planner: a compact, deterministic text view of the state, bounded in size.
//!
//! The view has one line per task-relevant object (its states, what it is on or in, what is on or
//! in it; floors, walls and ceilings after the others), then where the robot is, what it holds and
//! what it is close to: the line that changes most often comes last, so a planner's prompt cache
//! keeps the lines above it. A byte budget truncates the object lines at a line boundary with a
//! marker saying how many were left out.
//! The object catalogue (class, id, properties, states) is what grammar building needs.

use std::fmt::Write;

use serde::Serialize;

use super::exec::Fact;
use super::state::{Ix, World};
use super::vocab::{Property, Relation, State};

/// One object with what it affords, for grammar building and prompts.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct ObjectInfo {
    pub id: u32,
    pub class_name: String,
    pub category: String,
    pub properties: Vec<Property>,
    pub states: Vec<State>,
}

/// At most this many names in one list (the rest is counted).
const LIST_MAX: usize = 6;

impl World {
    /// The state as the planner sees it: the objects in `relevant` (ascending id, floors, walls and
    /// ceilings last; unknown ids are skipped), then the robot, in at most `budget` bytes (the
    /// robot's line is always shown). Cut object lines are counted in a line `… (N more lines not
    /// shown)`.
    pub fn observe(&self, relevant: &[u32], budget: usize) -> String {
        self.observe_first(relevant, &[], budget)
    }

    /// [`World::observe`] with the objects of `first` that are in `relevant` listed before the
    /// others, in the order of `first`, so that a budget cutting a whole house keeps them.
    pub fn observe_first(&self, relevant: &[u32], first: &[u32], budget: usize) -> String {
        let c = self.char_ix();
        let mut ids: Vec<u32> = relevant.iter().copied().filter(|&id| id != self.character()).collect();
        ids.sort_unstable();
        ids.dedup();
        let mut rel_ix: Vec<Ix> = ids.iter().filter_map(|&id| self.ix(id)).collect();
        // The building's own floors, walls and ceilings last, so that the budget cuts them first:
        // a task's relevant objects count a dozen of them, and in id order they used to fill the
        // view before the objects the task is about (the phone of "Pick up phone" was cut).
        let rank = |ix: Ix| first.iter().position(|&id| id == self.id(ix)).unwrap_or(usize::MAX);
        rel_ix.sort_by_key(|&ix| (rank(ix), self.view(ix).is_structure()));

        let mut lines = Vec::with_capacity(rel_ix.len() + 2);
        let mut robot = String::from("robot: in ");
        robot.push_str(&self.room_ix(c).map(|r| self.label_ix(r)).unwrap_or_else(|| "no room".into()));
        let held = self.held();
        if held.is_empty() {
            robot.push_str("; hands empty");
        } else {
            let hs: Vec<String> = held
                .iter()
                .map(|&(h, id)| {
                    let hand = if h == Relation::HoldsRh { "right" } else { "left" };
                    format!("{} ({hand} hand)", self.node(id).map(|n| n.label()).unwrap_or_default())
                })
                .collect();
            robot.push_str("; holding ");
            robot.push_str(&hs.join(", "));
        }
        let s = self.states_ix(c);
        if s.contains(State::Sitting) || s.contains(State::Lying) {
            let on: Vec<String> = self.targets(c, Relation::On).map(|x| self.label_ix(x)).collect();
            let how = if s.contains(State::Lying) { "lying" } else { "sitting" };
            let _ = write!(
                robot,
                "; {how}{}",
                if on.is_empty() { String::new() } else { format!(" on {}", on.join(", ")) }
            );
        }
        // Close to: relevant objects by name, the others counted.
        let close: Vec<Ix> = self.targets(c, Relation::Close).filter(|&x| !self.is_room_ix(x)).collect();
        let named: Vec<String> = close.iter().filter(|x| rel_ix.contains(x)).map(|&x| self.label_ix(x)).collect();
        let others = close.len() - named.len();
        if named.is_empty() {
            robot.push_str("; close to no task object");
            if others > 0 {
                let _ = write!(robot, " ({others} other objects)");
            }
        } else {
            let _ = write!(robot, "; close to {}", named.join(", "));
            if others > 0 {
                let _ = write!(robot, " and {others} other objects");
            }
        }
        let facing: Vec<String> =
            self.targets(c, Relation::Facing).filter(|x| rel_ix.contains(x)).map(|x| self.label_ix(x)).collect();
        if !facing.is_empty() {
            let _ = write!(robot, "; facing {}", facing.join(", "));
        }
        // The robot's line comes last: it changes with nearly every action, and a planner's prompt
        // cache is kept only up to the first changed character, so the lines that stay put go first.
        for &ix in &rel_ix {
            lines.push(self.object_line(ix));
        }
        let n = lines.len();
        let mut out = bounded(lines, budget.saturating_sub(robot.len() + 1));
        if out.is_empty() && n > 0 {
            // No room for any object line: still say that there are some.
            out = cut_marker(n);
        }
        if !out.is_empty() && !out.ends_with('\n') {
            out.push('\n');
        }
        out.push_str(&robot);
        out
    }

    fn object_line(&self, ix: Ix) -> String {
        let c = self.char_ix();
        let mut l = self.label_ix(ix);
        l.push(':');
        let states: Vec<&str> = self.states_ix(ix).iter().map(|s| s.name()).collect();
        if !states.is_empty() {
            let _ = write!(l, " {}", states.join(" "));
        }
        let mut parts: Vec<String> = Vec::new();
        if let Some(h) = [Relation::HoldsRh, Relation::HoldsLh].into_iter().find(|&h| self.has_ix(c, h, ix)) {
            parts.push(format!("held by the robot ({} hand)", if h == Relation::HoldsRh { "right" } else { "left" }));
        }
        if self.has_ix(ix, Relation::On, c) {
            parts.push("worn by the robot".into());
        }
        for (r, word) in [(Relation::On, "on"), (Relation::Inside, "in")] {
            let targets: Vec<Ix> = self.targets(ix, r).filter(|&t| t != c).collect();
            // A room is mentioned only when the object is in nothing else.
            let non_room: Vec<Ix> = targets.iter().copied().filter(|&t| !self.is_room_ix(t)).collect();
            let shown = if r == Relation::Inside && non_room.is_empty() { targets } else { non_room };
            if !shown.is_empty() {
                parts.push(format!("{word} {}", list(self, &shown)));
            }
        }
        for (r, word) in [(Relation::On, "has on it"), (Relation::Inside, "contains")] {
            let xs: Vec<Ix> = self.sources(ix, r).filter(|&x| x != c && !self.is_room_ix(ix)).collect();
            if !xs.is_empty() {
                parts.push(format!("{word} {}", list(self, &xs)));
            }
        }
        if !parts.is_empty() {
            let _ = write!(l, "; {}", parts.join("; "));
        }
        l
    }

    /// Every object of the scene except the character, by id: class, category, properties, states.
    pub fn objects(&self) -> Vec<ObjectInfo> {
        let ch = self.character();
        self.nodes()
            .filter(|n| n.id != ch)
            .map(|n| ObjectInfo {
                id: n.id,
                class_name: n.class_name.to_string(),
                category: n.category.to_string(),
                properties: n.properties.iter().collect(),
                states: n.states.iter().collect(),
            })
            .collect()
    }

    /// The object catalogue as text, one line per object (`<apple> (12): GRABBABLE EATABLE …`), for
    /// the given ids (all objects when `None`), in at most `budget` bytes.
    pub fn catalog(&self, ids: Option<&[u32]>, budget: usize) -> String {
        let objs = self.objects();
        let lines: Vec<String> = objs
            .iter()
            .filter(|o| ids.is_none_or(|ids| ids.contains(&o.id)))
            .map(|o| {
                let props: Vec<&str> = o.properties.iter().map(|p| p.name()).collect();
                let kind = if o.category == "Rooms" { " room" } else { "" };
                if props.is_empty() {
                    format!("<{}> ({}):{kind}", o.class_name, o.id)
                } else {
                    format!("<{}> ({}):{kind} {}", o.class_name, o.id, props.join(" "))
                }
            })
            .collect();
        bounded(lines, budget)
    }
}

impl World {
    /// What holds among `ids` (the robot is always included): their states, and the edges between
    /// them, as [`Fact::State`] and [`Fact::Edge`]. The planner reports what an action changed as
    /// the facts among its objects that hold after it and did not before ([`World::describe`] words
    /// them).
    pub fn facts_among(&self, ids: &[u32]) -> Vec<Fact> {
        let mut ix: Vec<Ix> = ids.iter().filter_map(|&id| self.ix(id)).collect();
        ix.push(self.char_ix());
        ix.sort_unstable();
        ix.dedup();
        let mut out = Vec::new();
        for &i in &ix {
            let id = self.id(i);
            out.extend(self.states_ix(i).iter().map(|state| Fact::State { id, state }));
            for &(relation, t) in self.out.get(i as usize).map(Vec::as_slice).unwrap_or(&[]) {
                if ix.contains(&t) {
                    out.push(Fact::Edge { from: id, relation, to: self.id(t) });
                }
            }
        }
        out
    }

    /// A `tool` among `ids`, or of the whole scene where `ids` is `None`: one in `room` where
    /// there is one, else the first. What CUT needs held (a knife), or what WIPE is done with (a
    /// cloth).
    pub fn a_tool(&self, tool: Tool, ids: Option<&[u32]>, room: Option<u32>) -> Option<u32> {
        let is_one = |id: u32| ids.is_none_or(|ids| ids.contains(&id)) && self.node(id).is_some_and(|n| tool.is_class(n.class_name));
        let all: Vec<u32> = self.nodes().map(|n| n.id).filter(|&id| is_one(id)).collect();
        all.iter().copied().find(|&k| room.is_some() && self.room_of(k) == room).or(all.first().copied())
    }

    /// Whether `fact` holds now.
    pub fn holds(&self, fact: &Fact) -> bool {
        match *fact {
            Fact::Edge { from, relation, to } => self.has_edge(from, relation, to),
            Fact::Holds { from, to } => [Relation::HoldsRh, Relation::HoldsLh]
                .iter()
                .any(|&h| self.related(from, h).iter().any(|&x| to.is_none_or(|t| t == x))),
            Fact::State { id, state } => self.node(id).is_some_and(|n| n.states.contains(state)),
        }
    }

    /// `fact` in the words of a task's goal lines: `<class> is <STATE>`, `<class> is <RELATION> to
    /// <class>`.
    pub fn describe(&self, fact: &Fact) -> String {
        let name = |id: u32| self.node(id).map_or_else(|| format!("({id})"), |n| n.class_name.to_string());
        match *fact {
            Fact::Edge { from, relation, to } => format!("{} is {} to {}", name(from), relation.name(), name(to)),
            Fact::Holds { from, to: Some(to) } => format!("{} holds {}", name(from), name(to)),
            Fact::Holds { from, to: None } => format!("{} holds something", name(from)),
            Fact::State { id, state } => format!("{} is {}", name(id), state.name()),
        }
    }
}

fn list(w: &World, xs: &[Ix]) -> String {
    let mut names: Vec<String> = xs.iter().take(LIST_MAX).map(|&x| w.label_ix(x)).collect();
    if xs.len() > LIST_MAX {
        names.push(format!("{} more", xs.len() - LIST_MAX));
    }
    names.join(", ")
}

/// The line that stands for `n` lines left out of a bounded view.
fn cut_marker(n: usize) -> String {
    format!("… ({n} more lines not shown)")
}

/// Joins lines with `\n` while they fit in `budget` bytes, keeping room for the truncation marker.
fn bounded(lines: Vec<String>, budget: usize) -> String {
    let total: usize = lines.iter().map(|l| l.len() + 1).sum();
    if total <= budget {
        return lines.join("\n");
    }
    let mut out = String::new();
    for (i, l) in lines.iter().enumerate() {
        let left = lines.len() - i;
        let marker = cut_marker(left);
        // Keep room for this line, a newline, and the marker that may follow it.
        if out.len() + l.len() + 1 + marker.len() + 1 > budget {
            if out.len() + marker.len() <= budget {
                out.push_str(&marker);
            }
            return out;
        }
        out.push_str(l);
        out.push('\n');
    }
    out
}

/// A thing a verb is done with, known by its class.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tool {
    /// What CUT needs held: a class named with "knife" (knife, cutlery_knife, chef_knife).
    Knife,
    /// What WIPE is done with (the executor takes anything held; VirtualHome's programs wipe
    /// with a towel or a rag).
    Cloth,
}

impl Tool {
    /// VirtualHome's classes of cloths (not "towel_rack", "table_cloth" or clothes).
    const CLOTHS: &'static [&'static str] = &["rag", "towel", "sponge", "paper_towel", "dish_cloth", "cloth_napkin"];

    /// Whether an object of `class` is such a tool.
    pub fn is_class(self, class: &str) -> bool {
        match self {
            Tool::Knife => class.contains("knife"),
            Tool::Cloth => Tool::CLOTHS.contains(&class),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::{Action, ObjRef, Verb};

    #[test]
    fn facts_among_objects_hold_and_are_worded_as_goal_lines() {
        let mut w = World::demo();
        let (fridge, apple) = (10, 12);
        let facts = w.facts_among(&[fridge, apple]);
        let closed = Fact::State { id: fridge, state: State::Closed };
        assert!(facts.contains(&closed), "{facts:?}");
        assert!(facts.iter().all(|f| w.holds(f)));
        assert_eq!(w.describe(&closed), "fridge is CLOSED");
        // Edges only between the given objects and the robot (the apple lies on the counter, not given).
        assert!(!facts.iter().any(|f| matches!(f, Fact::Edge { to: 11, .. })), "{facts:?}");
        w.execute(&a(Verb::Walk, &[("fridge", fridge)])).unwrap();
        w.execute(&a(Verb::Open, &[("fridge", fridge)])).unwrap();
        assert!(!w.holds(&closed) && w.holds(&Fact::State { id: fridge, state: State::Open }));
        let close = Fact::Edge { from: w.character(), relation: Relation::Close, to: fridge };
        assert!(w.facts_among(&[fridge]).contains(&close));
        assert_eq!(w.describe(&close), "character is CLOSE to fridge");
        assert!(!w.holds(&Fact::Holds { from: w.character(), to: None }));
    }

    fn a(verb: Verb, args: &[(&str, u32)]) -> Action {
        Action::new(verb, args.iter().map(|&(c, i)| ObjRef::new(c, i)).collect()).unwrap()
    }

    #[test]
    fn observation_shows_robot_and_relevant_objects() {
        let mut w = World::demo();
        let o = w.observe(&[12, 10], 10_000);
        assert_eq!(
            o,
            "<fridge> (10): CLOSED OFF CLEAN PLUGGED_IN; in <kitchen> (1)\n\
             <apple> (12): CLEAN; on <kitchencounter> (11); in <kitchen> (1)\n\
             robot: in <kitchen> (1); hands empty; close to no task object"
        );
        w.execute(&a(Verb::Walk, &[("apple", 12)])).unwrap();
        let walked = w.observe(&[12, 10, 11], 10_000);
        w.execute(&a(Verb::Grab, &[("apple", 12)])).unwrap();
        let o = w.observe(&[12, 10, 11], 10_000);
        assert!(o.ends_with("\nrobot: in <kitchen> (1); holding <apple> (12) (right hand); close to <kitchencounter> (11), <apple> (12)"), "{o}");
        assert!(o.contains("<apple> (12): CLEAN; held by the robot (right hand); in <kitchen> (1)\n"), "{o}");
        // A walk changes the robot's line only, the last one (what the prompt cache keeps depends on it).
        let before = World::demo().observe(&[12, 10, 11], 10_000);
        let (b, a_) = (before.rsplit_once('\n').unwrap().0, walked.rsplit_once('\n').unwrap().0);
        assert_eq!(b, a_);
        assert!(o.contains("<kitchencounter> (11): CLEAN; in <kitchen> (1); has on it <milk> (13), <bread> (14), <microwave> (15), <knife> (24), <rag> (26)"), "{o}");
        assert_eq!(o, w.observe(&[11, 10, 12, 12], 10_000), "order and duplicates do not matter");
    }

    #[test]
    fn floors_walls_and_ceilings_come_after_the_objects_a_task_is_about() {
        // The demo kitchen with a floor and a wall whose ids come before the fridge's.
        let mut g: serde_json::Value = serde_json::from_str(super::super::demo::DEMO_KITCHEN_JSON).unwrap();
        for (id, class, category) in [(4, "floor", "Floors"), (5, "wall", "Walls")] {
            g["nodes"].as_array_mut().unwrap().push(serde_json::json!(
                {"id": id, "class_name": class, "category": category, "properties": [], "states": ["CLEAN"]}));
            g["edges"].as_array_mut().unwrap().push(serde_json::json!({"from_id": id, "relation_type": "INSIDE", "to_id": 1}));
        }
        let w = World::from_json(&g.to_string(), "test").unwrap();
        let o = w.observe(&[4, 5, 10, 12], 10_000);
        let starts: Vec<&str> = o.lines().map(|l| l.split(' ').next().unwrap()).collect();
        assert_eq!(starts, ["<fridge>", "<apple>", "<floor>", "<wall>", "robot:"], "{o}");
        // So a budget cuts the structure first.
        let cut = w.observe(&[4, 5, 10, 12], 220);
        assert!(cut.contains("<apple> (12)") && !cut.contains("<wall>"), "{cut}");
    }

    #[test]
    fn objects_asked_for_first_lead_the_view_in_the_order_asked() {
        let w = World::demo();
        let all: Vec<u32> = w.nodes().map(|n| n.id).collect();
        let o = w.observe_first(&all, &[33, 32], 10_000);
        let starts: Vec<&str> = o.lines().take(3).map(|l| l.split(' ').next().unwrap()).collect();
        assert_eq!(starts, ["<coffee_table>", "<remote_control>", "<kitchen>"], "{o}");
        // A budget that holds two object lines keeps those two.
        let cut = w.observe_first(&all, &[33, 32], 250);
        assert!(cut.contains("(33)") && cut.contains("(32)") && !cut.contains("<fridge>"), "{cut}");
        assert_eq!(w.observe_first(&all, &[], 500), w.observe(&all, 500));
    }

    #[test]
    fn observation_respects_the_budget_with_a_marker() {
        let w = World::demo();
        let all: Vec<u32> = w.nodes().map(|n| n.id).collect();
        let full = w.observe(&all, usize::MAX);
        let robot = full.lines().last().unwrap();
        assert!(robot.starts_with("robot: "), "{full}");
        for budget in [20, 200, 500] {
            let o = w.observe(&all, budget);
            assert!(o.len() <= budget.max(robot.len() + 40), "{} > {budget}", o.len());
            // The robot's line is always shown, last; the objects' lines are cut, with a marker.
            let shown: Vec<&str> = o.lines().collect();
            let (last, rest) = shown.split_last().unwrap();
            assert_eq!(last, &robot);
            let (marker, kept) = rest.split_last().unwrap();
            assert!(full.starts_with(&kept.iter().map(|l| format!("{l}\n")).collect::<String>()));
            let left = full.lines().count() - 1 - kept.len();
            assert_eq!(*marker, format!("… ({left} more lines not shown)"));
        }
        assert!(!full.contains("not shown"));
    }

    #[test]
    fn catalog_lists_objects_with_properties() {
        let w = World::demo();
        let c = w.catalog(None, usize::MAX);
        assert!(c.contains("<fridge> (10): CAN_OPEN HAS_SWITCH CONTAINERS HAS_PLUG"), "{c}");
        assert!(c.contains("<living_room> (2): room"), "{c}");
        assert!(!c.contains("<character>"));
        let objs = w.objects();
        let apple = objs.iter().find(|o| o.id == 12).unwrap();
        assert!(apple.properties.contains(&Property::Grabbable));
        assert_eq!(w.catalog(Some(&[12]), 100), "<apple> (12): GRABBABLE EATABLE CUTTABLE MOVABLE");
    }
}
