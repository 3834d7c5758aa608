//! The metrics of a batch of task reports (EAI's rates and error taxonomy) and their text table.

use std::collections::BTreeMap;

use serde::Serialize;

use super::goal::Count;
use super::score::TaskReport;

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
