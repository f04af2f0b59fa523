//! Conjugate task graphs (CTGs): the small core of ntg-rs.
//!
//! A *conjugate task graph* (Huang et al., "Neural Task Graphs", CVPR 2019)
//! turns the usual task graph inside out: its **nodes are actions** and a
//! directed **edge `a -> b` means "`b` may follow `a`"**; the states between
//! actions are implicit. One demonstration is a path through it; the union of
//! several demonstrations of a task is the task's CTG. Executed with a node
//! scorer ℓ(n|o) (where am I?) and an edge scorer ε(a|n,o) (which way now?),
//! a CTG becomes a reactive policy π(a|o) ∝ Σ_n ε(a|n,o) ℓ(n|o).
//!
//! This crate holds the types everything else shares:
//!
//! - [`Vocabulary`] / [`ActionId`]: a domain's fixed action set, with the
//!   reserved nodes `<start>` and `<end>`;
//! - [`Ctg`]: dense weighted adjacency, built from demonstrated paths and
//!   their union, thresholded, exported to DOT, serialised with serde;
//! - [`Demonstration`]: observations plus actions, validated;
//!   [`VideoDemonstration`]: the same as a video, many frames per action,
//!   each frame labelled with the action it belongs to;
//! - [`Environment`] / [`Expert`] in the Gymnasium style (`reset(seed)`,
//!   `step` with `terminated` vs `truncated`), and [`check_environment`],
//!   the conformance check every environment crate runs;
//! - [`GraphExecutor`] with pluggable [`NodeScorer`]s and [`EdgeScorer`]s,
//!   plus uniform and oracle scorers so the executor runs without networks;
//! - [`symbolic::SequenceTask`], a tiny environment for tests and examples.
//!
//! # Design
//!
//! Graphs are small (a domain has 12–40 actions), so a `Ctg` is a dense
//! `n x n` matrix of weights in `[0, 1]`; an edge exists when its weight is
//! positive. Ids are plain indices validated where they are used; every
//! fallible function returns [`CtgError`], and nothing panics on user input.
//! The executor needs no random number generator: greedy by default,
//! sampling takes a uniform number from the caller.
//!
//! **Architecture invariant:** this crate depends on nothing heavier than
//! `thiserror` and (optionally, feature `serde`) `serde`. It must never depend
//! on burn, parry, glam, rayon, image crates, clap, or the file system: a
//! downstream crate can build, combine, inspect, serialise and execute task
//! graphs with `ctg-graph` alone.
//!
//! # Example
//!
//! ```
//! use ctg_graph::symbolic::{SequenceObservation, SequenceTask};
//! use ctg_graph::{Ctg, GraphExecutor, OracleEdgeScorer, OracleNodeScorer, Vocabulary};
//!
//! // Two demonstrations of one task; the vocabulary is inferred from them.
//! let demos = [["pick", "place"].as_slice(), ["pick", "pick", "place"].as_slice()];
//! let vocab = Vocabulary::from_sequences(demos).unwrap();
//! let paths: Vec<_> = demos
//!     .iter()
//!     .map(|d| vocab.parse_sequence(&d.join(" ")).unwrap())
//!     .collect();
//! let graph = Ctg::from_paths(vocab.len(), paths.iter().map(Vec::as_slice)).unwrap();
//!
//! let pick = vocab.id("pick").unwrap();
//! assert!(graph.has_edge(pick, pick)); // pick may follow pick
//! println!("{}", graph.to_dot(&vocab).unwrap());
//!
//! // Execute the graph with oracle scorers in a symbolic environment whose
//! // goal is the second demonstration.
//! let target = paths[1].clone();
//! let mut env = SequenceTask::new(vocab.clone(), target.clone());
//! let mut nodes = OracleNodeScorer(|o: &SequenceObservation| o.last);
//! let mut edges = OracleEdgeScorer(move |o: &SequenceObservation| {
//!     target.get(o.step).copied().unwrap_or(Vocabulary::END)
//! });
//! let rollout = GraphExecutor::new(graph).run(&mut env, &mut nodes, &mut edges, 7).unwrap();
//! assert!(rollout.success);
//! assert_eq!(vocab.format_sequence(&rollout.actions()), "pick pick place");
//! ```
#![deny(missing_docs)]

mod demo;
mod env;
mod error;
mod exec;
mod graph;
pub mod symbolic;
mod video;
mod vocab;

pub use demo::Demonstration;
pub use env::{
    ConformanceReport, Environment, Expert, Step, check_environment, record_demonstration,
};
pub use error::{CtgError, Result};
pub use exec::{
    ActionDistribution, EdgeScorer, ExecutedStep, GraphExecutor, NodeScorer, NodeSelection,
    OracleEdgeScorer, OracleNodeScorer, Rollout, UniformEdgeScorer, UniformNodeScorer,
};
pub use graph::{Ctg, Edge, MAX_SERIALISED_NODES};
pub use video::VideoDemonstration;
pub use vocab::{ActionId, Vocabulary};
