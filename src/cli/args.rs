//! Arguments shared by several commands, in one place so that commands never import from each
//! other: where tasks come from, the plan format, and the knobs of commands that run inference.

use std::path::PathBuf;

use clap::Args;

use crate::eval::TaskSource;
use crate::planner::{ActionChoice, PlannerConfig};
use crate::program::PlanFormat;

/// Where tasks come from (the commands that take tasks).
#[derive(Args, Debug, Clone, Default)]
pub struct TaskArgs {
    /// A task file of your own: a JSON list of {"id", "scene" (a scene graph JSON file relative to the
    /// task file, or an EAI task id such as 27_2), "title", "description" (optional), "vh_goal":
    /// {"goal": [...], "actions": [...]} in EAI's shape, "gold" (optional list of program lines)}.
    /// See the README's "Tasks". Without it, EAI's VirtualHome tasks are used.
    #[arg(long, value_name = "FILE")]
    pub tasks_file: Option<PathBuf>,
    /// The VirtualHome benchmark data directory (holding eai/ and resources/); default: $STEP_VH_DATA,
    /// else ../shared/bench/virtualhome beside the repo.
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
}

impl TaskArgs {
    pub fn source(&self) -> TaskSource {
        TaskSource { tasks_file: self.tasks_file.clone(), data: self.data.clone() }
    }
}

/// `--format`: a plan format by name (`PlanFormat`'s own `FromStr`).
pub fn parse_plan_format(s: &str) -> Result<PlanFormat, String> {
    s.parse::<PlanFormat>().map_err(|e| e.to_string())
}

/// Knobs of the commands that run inference (`generate`, `bench llm`, `plan`, `replay`, `eval plan`,
/// `bench nodes`).
#[derive(Args, Debug, Clone, Default)]
pub struct InferenceArgs {
    /// CPU threads for inference: a count (more than the machine has is capped, with a warning), or
    /// `auto`, the default: the cores not busy with other processes when the model starts (at least
    /// one). `STEP_THREADS` in the environment is used when this is not given.
    #[arg(long, value_parser = parse_threads, value_name = "N|auto")]
    pub threads: Option<Threads>,
    /// Where the planner's system message is kept between runs, as a snapshot of its keys and values
    /// (default: `$STEP_PREFIX_CACHE`, else `$XDG_CACHE_HOME/step/prefix`, else
    /// `~/.cache/step/prefix`). It saves the first model call most of its time; a snapshot is used
    /// only by the same build, model file and CPU kind, and the 4 newest are kept.
    #[arg(long, value_name = "DIR")]
    pub prefix_cache: Option<PathBuf>,
    /// Neither read nor write prefix snapshots: the first call computes the system message.
    #[arg(long, conflicts_with = "prefix_cache")]
    pub no_prefix_cache: bool,
}

/// `--threads`: a count, or `auto`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Threads {
    Auto,
    Count(u64),
}

fn parse_threads(s: &str) -> Result<Threads, String> {
    if s.trim().eq_ignore_ascii_case("auto") {
        return Ok(Threads::Auto);
    }
    match s.parse::<u64>() {
        Ok(0) => Err("at least 1 thread is needed (or `auto`: the cores not already busy)".into()),
        Ok(n) => Ok(Threads::Count(n)),
        Err(_) => Err(format!("'{s}' is not a whole number of threads, nor `auto`")),
    }
}

impl InferenceArgs {
    /// The prefix-snapshot directory these flags ask for (none with `--no-prefix-cache`).
    pub fn prefix_dir(&self) -> Option<PathBuf> {
        if self.no_prefix_cache {
            return None;
        }
        self.prefix_cache.clone().or_else(crate::llm::prefix::default_dir)
    }

    /// Sizes candle's worker pool. candle reads these variables the first time it is used, so this
    /// runs before any model is loaded.
    pub fn apply(&self) {
        let asked = match self.threads {
            None => return,
            Some(Threads::Auto) => {
                // Counted when the pool starts (after a bench's neighbours are running), not now.
                std::env::set_var("STEP_THREADS", "auto");
                return;
            }
            Some(Threads::Count(n)) => n,
        };
        let n = cap_threads(asked as usize, machine_threads());
        if n < asked as usize {
            eprintln!("warning: --threads {asked} is more than this machine's {n} hardware threads; using {n}");
        }
        std::env::set_var("CANDLE_NUM_THREADS", n.to_string());
        std::env::set_var("RAYON_NUM_THREADS", n.to_string());
    }
}

