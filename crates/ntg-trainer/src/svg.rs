//! Task graphs as SVG, laid out in-process (layout-rs), so no Graphviz
//! install is needed.

use anyhow::{Context, bail};
use layout::backends::svg::SVGWriter;
use layout::gv::{DotParser, GraphBuilder};

/// Lays out a DOT graph (as written by [`ctg_graph::Ctg::to_dot`]) and
/// renders it as an SVG document.
pub fn dot_to_svg(dot: &str) -> anyhow::Result<String> {
    let mut parser = DotParser::new(dot);
    let graph = match parser.process() {
        Ok(graph) => graph,
        Err(err) => bail!("invalid DOT: {err}"),
    };
    // layout-rs may panic on graphs it cannot lay out; report that as an error.
    let svg = std::panic::catch_unwind(|| {
        let mut builder = GraphBuilder::new();
        builder.visit_graph(&graph);
        let mut visual = builder.get();
        let mut writer = SVGWriter::new();
        visual.do_it(false, false, false, &mut writer);
        writer.finalize()
    })
    .ok()
    .context("the graph layout engine (layout-rs) failed on this graph")?;
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ctg_graph::{Ctg, Vocabulary};

    #[test]
    fn renders_a_ctg_with_self_loop_and_weights() {
        let v =
            Vocabulary::from_sequences([["pick", "place"].as_slice(), &["pick", "pick", "place"]])
                .unwrap();
        let mut g = Ctg::from_paths(
            v.len(),
            [
                v.parse_sequence("pick place").unwrap().as_slice(),
                v.parse_sequence("pick pick place").unwrap().as_slice(),
            ],
        )
        .unwrap();
        g.set_weight(v.id("place").unwrap(), v.id("pick").unwrap(), 0.4)
            .unwrap();
        let svg = dot_to_svg(&g.to_dot(&v).unwrap()).unwrap();
        assert!(svg.starts_with("<svg") || svg.contains("<svg"), "{svg}");
        assert!(svg.contains("pick") && svg.contains("place"));
        assert!(svg.contains("&lt;start&gt;") || svg.contains("<start>") || svg.contains("start"));
    }

    #[test]
    fn invalid_dot_is_an_error() {
        assert!(dot_to_svg("digraph { a -> }").is_err());
    }
}
