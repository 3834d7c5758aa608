//! Scoring one task's plan: parse errors, missing plans and run failures become one report line
//! with its taxonomy label, goal counts and the additional-step and relevant-object notes.

use serde::Serialize;

use super::goal::Count;
use super::run::{run_plan, StepResult};
use super::task::Task;
use crate::program::{PlanParseError, PlanParseErrorKind, Program};

/// The plan a task was given: read, unreadable, or missing.
#[derive(Clone, Debug)]
pub enum PlanInput {
    Plan(Program),
    Unreadable(PlanParseError),
    /// The task has no plan (e.g. no gold program).
    Missing,
}

/// One task's line in a report.
#[derive(Clone, Debug, Serialize)]
pub struct TaskReport {
    pub id: String,
    pub title: String,
    pub parsed: bool,
    pub executed: bool,
    pub success: bool,
    /// Parse error, or why the run stopped.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorReport>,
    pub state_goals: Count,
    pub relation_goals: Count,
    pub action_goals: Count,
    pub unmet_goals: Vec<String>,
    pub additional_steps: usize,
    pub outside_relevant: Vec<String>,
    pub steps: usize,
}

/// A parse or run error, with its taxonomy label.
#[derive(Clone, Debug, Serialize)]
pub struct ErrorReport {
    /// `parse_syntax`, `parse_unknown_action`, `parse_wrong_arity`, `parse_empty`, `no_plan`, or an
    /// executor failure kind (`missing_step`, `wrong_order`, `affordance`, `unknown_object`, …).
    pub kind: String,
    /// EAI's label for an executor failure, where it differs from `kind`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eai_kind: Option<String>,
    /// 1-based step number of a run failure.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub step: Option<usize>,
    pub message: String,
}

fn parse_kind(e: &PlanParseError) -> &'static str {
    match e.kind {
        PlanParseErrorKind::Syntax { .. } => "parse_syntax",
        PlanParseErrorKind::UnknownVerb(_) => "parse_unknown_action",
        PlanParseErrorKind::WrongArity(_) => "parse_wrong_arity",
        PlanParseErrorKind::Empty => "parse_empty",
    }
}

