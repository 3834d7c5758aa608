//! A task's goal as EAI writes it (`vh_goal`), and the check of a run against it.
//!
//! - node goals: `{id, class_name, state}`: the state is among the node's states at the end;
//! - edge goals: `{from_id, relation_type, to_id}`: that exact edge exists at the end;
//! - action goals: `["LOOKAT|WATCH", "DRINK"]`: the executed actions contain, in this order, one
//!   action of each group (`A|B`: either verb). As in EAI, the k-th action goal counts as met only if
//!   the goals before it are met in order (the matched prefix), so the count is the length of the
//!   longest prefix that is an ordered subsequence. Unlike EAI, verbs match whole (EAI matches
//!   substrings of the joined action text) and the order is the file's (EAI shuffles it through a set).

use serde::{Deserialize, Serialize};

use crate::action::{Action, Verb};
use crate::world::{Relation, State, World};

/// A state that must hold for one node at the end.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct NodeGoal {
    pub id: u32,
    pub class_name: String,
    pub state: State,
}

/// An edge that must exist at the end.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct EdgeGoal {
    pub from_id: u32,
    pub relation_type: Relation,
    pub to_id: u32,
}

/// One action goal: any of these verbs (EAI's `A|B`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct ActionGoal {
    pub any_of: Vec<Verb>,
}

impl ActionGoal {
    pub fn matches(&self, v: Verb) -> bool {
        self.any_of.contains(&v)
    }
}

impl std::fmt::Display for ActionGoal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = self.any_of.iter().map(|v| v.name()).collect();
        f.write_str(&names.join("|"))
    }
}

/// A task's goal: all of it must hold for the task to succeed.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Goal {
    pub nodes: Vec<NodeGoal>,
    pub edges: Vec<EdgeGoal>,
    pub actions: Vec<ActionGoal>,
}

/// `vh_goal` as written in EAI's `task_state_LTL_formula_accurate.json` and in users' task files.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RawGoal {
    #[serde(default)]
    pub goal: Vec<RawSceneGoal>,
    #[serde(default)]
    pub actions: Vec<String>,
}

/// One entry of `vh_goal.goal`: a node goal or an edge goal.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(untagged, deny_unknown_fields)]
pub enum RawSceneGoal {
    Node { id: u32, class_name: String, state: String },
    Edge { from_id: u32, relation_type: String, to_id: u32 },
}

impl RawGoal {
    /// Types the goal. Duplicate node and edge goals collapse (as in EAI); action goals keep their
    /// order. Errors name the offending entry.
    pub fn to_goal(&self) -> Result<Goal, String> {
        let mut g = Goal::default();
        for (i, e) in self.goal.iter().enumerate() {
            match e {
                RawSceneGoal::Node { id, class_name, state } => {
                    let state: State = state.parse().map_err(|m| format!("goal {}: {m}", i + 1))?;
                    let n = NodeGoal { id: *id, class_name: class_name.clone(), state };
                    if !g.nodes.contains(&n) {
                        g.nodes.push(n);
                    }
                }
                RawSceneGoal::Edge { from_id, relation_type, to_id } => {
                    let r: Relation = relation_type.parse().map_err(|m| format!("goal {}: {m}", i + 1))?;
                    let e = EdgeGoal { from_id: *from_id, relation_type: r, to_id: *to_id };
                    if !g.edges.contains(&e) {
                        g.edges.push(e);
                    }
                }
            }
        }
        for (i, a) in self.actions.iter().enumerate() {
            let any_of = a
                .split('|')
                .map(|v| v.trim().parse::<Verb>().map_err(|e| format!("action goal {} '{a}': {e}", i + 1)))
                .collect::<Result<Vec<_>, _>>()?;
            g.actions.push(ActionGoal { any_of });
        }
        Ok(g)
    }
}

