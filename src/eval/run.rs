//! Running a plan on a task, and the metrics of a batch of runs.
//!
//! A plan runs step by step through the world's executor. A step whose effect already holds
//! (an additional step) changes nothing and the run goes on, as in EAI; any other failure stops the
//! run, and the plan is not executable. Goals are checked in the state the run ended in, against the
//! actions that executed; a task succeeds only when the plan executed to the end AND every goal is
//! met (EAI also counts goals met by a plan that failed partway; here they count towards the goal
//! rates, never towards success).

use std::collections::BTreeMap;

use serde::Serialize;

use super::goal::{Count, GoalCheck};
use super::task::Task;
use crate::action::{Action, ObjRef};
use crate::program::{ParseError, ParseErrorKind, Program};
use crate::world::{Effects, ExecFailure, FailureKind, World};

/// What one step did.
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum StepResult {
    Ok {
        effects: Effects,
    },
    /// An additional step: its effect already held; nothing changed and the run went on.
    Skipped {
        failure: ExecFailure,
    },
    /// The run stopped here.
    Failed {
        failure: ExecFailure,
    },
}

#[derive(Clone, Debug, Serialize)]
pub struct StepOutcome {
    /// 1-based step number.
    pub step: usize,
    pub action: String,
    #[serde(flatten)]
    pub result: StepResult,
}

/// The outcome of running one plan on one task.
#[derive(Clone, Debug)]
pub struct RunOutcome {
    /// The steps that were tried (the run stops at the first failed one).
    pub steps: Vec<StepOutcome>,
    /// Every step ran (additional steps allowed) and the plan was not empty.
    pub executed: bool,
    pub failure: Option<ExecFailure>,
    pub goals: GoalCheck,
    pub success: bool,
    /// Objects the plan names that are not among the task's relevant objects (EAI's scorer rejects
    /// such plans as hallucinations; here it is reported only).
    pub outside_relevant: Vec<ObjRef>,
    /// The state the run ended in.
    pub end: World,
}

/// Runs `plan` on `task` from the task's initial state.
pub fn run_plan(task: &Task, plan: &Program) -> RunOutcome {
    let mut world = task.world.clone();
    let mut steps = Vec::with_capacity(plan.actions.len());
    let mut executed_actions: Vec<Action> = Vec::with_capacity(plan.actions.len());
    let mut failure = None;
    for (i, a) in plan.actions.iter().enumerate() {
        let result = match world.execute(a) {
            Ok(effects) => {
                executed_actions.push(a.clone());
                StepResult::Ok { effects }
            }
            Err(f) if f.kind == FailureKind::AdditionalStep => StepResult::Skipped { failure: f },
            Err(f) => {
                failure = Some(f.clone());
                StepResult::Failed { failure: f }
            }
        };
        steps.push(StepOutcome { step: i + 1, action: a.to_string(), result });
        if failure.is_some() {
            break;
        }
    }
    let executed = failure.is_none() && !plan.actions.is_empty();
    let goals = task.goal.check(&world, &executed_actions);
    let success = executed && goals.all_met();
    let mut outside: Vec<ObjRef> = plan
        .actions
        .iter()
        .flat_map(|a| a.args.iter())
        .filter(|o| task.relevant.binary_search(&o.id).is_err())
        .cloned()
        .collect();
    outside.sort();
    outside.dedup();
    RunOutcome { steps, executed, failure, goals, success, outside_relevant: outside, end: world }
}