/// Scores one task's plan.
pub fn score(task: &Task, plan: &PlanInput) -> TaskReport {
    let unscored = |error: ErrorReport| {
        let none = task.goal.check(&task.world, &[]);
        let zero = |c: Count| Count { met: 0, total: c.total };
        TaskReport {
            id: task.id.clone(),
            title: task.title.clone(),
            parsed: false,
            executed: false,
            success: false,
            error: Some(error),
            state_goals: zero(none.state()),
            relation_goals: zero(none.relation()),
            action_goals: zero(none.action()),
            unmet_goals: Vec::new(),
            additional_steps: 0,
            outside_relevant: Vec::new(),
            steps: 0,
        }
    };
    let program = match plan {
        PlanInput::Plan(p) => p,
        PlanInput::Unreadable(e) => {
            return unscored(ErrorReport {
                kind: parse_kind(e).into(),
                eai_kind: None,
                step: None,
                message: e.to_string(),
            })
        }
        PlanInput::Missing => {
            return unscored(ErrorReport {
                kind: "no_plan".into(),
                eai_kind: None,
                step: None,
                message: "the task has no plan".into(),
            })
        }
    };
    if program.actions.is_empty() {
        return unscored(ErrorReport {
            kind: "parse_empty".into(),
            eai_kind: None,
            step: None,
            message: "the plan has no steps".into(),
        });
    }
    let out = run_plan(task, program);
    let error = out.failure.as_ref().map(|f| ErrorReport {
        kind: f.kind.name().into(),
        eai_kind: (f.eai_kind != f.kind).then(|| f.eai_kind.name().to_string()),
        step: out.steps.last().map(|s| s.step),
        message: f.message.clone(),
    });
    TaskReport {
        id: task.id.clone(),
        title: task.title.clone(),
        parsed: true,
        executed: out.executed,
        success: out.success,
        error,
        state_goals: out.goals.state(),
        relation_goals: out.goals.relation(),
        action_goals: out.goals.action(),
        unmet_goals: out.goals.unmet(),
        additional_steps: out.steps.iter().filter(|s| matches!(s.result, StepResult::Skipped { .. })).count(),
        outside_relevant: out.outside_relevant.iter().map(|o| o.to_string()).collect(),
        steps: out.steps.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::goal::RawGoal;
    use crate::eval::report::Summary;
    use crate::eval::task::TaskOrigin;
    use crate::program::PlanFormat;
    use crate::world::{Edge, Graph, Node, World};

    fn node(id: u32, class: &str, cat: &str, props: &[&str], states: &[&str]) -> Node {
        Node::new(id, class, cat, props, states)
    }

    /// A kitchen with the robot, a lamp (switch, off) and a light switch nobody needs.
    fn task(goal: &str) -> Task {
        let g = Graph {
            nodes: vec![
                node(1, "kitchen", "Rooms", &[], &[]),
                node(2, "character", "Characters", &[], &[]),
                node(3, "lamp", "Lamps", &["HAS_SWITCH"], &["OFF"]),
                node(4, "wall", "Walls", &[], &[]),
            ],
            edges: vec![
                Edge { from_id: 2, relation_type: "INSIDE".into(), to_id: 1 },
                Edge { from_id: 3, relation_type: "INSIDE".into(), to_id: 1 },
                Edge { from_id: 4, relation_type: "INSIDE".into(), to_id: 1 },
            ],
        };
        let world = World::from_graph(&g, "test").unwrap();
        let goal = serde_json::from_str::<RawGoal>(goal).unwrap().to_goal().unwrap();
        Task {
            id: "t".into(),
            title: "Turn on the lamp".into(),
            description: String::new(),
            goal,
            gold: None,
            world,
            relevant: vec![1, 2, 3],
            relevance: Default::default(),
            origin: TaskOrigin::Eai,
        }
    }

    fn plan(text: &str) -> PlanInput {
        PlanInput::Plan(Program::parse(text, PlanFormat::Lines).unwrap())
    }

    const LAMP_ON: &str = r#"{"goal": [{"id": 3, "class_name": "lamp", "state": "ON"}], "actions": ["SWITCHON"]}"#;

    #[test]
    fn a_good_plan_executes_and_meets_its_goals() {
        let t = task(LAMP_ON);
        let r = score(&t, &plan("[WALK] <lamp> (3)\n[SWITCHON] <lamp> (3)\n"));
        assert!(r.parsed && r.executed && r.success, "{r:?}");
        assert_eq!((r.state_goals, r.action_goals), (Count { met: 1, total: 1 }, Count { met: 1, total: 1 }));
        assert!(r.outside_relevant.is_empty() && r.error.is_none());
    }

    #[test]
    fn a_failed_step_stops_the_run_and_the_task_fails_even_if_goals_held_before() {
        // The empty goal is met by anything; EAI would count this plan a success.
        let t = task(r#"{"goal": [], "actions": []}"#);
        let r = score(&t, &plan("[SWITCHON] <lamp> (3)\n[WALK] <lamp> (3)\n"));
        assert!(r.parsed && !r.executed && !r.success, "{r:?}");
        let e = r.error.unwrap();
        assert_eq!((e.kind.as_str(), e.step), ("missing_step", Some(1)), "{}", e.message);
        assert_eq!(r.steps, 1, "the run stops at the failed step");
    }

    #[test]
    fn goals_count_in_the_state_the_run_ended_in() {
        let t = task(LAMP_ON);
        let r = score(&t, &plan("[WALK] <lamp> (3)\n[SWITCHON] <lamp> (3)\n[SIT] <wall> (4)\n"));
        assert!(!r.executed && !r.success);
        assert_eq!(r.state_goals.met, 1, "the lamp is on when the run stops");
        assert_eq!(r.outside_relevant, ["<wall> (4)"]);
    }

    #[test]
    fn unreadable_and_missing_plans_score_zero_with_their_kind() {
        let t = task(LAMP_ON);
        let e = Program::parse("[FLY] <lamp> (3)", PlanFormat::Lines).unwrap_err();
        let reports = [
            score(&t, &PlanInput::Unreadable(e)),
            score(&t, &PlanInput::Missing),
            score(&t, &plan("[WALK] <lamp> (3)\n[SWITCHON] <lamp> (3)")),
        ];
        assert_eq!(reports[0].error.as_ref().unwrap().kind, "parse_unknown_action");
        assert_eq!(reports[1].error.as_ref().unwrap().kind, "no_plan");
        let s = Summary::of(&reports);
        assert_eq!((s.tasks, s.parsed, s.executed, s.succeeded), (3, 1, 1, 1));
        assert_eq!(s.state_goals, Count { met: 1, total: 3 }, "unread plans still count their goals");
        assert_eq!(s.errors.get("parse_unknown_action"), Some(&1));
        assert_eq!(s.eai_errors.get("hallucination"), Some(&1));
        assert_eq!(s.eai_errors.get("parsing"), Some(&1));
        let table = s.table();
        assert!(table.contains("task success") && table.contains("1/3"), "{table}");
    }

    #[test]
    fn an_additional_step_is_skipped_and_the_run_goes_on() {
        let t = task(LAMP_ON);
        let r = score(&t, &plan("[WALK] <lamp> (3)\n[SWITCHON] <lamp> (3)\n[SWITCHON] <lamp> (3)\n"));
        assert!(r.executed && r.success, "{r:?}");
        assert_eq!(r.additional_steps, 1);
    }
}