impl Goal {
    pub fn len(&self) -> usize {
        self.nodes.len() + self.edges.len() + self.actions.len()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Every object id the goal names, ascending, without repeats.
    pub fn object_ids(&self) -> Vec<u32> {
        let mut v: Vec<u32> = self.nodes.iter().map(|n| n.id).collect();
        v.extend(self.edges.iter().flat_map(|e| [e.from_id, e.to_id]));
        v.sort_unstable();
        v.dedup();
        v
    }

    /// Checks the goal in the `end` state, given the actions that executed successfully, in order.
    pub fn check(&self, end: &World, executed: &[Action]) -> GoalCheck {
        let nodes = self
            .nodes
            .iter()
            .map(|n| (n.clone(), end.node(n.id).is_some_and(|v| v.states.contains(n.state))))
            .collect();
        let edges = self.edges.iter().map(|e| (e.clone(), end.has_edge(e.from_id, e.relation_type, e.to_id))).collect();
        // Greedy earliest match is optimal for "longest prefix that is an ordered subsequence".
        let mut cursor = 0;
        let mut prefix_intact = true;
        let actions = self
            .actions
            .iter()
            .map(|g| {
                let found = prefix_intact
                    && match executed.get(cursor..).and_then(|rest| rest.iter().position(|a| g.matches(a.verb))) {
                        Some(p) => {
                            cursor += p + 1;
                            true
                        }
                        None => false,
                    };
                prefix_intact = found;
                (g.clone(), found)
            })
            .collect();
        GoalCheck { nodes, edges, actions }
    }
}

/// Each goal with whether it was met.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct GoalCheck {
    pub nodes: Vec<(NodeGoal, bool)>,
    pub edges: Vec<(EdgeGoal, bool)>,
    pub actions: Vec<(ActionGoal, bool)>,
}

/// Met and total counts of one goal category.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Count {
    pub met: usize,
    pub total: usize,
}

impl Count {
    pub fn add(&mut self, o: Count) {
        self.met += o.met;
        self.total += o.total;
    }
    /// Percentage met; `None` when there is nothing to meet.
    pub fn rate(&self) -> Option<f64> {
        (self.total > 0).then(|| 100.0 * self.met as f64 / self.total as f64)
    }
}

fn count<T>(v: &[(T, bool)]) -> Count {
    Count { met: v.iter().filter(|(_, ok)| *ok).count(), total: v.len() }
}

impl GoalCheck {
    pub fn state(&self) -> Count {
        count(&self.nodes)
    }
    pub fn relation(&self) -> Count {
        count(&self.edges)
    }
    pub fn action(&self) -> Count {
        count(&self.actions)
    }
    pub fn overall(&self) -> Count {
        let mut c = self.state();
        c.add(self.relation());
        c.add(self.action());
        c
    }
    pub fn all_met(&self) -> bool {
        let c = self.overall();
        c.met == c.total
    }

