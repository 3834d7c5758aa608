//! The two baselines every STEP figure is reported beside, on the same grammars and executors:
//!
//! - `flat`: the whole plan in one constrained generation under a [`PlanGrammar`], then executed in
//!   order until the first failure (EAI's open-loop protocol: written whole, then executed). A
//!   `feasible` grammar cannot be built for a whole plan (only the first action's preconditions are
//!   known before anything runs), so flat uses `typed` then, and the trace says so.
//! - `random`: the same closed loop, grammars and symbolic checks as the tree planner, with a seeded
//!   uniform choice among the action lines the grammar admits in place of the model, stopping after a
//!   fixed number of actions (`PlannerConfig::random_actions`). It shows what the scaffolding alone
//!   achieves. It never looks at the goal.

use std::time::Instant;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde_json::json;

use super::env::{Env, Outcome};
use super::trace::TraceWriter;
use super::tree::{Status, SubgoalTree};
use super::{CallRecord, PlanOutcome, PlanRequest, PlanStats, PlannerConfig, StopCause};
use crate::action::{Action, ObjRef, Verb};
use crate::grammar::{ActionSet, PlanGrammar, Strength};

/// The strength `flat` really uses: a whole plan is written before anything runs, so only the first
/// step's preconditions are known and `feasible` cannot constrain it; `typed` is used instead.
pub fn flat_strength(asked: Strength) -> Strength {
    if asked == Strength::Feasible {
        Strength::Typed
    } else {
        asked
    }
}
use crate::llm::chat::Message;
use crate::llm::engine::{GenOptions, Generate, Prompt};
use crate::llm::LlmError;
use crate::world::World;

/// The flat planner's system prompt (written on the demo kitchen, never on a scored task).
const FLAT_SYSTEM: &str = include_str!("../../prompts/flat_system.txt");

/// Output tokens allowed per plan line (an action line is 8-20 tokens; two long object names and
/// ids make ~30).
const TOKENS_PER_LINE: usize = 32;

/// The number of distinct lines `set` admits for each verb, in the set's order, with what to draw
/// from: uniform sampling over lines is "pick a verb weighted by its count, then each slot uniformly".
enum Draw<'a> {
    Exact(Vec<Action>),
    Slots(Vec<(Verb, Vec<Vec<&'a ObjRef>>, usize)>),
}

fn unique<'a>(objs: impl Iterator<Item = &'a ObjRef>) -> Vec<&'a ObjRef> {
    let mut v: Vec<&ObjRef> = objs.collect();
    v.sort();
    v.dedup();
    v
}

fn draw_table(set: &ActionSet) -> Draw<'_> {
    match set {
        ActionSet::Exact(list) => {
            let mut v = list.clone();
            v.sort_by_key(|a| a.to_string());
            v.dedup();
            Draw::Exact(v)
        }
        ActionSet::Slots(verbs, objects) => {
            let mut seen = std::collections::HashSet::new();
            let mut out = Vec::new();
            for spec in verbs {
                // The first spec of a verb name counts (as `ActionSet::contains` reads it).
                if !seen.insert(spec.name.as_str()) {
                    continue;
                }
                let Ok(verb) = spec.name.parse::<Verb>() else { continue };
                if verb.arity() != spec.arity {
                    continue;
                }
                let slots: Vec<Vec<&ObjRef>> = match &spec.slots {
                    None => (0..spec.arity).map(|_| unique(objects.iter())).collect(),
                    Some(s) => s.iter().map(|l| unique(l.iter())).collect(),
                };
                let n: usize = slots.iter().map(Vec::len).product();
                if n > 0 {
                    out.push((verb, slots, n));
                }
            }
            Draw::Slots(out)
        }
    }
}

/// One action line drawn uniformly from `set`, or `None` when it admits nothing.
pub fn draw(set: &ActionSet, rng: &mut StdRng) -> Option<Action> {
    match draw_table(set) {
        Draw::Exact(v) => (!v.is_empty()).then(|| v[rng.random_range(0..v.len())].clone()),
        Draw::Slots(t) => {
            let total: usize = t.iter().map(|e| e.2).sum();
            if total == 0 {
                return None;
            }
            let mut k = rng.random_range(0..total);
            for (verb, slots, n) in &t {
                if k < *n {
                    let args = slots.iter().map(|s| s[rng.random_range(0..s.len())].clone()).collect();
                    return Action::new(*verb, args).ok();
                }
                k -= n;
            }
            None
        }
    }
}

fn world_or_error<'a>(env: &'a dyn Env, what: &str) -> Result<&'a World, StopCause> {
    env.world()
        .ok_or_else(|| StopCause::Error(format!("the {what} planner needs a world model; {} has none", env.name())))
}

