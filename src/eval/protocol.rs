//! What a planner is told about a task (the protocol), stated in every report so that only
//! like-for-like figures are compared.
//!
//! Three levels of information, each including the one before:
//! - `instruction`: the task's title and description only; grammars may name any object of the scene;
//! - `objects`: plus the relevant objects (name, id, properties) and their initial states, as EAI's
//!   action-sequencing prompt shows them (the objects that change, with their states; the initial
//!   relations that do not survive); grammars name only the relevant objects;
//! - `goals`: plus the goal conditions in words, as EAI's prompt gives them (class names, no ids).
//!
//! And how it plans: open-loop (the plan is written whole, then executed: EAI's protocol) or
//! closed-loop (the world answers each action). EAI's published table is `goals`, open-loop.

use std::fmt;
use std::str::FromStr;

use serde::Serialize;

use super::task::{RelevantRule, Task};
use crate::action::Verb;
use crate::world::vocab::Relation;
use crate::world::{Fact, World};

/// How much of the task the planner is shown (each level includes the previous).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Seen {
    Instruction,
    Objects,
    Goals,
}

impl Seen {
    pub const ALL: [Seen; 3] = [Seen::Instruction, Seen::Objects, Seen::Goals];
    pub fn name(self) -> &'static str {
        match self {
            Seen::Instruction => "instruction",
            Seen::Objects => "objects",
            Seen::Goals => "goals",
        }
    }
    /// In words, for reports.
    pub fn describe(self) -> &'static str {
        match self {
            Seen::Instruction => "title and description only",
            Seen::Objects => "title and description + relevant objects and their initial states",
            Seen::Goals => "title and description + relevant objects and their initial states + goals in words",
        }
    }
}

impl fmt::Display for Seen {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Seen {
    type Err = String;
    fn from_str(s: &str) -> Result<Seen, String> {
        Seen::ALL.into_iter().find(|v| v.name() == s.trim()).ok_or_else(|| {
            format!("unknown protocol '{s}': expected instruction, objects or goals (what the planner is shown)")
        })
    }
}

/// The protocol of a run: what the planner saw and whether the world answered between actions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Protocol {
    pub seen: Seen,
    pub closed_loop: bool,
}

impl Protocol {
    /// EAI's own protocol (its published table): goals in the prompt, open-loop.
    pub const EAI: Protocol = Protocol { seen: Seen::Goals, closed_loop: false };

    /// Whether figures under this protocol may be set beside EAI's table.
    pub fn comparable_with_eai(&self) -> bool {
        *self == Protocol::EAI
    }
}

impl fmt::Display for Protocol {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let l = if self.closed_loop {
            "closed-loop (world feedback after each action)"
        } else {
            "open-loop (plan written whole, then executed)"
        };
        write!(f, "saw {} [{}]; {l}", self.seen.describe(), self.seen)
    }
}

/// The instruction a planner gets for a task: its title, then its description when there is one.
pub fn instruction(task: &Task) -> String {
    let title = task.title.trim();
    let desc = task.description.trim();
    match (title.is_empty(), desc.is_empty()) {
        (_, true) => title.to_string(),
        (true, false) => desc.to_string(),
        (false, false) => {
            let sep = if title.ends_with(['.', '!', '?']) { " " } else { ". " };
            format!("{title}{sep}{desc}")
        }
    }
}

/// The object ids grammars may name under `seen`: the whole scene for `instruction` (the planner was
/// told nothing else), else the task's relevant objects.
pub fn focus(task: &Task, seen: Seen) -> Vec<u32> {
    match seen {
        Seen::Instruction => task.world.nodes().map(|n| n.id).collect(),
        Seen::Objects | Seen::Goals => task.relevant.clone(),
    }
}

fn name(world: &World, id: u32) -> String {
    world.node(id).map_or_else(|| format!("object_{id}"), |n| n.class_name.to_string())
}

/// EAI writes the CLOSE relation as NEAR in prompts.
fn relation_word(r: &str) -> &str {
    if r == "CLOSE" {
        "NEAR"
    } else {
        r
    }
}