/// The hardware threads this process may use.
pub fn machine_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// A thread count capped to the machine (oversubscribing a CPU-bound pool only slows it down).
pub fn cap_threads(asked: usize, machine: usize) -> usize {
    asked.clamp(1, machine.max(1))
}

/// Reads a text input: a file, or standard input for `-` (which must be piped in). A byte-order
/// mark is dropped. Errors name the path.
pub fn read_input(path: &std::path::Path, what: &str) -> anyhow::Result<String> {
    use anyhow::Context;
    use std::io::{IsTerminal, Read};
    let text = if path.as_os_str() == "-" {
        if std::io::stdin().is_terminal() {
            anyhow::bail!("{what} '-' reads standard input, but nothing is piped in");
        }
        let mut s = String::new();
        std::io::stdin().read_to_string(&mut s).with_context(|| format!("reading the {what} from standard input"))?;
        s
    } else {
        std::fs::read_to_string(path).with_context(|| format!("cannot read {what} {}", path.display()))?
    };
    Ok(crate::program::strip_bom(&text).to_string())
}

/// How the tree planner makes its decisions (`plan` and `eval plan`); the defaults are
/// [`PlannerConfig`]'s.
#[derive(Args, Debug, Clone)]
pub struct DecisionArgs {
    /// Ask the termination model about actions the world already found runnable (congruence only).
    #[arg(long)]
    pub judge_actions: bool,
    /// Offer every feasible step (by default a walk right after a walk, the run's last three
    /// actions and what the node has already done are not offered again while anything else can be
    /// done; the random planner obeys the same rule).
    #[arg(long)]
    pub allow_repeats: bool,
    /// How the action of an `action:` proposal is chosen: `score` ranks every action the grammar
    /// admits by likelihood (feasible grammar), `generate` keeps what the model wrote.
    #[arg(long, default_value = "generate")]
    pub choose: ActionChoice,
    /// Let the root write its own subgoals even when the protocol shows the goals (by default each
    /// goal line is offered as a subgoal, and the root chooses among them).
    #[arg(long)]
    pub free_subgoals: bool,
    /// Let a subgoal's actions name any object of the focus (by default they name the objects its
    /// text names, and what holds them, when it names any).
    #[arg(long)]
    pub no_subgoal_focus: bool,
    /// Let subgoals be only the goal lines or free text (by default a node may also name an action
    /// over its objects that cannot run yet: a target, worked towards below it).
    #[arg(long)]
    pub no_target_subgoals: bool,
    /// Let the model choose the steps below a target among the feasible actions (by default the
    /// world gives the next step towards the target's action: the step its failure names).
    #[arg(long)]
    pub no_target_steps: bool,
    /// Reach each offered goal line with one chosen step (an action, or a target worked out below
    /// it), instead of steps until the model says `done` there.
    #[arg(long)]
    pub single_step_lines: bool,
    /// Say only "ok" after a step (by default: "ok, now <what it changed among its objects>", in
    /// the goal lines' words).
    #[arg(long)]
    pub no_change_report: bool,
    /// Let a node's steps undo what its earlier steps changed (by default a step that would, e.g.
    /// SWITCHOFF after the node's SWITCHON, is not offered; holding and closeness excepted).
    #[arg(long)]
    pub no_protect: bool,
    /// Offer steps that undo what the shown goal lines ask for (by default, under `--protocol goals`,
    /// a step that would make a goal line false while it holds is not offered, e.g. PLUGOUT of a
    /// television that is to stay plugged in; a target is judged by its own action).
    #[arg(long)]
    pub no_keep_goals: bool,
    /// Offer steps that change nothing among their objects and the robot (by default, where the
    /// goals are kept, LOOKAT, TOUCH or WASH of a clean plate is not offered unless the goals name
    /// its verb as an action the plan must include).
    #[arg(long)]
    pub offer_idle_steps: bool,
    /// Where `done` may be answered, the model is done when its probability of `done` as the
    /// answer's first word (against `action:` and `subgoal:`) is at least P. Not used on the task's
    /// goal lines with the goals kept (`--protocol goals` without `--no-keep-goals`): see
    /// `--lines-done-at`.
    #[arg(long, value_name = "P", default_value_t = crate::planner::DONE_AT, value_parser = probability)]
    pub done_at: f64,
    /// Take `done` only when greedy decoding writes it (no look at its probability), on goal lines
    /// too.
    #[arg(long)]
    pub no_done_check: bool,
    /// On the task's goal lines with the goals kept, the model is done with a line only when its
    /// probability of `done` as the answer's first word is at least P (below it, `done` is not
    /// offered to that decision).
    #[arg(long, value_name = "P", default_value_t = crate::planner::LINES_DONE_AT, value_parser = probability)]
    pub lines_done_at: f64,
    /// Show each decision the steps it may write with what each would make true, read from the
    /// world model (e.g. "[LIE] <couch> (352): character is LYING"; at most 24). Off by default:
    /// no gain measured with SmolLM2, at three times the time a call.
    #[arg(long)]
    pub show_effects: bool,
    /// Where the protocol shows no goals (`objects`, `instruction`), the root first sets its own
    /// goal lines, choosing one at a time among what the world can state about its objects
    /// ("fridge is CLOSED", "apple is INSIDE to fridge", "WATCH"), until it says done. The
    /// default of `step plan`; `step eval plan` keeps each protocol's measured default (off).
    #[arg(long)]
    pub infer_goals: bool,
    /// `step plan`: the root proposes steps at once, setting no goal lines of its own.
    #[arg(long, conflicts_with = "infer_goals")]
    pub no_infer_goals: bool,
    /// Below a goal line the root set, offer every step (by default only those that make the line
    /// true or run its verb, where any do); below a shown line that names actions ("POUR"), every
    /// step too (by default only that verb's, where any are offered).
    #[arg(long)]
    pub any_step_under_lines: bool,
    /// Where the root sets goal lines: offer as lines the verbs of every step that changes
    /// nothing (LOOKAT, TOUCH, PULL), not only those the instruction names ("Watch TV": WATCH),
    /// and every posture of the robot, not only the one whose verb it names ("sit": SITTING).
    #[arg(long)]
    pub all_verb_lines: bool,
    /// Where the root sets goal lines: offer lines about every object of the task, not only
    /// those the instruction names (where it names any), and meet a line about the robot alone
    /// on any object (by default on a named one, where it can be: "sit on the sofa").
    #[arg(long)]
    pub any_object_lines: bool,
    /// Where the root sets goal lines: offer an object's lines of verbs the instruction does not
    /// say of it (by default "open the fridge" leaves out "fridge is ON"), and both relations
    /// between two objects it names, whichever it says ("the bread on the plate": ON, not INSIDE).
    #[arg(long)]
    pub unsaid_lines: bool,
    /// Where the root sets goal lines: offer lines whose state already holds too.
    #[arg(long)]
    pub offer_held_lines: bool,
    /// Where the root sets goal lines: choose by how much more likely the instruction makes each
    /// answer (its log probability less that under the prompt without the instruction).
    #[arg(long)]
    pub calibrate_lines: bool,
}

