//! Property tests for the invariants of conjugate task graphs.

use ctg_graph::symbolic::{SequenceObservation, SequenceTask};
use ctg_graph::{ActionId, Ctg, GraphExecutor, OracleEdgeScorer, OracleNodeScorer, Vocabulary};
use proptest::prelude::*;

const NUM_ACTIONS: usize = 6;

fn vocab() -> Vocabulary {
    Vocabulary::new((0..NUM_ACTIONS).map(|i| format!("a{i}"))).unwrap()
}

/// A non-empty action sequence over the real actions of `vocab()`.
fn path() -> impl Strategy<Value = Vec<ActionId>> {
    prop::collection::vec((2..NUM_ACTIONS + 2).prop_map(ActionId::new), 1..12)
}

/// A weighted graph over `vocab()` (weights in [0, 1], many exact zeros).
fn weighted_graph() -> impl Strategy<Value = Ctg> {
    let n = NUM_ACTIONS + 2;
    prop::collection::vec(prop_oneof![Just(0.0f32), 0.0f32..=1.0], n * n)
        .prop_map(move |w| Ctg::from_adjacency(n, w).unwrap())
}

proptest! {
    #[test]
    fn union_of_paths_contains_each_path(paths in prop::collection::vec(path(), 1..6)) {
        let n = vocab().len();
        let union = Ctg::from_paths(n, paths.iter().map(Vec::as_slice)).unwrap();
        for p in &paths {
            prop_assert!(union.contains_path(p));
            prop_assert!(Ctg::from_path(n, p).unwrap().is_subgraph_of(&union));
        }
        // Union by `union` equals union by `from_paths`.
        let folded = paths
            .iter()
            .map(|p| Ctg::from_path(n, p).unwrap())
            .reduce(|a, b| a.union(&b).unwrap())
            .unwrap();
        prop_assert_eq!(folded, union);
    }

    #[test]
    fn oracle_executor_replays_the_demonstrated_path(p in path(), seed in any::<u64>()) {
        let v = vocab();
        let graph = Ctg::from_path(v.len(), &p).unwrap();
        let mut env = SequenceTask::new(v, p.clone());
        let target = p.clone();
        let mut nodes = OracleNodeScorer(|o: &SequenceObservation| o.last);
        let mut edges = OracleEdgeScorer(move |o: &SequenceObservation| {
            target.get(o.step).copied().unwrap_or(Vocabulary::END)
        });
        let rollout = GraphExecutor::new(graph).run(&mut env, &mut nodes, &mut edges, seed).unwrap();
        prop_assert_eq!(rollout.actions(), p);
        prop_assert!(rollout.success);
        prop_assert!(rollout.terminated && !rollout.truncated);
    }

    #[test]
    fn json_round_trip_is_identity(graph in weighted_graph()) {
        let json = serde_json::to_string(&graph).unwrap();
        let back: Ctg = serde_json::from_str(&json).unwrap();
        prop_assert_eq!(back, graph);
    }

    #[test]
    fn vocabulary_json_round_trip_is_identity(names in prop::collection::btree_set("[a-z]{1,8}", 0..10)) {
        let v = Vocabulary::new(names).unwrap();
        let back: Vocabulary = serde_json::from_str(&serde_json::to_string(&v).unwrap()).unwrap();
        prop_assert_eq!(back, v);
    }

    #[test]
    fn thresholding_is_monotone(graph in weighted_graph(), t1 in -0.5f32..1.5, t2 in -0.5f32..1.5) {
        let (lo, hi) = if t1 <= t2 { (t1, t2) } else { (t2, t1) };
        let strict = graph.threshold(hi).unwrap();
        let loose = graph.threshold(lo).unwrap();
        prop_assert!(strict.is_subgraph_of(&loose));
        prop_assert!(loose.is_subgraph_of(&graph));
        prop_assert!(strict.num_edges() <= loose.num_edges());
    }

    #[test]
    fn successors_and_predecessors_agree(graph in weighted_graph()) {
        for edge in graph.edges() {
            prop_assert!(graph.successors(edge.from).contains(&edge.to));
            prop_assert!(graph.predecessors(edge.to).contains(&edge.from));
        }
        let total: usize = (0..graph.num_nodes())
            .map(|i| graph.successors(ActionId::new(i)).len())
            .sum();
        prop_assert_eq!(total, graph.num_edges());
    }
}

#[test]
fn graphs_are_written_as_edge_lists_and_old_matrices_still_read() {
    let mut graph = Ctg::empty(3);
    graph.add_edge(ActionId::new(0), ActionId::new(2)).unwrap();
    graph
        .set_weight(ActionId::new(2), ActionId::new(1), 0.25)
        .unwrap();
    let json = serde_json::to_string(&graph).unwrap();
    assert_eq!(json, r#"{"num_nodes":3,"edges":[[0,2,1.0],[2,1,0.25]]}"#);
    let old = r#"{"num_nodes":3,"adjacency":[0,0,1,0,0,0,0,0.25,0]}"#;
    assert_eq!(serde_json::from_str::<Ctg>(old).unwrap(), graph);
}

#[test]
fn corrupt_json_is_an_error_not_a_panic() {
    for bad in [
        r#"{"num_nodes": 2, "adjacency": [0.0, 1.0, 0.0]}"#,
        r#"{"num_nodes": 1, "adjacency": [7.0]}"#,
        r#"{"num_nodes": 1}"#,
        r#"[1, 2]"#,
        r#"{"num_nodes": 2, "edges": [[0, 2, 1.0]]}"#,
        r#"{"num_nodes": 2, "edges": [[0, 1, 1.5]]}"#,
        r#"{"num_nodes": 2, "edges": [[0, 1, 1.0], [0, 1, 0.5]]}"#,
        r#"{"num_nodes": 2, "edges": [], "adjacency": [0, 0, 0, 0]}"#,
        r#"{"num_nodes": 18446744073709551615, "edges": []}"#,
    ] {
        assert!(serde_json::from_str::<Ctg>(bad).is_err(), "{bad}");
    }
    assert!(serde_json::from_str::<Vocabulary>(r#"["a", "a"]"#).is_err());
    assert!(serde_json::from_str::<Vocabulary>(r#"["<start>"]"#).is_err());
}