/// The relevant objects and their initial states, as EAI's prompt shows them: every relevant object
/// with its id and properties; the states of the objects that change; the initial relations that do
/// not hold at the end. For a task whose list has no final state (explicit or goal rule), the states
/// of every relevant object that has any, and the initial relations among relevant objects.
pub fn objects_text(task: &Task) -> String {
    let w = &task.world;
    let mut out = String::from("Relevant objects (name, id, properties):\n");
    for &id in &task.relevant {
        let Some(n) = w.node(id) else { continue };
        let props: Vec<&str> = n.properties.iter().map(|p| p.name()).collect();
        out.push_str(&format!("{}, id {}, properties [{}]\n", n.class_name, id, props.join(", ")));
    }
    let diffed = matches!(task.relevance.rule, RelevantRule::FinalGraph | RelevantRule::GoldRun);
    out.push_str("Initial states:\n");
    let stated: Vec<u32> = if diffed {
        task.relevance.changed.clone()
    } else {
        task.relevant.iter().copied().filter(|&id| w.node(id).is_some_and(|n| !n.states.is_empty())).collect()
    };
    if stated.is_empty() {
        out.push_str("(none)\n");
    }
    for id in stated {
        let Some(n) = w.node(id) else { continue };
        let states: Vec<&str> = n.states.iter().map(|s| s.name()).collect();
        out.push_str(&format!("{} ({}): {}\n", n.class_name, id, states.join(", ")));
    }
    out.push_str("Initial relations:\n");
    let edges: Vec<(u32, String, u32)> = if diffed {
        task.relevance.removed_edges.clone()
    } else {
        let rel: std::collections::BTreeSet<u32> = task.relevant.iter().copied().collect();
        w.edges()
            .into_iter()
            .filter(|(f, _, t)| rel.contains(f) && rel.contains(t))
            .map(|(f, r, t)| (f, r.name().to_string(), t))
            .collect()
    };
    if edges.is_empty() {
        out.push_str("(none)\n");
    }
    for (f, r, t) in edges {
        out.push_str(&format!("<{}> ({f}) is {} <{}> ({t})\n", name(w, f), relation_word(&r), name(w, t)));
    }
    out
}

/// The goal conditions in words, as EAI's prompt gives them: node goals as `name is STATE`, edge goals
/// as `name is RELATION to name` (class names, no ids), action goals one line each, alternatives
/// joined by `or`. (EAI's own prompt writes each action-goal line twice, once as `A or B` and once as
/// `A|B`; here each is written once.)
pub fn goals_text(task: &Task) -> String {
    let lines = GoalLines::of(task);
    let mut out = String::from("Goal states:\n");
    let section = |out: &mut String, lines: &[String], none: &str| {
        if lines.is_empty() {
            out.push_str(none);
            out.push('\n');
        }
        for l in lines {
            out.push_str(l);
            out.push('\n');
        }
    };
    section(&mut out, &lines.states, "(none)");
    out.push_str("Goal relations:\n");
    section(&mut out, &lines.relations, "(none)");
    out.push_str("Actions the plan must include, in this order:\n");
    section(&mut out, &lines.actions, "(no action requirement)");
    out
}

/// A task's goal conditions, one line each, in the words of [`goals_text`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GoalLines {
    pub states: Vec<String>,
    pub relations: Vec<String>,
    pub actions: Vec<String>,
}

impl GoalLines {
    pub fn of(task: &Task) -> GoalLines {
        let (g, w) = (&task.goal, &task.world);
        GoalLines {
            states: g.nodes.iter().map(|n| format!("{} is {}", n.class_name, n.state.name())).collect(),
            relations: g
                .edges
                .iter()
                .map(|e| format!("{} is {} to {}", name(w, e.from_id), e.relation_type.name(), name(w, e.to_id)))
                .collect(),
            actions: g
                .actions
                .iter()
                .map(|a| a.any_of.iter().map(|v| v.name()).collect::<Vec<_>>().join(" or "))
                .collect(),
        }
    }

    /// Every line, states first, without repeats: the subgoals a planner shown the goals is offered.
    pub fn all(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for l in self.states.iter().chain(&self.relations).chain(&self.actions) {
            if !out.contains(l) {
                out.push(l.clone());
            }
        }
        out
    }
}

/// The subgoals offered to the root under `seen`: the goal lines when the planner is shown the
/// goals, else none (it writes its own).
pub fn subgoals(task: &Task, seen: Seen) -> Vec<String> {
    match seen {
        Seen::Goals => GoalLines::of(task).all(),
        Seen::Instruction | Seen::Objects => Vec::new(),
    }
}

/// `PlanRequest.kept` for a task under `seen`: the goal's states and relations as facts when the
/// planner is shown the goals (closeness left out: a robot walks away from things on its way),
/// else none.
pub fn kept(task: &Task, seen: Seen) -> Vec<Fact> {
    if seen != Seen::Goals {
        return Vec::new();
    }
    let g = &task.goal;
    let states = g.nodes.iter().map(|n| Fact::State { id: n.id, state: n.state });
    let edges = g
        .edges
        .iter()
        .filter(|e| e.relation_type != Relation::Close)
        .map(|e| Fact::Edge { from: e.from_id, relation: e.relation_type, to: e.to_id });
    states.chain(edges).collect()
}

/// `PlanRequest.named_verbs` for a task under `seen`: the verbs its action lines name ("LOOKAT or
/// WATCH") when the planner is shown the goals, else none.
pub fn named_verbs(task: &Task, seen: Seen) -> Vec<Verb> {
    if seen != Seen::Goals {
        return Vec::new();
    }
    let mut out: Vec<Verb> = task.goal.actions.iter().flat_map(|a| a.any_of.iter().copied()).collect();
    out.sort();
    out.dedup();
    out
}

