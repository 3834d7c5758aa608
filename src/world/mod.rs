//! The symbolic VirtualHome world: scene graphs, the state the robot acts on, the executor with
//! VirtualHome's evolving-graph semantics, feasible actions and observations. It knows nothing
//! about LLMs.
//!
//! - [`graph`]: the raw graph JSON (bare or EAI's `{init_graph, final_graph}`).
//! - [`vocab`]: relations, states, properties.
//! - [`state`]: [`World`], the indexed, cheaply cloned state with look-ups.
//! - [`exec`]: `World::execute` / `World::check`, typed failures in EAI's taxonomy.
//! - [`step`]: `World::step`, one step of a run with the additional-step rule ([`StepResult`]).
//! - [`feasible`]: every action that would succeed now, and why one would not.
//! - [`observe`]: the planner's bounded text view and the object catalogue.
//! - [`demo`]: the embedded demo kitchen (`World::demo()`).

pub mod affordance;
pub mod demo;
pub mod exec;
pub mod feasible;
pub mod graph;
pub mod observe;
pub mod state;
pub mod step;
pub mod vocab;

pub use demo::{demo_kitchen, DEMO_KITCHEN_JSON};
pub use exec::{Connective, Effects, ExecFailure, Fact, FailureKind, Missing};
pub use graph::{parse_scene, read_scene, Edge, Graph, GraphError, Node, SceneFile};
pub use observe::{ObjectInfo, Tool};
pub use state::{NodeView, World};
pub use step::StepResult;
pub use vocab::{Property, PropertySet, Relation, State, StateSet};
