//! Tasks: a scene, a goal, and optionally a gold plan, from EAI's data set or from a user's task file.
//!
//! A task file is a JSON list; each task has `id`, `scene` (a graph JSON file, bare or EAI's
//! `{init_graph, final_graph}`, relative to the task file; or an EAI task id, whose initial graph is
//! used), `title`, optional `description`, `vh_goal` in EAI's shape, and optional `gold` program lines.
//! Everything is checked on load: an unknown object in a goal or a gold step names the task and the id.
//!
//! A task's relevant objects (the objects the planner is shown and may name, and the only ones EAI's
//! scorer admits) are made as EAI makes them, so that a user's task gets the same protocol as EAI's
//! own ([`RelevantRule`], reported per task):
//! 1. an explicit `relevant` list in the task file, taken as written;
//! 2. else, when the task has a gold program: run it from the initial state, and take the objects whose
//!    node differs between the initial and the final state, both ends of every edge in one state only
//!    (EAI's diff rule), plus every object the gold program names;
//! 3. else, when the scene file has a final graph (EAI's own tasks): EAI's diff rule on it;
//! 4. else (no gold, no final graph): the goal's objects, the character and their rooms, a smaller and
//!    easier list than EAI's, which is why it is only the fallback.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::dataset::{task_id_key, EaiData};
use super::goal::{Goal, RawGoal};
use super::EvalError;
use crate::program::{parse_step_line, Location, PlanParseError, Program};
use crate::world::{read_scene, Graph, Node, World};

/// Where a task came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TaskOrigin {
    /// EAI's VirtualHome data set.
    Eai,
    /// A user's task file.
    File(PathBuf),
}

/// One task, ready to run.
#[derive(Clone, Debug)]
pub struct Task {
    pub id: String,
    pub title: String,
    pub description: String,
    pub goal: Goal,
    /// The gold plan: absent for user tasks without one; an error when EAI's file does not parse.
    pub gold: Option<Result<Program, PlanParseError>>,
    /// The initial state.
    pub world: World,
    /// Relevant object ids, ascending (see the module documentation).
    pub relevant: Vec<u32>,
    /// How `relevant` was made, and what EAI's prompt shows of the initial state besides the list.
    pub relevance: Relevance,
    pub origin: TaskOrigin,
}

/// Which rule made a task's relevant objects (see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RelevantRule {
    /// EAI's diff rule on a stored final graph (EAI's tasks; a scene file with a final graph).
    FinalGraph,
    /// EAI's diff rule on the state the gold program reaches, plus the gold program's objects.
    GoldRun,
    /// Listed in the task file.
    Explicit,
    /// Fallback: the goal's objects, the character and their rooms.
    #[default]
    Goal,
}

impl RelevantRule {
    pub fn name(self) -> &'static str {
        match self {
            RelevantRule::FinalGraph => "final_graph",
            RelevantRule::GoldRun => "gold_run",
            RelevantRule::Explicit => "explicit",
            RelevantRule::Goal => "goal",
        }
    }
}

impl std::fmt::Display for RelevantRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How a task's relevant objects were made, and the parts of the initial state EAI's prompt shows
/// besides the object list: the nodes that change (with their initial states) and the initial edges
/// that do not survive. Empty for the explicit and goal rules, which have no final state.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Relevance {
    pub rule: RelevantRule,
    /// Ids of nodes whose own entry (states, properties) differs between the two states, ascending.
    pub changed: Vec<u32>,
    /// Initial edges absent from the final state, as `(from, relation, to)`, sorted.
    pub removed_edges: Vec<(u32, String, u32)>,
    /// Anything the rule could not do as intended (e.g. the gold program failed at a step).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// The full result of EAI's diff rule: relevant ids, changed nodes, removed initial edges.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Diff {
    pub ids: Vec<u32>,
    pub changed: Vec<u32>,
    pub removed_edges: Vec<(u32, String, u32)>,
}

/// Whether two lists hold the same strings with the same multiplicities (EAI compares nodes with
/// their property and state lists sorted).
fn same_multiset(a: &[String], b: &[String]) -> bool {
    if a == b {
        return true;
    }
    if a.len() != b.len() {
        return false;
    }
    let (mut x, mut y) = (a.to_vec(), b.to_vec());
    x.sort_unstable();
    y.sort_unstable();
    x == y
}

