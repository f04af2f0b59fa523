//! `ntg graph`: the union CTG of demonstrated action sequences.

use std::io::Write;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use ctg_graph::{Ctg, Vocabulary};

/// Arguments of `ntg graph`.
#[derive(Debug, Args)]
pub struct GraphArgs {
    /// One demonstration: action names separated by spaces, e.g. "pick place".
    /// Repeat the flag for more demonstrations.
    #[arg(long = "demo", value_name = "ACTIONS", required = true)]
    pub demos: Vec<String>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = GraphFormat::Dot)]
    pub format: GraphFormat,
}

/// How `ntg graph` prints the graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum GraphFormat {
    /// Graphviz DOT, nodes named by action.
    Dot,
    /// JSON: `{"vocabulary": [...], "graph": {"num_nodes", "edges"}}`, each
    /// edge a `[from, to, weight]` triple of node ids.
    Json,
}

/// The vocabulary (inferred, in order of first appearance) and union CTG of
/// the given demonstrations.
pub fn union_graph(demos: &[String]) -> anyhow::Result<(Vocabulary, Ctg)> {
    for (i, demo) in demos.iter().enumerate() {
        if demo.split_whitespace().next().is_none() {
            bail!("demonstration {} is empty; give at least one action", i + 1);
        }
    }
    let vocab = Vocabulary::from_sequences(demos.iter().map(|d| d.split_whitespace()))
        .context("invalid action name")?;
    let mut graph = Ctg::empty(vocab.len());
    for (i, demo) in demos.iter().enumerate() {
        let path = vocab
            .parse_sequence(demo)
            .with_context(|| format!("demonstration {}", i + 1))?;
        graph.add_path(&path)?;
    }
    Ok((vocab, graph))
}

/// Runs `ntg graph`, writing the graph to `out`.
pub fn run(args: &GraphArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let (vocab, graph) = union_graph(&args.demos)?;
    match args.format {
        GraphFormat::Dot => out.write_all(graph.to_dot(&vocab)?.as_bytes())?,
        GraphFormat::Json => {
            let value = serde_json::json!({ "vocabulary": vocab, "graph": graph });
            serde_json::to_writer_pretty(&mut *out, &value)?;
            writeln!(out)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_to_string(demos: &[&str], format: GraphFormat) -> anyhow::Result<String> {
        let args = GraphArgs {
            demos: demos.iter().map(|s| s.to_string()).collect(),
            format,
        };
        let mut out = Vec::new();
        run(&args, &mut out)?;
        Ok(String::from_utf8(out)?)
    }

    #[test]
    fn dot_has_pick_self_loop() {
        let dot = run_to_string(&["pick place", "pick pick place"], GraphFormat::Dot).unwrap();
        assert!(dot.contains("\"pick\" -> \"pick\";"), "{dot}");
        assert!(dot.contains("\"<start>\" -> \"pick\";"));
        assert!(dot.contains("\"place\" -> \"<end>\";"));
    }

    #[test]
    fn json_round_trips() {
        let json = run_to_string(&["a b c", "a c b"], GraphFormat::Json).unwrap();
        let value: serde_json::Value = serde_json::from_str(&json).unwrap();
        let vocab: Vocabulary = serde_json::from_value(value["vocabulary"].clone()).unwrap();
        let graph: Ctg = serde_json::from_value(value["graph"].clone()).unwrap();
        assert_eq!(vocab.action_names().collect::<Vec<_>>(), ["a", "b", "c"]);
        let (b, c) = (vocab.id("b").unwrap(), vocab.id("c").unwrap());
        assert!(graph.has_edge(b, c) && graph.has_edge(c, b));
    }

    /// A graph of 10,000 distinct actions (a dense matrix once printed
    /// 1.1 GB of JSON for it) prints as an edge list: one edge per step.
    #[test]
    fn a_ten_thousand_action_graph_prints_as_a_short_edge_list() {
        let demo: Vec<String> = (0..10_000).map(|i| format!("a{i}")).collect();
        let json = run_to_string(&[demo.join(" ").as_str()], GraphFormat::Json).unwrap();
        assert!(json.len() < 1_000_000, "{} bytes", json.len());
        let value: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(value["graph"]["edges"].as_array().unwrap().len(), 10_001);
    }

    #[test]
    fn empty_demo_is_an_error() {
        let err = run_to_string(&["a b", "  "], GraphFormat::Dot).unwrap_err();
        assert_eq!(
            err.to_string(),
            "demonstration 2 is empty; give at least one action"
        );
    }

    #[test]
    fn reserved_name_is_an_error() {
        let err = run_to_string(&["a <end>"], GraphFormat::Dot).unwrap_err();
        assert!(format!("{err:#}").contains("reserved"), "{err:#}");
    }
}