    /// The unmet goals in words, one per line, for reports and prompts.
    pub fn unmet(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (n, ok) in &self.nodes {
            if !ok {
                out.push(format!("<{}> ({}) is not {}", n.class_name, n.id, n.state));
            }
        }
        for (e, ok) in &self.edges {
            if !ok {
                out.push(format!("no edge {} {} {}", e.from_id, e.relation_type, e.to_id));
            }
        }
        for (a, ok) in &self.actions {
            if !ok {
                out.push(format!("action goal {a} not done in order"));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::ObjRef;
    use crate::world::{Edge, Graph, Node};

    fn node(id: u32, class: &str, states: &[&str]) -> Node {
        let category = if class == "kitchen" { "Rooms" } else { "Props" };
        Node::new(id, class, category, &[], states)
    }

    /// A kitchen (1), the robot (2) and a fridge (3, closed, plugged in) in it, an apple (4) inside the fridge.
    fn world() -> World {
        let g = Graph {
            nodes: vec![
                node(1, "kitchen", &[]),
                node(2, "character", &[]),
                node(3, "fridge", &["CLOSED", "PLUGGED_IN"]),
                node(4, "apple", &[]),
            ],
            edges: vec![
                Edge { from_id: 2, relation_type: "INSIDE".into(), to_id: 1 },
                Edge { from_id: 3, relation_type: "INSIDE".into(), to_id: 1 },
                Edge { from_id: 4, relation_type: "INSIDE".into(), to_id: 3 },
            ],
        };
        World::from_graph(&g, "test").unwrap()
    }

    fn goal(json: &str) -> Goal {
        serde_json::from_str::<RawGoal>(json).unwrap().to_goal().unwrap()
    }

    fn act(v: Verb) -> Action {
        let args = (0..v.arity()).map(|_| ObjRef::new("apple", 4)).collect();
        Action::new(v, args).unwrap()
    }

    #[test]
    fn node_and_edge_goals_check_the_end_state() {
        let g = goal(
            r#"{"goal": [{"id": 3, "class_name": "fridge", "state": "CLOSED"},
                         {"id": 3, "class_name": "fridge", "state": "OPEN"},
                         {"id": 3, "class_name": "fridge", "state": "CLOSED"},
                         {"from_id": 4, "relation_type": "INSIDE", "to_id": 3},
                         {"from_id": 4, "relation_type": "ON", "to_id": 3},
                         {"id": 99, "class_name": "ghost", "state": "ON"}], "actions": []}"#,
        );
        assert_eq!(g.nodes.len(), 3, "the duplicate CLOSED goal collapses");
        let c = g.check(&world(), &[]);
        assert_eq!(c.state(), Count { met: 1, total: 3 });
        assert_eq!(c.relation(), Count { met: 1, total: 2 }, "each edge goal is checked (EAI stops at the first met)");
        assert!(!c.all_met());
        assert_eq!(c.unmet(), ["<fridge> (3) is not OPEN", "<ghost> (99) is not ON", "no edge 4 ON 3"]);
        assert_eq!(g.object_ids(), [3, 4, 99]);
    }

    #[test]
    fn action_goals_are_an_ordered_prefix_with_alternatives() {
        let g = goal(r#"{"actions": ["LOOKAT|WATCH", "DRINK", "STANDUP"]}"#);
        let w = world();
        let run = |vs: &[Verb]| g.check(&w, &vs.iter().map(|&v| act(v)).collect::<Vec<_>>()).action().met;
        assert_eq!(run(&[Verb::Watch, Verb::Walk, Verb::Drink, Verb::StandUp]), 3);
        assert_eq!(run(&[Verb::LookAt, Verb::Drink, Verb::StandUp]), 3);
        // Out of order: DRINK before any LOOKAT/WATCH; the later DRINK is missing.
        assert_eq!(run(&[Verb::Drink, Verb::Watch, Verb::StandUp]), 1);
        // A zero-argument action goal is met by a zero-argument action (EAI's regex drops those).
        assert_eq!(run(&[Verb::Watch, Verb::Drink]), 2);
        // A later goal does not count when an earlier one is unmet, as in EAI.
        assert_eq!(run(&[Verb::Drink, Verb::StandUp]), 0);
        // Whole verbs: LOOKAT_SHORT is not LOOKAT (EAI's substring match would accept it).
        assert_eq!(run(&[Verb::LookAtShort, Verb::Drink, Verb::StandUp]), 0);
        assert!(g.check(&w, &[act(Verb::Watch), act(Verb::Drink), act(Verb::StandUp)]).all_met());
    }

    #[test]
    fn an_empty_goal_is_met() {
        let g = goal(r#"{"goal": [], "actions": []}"#);
        assert!(g.is_empty() && g.check(&world(), &[]).all_met());
    }

    #[test]
    fn bad_goal_entries_are_named() {
        let bad = |j: &str| serde_json::from_str::<RawGoal>(j).unwrap().to_goal().unwrap_err();
        assert!(bad(r#"{"goal": [{"id": 1, "class_name": "a", "state": "HAPPY"}]}"#)
            .contains("goal 1: unknown state 'HAPPY'"));
        assert!(bad(r#"{"goal": [{"from_id": 1, "relation_type": "NEAR", "to_id": 2}]}"#)
            .contains("unknown relation 'NEAR'"));
        assert!(bad(r#"{"actions": ["DRINK", "FLY|WALK"]}"#).contains("action goal 2 'FLY|WALK'"));
        assert!(serde_json::from_str::<RawGoal>(r#"{"goal": [{"id": 1, "state": "ON"}]}"#).is_err());
    }
}