fn same_node(a: &Node, b: &Node) -> bool {
    a.id == b.id
        && a.class_name == b.class_name
        && a.category == b.category
        && a.prefab_name == b.prefab_name
        && a.bounding_box == b.bounding_box
        && a.obj_transform == b.obj_transform
        && same_multiset(&a.properties, &b.properties)
        && same_multiset(&a.states, &b.states)
}

/// EAI's relevant objects: ids of nodes that differ between the two graphs (or are in one only), and
/// both ends of every edge that is in one graph only. Ascending.
pub fn relevant_by_diff(init: &Graph, fin: &Graph) -> Vec<u32> {
    diff_ids(&init.nodes, edge_list(init), &fin.nodes, edge_list(fin)).ids
}

/// [`relevant_by_diff`] with the changed nodes and removed edges (what EAI's prompt shows).
pub fn diff_graphs(init: &Graph, fin: &Graph) -> Diff {
    diff_ids(&init.nodes, edge_list(init), &fin.nodes, edge_list(fin))
}

/// EAI's rule for a task with a gold program and no stored final graph: run the gold program from the
/// initial state (an additional step is skipped; any other failure stops the run, and the note says
/// where: the diff is then of the state reached up to there), diff the initial and the reached
/// state, and add every object the gold program names.
pub fn relevant_by_gold_run(world: &World, gold: &Program) -> (Vec<u32>, Relevance) {
    let mut end = world.clone();
    let mut note = None;
    for (i, a) in gold.actions.iter().enumerate() {
        match end.execute(a) {
            Ok(_) => {}
            Err(f) if f.kind == crate::world::FailureKind::AdditionalStep => {}
            Err(f) => {
                note =
                    Some(format!("the gold program fails at step {} ({a}): {}", i + 1, f.message));
                break;
            }
        }
    }
    let d = diff_graphs(&world.to_graph(), &end.to_graph());
    let mut ids: BTreeSet<u32> = d.ids.into_iter().collect();
    ids.extend(gold.actions.iter().flat_map(|a| a.args.iter().map(|o| o.id)).filter(|&id| world.node(id).is_some()));
    let rel = Relevance { rule: RelevantRule::GoldRun, changed: d.changed, removed_edges: d.removed_edges, note };
    (ids.into_iter().collect(), rel)
}

/// A graph's edges as `(from, relation, to)`, for [`diff_ids`].
pub(crate) fn edge_list(g: &Graph) -> Vec<(u32, &str, u32)> {
    g.edges.iter().map(|e| (e.from_id, e.relation_type.as_str(), e.to_id)).collect()
}

