//! The subgoal tree: the instruction at the root, ordered children, every node with its status and
//! the history of why it changed. The executed leaves, in order, are the plan.

use petgraph::graph::{DiGraph, NodeIndex};
use serde::Serialize;

use crate::action::Action;

/// A node's id: its index in the tree (stable: nodes are never removed).
pub type NodeId = usize;

/// Where a node stands.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum Status {
    /// Proposed, not judged yet.
    Pending,
    /// Judged not mappable to one action: being decomposed into children.
    Decomposing,
    /// Judged to be this action; not executed yet.
    Mapped { action: Action },
    /// Its action ran (or, for an inner node, all its children are complete).
    Executed,
    /// Its action was tried and failed.
    Failed,
    /// Judged inconsistent (or its subtree could not be completed); the parent proposes another child.
    Replanned,
    /// Gave up: the replan budget ran out below it.
    Abandoned,
}

impl Status {
    pub fn name(&self) -> &'static str {
        match self {
            Status::Pending => "pending",
            Status::Decomposing => "decomposing",
            Status::Mapped { .. } => "mapped",
            Status::Executed => "executed",
            Status::Failed => "failed",
            Status::Replanned => "replanned",
            Status::Abandoned => "abandoned",
        }
    }
}

/// One node of the tree.
#[derive(Clone, Debug, Serialize)]
pub struct TreeNode {
    pub id: NodeId,
    pub parent: Option<NodeId>,
    pub depth: usize,
    /// The subgoal in words (the instruction at the root; the action line for a proposed action).
    pub text: String,
    pub status: Status,
    /// Every status the node had, with why it changed, oldest first.
    pub history: Vec<(String, String)>,
    /// The action of a leaf.
    pub action: Option<Action>,
    /// Ordered children.
    pub children: Vec<NodeId>,
    /// Indices (into `PlanStats::calls`) of the LLM calls that produced or judged this node.
    pub calls: Vec<usize>,
}

/// The tree (a petgraph digraph; children keep their order in each node).
#[derive(Clone, Debug, Default)]
pub struct SubgoalTree {
    graph: DiGraph<TreeNode, ()>,
}

impl SubgoalTree {
    /// A tree with only the root.
    pub fn new(instruction: &str) -> SubgoalTree {
        let mut t = SubgoalTree::default();
        t.push(None, instruction.to_string(), None);
        t
    }

    fn push(&mut self, parent: Option<NodeId>, text: String, action: Option<Action>) -> NodeId {
        let id = self.graph.node_count();
        let depth = parent.map_or(0, |p| self.graph[NodeIndex::new(p)].depth + 1);
        let node = TreeNode {
            id,
            parent,
            depth,
            text,
            status: Status::Pending,
            history: vec![("pending".into(), "proposed".into())],
            action,
            children: Vec::new(),
            calls: Vec::new(),
        };
        let ix = self.graph.add_node(node);
        if let Some(p) = parent {
            self.graph.add_edge(NodeIndex::new(p), ix, ());
            self.graph[NodeIndex::new(p)].children.push(id);
        }
        id
    }

    /// Adds a child at the end of `parent`'s children.
    pub fn add_child(&mut self, parent: NodeId, text: String, action: Option<Action>) -> NodeId {
        self.push(Some(parent), text, action)
    }

    pub fn root(&self) -> NodeId {
        0
    }

    pub fn len(&self) -> usize {
        self.graph.node_count()
    }

    pub fn is_empty(&self) -> bool {
        self.graph.node_count() == 0
    }

    pub fn node(&self, id: NodeId) -> &TreeNode {
        &self.graph[NodeIndex::new(id)]
    }

    pub fn nodes(&self) -> impl Iterator<Item = &TreeNode> {
        self.graph.node_weights()
    }

    /// Sets a node's status, recording why.
    pub fn set_status(&mut self, id: NodeId, status: Status, why: impl Into<String>) {
        let n = &mut self.graph[NodeIndex::new(id)];
        n.history.push((status.name().to_string(), why.into()));
        if let Status::Mapped { action } = &status {
            n.action = Some(action.clone());
        }
        n.status = status;
    }

    /// Records an LLM call against a node.
    pub fn add_call(&mut self, id: NodeId, call: usize) {
        self.graph[NodeIndex::new(id)].calls.push(call);
    }

    /// The executed leaves in order: the plan.
    pub fn plan(&self) -> Vec<Action> {
        let mut out = Vec::new();
        self.collect(self.root(), &mut out);
        out
    }

    fn collect(&self, id: NodeId, out: &mut Vec<Action>) {
        let n = self.node(id);
        if n.children.is_empty() {
            if n.status == Status::Executed {
                if let Some(a) = &n.action {
                    out.push(a.clone());
                }
            }
            return;
        }
        for &c in &n.children {
            self.collect(c, out);
        }
    }

    pub fn graph(&self) -> &DiGraph<TreeNode, ()> {
        &self.graph
    }

    /// The whole tree as JSON: `{"nodes": [...]}`, nodes by id, each with its children in order.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({ "nodes": self.nodes().collect::<Vec<_>>() })
    }

    /// The tree in Graphviz DOT: one box per node (its text, status and action), coloured by status,
    /// children left to right in order.
    pub fn to_dot(&self) -> String {
        let mut s = String::from("digraph subgoal_tree {\n  rankdir=TB;\n  node [shape=box, style=\"rounded,filled\", fontname=\"Helvetica\"];\n");
        for n in self.nodes() {
            let mut label = format!("{}. {}", n.id, n.text);
            if let Some(a) = &n.action {
                if a.to_string() != n.text {
                    label.push_str(&format!("\n{a}"));
                }
            }
            label.push_str(&format!("\n[{}]", n.status.name()));
            let color = match n.status {
                Status::Executed => "palegreen",
                Status::Failed => "salmon",
                Status::Replanned => "khaki",
                Status::Abandoned => "lightgrey",
                Status::Decomposing | Status::Mapped { .. } => "lightblue",
                Status::Pending => "white",
            };
            s.push_str(&format!("  n{} [label={}, fillcolor={color}];\n", n.id, dot_string(&label)));
        }
        for n in self.nodes() {
            for &c in &n.children {
                s.push_str(&format!("  n{} -> n{c};\n", n.id));
            }
            if n.children.len() > 1 {
                // Keep siblings in their order.
                let ids: Vec<String> = n.children.iter().map(|c| format!("n{c}")).collect();
                s.push_str(&format!("  {{ rank=same; {} [style=invis]; }}\n", ids.join(" -> ")));
            }
        }
        s.push_str("}\n");
        s
    }
}

/// A DOT string literal (quotes and backslashes escaped, newlines as DOT's centred line break).
fn dot_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// Writes `dot` to `path`; when Graphviz's `dot` is on the PATH, also `path` with extension `.svg`.
/// Returns the SVG path when one was written.
pub fn write_dot(dot: &str, path: &std::path::Path) -> std::io::Result<Option<std::path::PathBuf>> {
    std::fs::write(path, dot)?;
    let svg = path.with_extension("svg");
    let status = std::process::Command::new("dot")
        .arg("-Tsvg")
        .arg(path)
        .arg("-o")
        .arg(&svg)
        .stderr(std::process::Stdio::null())
        .status();
    match status {
        Ok(s) if s.success() => Ok(Some(svg)),
        // No Graphviz (or it failed): the DOT file alone is still useful.
        _ => Ok(None),
    }
}
