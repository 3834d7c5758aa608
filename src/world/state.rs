//! The world state: a scene graph indexed for the executor and the planner.
//!
//! What never changes while actions run (ids, classes, categories, properties, the class index) sits
//! behind an `Arc`; what changes (node states, edges, what was grabbed from where, the run's history)
//! is a few small vectors, so cloning a `World` to simulate a step is cheap. Edges are kept per node,
//! outgoing and incoming, sorted by relation, so "what is the apple ON", "what is CLOSE to the robot"
//! are a binary search on one node's list, never a scan over the ~5,700 edges of a scene.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::Path;
use std::sync::Arc;

use crate::action::ObjRef;

use super::graph::{self, Edge, Graph, GraphError};
use super::vocab::{Property, PropertySet, Relation, State, StateSet};

/// Dense node index (position in id order).
pub(crate) type Ix = u32;

/// The parts of a scene that actions never change.
#[derive(Clone, Debug)]
pub(crate) struct Static {
    pub ids: Vec<u32>,
    pub index: HashMap<u32, Ix>,
    pub class: Vec<String>,
    pub category: Vec<String>,
    pub props: Vec<PropertySet>,
    /// prefab_name, bounding_box, obj_transform: carried only to write the graph back.
    pub extra: Vec<(Option<String>, Option<serde_json::Value>, Option<serde_json::Value>)>,
    pub by_class: BTreeMap<String, Vec<u32>>,
    pub body_parts: Vec<Ix>,
    pub character: Ix,
    /// The edges at load time, per node as in `World::out` (for the wrong-order rule).
    pub initial_out: Vec<Vec<(Relation, Ix)>>,
    pub initial_states: Vec<StateSet>,
}

/// What held at some point of the current run: EAI calls a failed precondition that held earlier a
/// wrong-order error rather than a missing step.
#[derive(Clone, Debug, Default)]
pub(crate) struct History {
    pub added_edges: HashSet<(Ix, Relation, Ix)>,
    pub added_states: HashSet<(Ix, State)>,
    pub removed_states: HashSet<(Ix, State)>,
    pub character_hands_were_free: bool,
    pub character_held_something: bool,
}

/// A read-only view of one node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NodeView<'a> {
    pub id: u32,
    pub class_name: &'a str,
    pub category: &'a str,
    pub properties: PropertySet,
    pub states: StateSet,
}

impl NodeView<'_> {
    /// `<class> (id)`, the form actions and messages use.
    pub fn label(&self) -> String {
        format!("<{}> ({})", self.class_name, self.id)
    }
    pub fn is_room(&self) -> bool {
        self.category == "Rooms"
    }
    /// A floor, wall or ceiling: VirtualHome's categories for the building itself.
    pub fn is_structure(&self) -> bool {
        matches!(self.category, "Floor" | "Floors" | "Walls" | "Ceiling")
    }
}

/// A scene's current state. See the module documentation.
#[derive(Clone, Debug)]
pub struct World {
    pub(crate) st: Arc<Static>,
    pub(crate) states: Vec<StateSet>,
    /// Per node, sorted `(relation, other)`: edges from it, and edges to it.
    pub(crate) out: Vec<Vec<(Relation, Ix)>>,
    pub(crate) inc: Vec<Vec<(Relation, Ix)>>,
    /// Object grabbed → (what it was on/in/close to, that relation): PUTOBJBACK returns it there.
    pub(crate) grabbed_from: BTreeMap<Ix, (Ix, Relation)>,
    pub(crate) history: History,
}

fn invalid(origin: &str, message: String) -> GraphError {
    GraphError::Invalid { origin: origin.to_string(), message }
}