/// `PlanRequest.context` for a task under `seen`: nothing for `instruction`; the objects for
/// `objects`; the objects and the goals for `goals`.
pub fn context(task: &Task, seen: Seen) -> Option<String> {
    match seen {
        Seen::Instruction => None,
        Seen::Objects => Some(objects_text(task)),
        Seen::Goals => Some(format!("{}{}", objects_text(task), goals_text(task))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn demo_tasks() -> Vec<Task> {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/demo_tasks.json");
        crate::eval::task::load_file(&p, None).unwrap()
    }

    #[test]
    fn protocol_parses_and_states_itself() {
        assert_eq!("goals".parse::<Seen>().unwrap(), Seen::Goals);
        assert!("everything".parse::<Seen>().unwrap_err().contains("instruction, objects or goals"));
        let p = Protocol { seen: Seen::Objects, closed_loop: true };
        let s = p.to_string();
        assert!(s.contains("initial states") && s.contains("closed-loop") && !s.contains("goals in words"), "{s}");
        assert!(Protocol::EAI.comparable_with_eai() && !p.comparable_with_eai());
    }

    #[test]
    fn context_grows_with_the_protocol_and_never_leaks_goals_below_goals() {
        let tasks = demo_tasks();
        let apple = tasks.iter().find(|t| t.id == "apple_in_fridge").unwrap();
        assert_eq!(context(apple, Seen::Instruction), None);
        let objects = context(apple, Seen::Objects).unwrap();
        assert!(objects.contains("apple, id 12") && objects.contains("fridge, id 10"), "{objects}");
        // The fridge's state changes (it is opened and closed again, so it ends as it began) or not:
        // either way, the apple leaves the counter, so that relation is shown.
        assert!(objects.contains("<apple> (12) is ON <"), "{objects}");
        assert!(!objects.contains("Goal"), "{objects}");
        let goals = context(apple, Seen::Goals).unwrap();
        assert!(goals.starts_with(&objects));
        assert!(goals.contains("apple is INSIDE to fridge") && goals.contains("fridge is CLOSED"), "{goals}");
        let tv = tasks.iter().find(|t| t.id == "watch_tv").unwrap();
        let g = goals_text(tv);
        assert!(g.contains("LOOKAT or WATCH"), "{g}");
        assert_eq!(
            instruction(tv),
            "Watch TV. Go to the living room, switch on the television, sit on the sofa and watch."
        );
    }

    #[test]
    fn the_kept_facts_are_the_goals_states_and_relations_under_goals_only() {
        use crate::world::vocab::State;
        let tasks = demo_tasks();
        let apple = tasks.iter().find(|t| t.id == "apple_in_fridge").unwrap();
        assert!(kept(apple, Seen::Instruction).is_empty() && kept(apple, Seen::Objects).is_empty());
        let facts = kept(apple, Seen::Goals);
        assert!(facts.contains(&Fact::State { id: 10, state: State::Closed }), "{facts:?}");
        assert!(facts.contains(&Fact::Edge { from: 12, relation: Relation::Inside, to: 10 }), "{facts:?}");
        // One fact per state and relation goal, closeness aside (none here).
        assert_eq!(facts.len(), apple.goal.nodes.len() + apple.goal.edges.len(), "{facts:?}");
    }

    #[test]
    fn the_offered_subgoals_are_the_goal_lines_under_goals_only() {
        let tasks = demo_tasks();
        let apple = tasks.iter().find(|t| t.id == "apple_in_fridge").unwrap();
        assert!(subgoals(apple, Seen::Instruction).is_empty() && subgoals(apple, Seen::Objects).is_empty());
        let lines = subgoals(apple, Seen::Goals);
        assert!(lines.contains(&"apple is INSIDE to fridge".to_string()), "{lines:?}");
        assert!(lines.contains(&"fridge is CLOSED".to_string()), "{lines:?}");
        // Every offered line is a line of the goals text the prompt shows.
        let text = goals_text(apple);
        assert!(lines.iter().all(|l| text.lines().any(|t| t == l)), "{lines:?}\n{text}");
        let tv = tasks.iter().find(|t| t.id == "watch_tv").unwrap();
        assert!(subgoals(tv, Seen::Goals).contains(&"LOOKAT or WATCH".to_string()));
    }

    #[test]
    fn focus_is_the_scene_for_instruction_only() {
        let tasks = demo_tasks();
        let t = &tasks[0];
        assert_eq!(focus(t, Seen::Objects), t.relevant);
        assert_eq!(focus(t, Seen::Instruction).len(), t.world.len());
    }
}
