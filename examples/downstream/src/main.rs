//! Builds the union CTG of two demonstrations, prints it as DOT, and replays
//! one demonstration with the oracle executor, using only `ctg-graph`.

use ctg_graph::symbolic::{SequenceObservation, SequenceTask};
use ctg_graph::{Ctg, CtgError, GraphExecutor, OracleEdgeScorer, OracleNodeScorer, Vocabulary};

fn main() -> Result<(), CtgError> {
    let demos = ["pick place", "pick pick place"];
    let vocab = Vocabulary::from_sequences(demos.iter().map(|d| d.split_whitespace()))?;
    let paths = demos
        .iter()
        .map(|d| vocab.parse_sequence(d))
        .collect::<Result<Vec<_>, _>>()?;
    let graph = Ctg::from_paths(vocab.len(), paths.iter().map(Vec::as_slice))?;
    print!("{}", graph.to_dot(&vocab)?);

    let target = paths[1].clone();
    let mut env = SequenceTask::new(vocab.clone(), target.clone());
    let mut nodes = OracleNodeScorer(|o: &SequenceObservation| o.last);
    let mut edges = OracleEdgeScorer(move |o: &SequenceObservation| {
        target.get(o.step).copied().unwrap_or(Vocabulary::END)
    });
    let rollout = GraphExecutor::new(graph).run(&mut env, &mut nodes, &mut edges, 0)?;
    println!(
        "oracle replay: {} (success: {})",
        vocab.format_sequence(&rollout.actions()),
        rollout.success
    );
    if !rollout.success {
        return Err(CtgError::Environment("the oracle replay failed".into()));
    }
    Ok(())
}