/// The plan a task was given: read, unreadable, or missing.
#[derive(Clone, Debug)]
pub enum PlanInput {
    Plan(Program),
    Unreadable(ParseError),
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

fn parse_kind(e: &ParseError) -> &'static str {
    match e.kind {
        ParseErrorKind::Syntax { .. } => "parse_syntax",
        ParseErrorKind::UnknownVerb(_) => "parse_unknown_action",
        ParseErrorKind::WrongArity(_) => "parse_wrong_arity",
        ParseErrorKind::Empty => "parse_empty",
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

/// Rates in percent (`null` when a category has no goals).
#[derive(Clone, Debug, Serialize)]
pub struct Rates {
    pub task_success: Option<f64>,
    pub execution_success: Option<f64>,
    pub state_goal: Option<f64>,
    pub relation_goal: Option<f64>,
    pub action_goal: Option<f64>,
    pub total_goal: Option<f64>,
}

/// The metrics of a batch of tasks.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    pub tasks: usize,
    pub parsed: usize,
    pub executed: usize,
    pub succeeded: usize,
    pub state_goals: Count,
    pub relation_goals: Count,
    pub action_goals: Count,
    pub total_goals: Count,
    /// Tasks by what stopped them: parse error kinds, `no_plan`, executor failure kinds. Sorted.
    pub errors: BTreeMap<String, usize>,
    /// The same run failures under EAI's labels (parse errors as EAI groups them).
    pub eai_errors: BTreeMap<String, usize>,
    /// Plans with at least one additional (skipped) step, and the number of such steps.
    pub plans_with_additional_steps: usize,
    pub additional_steps: usize,
    /// Plans naming objects outside the task's relevant objects (which EAI's scorer rejects).
    pub plans_outside_relevant: usize,
}

impl Summary {
    pub fn of(reports: &[TaskReport]) -> Summary {
        let mut s = Summary { tasks: reports.len(), ..Summary::default() };
        for r in reports {
            s.parsed += r.parsed as usize;
            s.executed += r.executed as usize;
            s.succeeded += r.success as usize;
            s.state_goals.add(r.state_goals);
            s.relation_goals.add(r.relation_goals);
            s.action_goals.add(r.action_goals);
            if let Some(e) = &r.error {
                *s.errors.entry(e.kind.clone()).or_default() += 1;
                let eai = match e.kind.as_str() {
                    "parse_syntax" | "parse_empty" | "no_plan" => "parsing",
                    "parse_unknown_action" | "unknown_object" => "hallucination",
                    "parse_wrong_arity" | "wrong_arity" => "predicate_argument_number",
                    k => e.eai_kind.as_deref().unwrap_or(k),
                };
                *s.eai_errors.entry(eai.to_string()).or_default() += 1;
            }
            s.plans_with_additional_steps += (r.additional_steps > 0) as usize;
            s.additional_steps += r.additional_steps;
            s.plans_outside_relevant += !r.outside_relevant.is_empty() as usize;
        }
        s.total_goals = s.state_goals;
        s.total_goals.add(s.relation_goals);
        s.total_goals.add(s.action_goals);
        s
    }

    pub fn rates(&self) -> Rates {
        let pct = |n: usize| (self.tasks > 0).then(|| 100.0 * n as f64 / self.tasks as f64);
        Rates {
            task_success: pct(self.succeeded),
            execution_success: pct(self.executed),
            state_goal: self.state_goals.rate(),
            relation_goal: self.relation_goals.rate(),
            action_goal: self.action_goals.rate(),
            total_goal: self.total_goals.rate(),
        }
    }

    /// The summary as a text table.
    pub fn table(&self) -> String {
        let mut out = String::new();
        let pct = |r: Option<f64>| r.map_or("-".to_string(), |r| format!("{r:.2}%"));
        let rates = self.rates();
        let row = |out: &mut String, name: &str, met: usize, total: usize, r: Option<f64>| {
            out.push_str(&format!("{name:<22} {:>9} {:>8}\n", format!("{met}/{total}"), pct(r)));
        };
        out.push_str(&format!("{:<22} {:>9} {:>8}\n", "metric", "count", "rate"));
        row(
            &mut out,
            "parsed",
            self.parsed,
            self.tasks,
            (self.tasks > 0).then(|| 100.0 * self.parsed as f64 / self.tasks as f64),
        );
        row(&mut out, "executed", self.executed, self.tasks, rates.execution_success);
        row(&mut out, "task success", self.succeeded, self.tasks, rates.task_success);
        row(&mut out, "state goals", self.state_goals.met, self.state_goals.total, rates.state_goal);
        row(&mut out, "relation goals", self.relation_goals.met, self.relation_goals.total, rates.relation_goal);
        row(&mut out, "action goals", self.action_goals.met, self.action_goals.total, rates.action_goal);
        row(&mut out, "all goals", self.total_goals.met, self.total_goals.total, rates.total_goal);
        out.push_str("errors (tasks):");
        if self.errors.is_empty() {
            out.push_str(" none");
        }
        for (k, n) in &self.errors {
            out.push_str(&format!(" {k}={n}"));
        }
        out.push('\n');
        out.push_str(&format!(
            "additional steps skipped: {} in {} plan(s); plans naming objects outside the relevant list: {}\n",
            self.additional_steps, self.plans_with_additional_steps, self.plans_outside_relevant
        ));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::goal::RawGoal;
    use crate::eval::task::TaskOrigin;
    use crate::program::PlanFormat;
    use crate::world::{Edge, Graph, Node};

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