fn outcome_json(o: &Outcome) -> serde_json::Value {
    serde_json::to_value(o).unwrap_or(serde_json::Value::Null)
}

/// The `random` planner (see the module documentation).
pub fn random(env: &mut dyn Env, req: &PlanRequest, cfg: &PlannerConfig, trace: &mut TraceWriter) -> PlanOutcome {
    let t0 = Instant::now();
    let mut tree = SubgoalTree::new(&req.instruction);
    let root = tree.root();
    tree.set_status(root, Status::Decomposing, "random: children drawn from the grammar");
    let mut stats = PlanStats::default();
    let mut executed = Vec::new();
    let mut rng = StdRng::seed_from_u64(cfg.random_seed);
    trace.event(
        "start",
        json!({"planner": "random", "seed": cfg.random_seed, "actions": cfg.random_actions,
               "strength": cfg.strength.to_string(), "instruction": req.instruction, "env": env.name()}),
    );
    let n = cfg.random_actions.min(cfg.budgets.max_actions);
    let stop = loop {
        if stats.actions >= n {
            // Its fixed length is the random planner's only stopping rule (nobody says "done").
            break if n == cfg.random_actions {
                StopCause::Budget("random_actions")
            } else {
                StopCause::Budget("actions")
            };
        }
        if cfg.budgets.deadline.is_some_and(|d| t0.elapsed() >= d) {
            break StopCause::Budget("deadline");
        }
        let world = match world_or_error(env, "random") {
            Ok(w) => w,
            Err(e) => break e,
        };
        let set = match cfg.action_set(cfg.strength, world, &req.focus) {
            ActionSet::Exact(list) if cfg.fresh_steps => {
                ActionSet::Exact(super::rules::fresh_steps(list, &executed, &executed))
            }
            set => set,
        };
        // Draw; a doomed draw is rejected by the symbolic check and drawn again, up to the replan budget.
        let mut chosen = None;
        for _ in 0..=cfg.budgets.max_replans {
            let Some(a) = draw(&set, &mut rng) else { break };
            let doomed = if cfg.symbolic_check { world.why_not(&a) } else { None };
            match doomed {
                None => {
                    chosen = Some(a);
                    break;
                }
                Some(f) => {
                    stats.replans += 1;
                    stats.symbolic_rejections += 1;
                    let id = tree.add_child(root, a.to_string(), Some(a.clone()));
                    tree.set_status(id, Status::Replanned, format!("symbolic check: {}", f.message));
                    trace.event("rejected", json!({"node": id, "action": a.to_string(), "reason": f.message}));
                }
            }
        }
        let Some(a) = chosen else {
            if set.is_empty() {
                break StopCause::Error("the grammar admits no action here".into());
            }
            // Every draw was doomed: this step is given up and counts towards the action budget, so
            // the loop still ends.
            stats.abandoned += 1;
            stats.actions += 1;
            continue;
        };
        let id = tree.add_child(root, a.to_string(), Some(a.clone()));
        tree.set_status(id, Status::Mapped { action: a.clone() }, "random draw");
        stats.actions += 1;
        match env.execute(&a) {
            Ok(o) => {
                trace.event("execute", json!({"node": id, "action": a.to_string(), "outcome": outcome_json(&o)}));
                match &o {
                    Outcome::Failed { reason, .. } => {
                        stats.failed_executions += 1;
                        tree.set_status(id, Status::Failed, reason.clone());
                    }
                    _ => {
                        executed.push(a);
                        tree.set_status(id, Status::Executed, o.summary());
                    }
                }
            }
            Err(e) => {
                trace.event("env_error", json!({"node": id, "action": a.to_string(), "error": e.to_string()}));
                tree.set_status(id, Status::Failed, e.to_string());
                break StopCause::Error(e.to_string());
            }
        }
    };
    finish(tree, executed, stop, stats, t0, trace)
}

fn finish(
    mut tree: SubgoalTree,
    executed: Vec<Action>,
    stop: StopCause,
    mut stats: PlanStats,
    t0: Instant,
    trace: &mut TraceWriter,
) -> PlanOutcome {
    let root = tree.root();
    let status = if matches!(stop, StopCause::Error(_)) { Status::Failed } else { Status::Executed };
    tree.set_status(root, status, stop.to_string());
    stats.wall_ms = t0.elapsed().as_secs_f64() * 1e3;
    trace.event(
        "stop",
        json!({"stop": stop.to_string(), "executed": executed.iter().map(|a| a.to_string()).collect::<Vec<_>>(),
               "actions": stats.actions, "llm_calls": stats.llm_calls, "wall_ms": stats.wall_ms}),
    );
    PlanOutcome { tree, executed, stop, stats }
}