/// [`relevant_by_diff`] on node lists and edge lists (which may borrow from the file's text).
pub(crate) fn diff_ids<'a>(
    a_nodes: &[Node],
    mut ea: Vec<(u32, &'a str, u32)>,
    b_nodes: &[Node],
    mut eb: Vec<(u32, &'a str, u32)>,
) -> Diff {
    let b: HashMap<u32, &Node> = b_nodes.iter().map(|n| (n.id, n)).collect();
    let a_ids: HashSet<u32> = a_nodes.iter().map(|n| n.id).collect();
    let mut ids = BTreeSet::new();
    let mut changed = BTreeSet::new();
    let mut removed_edges = Vec::new();
    for n in a_nodes {
        if !b.get(&n.id).is_some_and(|m| same_node(n, m)) {
            ids.insert(n.id);
            changed.insert(n.id);
        }
    }
    let added = b_nodes.iter().map(|n| n.id).filter(|id| !a_ids.contains(id));
    for id in added {
        ids.insert(id);
        changed.insert(id);
    }
    // Edges as sorted sets, then one merge pass for the symmetric difference.
    for v in [&mut ea, &mut eb] {
        v.sort_unstable();
        v.dedup();
    }
    let (mut i, mut j) = (0, 0);
    while i < ea.len() || j < eb.len() {
        let odd = match (ea.get(i), eb.get(j)) {
            (Some(x), Some(y)) if x == y => {
                i += 1;
                j += 1;
                None
            }
            (Some(x), Some(y)) if x < y => {
                i += 1;
                removed_edges.push((x.0, x.1.to_string(), x.2));
                Some(*x)
            }
            (Some(_), Some(y)) => {
                j += 1;
                Some(*y)
            }
            (Some(x), None) => {
                i += 1;
                removed_edges.push((x.0, x.1.to_string(), x.2));
                Some(*x)
            }
            (None, Some(y)) => {
                j += 1;
                Some(*y)
            }
            (None, None) => None,
        };
        if let Some((f, _, t)) = odd {
            ids.insert(f);
            ids.insert(t);
        }
    }
    Diff { ids: ids.into_iter().collect(), changed: changed.into_iter().collect(), removed_edges }
}

/// Relevant objects without a final graph: the goal's and gold plan's objects, the character, and
/// the rooms they are in. Ascending; ids not in the world are left out.
pub fn relevant_by_goal(world: &World, goal: &Goal, gold: Option<&Program>) -> Vec<u32> {
    let mut ids: BTreeSet<u32> = goal.object_ids().into_iter().collect();
    if let Some(p) = gold {
        ids.extend(p.actions.iter().flat_map(|a| a.args.iter().map(|o| o.id)));
    }
    ids.insert(world.character());
    let rooms: Vec<u32> = ids.iter().filter_map(|&id| world.room_of(id)).collect();
    ids.extend(rooms);
    ids.into_iter().filter(|&id| world.node(id).is_some()).collect()
}

impl Task {
    /// The relevant objects as `(class_name, id)`, for prompts and reports.
    pub fn relevant_objects(&self) -> Vec<(String, u32)> {
        self.relevant.iter().filter_map(|&id| self.world.node(id).map(|n| (n.class_name.to_string(), id))).collect()
    }
}

/// An EAI scene file's final graph, with its ~5,700 edges borrowing their relation names from the
/// text: the final graph is only compared, so there is no need to allocate it.
#[derive(Deserialize)]
struct LightScene<'a> {
    init_graph: Graph,
    #[serde(borrow)]
    final_graph: LightGraph<'a>,
}

#[derive(Deserialize)]
struct LightGraph<'a> {
    nodes: Vec<Node>,
    #[serde(borrow)]
    edges: Vec<LightEdge<'a>>,
}

#[derive(Deserialize)]
struct LightEdge<'a> {
    from_id: u32,
    #[serde(borrow)]
    relation_type: std::borrow::Cow<'a, str>,
    to_id: u32,
}

/// One EAI scene file → the initial world and its relevant objects (EAI's diff rule).
fn eai_scene(id: &str, text: &str, origin: &str) -> Result<(World, Relevance, Vec<u32>), EvalError> {
    let name = format!("EAI task {id}");
    let with_rule = |d: Diff| {
        let rel = Relevance {
            rule: RelevantRule::FinalGraph,
            changed: d.changed,
            removed_edges: d.removed_edges,
            note: None,
        };
        (rel, d.ids)
    };
    match serde_json::from_str::<LightScene>(crate::program::strip_bom(text)) {
        Ok(l) => {
            let world = World::from_graph(&l.init_graph, &name)?;
            let fin: Vec<(u32, &str, u32)> =
                l.final_graph.edges.iter().map(|e| (e.from_id, e.relation_type.as_ref(), e.to_id)).collect();
            let (rel, ids) =
                with_rule(diff_ids(&l.init_graph.nodes, edge_list(&l.init_graph), &l.final_graph.nodes, fin));
            Ok((world, rel, ids))
        }
        // Not the usual shape: the general reader accepts more, and words its errors better.
        Err(_) => {
            let scene = crate::world::parse_scene(text, origin)?;
            let world = World::from_graph(&scene.init, &name)?;
            let (rel, ids) = match scene.final_graph.as_ref() {
                Some(f) => with_rule(diff_graphs(&scene.init, f)),
                None => (
                    Relevance { note: Some("the scene file has no final graph".into()), ..Relevance::default() },
                    vec![],
                ),
            };
            Ok((world, rel, ids))
        }
    }
}