impl World {
    /// Builds a world from a graph. `origin` names the graph in errors (a path, `demo`, a task id).
    /// Fails on a duplicate node id, a class name no action line can hold, an edge to a missing
    /// node or from a node to itself, an unknown relation, state or property, two states that
    /// exclude each other ([`State::EXCLUSIVE`]), a node in no room, or a scene without a
    /// `character` node.
    pub fn from_graph(g: &Graph, origin: &str) -> Result<World, GraphError> {
        let mut order: Vec<usize> = (0..g.nodes.len()).collect();
        order.sort_by_key(|&i| g.nodes.get(i).map(|n| n.id));
        let mut ids = Vec::with_capacity(order.len());
        let mut index = HashMap::with_capacity(order.len());
        let mut class = Vec::with_capacity(order.len());
        let mut category = Vec::with_capacity(order.len());
        let mut props = Vec::with_capacity(order.len());
        let mut states = Vec::with_capacity(order.len());
        let mut extra = Vec::with_capacity(order.len());
        let mut by_class: BTreeMap<String, Vec<u32>> = BTreeMap::new();
        for &i in &order {
            let Some(n) = g.nodes.get(i) else { continue };
            let ix = ids.len() as Ix;
            if index.insert(n.id, ix).is_some() {
                return Err(invalid(origin, format!("duplicate node id {} (class '{}')", n.id, n.class_name)));
            }
            ids.push(n.id);
            let mut p = PropertySet::EMPTY;
            for s in &n.properties {
                let v: Property =
                    s.parse().map_err(|e| invalid(origin, format!("node {} <{}>: {e}", n.id, n.class_name)))?;
                p.insert(v);
            }
            if let Some(why) = ObjRef::class_name_problem(&n.class_name) {
                return Err(invalid(origin, format!("node {}: class_name {:?}: {why}; rename the class", n.id, n.class_name)));
            }
            let mut st = StateSet::EMPTY;
            for s in &n.states {
                let v: State =
                    s.parse().map_err(|e| invalid(origin, format!("node {} <{}>: {e}", n.id, n.class_name)))?;
                st.insert(v);
            }
            if let Some((a, b)) = State::EXCLUSIVE.into_iter().find(|&(a, b)| st.contains(a) && st.contains(b)) {
                return Err(invalid(
                    origin,
                    format!("node {} <{}>: states {} and {} both given; keep the one it is in", n.id, n.class_name, a.name(), b.name()),
                ));
            }
            class.push(n.class_name.clone());
            category.push(n.category.clone());
            props.push(p);
            states.push(st);
            extra.push((n.prefab_name.clone(), n.bounding_box.clone(), n.obj_transform.clone()));
            by_class.entry(n.class_name.clone()).or_default().push(n.id);
        }
        let character = class
            .iter()
            .position(|c| c == "character")
            .ok_or_else(|| invalid(origin, "the scene has no node of class 'character' (the robot)".into()))?
            as Ix;
        let body_parts = (0..ids.len() as Ix).filter(|&i| props[i as usize].contains(Property::BodyPart)).collect();
        let mut out = vec![Vec::new(); ids.len()];
        let mut inc = vec![Vec::new(); ids.len()];
        for e in &g.edges {
            let r: Relation = e
                .relation_type
                .parse()
                .map_err(|m| invalid(origin, format!("edge {} {} {}: {m}", e.from_id, e.relation_type, e.to_id)))?;
            let look = |id: u32| {
                index.get(&id).copied().ok_or_else(|| {
                    invalid(origin, format!("edge {} {} {}: no node with id {id}", e.from_id, e.relation_type, e.to_id))
                })
            };
            let (f, t) = (look(e.from_id)?, look(e.to_id)?);
            // A node on, in or held by itself has no place (EAI's scenes have none; their final
            // graphs do have a node CLOSE to itself, which is harmless and kept).
            if f == t && !matches!(r, Relation::Close | Relation::Facing) {
                return Err(invalid(
                    origin,
                    format!("edge {} {} {}: a node cannot be {} itself; drop the edge", e.from_id, e.relation_type, e.to_id, r.name()),
                ));
            }
            out[f as usize].push((r, t));
            inc[t as usize].push((r, f));
        }
        // The simulator treats edges as a set: duplicates collapse.
        for l in out.iter_mut().chain(inc.iter_mut()) {
            l.sort_unstable();
            l.dedup();
        }
        let initial_out = out.clone();
        let initial_states = states.clone();
        let st = Static {
            ids,
            index,
            class,
            category,
            props,
            extra,
            by_class,
            body_parts,
            character,
            initial_out,
            initial_states,
        };
        let mut w =
            World { st: Arc::new(st), states, out, inc, grabbed_from: BTreeMap::new(), history: History::default() };
        w.history.character_hands_were_free = w.hands_free();
        w.history.character_held_something = !w.hands_free();
        // Walking needs the room of what is walked to (VirtualHome's rule, `room_ix`): an object
        // in no room could be named but never reached. Every node of EAI's scenes has one.
        if let Some(ix) = (0..w.len() as Ix).find(|&ix| w.room_ix(ix).is_none()) {
            let rooms: Vec<String> = w.rooms().iter().filter_map(|&r| w.node(r)).map(|n| n.label()).take(6).collect();
            let fix = if rooms.is_empty() {
                "the scene has no room (a node of category 'Rooms'): add one and put every object INSIDE it".to_string()
            } else {
                format!("add an INSIDE edge from it to a room ({}) or to an object that is in one", rooms.join(", "))
            };
            let n = w.view(ix);
            return Err(invalid(origin, format!("node {} <{}> is in no room: {fix}", n.id, n.class_name)));
        }
        Ok(w)
    }

