//! The leaf-node termination model (the paper's section III-C): a new child is judged *execute*
//! (exactly one primitive action), *decompose* (consistent but not one action yet) or *replan*
//! (inconsistent, with its cause: affordance, congruence with the parent, environment, and why).
//! What the world can answer exactly is not left to the model: an action's affordances and
//! preconditions (the symbolic check, with the executor's reason) and a subgoal that only repeats
//! its parent (congruence).

use serde_json::json;

use super::planner::{grammar_error, Run};
use super::prompt::NodeView;
use super::tree::{NodeId, Status};
use super::StopCause;
use crate::action::Action;
use crate::grammar::{ActionSet, Cause, Verdict, VerdictGrammar};

impl Run<'_> {
    /// The termination model's verdict on the new `child` of a node at `depth` (`text`: the
    /// proposal that made it; `action`: its action, if it is one). A proposed action can only be
    /// executed or rejected, so its grammar names that one action (the verdict is mostly forced
    /// tokens, still the model's choice); with the symbolic check on, an action the world finds
    /// runnable can be rejected only as not serving the goal (congruence): the world decides
    /// affordance and environment. A subgoal may also be decomposed, while the depth budget allows.
    /// An offered goal line or a target (`decomposed`) is congruent and not one action by
    /// construction: it is decomposed without a call, as the random chooser decomposes every
    /// subgoal it draws. `None`: no verdict within the token cap (the node replans).
    pub(super) fn judge(
        &mut self,
        child: NodeId,
        action: Option<&Action>,
        depth: usize,
        view: &NodeView,
        text: &str,
        decomposed: bool,
    ) -> Result<Option<Verdict>, StopCause> {
        let vg = match action {
            Some(a) => {
                let grounded = self.cfg.symbolic_check && self.world()?.why_not(a).is_none();
                VerdictGrammar {
                    actions: ActionSet::Exact(vec![a.clone()]),
                    reason_chars: self.cfg.reason_chars,
                    allow_decompose: false,
                    causes: if grounded { vec![Cause::Congruence] } else { Cause::ALL.to_vec() },
                }
            }
            None => VerdictGrammar {
                actions: self.action_set(child)?,
                reason_chars: self.cfg.reason_chars,
                allow_decompose: depth + 1 < self.cfg.budgets.max_depth,
                causes: Cause::ALL.to_vec(),
            },
        };
        let lark = vg.to_lark().map_err(|e| StopCause::Error(format!("verdict grammar: {e}")))?;
        let prompt = self.prompter.terminate(view, text);
        let vtext = if self.rng.is_some() || decomposed {
            Some("decompose".to_string())
        } else {
            self.call("terminate", child, &prompt, &lark)?
        };
        let Some(vtext) = vtext else { return Ok(None) };
        let verdict = vg.parse(&vtext).map_err(|e| grammar_error("terminate", child, &vtext, &e.to_string()))?;
        self.trace.event("verdict", json!({"node": child, "verdict": vtext}));
        Ok(Some(verdict))
    }

    /// The symbolic check of a leaf before it runs (`PlannerConfig::symbolic_check`): the world
    /// says whether its affordances and preconditions hold now. `Some(reason)`: it cannot run, and
    /// the reason is the executor's own message, which names the fix ("OPEN <fridge> (10) first").
    pub(super) fn symbolic_check(&mut self, child: NodeId, a: &Action) -> Result<Option<String>, StopCause> {
        if !self.cfg.symbolic_check {
            return Ok(None);
        }
        let Some(f) = self.world()?.why_not(a) else { return Ok(None) };
        self.stats.symbolic_rejections += 1;
        self.trace.event(
            "symbolic_check",
            json!({"node": child, "action": a.to_string(), "kind": f.kind.name(), "message": f.message}),
        );
        self.set_status(child, Status::Replanned, format!("environment: {} (symbolic check)", f.message));
        Ok(Some(f.message))
    }
}

/// Whether a proposed subgoal only repeats its parent's goal (the same words, or the start of them):
/// decomposing it would make the same decision one level down.
pub(super) fn echoes(subgoal: &str, goal: &str) -> bool {
    let words = |s: &str| -> Vec<String> {
        s.split(|c: char| !c.is_alphanumeric()).filter(|w| !w.is_empty()).map(str::to_lowercase).collect()
    };
    let (s, g) = (words(subgoal), words(goal));
    !s.is_empty() && (g.starts_with(&s) || s.starts_with(&g))
}
