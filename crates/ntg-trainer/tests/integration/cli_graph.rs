//! The `ntg graph` binary end to end: output, exit codes, one-line errors.

use crate::common;
use common::ntg;

#[test]
fn union_graph_has_a_pick_self_loop() {
    let (code, stdout, _) = ntg(&[
        "graph",
        "--demo",
        "pick place",
        "--demo",
        "pick pick place",
        "--format",
        "dot",
    ]);
    assert_eq!(code, 0);
    assert!(stdout.starts_with("digraph ctg {"), "{stdout}");
    assert!(stdout.contains("\"pick\" -> \"pick\";"), "{stdout}");
}

#[test]
fn errors_are_one_line_and_non_zero() {
    for args in [
        &["graph", "--demo", ""][..],
        &["graph", "--demo", "a", "--format", "xml"][..],
        &["graph"][..],
        &["eval", "--run", "/nonexistent/run"][..],
    ] {
        let (code, stdout, stderr) = ntg(args);
        assert_ne!(code, 0, "{args:?}");
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.starts_with("error:"), "{args:?}: {stderr}");
    }
}