/// A probability in (0, 1] (`--done-at`): 0 would stop everywhere, above 1 nowhere (say
/// `--no-done-check` for that).
fn probability(s: &str) -> Result<f64, String> {
    let p: f64 = s.parse().map_err(|_| format!("{s:?} is not a number: give a probability such as 0.2"))?;
    if p > 0.0 && p <= 1.0 {
        Ok(p)
    } else {
        Err(format!("{s} is not in (0, 1]: give a probability such as 0.2, or --no-done-check to turn the check off"))
    }
}

impl DecisionArgs {
    /// Sets these choices in `cfg`.
    pub fn apply(&self, cfg: &mut PlannerConfig) {
        cfg.judge_actions = self.judge_actions;
        cfg.fresh_steps = !self.allow_repeats;
        cfg.choose = self.choose;
        cfg.goal_subgoals = !self.free_subgoals;
        cfg.subgoal_focus = !self.no_subgoal_focus;
        cfg.target_subgoals = !self.no_target_subgoals;
        cfg.target_steps = !self.no_target_steps;
        cfg.single_step_lines = self.single_step_lines;
        cfg.report_changes = !self.no_change_report;
        cfg.protect_changes = !self.no_protect;
        cfg.keep_goals = !self.no_keep_goals;
        cfg.skip_idle = !self.offer_idle_steps;
        cfg.done_at = (!self.no_done_check).then_some(self.done_at);
        cfg.lines_done_at = (!self.no_done_check).then_some(self.lines_done_at);
        cfg.show_effects = self.show_effects;
        cfg.infer_goals = self.infer_goals;
        cfg.toward_lines = !self.any_step_under_lines;
        cfg.all_verb_lines = self.all_verb_lines;
        cfg.named_lines = !self.any_object_lines;
        cfg.said_lines = !self.unsaid_lines;
        cfg.skip_held_lines = !self.offer_held_lines;
        cfg.calibrate_lines = self.calibrate_lines;
    }
}