/// The flat planner's prompt: the constant part first (instructions, example), then the task.
pub fn flat_prompt(req: &PlanRequest, observation: &str) -> Prompt {
    let mut user = format!("Instruction: {}\n", req.instruction.trim());
    if let Some(c) = &req.context {
        user.push_str(c.trim_end());
        user.push('\n');
    }
    if !observation.trim().is_empty() {
        user.push_str("What the robot sees now:\n");
        user.push_str(observation.trim_end());
        user.push('\n');
    }
    user.push_str("Write the whole plan, one action a line.");
    Prompt::Chat(vec![Message::system(FLAT_SYSTEM.trim()), Message::user(user)])
}

/// The `flat` planner (see the module documentation).
pub fn flat(
    model: &mut dyn Generate,
    env: &mut dyn Env,
    req: &PlanRequest,
    cfg: &PlannerConfig,
    trace: &mut TraceWriter,
) -> PlanOutcome {
    let t0 = Instant::now();
    let mut tree = SubgoalTree::new(&req.instruction);
    let root = tree.root();
    let mut stats = PlanStats::default();
    let world = match world_or_error(env, "flat") {
        Ok(w) => w,
        Err(e) => return finish(tree, vec![], e, stats, t0, trace),
    };
    let asked = cfg.strength;
    let strength = flat_strength(asked);
    trace.event(
        "start",
        json!({"planner": "flat", "strength": strength.to_string(), "asked_strength": asked.to_string(),
               "note": (strength != asked).then_some("a whole plan cannot be feasible-constrained; typed is used"),
               "instruction": req.instruction, "env": env.name()}),
    );
    let max_lines = cfg.budgets.max_actions.clamp(1, 256);
    let grammar = PlanGrammar { actions: cfg.action_set(strength, world, &req.focus), max_lines };
    let lark = match grammar.to_lark() {
        Ok(l) => l,
        Err(e) => return finish(tree, vec![], StopCause::Error(format!("plan grammar: {e}")), stats, t0, trace),
    };
    let prompt = flat_prompt(req, &env.observe(&[], cfg.observe_budget));
    let opts = GenOptions { max_tokens: cfg.gen.max_tokens.max(max_lines * TOKENS_PER_LINE), ..cfg.gen.clone() };
    let prompt_hash = super::planner::prompt_hash(&prompt, &lark);
    let call_t0 = Instant::now();
    let generated = model.generate(&prompt, Some(&lark), &opts);
    let total_ms = call_t0.elapsed().as_secs_f64() * 1e3;
    // The plan grammar is line by line, so when the token limit cuts a long plan (a tiny model
    // that repeats one line to the line cap) every complete line written is still a valid step:
    // the plan is those lines (a robot would run them the same way), and the trace says so.
    let text = match generated {
        Ok(g) => {
            let rec = CallRecord::of("flat", root, prompt_hash, &g, total_ms);
            trace.event("llm_call", serde_json::to_value(&rec).unwrap_or_default());
            stats.prompt_tokens += rec.prompt_tokens;
            stats.reused_tokens += rec.reused_tokens;
            stats.output_tokens += rec.output_tokens;
            stats.forced_tokens += rec.forced_tokens;
            stats.calls.push(rec);
            tree.add_call(root, 0);
            g.text
        }
        Err(LlmError::TokenBudget { max_tokens, so_far }) if so_far.contains('\n') => {
            let cut = so_far[..so_far.rfind('\n').unwrap_or(0)].to_string();
            trace.event("token_budget", json!({"role": "flat", "max_tokens": max_tokens,
                "kept_lines": cut.lines().count(), "ms": total_ms}));
            stats.output_tokens += max_tokens;
            cut
        }
        Err(e) => {
            trace.event("llm_error", json!({"role": "flat", "error": e.to_string()}));
            return finish(tree, vec![], StopCause::Error(format!("flat generation: {e}")), stats, t0, trace);
        }
    };
    stats.llm_calls += 1;
    // The independent checker reads the output; a failure here is a grammar error (it must not happen).
    let plan = match grammar.parse(text.trim_end_matches('\n')) {
        Ok(p) => p,
        Err(e) => {
            trace.event("grammar_error", json!({"role": "flat", "output": text, "error": e.to_string()}));
            return finish(tree, vec![], StopCause::Error(format!("grammar error: {e}")), stats, t0, trace);
        }
    };
    tree.set_status(root, Status::Decomposing, "flat: the whole plan in one generation");
    let ids: Vec<usize> = plan.iter().map(|a| tree.add_child(root, a.to_string(), Some(a.clone()))).collect();
    for (&id, a) in ids.iter().zip(&plan) {
        tree.set_status(id, Status::Mapped { action: a.clone() }, "written by the flat plan");
    }
    // Open loop: run in order; the first failure ends the run (the rest are abandoned).
    let mut executed = Vec::new();
    let mut stop = StopCause::Done;
    for (k, (&id, a)) in ids.iter().zip(&plan).enumerate() {
        stats.actions += 1;
        match env.execute(a) {
            Ok(o) => {
                trace.event("execute", json!({"node": id, "action": a.to_string(), "outcome": outcome_json(&o)}));
                if let Outcome::Failed { reason, .. } = &o {
                    stats.failed_executions += 1;
                    tree.set_status(id, Status::Failed, reason.clone());
                    for &rest in &ids[k + 1..] {
                        tree.set_status(rest, Status::Abandoned, "an earlier step failed (open loop)");
                    }
                    break;
                }
                tree.set_status(id, Status::Executed, o.summary());
                executed.push(a.clone());
            }
            Err(e) => {
                trace.event("env_error", json!({"node": id, "action": a.to_string(), "error": e.to_string()}));
                tree.set_status(id, Status::Failed, e.to_string());
                stop = StopCause::Error(e.to_string());
                break;
            }
        }
    }
    finish(tree, executed, stop, stats, t0, trace)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planner::{Budgets, PlannerKind, SimEnv, Strength as PS};

    fn cfg(seed: u64, n: usize, strength: crate::planner::Strength) -> PlannerConfig {
        PlannerConfig {
            kind: PlannerKind::Random,
            strength,
            random_seed: seed,
            random_actions: n,
            budgets: Budgets { max_actions: 100, ..Budgets::default() },
            ..PlannerConfig::default()
        }
    }

    fn run(seed: u64, n: usize, strength: crate::planner::Strength) -> PlanOutcome {
        let w = World::demo();
        let focus: Vec<u32> = w.nodes().map(|n| n.id).collect();
        let mut env = SimEnv::new(w, focus.clone());
        let req = PlanRequest::new("tidy the kitchen", focus);
        random(&mut env, &req, &cfg(seed, n, strength), &mut TraceWriter::sink())
    }

    #[test]
    fn random_is_deterministic_per_seed_and_differs_across_seeds() {
        let a = run(7, 15, PS::Feasible);
        let b = run(7, 15, PS::Feasible);
        assert_eq!(a.executed, b.executed);
        assert_eq!(a.stats.actions, 15);
        assert_eq!(a.stop, StopCause::Budget("random_actions"));
        let c = run(8, 15, PS::Feasible);
        assert_ne!(a.executed, c.executed, "another seed, another plan");
    }

    #[test]
    fn random_under_feasible_never_fails_and_under_format_checks_reject() {
        let f = run(3, 20, PS::Feasible);
        assert_eq!(f.stats.failed_executions, 0);
        assert_eq!(f.executed.len(), 20, "every feasible action runs (skips count as run)");
        let g = run(3, 20, PS::Format);
        assert!(g.stats.symbolic_rejections > 0, "format draws doomed actions, which the check rejects");
        assert_eq!(g.stats.failed_executions, 0, "the symbolic check is exact in simulation");
    }

    #[test]
    fn uniform_draw_covers_slot_sets_in_proportion() {
        let w = World::demo();
        let ids: Vec<u32> = w.nodes().map(|n| n.id).collect();
        let set = crate::scene_grammar::action_set(Strength::Typed, &w, &ids);
        let mut rng = StdRng::seed_from_u64(1);
        let mut n_two = 0;
        let draws = 2000;
        for _ in 0..draws {
            let a = draw(&set, &mut rng).unwrap();
            assert!(set.contains(&a), "{a} is not admitted");
            n_two += (a.args.len() == 2) as usize;
        }
        // Share of two-object lines among all lines the set admits, against the draws.
        let Draw::Slots(t) = draw_table(&set) else { panic!("typed is a slot set") };
        let total: usize = t.iter().map(|e| e.2).sum();
        let two: usize = t.iter().filter(|e| e.1.len() == 2).map(|e| e.2).sum();
        let expected = two as f64 / total as f64;
        let got = n_two as f64 / draws as f64;
        assert!((got - expected).abs() < 0.05, "two-object share {got:.3} vs {expected:.3}");
        assert_eq!(total, set.len());
    }
}