/// Loads EAI tasks: all of them, or the given ids (an unknown id is an error listing examples).
pub fn load_eai(data: &EaiData, only: Option<&BTreeSet<String>>) -> Result<Vec<Task>, EvalError> {
    let metas = data.tasks_meta()?;
    if let Some(only) = only {
        let known: BTreeSet<&str> = metas.iter().map(|m| m.id.as_str()).collect();
        if let Some(bad) = only.iter().find(|id| !known.contains(id.as_str())) {
            return Err(EvalError::UnknownTask {
                id: bad.clone(),
                source_name: format!("EAI's data set at {}", data.root.display()),
                examples: metas.iter().take(5).map(|m| m.id.clone()).collect(),
            });
        }
    }
    let metas: BTreeMap<String, _> =
        metas.into_iter().filter(|m| only.is_none_or(|o| o.contains(&m.id))).map(|m| (m.id.clone(), m)).collect();
    let scenes = data.scene_texts(only, eai_scene)?;
    let mut tasks = Vec::with_capacity(scenes.len());
    for (id, (world, relevance, relevant)) in scenes {
        let Some(meta) = metas.get(&id) else { continue }; // a scene file with no task entry
        let goal = meta.goal.to_goal().map_err(|m| EvalError::Data {
            path: data.root.join("eai/resources/task_state_LTL_formula_accurate.json"),
            message: format!("task {id}: {m}"),
        })?;
        // A task without a program file has no gold plan; a file that exists but cannot be read
        // (permissions, not UTF-8 text) is an error naming it, never a silent "no plan".
        let (description, gold) = match data.program_text(&id) {
            Ok(text) => {
                let text = crate::program::strip_bom(&text);
                let description = text.lines().nth(1).unwrap_or("").trim().to_string();
                (description, Some(Program::parse(text, crate::program::PlanFormat::Lines)))
            }
            Err(EvalError::Io { error, .. }) if error.kind() == std::io::ErrorKind::NotFound => (String::new(), None),
            Err(e) => return Err(e),
        };
        tasks.push(Task {
            id,
            title: meta.task_name.clone(),
            description,
            goal,
            gold,
            world,
            relevant,
            relevance,
            origin: TaskOrigin::Eai,
        });
    }
    Ok(tasks)
}

/// A task as written in a task file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTask {
    id: String,
    scene: String,
    title: String,
    #[serde(default)]
    description: String,
    vh_goal: RawGoal,
    #[serde(default)]
    gold: Option<Vec<String>>,
    /// The objects the planner is shown and may name, by id (else made by EAI's rule).
    #[serde(default)]
    relevant: Option<Vec<u32>>,
}