    /// Parses scene JSON (bare or `{init_graph, ...}`: the initial graph is used).
    pub fn from_json(text: &str, origin: &str) -> Result<World, GraphError> {
        let scene = graph::parse_scene(text, origin)?;
        World::from_graph(&scene.init, origin)
    }

    /// Reads a scene file (bare or `{init_graph, ...}`: the initial graph is used).
    pub fn load(path: &Path) -> Result<World, GraphError> {
        let scene = graph::read_scene(path)?;
        World::from_graph(&scene.init, &path.display().to_string())
    }

    // ----- look-ups -------------------------------------------------------------------------

    pub(crate) fn ix(&self, id: u32) -> Option<Ix> {
        self.st.index.get(&id).copied()
    }
    pub(crate) fn id(&self, ix: Ix) -> u32 {
        self.st.ids.get(ix as usize).copied().unwrap_or(u32::MAX)
    }
    pub(crate) fn view(&self, ix: Ix) -> NodeView<'_> {
        let i = ix as usize;
        NodeView {
            id: self.id(ix),
            class_name: self.st.class.get(i).map(String::as_str).unwrap_or(""),
            category: self.st.category.get(i).map(String::as_str).unwrap_or(""),
            properties: self.st.props.get(i).copied().unwrap_or_default(),
            states: self.states.get(i).copied().unwrap_or_default(),
        }
    }
    pub(crate) fn label_ix(&self, ix: Ix) -> String {
        self.view(ix).label()
    }
    pub(crate) fn props_ix(&self, ix: Ix) -> PropertySet {
        self.st.props.get(ix as usize).copied().unwrap_or_default()
    }
    pub(crate) fn states_ix(&self, ix: Ix) -> StateSet {
        self.states.get(ix as usize).copied().unwrap_or_default()
    }
    pub(crate) fn class_ix(&self, ix: Ix) -> &str {
        self.st.class.get(ix as usize).map(String::as_str).unwrap_or("")
    }
    pub(crate) fn is_room_ix(&self, ix: Ix) -> bool {
        self.st.category.get(ix as usize).is_some_and(|c| c == "Rooms")
    }
    pub(crate) fn char_ix(&self) -> Ix {
        self.st.character
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.st.ids.len()
    }
    pub fn is_empty(&self) -> bool {
        self.st.ids.is_empty()
    }

    /// The node with this id.
    pub fn node(&self, id: u32) -> Option<NodeView<'_>> {
        self.ix(id).map(|ix| self.view(ix))
    }

    /// All nodes, in id order.
    pub fn nodes(&self) -> impl Iterator<Item = NodeView<'_>> + '_ {
        (0..self.st.ids.len() as Ix).map(|ix| self.view(ix))
    }

    /// Ids of the nodes of a class, ascending (empty if none).
    pub fn ids_of_class(&self, class_name: &str) -> &[u32] {
        self.st.by_class.get(class_name).map(Vec::as_slice).unwrap_or(&[])
    }

    /// The character (robot) node's id.
    pub fn character(&self) -> u32 {
        self.id(self.st.character)
    }

    /// Ids of all rooms, ascending.
    pub fn rooms(&self) -> Vec<u32> {
        (0..self.len() as Ix).filter(|&i| self.is_room_ix(i)).map(|i| self.id(i)).collect()
    }

    fn range(list: &[(Relation, Ix)], r: Relation) -> &[(Relation, Ix)] {
        let lo = list.partition_point(|&(x, _)| x < r);
        let hi = list.partition_point(|&(x, _)| x <= r);
        list.get(lo..hi).unwrap_or(&[])
    }
    pub(crate) fn targets(&self, ix: Ix, r: Relation) -> impl Iterator<Item = Ix> + '_ {
        let l = self.out.get(ix as usize).map(Vec::as_slice).unwrap_or(&[]);
        Self::range(l, r).iter().map(|&(_, t)| t)
    }
    pub(crate) fn sources(&self, ix: Ix, r: Relation) -> impl Iterator<Item = Ix> + '_ {
        let l = self.inc.get(ix as usize).map(Vec::as_slice).unwrap_or(&[]);
        Self::range(l, r).iter().map(|&(_, f)| f)
    }
    pub(crate) fn has_ix(&self, f: Ix, r: Relation, t: Ix) -> bool {
        self.out.get(f as usize).is_some_and(|l| l.binary_search(&(r, t)).is_ok())
    }

    /// Ids `x` with an edge `id r x`, ascending (e.g. what the apple is ON).
    pub fn related(&self, id: u32, r: Relation) -> Vec<u32> {
        self.ix(id).map(|ix| self.targets(ix, r).map(|t| self.id(t)).collect()).unwrap_or_default()
    }

    /// Ids `x` with an edge `x r id`, ascending (e.g. what is ON the table).
    pub fn related_to(&self, id: u32, r: Relation) -> Vec<u32> {
        self.ix(id).map(|ix| self.sources(ix, r).map(|f| self.id(f)).collect()).unwrap_or_default()
    }

    /// Whether the edge `from r to` exists.
    pub fn has_edge(&self, from: u32, r: Relation, to: u32) -> bool {
        match (self.ix(from), self.ix(to)) {
            (Some(f), Some(t)) => self.has_ix(f, r, t),
            _ => false,
        }
    }

    /// Number of edges.
    pub fn edge_count(&self) -> usize {
        self.out.iter().map(Vec::len).sum()
    }

    /// All edges as `(from, relation, to)` ids, sorted by from id, relation, to id.
    pub fn edges(&self) -> Vec<(u32, Relation, u32)> {
        let mut v = Vec::with_capacity(self.edge_count());
        for (f, l) in self.out.iter().enumerate() {
            for &(r, t) in l {
                v.push((self.id(f as Ix), r, self.id(t)));
            }
        }
        v
    }

    /// The room a node is in, the way VirtualHome finds it: a room is its own room; with several
    /// INSIDE edges, the one that is a room; with one, follow INSIDE up until a room.
    pub(crate) fn room_ix(&self, ix: Ix) -> Option<Ix> {
        if self.is_room_ix(ix) {
            return Some(ix);
        }
        let inside: Vec<Ix> = self.targets(ix, Relation::Inside).collect();
        if inside.len() > 1 {
            return inside.into_iter().find(|&i| self.is_room_ix(i));
        }
        let mut cur = inside.first().copied();
        let mut steps = 0;
        while let Some(c) = cur {
            if self.is_room_ix(c) {
                return Some(c);
            }
            steps += 1;
            if steps > self.len() {
                return None; // an INSIDE cycle: no room
            }
            cur = self.targets(c, Relation::Inside).next();
        }
        None
    }

    /// The room a node is in (see VirtualHome's rule above), if any.
    pub fn room_of(&self, id: u32) -> Option<u32> {
        self.ix(id).and_then(|ix| self.room_ix(ix)).map(|r| self.id(r))
    }

    /// The room the character is in.
    pub fn character_room(&self) -> Option<u32> {
        self.room_ix(self.st.character).map(|r| self.id(r))
    }

    /// What the character holds: `(HOLDS_RH | HOLDS_LH, object id)`, right hand first.
    pub fn held(&self) -> Vec<(Relation, u32)> {
        let c = self.st.character;
        self.targets(c, Relation::HoldsRh)
            .map(|t| (Relation::HoldsRh, self.id(t)))
            .chain(self.targets(c, Relation::HoldsLh).map(|t| (Relation::HoldsLh, self.id(t))))
            .collect()
    }

    pub(crate) fn hands_free(&self) -> bool {
        let c = self.st.character;
        self.targets(c, Relation::HoldsRh).next().is_none() && self.targets(c, Relation::HoldsLh).next().is_none()
    }

    /// The graph of the current state: nodes in id order, edges sorted; properties and states in
    /// their declaration order.
    pub fn to_graph(&self) -> Graph {
        let nodes = (0..self.len() as Ix)
            .map(|ix| {
                let v = self.view(ix);
                let (prefab_name, bounding_box, obj_transform) =
                    self.st.extra.get(ix as usize).cloned().unwrap_or_default();
                graph::Node {
                    id: v.id,
                    class_name: v.class_name.to_string(),
                    category: v.category.to_string(),
                    properties: v.properties.iter().map(|p| p.name().to_string()).collect(),
                    states: v.states.iter().map(|s| s.name().to_string()).collect(),
                    prefab_name,
                    bounding_box,
                    obj_transform,
                }
            })
            .collect();
        let edges = self
            .edges()
            .into_iter()
            .map(|(f, r, t)| Edge { from_id: f, relation_type: r.name().to_string(), to_id: t })
            .collect();
        Graph { nodes, edges }
    }

    /// Makes the current state the start of a new run: the wrong-order rule then looks back only to
    /// here. Grab records (for PUTOBJBACK) are kept.
    pub fn start_new_run(&mut self) {
        let mut st = (*self.st).clone();
        st.initial_out = self.out.clone();
        st.initial_states = self.states.clone();
        self.st = Arc::new(st);
        self.history = History {
            character_hands_were_free: self.hands_free(),
            character_held_something: !self.hands_free(),
            ..History::default()
        };
    }

    // ----- history queries (for the wrong-order rule) -----------------------------------------

    fn initially_has(&self, f: Ix, r: Relation, t: Ix) -> bool {
        self.st.initial_out.get(f as usize).is_some_and(|l| l.binary_search(&(r, t)).is_ok())
    }
    pub(crate) fn edge_held_earlier(&self, f: Ix, r: Relation, t: Ix) -> bool {
        self.initially_has(f, r, t) || self.history.added_edges.contains(&(f, r, t))
    }
    pub(crate) fn state_held_earlier(&self, ix: Ix, s: State) -> bool {
        self.st.initial_states.get(ix as usize).is_some_and(|x| x.contains(s))
            || self.history.added_states.contains(&(ix, s))
    }
    pub(crate) fn state_absent_earlier(&self, ix: Ix, s: State) -> bool {
        self.st.initial_states.get(ix as usize).is_some_and(|x| !x.contains(s))
            || self.history.removed_states.contains(&(ix, s))
    }

    // ----- mutation primitives (used by the executor) -----------------------------------------

    pub(crate) fn add_edge(&mut self, f: Ix, r: Relation, t: Ix) {
        let Some(l) = self.out.get_mut(f as usize) else { return };
        if let Err(pos) = l.binary_search(&(r, t)) {
            l.insert(pos, (r, t));
            if let Some(li) = self.inc.get_mut(t as usize) {
                if let Err(p) = li.binary_search(&(r, f)) {
                    li.insert(p, (r, f));
                }
            }
            self.history.added_edges.insert((f, r, t));
        }
    }

    pub(crate) fn remove_edge(&mut self, f: Ix, r: Relation, t: Ix) {
        if let Some(l) = self.out.get_mut(f as usize) {
            if let Ok(pos) = l.binary_search(&(r, t)) {
                l.remove(pos);
            }
        }
        if let Some(li) = self.inc.get_mut(t as usize) {
            if let Ok(p) = li.binary_search(&(r, f)) {
                li.remove(p);
            }
        }
    }

    pub(crate) fn set_state(&mut self, ix: Ix, s: State, on: bool) {
        let Some(cur) = self.states.get_mut(ix as usize) else { return };
        if cur.contains(s) == on {
            return;
        }
        if on {
            cur.insert(s);
            self.history.added_states.insert((ix, s));
        } else {
            cur.remove(s);
            self.history.removed_states.insert((ix, s));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) const TINY: &str = r#"{"nodes":[
        {"id":1,"class_name":"kitchen","category":"Rooms","properties":[],"states":[]},
        {"id":2,"class_name":"character","category":"Characters","properties":[],"states":[]},
        {"id":5,"class_name":"fridge","category":"Appliances","properties":["CAN_OPEN","CONTAINERS"],"states":["CLOSED"]},
        {"id":12,"class_name":"apple","category":"Food","properties":["GRABBABLE","EATABLE"],"states":[]},
        {"id":7,"class_name":"kitchencounter","category":"Furniture","properties":["SURFACES"],"states":[]}],
      "edges":[
        {"from_id":2,"relation_type":"INSIDE","to_id":1},
        {"from_id":5,"relation_type":"INSIDE","to_id":1},
        {"from_id":7,"relation_type":"INSIDE","to_id":1},
        {"from_id":12,"relation_type":"ON","to_id":7},
        {"from_id":12,"relation_type":"INSIDE","to_id":1},
        {"from_id":12,"relation_type":"CLOSE","to_id":7},
        {"from_id":12,"relation_type":"CLOSE","to_id":7}]}"#;

    #[test]
    fn loads_and_indexes() {
        let w = World::from_json(TINY, "tiny").unwrap();
        assert_eq!(w.len(), 5);
        assert_eq!(w.character(), 2);
        assert_eq!(w.ids_of_class("apple"), &[12]);
        assert!(w.ids_of_class("banana").is_empty());
        assert_eq!(w.related(12, Relation::On), vec![7]);
        assert_eq!(w.related_to(7, Relation::On), vec![12]);
        assert!(w.has_edge(12, Relation::Close, 7));
        assert_eq!(w.edge_count(), 6, "duplicate edges collapse");
        assert_eq!(w.room_of(12), Some(1));
        assert_eq!(w.character_room(), Some(1));
        let f = w.node(5).unwrap();
        assert!(f.properties.contains(Property::CanOpen) && f.states.contains(State::Closed));
        assert_eq!(f.label(), "<fridge> (5)");
        assert_eq!(w.rooms(), vec![1]);
        assert!(w.held().is_empty());
    }

    #[test]
    fn to_graph_round_trips() {
        let w = World::from_json(TINY, "tiny").unwrap();
        let g = w.to_graph();
        assert_eq!(g.nodes.iter().map(|n| n.id).collect::<Vec<_>>(), vec![1, 2, 5, 7, 12]);
        let w2 = World::from_graph(&g, "again").unwrap();
        assert_eq!(w2.edges(), w.edges());
        assert_eq!(w2.to_graph(), g);
    }

    #[test]
    fn bad_graphs_are_named_errors() {
        let no_char = TINY.replace("\"character\"", "\"robot\"");
        let e = World::from_json(&no_char, "t.json").unwrap_err().to_string();
        assert!(e.contains("t.json") && e.contains("no node of class 'character'"), "{e}");
        let dangling = TINY.replace("\"to_id\":7}", "\"to_id\":99}");
        let e = World::from_json(&dangling, "t.json").unwrap_err().to_string();
        assert!(e.contains("no node with id 99"), "{e}");
        let rel = TINY.replace("\"ON\"", "\"ONTOP\"");
        let e = World::from_json(&rel, "t.json").unwrap_err().to_string();
        assert!(e.contains("edge 12 ONTOP 7") && e.contains("unknown relation"), "{e}");
        let st = TINY.replace("[\"CLOSED\"]", "[\"SHUT\"]");
        let e = World::from_json(&st, "t.json").unwrap_err().to_string();
        assert!(e.contains("node 5 <fridge>") && e.contains("unknown state 'SHUT'"), "{e}");
        let dup = TINY.replace("\"id\":12", "\"id\":7");
        let e = World::from_json(&dup, "t.json").unwrap_err().to_string();
        assert!(e.contains("duplicate node id 7"), "{e}");
    }

    /// Scenes that parse but cannot be planned on, or whose meaning is arbitrary, are refused at
    /// load with the node and the fix, not found out mid-plan (or never).
    #[test]
    fn scenes_no_plan_could_stand_on_are_refused_at_load() {
        let refused = |text: &str| World::from_json(text, "t.json").unwrap_err().to_string();
        let e = refused(&TINY.replace("[\"CLOSED\"]", "[\"CLOSED\",\"OPEN\"]"));
        assert!(e.contains("node 5 <fridge>: states OPEN and CLOSED both given"), "{e}");
        let e = refused(&TINY.replace("\"apple\"", "\"apple <x> (3)\""));
        assert!(e.contains("node 12: class_name \"apple <x> (3)\"") && e.contains("'<'"), "{e}");
        let e = refused(&TINY.replace("\"apple\"", "\"\""));
        assert!(e.contains("node 12") && e.contains("empty"), "{e}");
        let e = refused(&TINY.replace("\"relation_type\":\"ON\",\"to_id\":7", "\"relation_type\":\"ON\",\"to_id\":12"));
        assert!(e.contains("edge 12 ON 12: a node cannot be ON itself"), "{e}");
        // CLOSE to itself (EAI's final graphs have such edges) is kept.
        let close_self = TINY.replace("\"relation_type\":\"CLOSE\",\"to_id\":7}]", "\"relation_type\":\"CLOSE\",\"to_id\":12}]");
        assert!(World::from_json(&close_self, "t.json").is_ok());
        // The fridge's only edge (INSIDE the kitchen) gone: it is in no room, and the rooms are named.
        let e = refused(&TINY.replace("{\"from_id\":5,\"relation_type\":\"INSIDE\",\"to_id\":1},", ""));
        assert!(e.contains("node 5 <fridge> is in no room") && e.contains("<kitchen> (1)"), "{e}");
        // On the counter but not inside anything: ON does not place it in a room (VirtualHome's rule).
        let e = refused(&TINY.replace("{\"from_id\":12,\"relation_type\":\"INSIDE\",\"to_id\":1},", ""));
        assert!(e.contains("node 12 <apple> is in no room"), "{e}");
        let e = refused(&TINY.replace("\"Rooms\"", "\"Furniture\""));
        assert!(e.contains("is in no room") && e.contains("the scene has no room"), "{e}");
    }

    #[test]
    fn mutation_keeps_both_indices_and_history() {
        let mut w = World::from_json(TINY, "tiny").unwrap();
        let (c, a) = (w.ix(2).unwrap(), w.ix(12).unwrap());
        assert!(!w.edge_held_earlier(c, Relation::Close, a));
        w.add_edge(c, Relation::Close, a);
        assert_eq!(w.related_to(12, Relation::Close), vec![2]);
        w.remove_edge(c, Relation::Close, a);
        assert!(!w.has_edge(2, Relation::Close, 12));
        assert!(w.related_to(12, Relation::Close).is_empty());
        assert!(w.edge_held_earlier(c, Relation::Close, a), "history remembers it");
        let snapshot = w.clone();
        w.set_state(a, State::Dirty, true);
        assert!(!snapshot.node(12).unwrap().states.contains(State::Dirty), "clones are independent");
        // A new run forgets what held before it.
        w.start_new_run();
        assert!(!w.edge_held_earlier(c, Relation::Close, a));
        assert!(w.state_held_earlier(a, State::Dirty), "the new run starts from the current state");
    }
}
