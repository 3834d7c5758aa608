//! The planner's prompts: one system message shared by both roles (the method, the embodiment's
//! actions, the two questions; short, since every decision attends to all of it), then the task,
//! then the node's own part last, so the engine's prefix reuse recomputes only the tail.
//!
//! The two roles are one conversation: the termination question is asked as the next user turn after
//! the decomposition's answer, so a verdict's prompt extends the decomposition's prompt (and its
//! output) token for token and is almost entirely reused. Within the node's part the observation comes
//! first: it changes only when an action runs, while the goal, previous step and rejection change on
//! every move through the tree.
//!
//! The state is shown in two parts (`StateLog`): the state at the start, in the task part (read once
//! a run), and after it only the object lines that changed since, the last changed last, then the
//! robot. A full state rewritten after every action made each action's first call recompute every
//! line below the first changed one; now a changed object's line moves to the end, and what is
//! recomputed is mostly that line, the robot's and the node's own part.

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
    /// What changed since the start, and the robot ([`StateLog::since`]).
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
    /// The task part ends with the state at the start (`start_state`, as `Env::observe` writes
    /// it); each node's observation is then [`StateLog::since`]'s.
    pub fn new(instruction: &str, context: Option<&str>, start_state: &str) -> Prompter {
        let mut task = format!("Task: {}\n", instruction.trim());
        if let Some(c) = context.map(str::trim).filter(|c| !c.is_empty()) {
            task.push_str(c);
            task.push('\n');
        }
        task.push_str("State at the start:\n");
        task.push_str(start_state.trim_end());
        task.push_str("\nState now (the objects changed since the start, then the robot):\n");
        Prompter { system: system_message(), task }
    }

    /// The same prompts, with the worked examples of a root setting its own goals in the system
    /// message (only then: the other runs keep their prompt, and its reused prefix, unchanged).
    pub fn setting_goals(mut self) -> Prompter {
        self.system.push('\n');
        self.system.push_str(GOALS_EXAMPLES.trim_end());
        self
    }

    /// The same prompts with the instruction left out (its line says none is given): the
    /// baseline `PlannerConfig::calibrate_lines` scores answers against.
    pub fn without_instruction(&self) -> Prompter {
        let rest = self.task.split_once('\n').map_or("", |(_, rest)| rest);
        Prompter { system: self.system.clone(), task: format!("Task: (none)\n{rest}") }
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

/// The state a run's decisions see after its start: the object lines that differ from the start's,
/// the most recently changed last (an object changed back to its start keeps its place until it
/// changes again), then the robot's line as it is now. Lines are those `World::observe` writes:
/// `<name> (id): ...` for an object, `robot: ...`; its count of lines cut by the budget is left
/// out (it says how much of the whole state a view shows, and changes as lines grow).
#[derive(Clone, Debug, Default)]
pub struct StateLog {
    start: Vec<String>,
    /// Objects (their `<name> (id)` label) whose line differs from the start's, the one that
    /// changed last at the end.
    changed: Vec<String>,
    /// The object lines shown last time.
    shown: Vec<String>,
}

/// The object an observation line is about: its `<name> (id)` label, or `None` for other lines.
fn object_of(line: &str) -> Option<&str> {
    if !line.starts_with('<') {
        return None;
    }
    line.find("):").map(|i| &line[..i + 1])
}

impl StateLog {
    pub fn new(start: &str) -> StateLog {
        StateLog { start: start.lines().map(str::to_string).collect(), changed: Vec::new(), shown: Vec::new() }
    }

    /// What changed since the start in the observation `now` (see [`StateLog`]), the object lines
    /// in at most `budget` bytes: the oldest changes are left out first, and counted.
    pub fn since(&mut self, now: &str, budget: usize) -> String {
        let start_line = |o: &str| self.start.iter().find(|l| object_of(l) == Some(o)).cloned();
        // An object whose line differs from the one shown last time (or, the first time, from the
        // start's) moves to the end, so an object changed again and again is rewritten alone.
        let mut moved = Vec::new();
        for l in now.lines() {
            if let Some(o) = object_of(l) {
                let before = match self.shown.iter().find(|s| object_of(s) == Some(o)) {
                    Some(s) => Some(s.clone()),
                    None => start_line(o),
                };
                if before.as_deref() != Some(l) {
                    moved.push(o.to_string());
                }
            }
        }
        self.changed.retain(|c| !moved.contains(c));
        self.changed.extend(moved);
        let mut lines: Vec<&str> = Vec::new();
        for o in &self.changed {
            lines.extend(now.lines().filter(|l| object_of(l) == Some(o.as_str())));
        }
        self.shown = lines.iter().map(|l| l.to_string()).collect();
        let mut bytes: usize = lines.iter().map(|l| l.len() + 1).sum();
        let mut cut = 0;
        while bytes > budget && cut < lines.len() {
            bytes -= lines[cut].len() + 1;
            cut += 1;
        }
        let mut out: Vec<String> = Vec::new();
        if cut > 0 {
            out.push(format!("… ({cut} objects changed earlier not shown)"));
        }
        out.extend(lines[cut..].iter().map(|l| l.to_string()));
        out.extend(now.lines().filter(|l| l.starts_with("robot:")).map(str::to_string));
        out.join("\n")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_state_log_shows_changed_objects_the_last_changed_last() {
        let start = "<fridge> (10): CLOSED\n<apple> (11): on <table> (12)\n<table> (12): CLEAN\n\
                     robot: in <kitchen> (1); hands empty";
        let mut log = StateLog::new(start);
        assert_eq!(log.since(start, 600), "robot: in <kitchen> (1); hands empty");
        let now = "<fridge> (10): CLOSED\n<apple> (11): held by the robot (right hand)\n<table> (12): CLEAN\n\
                   robot: in <kitchen> (1); holding <apple> (11) (right hand)";
        assert_eq!(log.since(now, 600), "<apple> (11): held by the robot (right hand)\nrobot: in <kitchen> (1); holding <apple> (11) (right hand)");
        // The fridge changes after the apple: its line comes after the apple's, although its id
        // is smaller, so the prompt up to the apple's line is unchanged.
        let now = "<fridge> (10): OPEN\n<apple> (11): held by the robot (right hand)\n<table> (12): CLEAN\n\
                   robot: in <kitchen> (1); holding <apple> (11) (right hand)";
        assert_eq!(
            log.since(now, 600),
            "<apple> (11): held by the robot (right hand)\n<fridge> (10): OPEN\nrobot: in <kitchen> (1); holding <apple> (11) (right hand)"
        );
        // The apple changes again: it moves after the fridge.
        let now = "<fridge> (10): OPEN\n<apple> (11): in <fridge> (10)\n<table> (12): CLEAN\nrobot: in <kitchen> (1); hands empty";
        assert_eq!(log.since(now, 600), "<fridge> (10): OPEN\n<apple> (11): in <fridge> (10)\nrobot: in <kitchen> (1); hands empty");
        // The fridge changes back to its start: still shown, now last.
        let now = "<fridge> (10): CLOSED\n<apple> (11): in <fridge> (10)\n<table> (12): CLEAN\nrobot: in <kitchen> (1); hands empty";
        assert_eq!(log.since(now, 600), "<apple> (11): in <fridge> (10)\n<fridge> (10): CLOSED\nrobot: in <kitchen> (1); hands empty");
        // Nothing changed: the same lines in the same order.
        assert_eq!(log.since(now, 600), "<apple> (11): in <fridge> (10)\n<fridge> (10): CLOSED\nrobot: in <kitchen> (1); hands empty");
    }

    #[test]
    fn the_state_log_leaves_out_the_oldest_changes_beyond_its_budget() {
        let start = "<fridge> (10): CLOSED\n<apple> (11): on <table> (12)\nrobot: in <kitchen> (1)";
        let mut log = StateLog::new(start);
        let now = "<fridge> (10): OPEN\n<apple> (11): on <table> (12)\nrobot: in <kitchen> (1)";
        log.since(now, 30);
        let now = "<fridge> (10): OPEN\n<apple> (11): held by the robot (right hand)\nrobot: in <kitchen> (1)";
        assert_eq!(
            log.since(now, 50),
            "… (1 objects changed earlier not shown)\n<apple> (11): held by the robot (right hand)\nrobot: in <kitchen> (1)"
        );
        assert_eq!(
            log.since(now, 80),
            "<fridge> (10): OPEN\n<apple> (11): held by the robot (right hand)\nrobot: in <kitchen> (1)"
        );
    }

    #[test]
    fn the_state_log_leaves_out_the_views_cut_marker() {
        let start = "<fridge> (10): CLOSED\n… (2 more lines not shown)\nrobot: in <kitchen> (1)";
        let mut log = StateLog::new(start);
        assert_eq!(log.since(start, 600), "robot: in <kitchen> (1)");
        let now = "<fridge> (10): OPEN\n… (3 more lines not shown)\nrobot: in <kitchen> (1)";
        assert_eq!(log.since(now, 600), "<fridge> (10): OPEN\nrobot: in <kitchen> (1)");
    }

    #[test]
    fn a_prompt_with_the_start_state_begins_with_the_task_read_before_the_first_node() {
        let p = Prompter::new("put the apple in the fridge", None, "<fridge> (10): CLOSED\nrobot: in <kitchen> (1)");
        let v = NodeView { observation: "robot: in <kitchen> (1)".into(), goal: "fridge is OPEN".into(), ..Default::default() };
        let Prompt::Chat(d) = p.decompose(&v) else { panic!("chat prompt expected") };
        assert!(d[1].content.starts_with(p.task()), "{}", d[1].content);
        assert!(p.task().contains("State at the start:\n<fridge> (10): CLOSED\nrobot: in <kitchen> (1)\n"), "{}", p.task());
        assert!(d[1].content.ends_with("robot: in <kitchen> (1)\nGoal: fridge is OPEN\nNext step?"), "{}", d[1].content);
    }

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
        let p = Prompter::new("put the apple in the fridge", None, "robot: in kitchen");
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
