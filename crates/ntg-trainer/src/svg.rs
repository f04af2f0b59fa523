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
    Ok(sorted_style(&svg))
}

/// `svg` with the lines of its `<style>` block sorted: layout-rs writes
/// its font classes in a hash map's order, which changes from run to
/// run, so the same graph gave a different file each time.
fn sorted_style(svg: &str) -> String {
    let (Some(open), Some(close)) = (svg.find("<style>"), svg.find("</style>")) else {
        return svg.to_owned();
    };
    let start = open + "<style>".len();
    if close < start {
        return svg.to_owned();
    }
    // Only the non-empty lines move, so the block's layout stays.
    let mut lines: Vec<&str> = svg[start..close].split('\n').collect();
    let mut rules: Vec<&str> = lines.iter().copied().filter(|l| !l.is_empty()).collect();
    rules.sort_unstable();
    let mut rules = rules.into_iter();
    for line in lines.iter_mut().filter(|l| !l.is_empty()) {
        *line = rules.next().unwrap_or_default();
    }
    format!("{}{}{}", &svg[..start], lines.join("\n"), &svg[close..])
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
    fn the_same_graph_gives_the_same_file() {
        let v =
            Vocabulary::from_sequences([["pick(A)", "place(B)", "pick(C)"].as_slice()]).unwrap();
        let g = Ctg::from_paths(
            v.len(),
            [v.parse_sequence("pick(A) place(B) pick(C)")
                .unwrap()
                .as_slice()],
        )
        .unwrap();
        let svg = dot_to_svg(&g.to_dot(&v).unwrap()).unwrap();
        let (open, close) = (svg.find("<style>").unwrap(), svg.find("</style>").unwrap());
        let rules: Vec<&str> = svg[open + 7..close]
            .lines()
            .filter(|l| !l.is_empty())
            .collect();
        assert!(rules.is_sorted(), "{rules:?}");
        assert_eq!(
            sorted_style("<svg><style>\n.b { x }\n.a { y }\n</style></svg>"),
            "<svg><style>\n.a { y }\n.b { x }\n</style></svg>"
        );
    }

    #[test]
    fn invalid_dot_is_an_error() {
        assert!(dot_to_svg("digraph { a -> }").is_err());
    }
}