fn looks_like_eai_id(s: &str) -> bool {
    let mut parts = s.split('_');
    let num = |p: Option<&str>| p.is_some_and(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
    num(parts.next()) && num(parts.next()) && parts.next().is_none()
}

/// Loads and checks a user's task file. `data` is the `--data` directory, used only when a task's
/// scene is an EAI task id.
pub fn load_file(path: &Path, data: Option<&Path>) -> Result<Vec<Task>, EvalError> {
    let text = std::fs::read_to_string(path).map_err(|error| EvalError::Io { path: path.to_path_buf(), error })?;
    let raw: Vec<RawTask> = serde_json::from_str(crate::program::strip_bom(&text)).map_err(|e| EvalError::Json {
        path: path.to_path_buf(),
        line: e.line(),
        column: e.column(),
        message: format!(
            "{e} (a task file is a JSON list of {{\"id\", \"scene\", \"title\", \"description\", \"vh_goal\", \"gold\", \"relevant\"}})"
        ),
    })?;
    let task_err =
        |task: &str, message: String| EvalError::Task { file: path.to_path_buf(), task: task.to_string(), message };
    if raw.is_empty() {
        return Err(EvalError::Data { path: path.to_path_buf(), message: "the task file lists no tasks".into() });
    }
    let mut seen = BTreeSet::new();
    for t in &raw {
        if t.id.trim().is_empty() {
            return Err(task_err(&t.id, "the task id is empty".into()));
        }
        if !seen.insert(t.id.as_str()) {
            return Err(task_err(&t.id, "this id is used by more than one task".into()));
        }
    }
    let base = path.parent().unwrap_or(Path::new("."));
    // Scenes: files beside the task file, or EAI ids (read from the archive in one pass).
    let mut eai_ids = BTreeSet::new();
    let mut files: BTreeMap<String, (World, Option<Diff>)> = BTreeMap::new();
    for t in &raw {
        let p = base.join(&t.scene);
        if p.is_file() {
            if !files.contains_key(&t.scene) {
                let scene = read_scene(&p)?;
                let world = World::from_graph(&scene.init, &p.display().to_string())?;
                let rel = scene.final_graph.as_ref().map(|f| diff_graphs(&scene.init, f));
                files.insert(t.scene.clone(), (world, rel));
            }
        } else if looks_like_eai_id(&t.scene) {
            eai_ids.insert(t.scene.clone());
        } else {
            return Err(task_err(
                &t.id,
                format!(
                    "scene '{}' is neither a graph file (looked at {}) nor an EAI task id such as 27_2",
                    t.scene,
                    p.display()
                ),
            ));
        }
    }
    let mut eai_worlds: BTreeMap<String, World> = BTreeMap::new();
    if !eai_ids.is_empty() {
        let data = EaiData::open(data)?;
        let known: BTreeSet<String> = data.tasks_meta()?.into_iter().map(|m| m.id).collect();
        if let Some(t) = raw.iter().find(|t| eai_ids.contains(&t.scene) && !known.contains(&t.scene)) {
            return Err(task_err(
                &t.id,
                format!("scene '{}' is not an EAI task id (see eai/resources/id2task.json)", t.scene),
            ));
        }
        for (id, w) in
            data.scenes(Some(&eai_ids), |id, s| Ok(World::from_graph(&s.init, &format!("EAI task {id}"))?))?
        {
            eai_worlds.insert(id, w);
        }
    }
    let mut tasks = Vec::with_capacity(raw.len());
    for t in raw {
        let (world, diff_relevant) = match files.get(&t.scene) {
            Some((w, rel)) => (w.clone(), rel.clone()),
            None => match eai_worlds.get(&t.scene) {
                Some(w) => (w.clone(), None),
                None => return Err(task_err(&t.id, format!("scene '{}' could not be loaded", t.scene))),
            },
        };
        if t.title.trim().is_empty() {
            return Err(task_err(&t.id, "title is empty: give the task a title (the instruction a planner reads)".into()));
        }
        let goal = t.vh_goal.to_goal().map_err(|m| task_err(&t.id, format!("vh_goal: {m}")))?;
        check_goal_objects(&world, &goal, &t.scene).map_err(|m| task_err(&t.id, m))?;
        let gold = match &t.gold {
            None => None,
            Some(lines) => {
                let p = parse_gold(lines).map_err(|e| task_err(&t.id, format!("gold: {e}")))?;
                check_plan_objects(&world, &p, &t.scene).map_err(|m| task_err(&t.id, format!("gold: {m}")))?;
                Some(p)
            }
        };
        let (relevant, relevance) = match (&t.relevant, &gold, diff_relevant) {
            (Some(ids), _, _) => {
                // An empty list would leave the planner nothing to name (and the scorer's
                // hallucination check nothing to pass): a mistake, not a task.
                if ids.is_empty() {
                    return Err(task_err(
                        &t.id,
                        "relevant is an empty list: list the ids of the objects the task involves, or leave the \
                         field out (the gold program's run, or the goal's objects, then give them)"
                            .into(),
                    ));
                }
                if let Some(bad) = ids.iter().find(|&&id| world.node(id).is_none()) {
                    return Err(task_err(
                        &t.id,
                        format!(
                            "relevant: object id {bad} is not in scene '{}' (list ids of the scene's nodes)",
                            t.scene
                        ),
                    ));
                }
                let mut ids = ids.clone();
                ids.sort_unstable();
                ids.dedup();
                (ids, Relevance { rule: RelevantRule::Explicit, ..Relevance::default() })
            }
            (None, Some(g), _) => relevant_by_gold_run(&world, g),
            (None, None, Some(d)) => {
                let rel = Relevance {
                    rule: RelevantRule::FinalGraph,
                    changed: d.changed,
                    removed_edges: d.removed_edges,
                    note: None,
                };
                (d.ids, rel)
            }
            (None, None, None) => (relevant_by_goal(&world, &goal, None), Relevance::default()),
        };
        // A task without goals would count as met whatever the plan did.
        if goal.is_empty() {
            return Err(task_err(
                &t.id,
                "vh_goal has no goal conditions and no actions, so no plan could fail it: add at least one \
                 (e.g. \"goal\": [{\"from_id\": 12, \"relation_type\": \"INSIDE\", \"to_id\": 10}])"
                    .into(),
            ));
        }
        tasks.push(Task {
            id: t.id,
            title: t.title,
            description: t.description,
            goal,
            gold: gold.map(Ok),
            world,
            relevant,
            relevance,
            origin: TaskOrigin::File(path.to_path_buf()),
        });
    }
    tasks.sort_by_key(|t| task_id_key(&t.id));
    Ok(tasks)
}

/// Gold steps one per list entry; an error's line is the step number.
fn parse_gold(lines: &[String]) -> Result<Program, PlanParseError> {
    let mut actions = Vec::with_capacity(lines.len());
    for (i, l) in lines.iter().enumerate() {
        let a = parse_step_line(l).map_err(|mut e| {
            if let Location::Line { line, .. } = &mut e.location {
                *line = i + 1;
            }
            e
        })?;
        actions.push(a);
    }
    Ok(Program::new(actions))
}

fn check_object(world: &World, id: u32, class_name: &str, scene: &str, what: &str) -> Result<(), String> {
    match world.node(id) {
        None => Err(format!("{what} names object id {id} (<{class_name}>), which is not in scene '{scene}'")),
        Some(n) if n.class_name != class_name => {
            Err(format!("{what} names <{class_name}> ({id}), but node {id} of scene '{scene}' is <{}>", n.class_name))
        }
        Some(_) => Ok(()),
    }
}

fn check_goal_objects(world: &World, goal: &Goal, scene: &str) -> Result<(), String> {
    for n in &goal.nodes {
        check_object(world, n.id, &n.class_name, scene, "a node goal")?;
    }
    // Two states no object can be in at once: no plan could meet the goal.
    for n in &goal.nodes {
        if let Some(o) = n.state.opposite().filter(|&o| goal.nodes.iter().any(|m| m.id == n.id && m.state == o)) {
            return Err(format!(
                "vh_goal asks <{}> ({}) to be both {} and {}, which no object can be at once: keep one",
                n.class_name,
                n.id,
                n.state.name(),
                o.name()
            ));
        }
    }
    for e in &goal.edges {
        for id in [e.from_id, e.to_id] {
            if world.node(id).is_none() {
                return Err(format!(
                    "the edge goal {} {} {} names object id {id}, which is not in scene '{scene}'",
                    e.from_id, e.relation_type, e.to_id
                ));
            }
        }
    }
    Ok(())
}

fn check_plan_objects(world: &World, p: &Program, scene: &str) -> Result<(), String> {
    for (i, a) in p.actions.iter().enumerate() {
        for o in &a.args {
            check_object(world, o.id, &o.class_name, scene, &format!("step {} ({a})", i + 1))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Edge;

    fn n(id: u32, class: &str, states: &[&str]) -> Node {
        Node::new(id, class, "Props", &[], states)
    }
    fn e(f: u32, r: &str, t: u32) -> Edge {
        Edge { from_id: f, relation_type: r.into(), to_id: t }
    }

    #[test]
    fn relevant_objects_follow_eai_diff_rule() {
        let init = Graph {
            nodes: vec![
                n(1, "kitchen", &[]),
                n(2, "character", &[]),
                n(3, "fridge", &["CLOSED", "CLEAN"]),
                n(4, "apple", &[]),
            ],
            edges: vec![e(2, "INSIDE", 1), e(4, "INSIDE", 3), e(3, "INSIDE", 1)],
        };
        let mut fin = init.clone();
        // Same states in another order: not a change.
        fin.nodes[2].states = vec!["CLEAN".into(), "CLOSED".into()];
        assert_eq!(relevant_by_diff(&init, &fin), Vec::<u32>::new());
        // The apple moves from the fridge to the character's hand: 2, 3 and 4 are relevant.
        fin.edges[1] = e(2, "HOLDS_RH", 4);
        assert_eq!(relevant_by_diff(&init, &fin), [2, 3, 4]);
        // A state change makes the kitchen relevant too.
        fin.nodes[0].states = vec!["DIRTY".into()];
        assert_eq!(relevant_by_diff(&init, &fin), [1, 2, 3, 4]);
    }

    #[test]
    fn eai_ids_are_recognised() {
        assert!(looks_like_eai_id("27_2") && looks_like_eai_id("1003_1"));
        assert!(!looks_like_eai_id("27") && !looks_like_eai_id("scene.json") && !looks_like_eai_id("27_2_1"));
    }
}
