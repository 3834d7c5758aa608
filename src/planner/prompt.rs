//! The planner's prompts: one system message shared by both roles (the method, the embodiment's
//! actions, the two questions; short, since every decision attends to all of it), then the task,
//! then the node's own part last, so the engine's prefix reuse recomputes only the tail.
//!
//! The two roles are one conversation: the termination question is asked as the next user turn after
//! the decomposition's answer, so a verdict's prompt extends the decomposition's prompt (and its
//! output) token for token and is almost entirely reused. Within the node's part the observation comes
//! first: it changes only when an action runs, while the goal, previous step and rejection change on
//! every move through the tree.

use crate::action::Verb;
use crate::llm::chat::Message;
use crate::llm::engine::Prompt;

const SYSTEM_TEMPLATE: &str = include_str!("../../prompts/step_system.txt");
/// Appended to the system message when the root sets its own goals (`PlannerConfig::infer_goals`).
const GOALS_EXAMPLES: &str = include_str!("../../prompts/step_goals.txt");
const DECOMPOSE_REQUEST: &str = "Next step?";
const TERMINATE_REQUEST: &str = "Judge the step.";

/// The actions in a short form, generated from [`Verb`] (the one place an action is declared):
/// one-object verbs by name, the others with what their objects mean.
pub fn embodiment() -> String {
    let one: Vec<&str> = Verb::ALL.iter().filter(|v| v.arity() == 1).map(|v| v.name()).collect();
    let mut s = format!("with one object: {}.\n", one.join(", "));
    let two: Vec<String> =
        Verb::ALL.iter().filter(|v| v.arity() == 2).map(|v| format!("{} ({})", v.name(), v.description())).collect();
    s.push_str(&format!("with two objects: {}.\n", two.join("; ")));
    let zero: Vec<&str> = Verb::ALL.iter().filter(|v| v.arity() == 0).map(|v| v.name()).collect();
    s.push_str(&format!("with none: {}.", zero.join(", ")));
    s
}

/// The system message (constant for a process).
pub fn system_message() -> String {
    SYSTEM_TEMPLATE.trim_end().replace("{actions}", &embodiment())
}

/// What a decision at one node sees, besides the task.
#[derive(Clone, Debug, Default)]
pub struct NodeView {
    /// The current state, bounded.
    pub observation: String,
    /// The goal being decomposed (the parent; the root's instruction in `no-subgoal-tree`).
    pub goal: String,
    /// The previous step at this level and how it ended (`step` mode).
    pub previous: Option<String>,
    /// Every action executed so far, in order (the ablations' history).
    pub history: Option<Vec<String>>,
    /// The last rejected or failed attempt at this step, with why.
    pub rejected: Option<String>,
    /// Why a target subgoal's action cannot run yet (the executor's message, naming what to do first).
    pub blocked: Option<String>,
    /// The steps the decision may write, each with what it would make true (shown last, next to
    /// the question).
    pub options: Option<String>,
}

/// Builds the prompts of one run.
#[derive(Clone, Debug)]
pub struct Prompter {
    system: String,
    task: String,
}

impl Prompter {
    pub fn new(instruction: &str, context: Option<&str>) -> Prompter {
        let mut task = format!("Task: {}\n", instruction.trim());
        if let Some(c) = context.map(str::trim).filter(|c| !c.is_empty()) {
            task.push_str(c);
            task.push('\n');
        }
        Prompter { system: system_message(), task }
    }

    /// The same prompts, with the worked examples of a root setting its own goals in the system
    /// message (only then: the other runs keep their prompt, and its reused prefix, unchanged).
    pub fn setting_goals(mut self) -> Prompter {
        self.system.push('\n');
        self.system.push_str(GOALS_EXAMPLES.trim_end());
        self
    }

    /// The beginning every prompt of the run shares: the system message (the engine cuts it where
    /// the user turn's text begins, and may keep it on disk between runs).
    pub fn prefix(&self) -> Vec<Message> {
        vec![Message::system(self.system.clone())]
    }

    /// The beginning of every prompt's user turn: the task and its context (read once a run, before
    /// the first node; see `Generate::read`).
    pub fn task(&self) -> &str {
        &self.task
    }

    fn node_text(&self, v: &NodeView) -> String {
        let mut s = self.task.clone();
        s.push_str("State:\n");
        s.push_str(v.observation.trim_end());
        s.push('\n');
        s.push_str(&format!("Goal: {}\n", v.goal));
        if let Some(b) = &v.blocked {
            s.push_str(&format!("Not yet: {b}\n"));
        }
        if let Some(h) = &v.history {
            if h.is_empty() {
                s.push_str("Actions so far: none\n");
            } else {
                s.push_str(&format!("Actions so far: {}\n", h.join("; ")));
            }
        }
        if let Some(p) = &v.previous {
            s.push_str(&format!("Previous step: {p}\n"));
        }
        if let Some(r) = &v.rejected {
            s.push_str(&format!("Rejected: {r}\n"));
        }
        if let Some(o) = &v.options {
            s.push_str(o.trim_end());
            s.push('\n');
        }
        s.push_str(DECOMPOSE_REQUEST);
        s
    }

    /// "Next step?" at a node.
    pub fn decompose(&self, v: &NodeView) -> Prompt {
        Prompt::Chat(vec![Message::system(self.system.clone()), Message::user(self.node_text(v))])
    }

    /// "Judge the step." after the decomposition answered `proposal` (its output line, verbatim).
    pub fn terminate(&self, v: &NodeView, proposal: &str) -> Prompt {
        Prompt::Chat(vec![
            Message::system(self.system.clone()),
            Message::user(self.node_text(v)),
            Message::assistant(proposal.to_string()),
            Message::user(TERMINATE_REQUEST),
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embodiment_lists_every_verb_once() {
        let e = embodiment();
        for v in Verb::ALL {
            assert_eq!(e.matches(&format!("{}", v.name())).count() >= 1, true, "{} missing", v.name());
        }
        let sys = system_message();
        assert!(!sys.contains("{actions}"));
        assert!(sys.contains("PUTIN (put a held object A into object B)"), "{sys}");
    }

    #[test]
    fn terminate_extends_decompose() {
        let p = Prompter::new("put the apple in the fridge", None);
        let v = NodeView {
            observation: "robot: in kitchen".into(),
            goal: "put the apple in the fridge".into(),
            ..Default::default()
        };
        let (Prompt::Chat(d), Prompt::Chat(t)) = (p.decompose(&v), p.terminate(&v, "subgoal: take the apple")) else {
            panic!("chat prompts expected")
        };
        assert_eq!(&t[..2], &d[..]);
        assert_eq!(t[3].content, TERMINATE_REQUEST);
    }
}
