//! The raw VirtualHome scene-graph JSON: `{nodes: [...], edges: [...]}`, as the simulator and EAI's
//! data set write it, either bare or wrapped as `{init_graph, final_graph}`.
//!
//! These types mirror the file (strings, as written) so that a graph round-trips; [`crate::world::World`]
//! turns one into an indexed, typed state. Malformed input becomes a [`GraphError`] naming the file,
//! the line and column, and what was expected.

use std::path::Path;

use serde::{Deserialize, Serialize};

/// One node of a scene graph (an object, a room, the character).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Node {
    pub id: u32,
    pub class_name: String,
    #[serde(default)]
    pub category: String,
    #[serde(default)]
    pub properties: Vec<String>,
    #[serde(default)]
    pub states: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prefab_name: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bounding_box: Option<serde_json::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub obj_transform: Option<serde_json::Value>,
}

impl Node {
    /// A node without geometry, for scenes built in code (tests, tools).
    pub fn new(id: u32, class_name: &str, category: &str, properties: &[&str], states: &[&str]) -> Self {
        Node {
            id,
            class_name: class_name.to_string(),
            category: category.to_string(),
            properties: properties.iter().map(|s| s.to_string()).collect(),
            states: states.iter().map(|s| s.to_string()).collect(),
            prefab_name: None,
            bounding_box: None,
            obj_transform: None,
        }
    }
}

/// One directed edge: `from_id relation_type to_id`, e.g. `12 ON 5` (the apple is on the counter).
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Edge {
    pub from_id: u32,
    pub relation_type: String,
    pub to_id: u32,
}

/// A whole scene graph.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Graph {
    pub nodes: Vec<Node>,
    pub edges: Vec<Edge>,
}

/// A scene file: its initial graph, and the final graph when the file is EAI's `{init_graph, final_graph}`.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneFile {
    pub init: Graph,
    pub final_graph: Option<Graph>,
}

/// Why a scene graph could not be read or used.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    #[error("cannot read scene file {path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error("{origin}:{line}:{column}: invalid scene graph JSON: {message}")]
    Json { origin: String, line: usize, column: usize, message: String },
    #[error(
        "{origin}: not a scene graph: expected an object with `nodes` and `edges` arrays, or EAI's \
         `{{\"init_graph\": ..., \"final_graph\": ...}}`; {detail}"
    )]
    Shape { origin: String, detail: String },
    #[error("{origin}: {message}")]
    Invalid { origin: String, message: String },
}

/// Every field either form may have; deserialised in one pass (no intermediate `Value`).
#[derive(Deserialize)]
struct AnyScene {
    nodes: Option<Vec<Node>>,
    edges: Option<Vec<Edge>>,
    init_graph: Option<Graph>,
    final_graph: Option<Graph>,
}

/// Parses scene JSON text; `origin` (a path or a name) is used in error messages.
pub fn parse_scene(text: &str, origin: &str) -> Result<SceneFile, GraphError> {
    // A byte-order mark is not JSON; editors on Windows add one.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let any: AnyScene = serde_json::from_str(text).map_err(|e| GraphError::Json {
        origin: origin.to_string(),
        line: e.line(),
        column: e.column(),
        message: e.to_string().split(" at line ").next().unwrap_or_default().to_string(),
    })?;
    match any {
        AnyScene { init_graph: Some(init), final_graph, .. } => Ok(SceneFile { init, final_graph }),
        AnyScene { nodes: Some(nodes), edges, .. } => {
            Ok(SceneFile { init: Graph { nodes, edges: edges.unwrap_or_default() }, final_graph: None })
        }
        AnyScene { final_graph: Some(_), .. } => Err(GraphError::Shape {
            origin: origin.to_string(),
            detail: "found `final_graph` but no `init_graph`".into(),
        }),
        _ => Err(GraphError::Shape {
            origin: origin.to_string(),
            detail: "found neither `nodes` nor `init_graph`".into(),
        }),
    }
}

/// Reads and parses a scene file from disk.
pub fn read_scene(path: &Path) -> Result<SceneFile, GraphError> {
    let text =
        std::fs::read_to_string(path).map_err(|error| GraphError::Io { path: path.display().to_string(), error })?;
    parse_scene(&text, &path.display().to_string())
}

impl Graph {
    /// Serialises as pretty JSON (the same shape it was read from).
    pub fn to_json_pretty(&self) -> String {
        // Serialising plain strings, numbers and already-valid JSON values cannot fail.
        serde_json::to_string_pretty(self).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BARE: &str = r#"{"nodes":[{"id":1,"class_name":"kitchen","category":"Rooms","properties":[],"states":[]}],
        "edges":[]}"#;

    #[test]
    fn bare_and_wrapped_graphs_parse() {
        let s = parse_scene(BARE, "bare.json").unwrap();
        assert_eq!(s.init.nodes[0].class_name, "kitchen");
        assert!(s.final_graph.is_none());
        let wrapped = format!(r#"{{"init_graph":{BARE},"final_graph":{BARE}}}"#);
        let s = parse_scene(&wrapped, "w.json").unwrap();
        assert_eq!(s.init.nodes.len(), 1);
        assert_eq!(s.final_graph.unwrap().nodes[0].id, 1);
    }

    #[test]
    fn malformed_json_names_file_line_and_column() {
        let bad = "{\"nodes\": [\n {\"id\": \"x\", \"class_name\": \"a\"}]}";
        let e = parse_scene(bad, "scene.json").unwrap_err().to_string();
        assert!(e.starts_with("scene.json:2:"), "{e}");
        assert!(e.contains("expected u32"), "{e}");
        let e = parse_scene("{\"nodes\": [", "s.json").unwrap_err().to_string();
        assert!(e.contains("s.json:1:"), "{e}");
    }

    #[test]
    fn wrong_shape_says_what_is_expected() {
        let e = parse_scene("{\"vertices\": []}", "v.json").unwrap_err().to_string();
        assert!(e.contains("v.json") && e.contains("`nodes` and `edges`"), "{e}");
        let e = parse_scene("[1,2]", "a.json").unwrap_err().to_string();
        assert!(e.contains("a.json:1:"), "{e}");
    }

    #[test]
    fn a_missing_file_is_named() {
        let e = read_scene(Path::new("/nonexistent/scene.json")).unwrap_err().to_string();
        assert!(e.starts_with("cannot read scene file /nonexistent/scene.json:"), "{e}");
    }

    #[test]
    fn graph_round_trips_through_json() {
        let s = parse_scene(BARE, "bare.json").unwrap();
        let back = parse_scene(&s.init.to_json_pretty(), "again").unwrap();
        assert_eq!(back.init, s.init);
    }
}
