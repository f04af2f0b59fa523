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
    // Errors of running a command: one line.
    for args in [
        &["graph", "--demo", ""][..],
        &["eval", "--run", "/nonexistent/run"][..],
    ] {
        let (code, stdout, stderr) = ntg(args);
        assert_eq!(code, 1, "{args:?}");
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.starts_with("error:"), "{args:?}: {stderr}");
    }
    // Usage errors: clap's error with the usage line, exit 2.
    for args in [
        &["graph", "--demo", "a", "--format", "xml"][..],
        &["graph"][..],
    ] {
        let (code, stdout, stderr) = ntg(args);
        assert_eq!(code, 2, "{args:?}");
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        assert!(stderr.starts_with("error:"), "{args:?}: {stderr}");
        assert!(
            stderr.contains("Usage: ntg graph") || stderr.contains("[possible values: dot, json]"),
            "{args:?}: {stderr}"
        );
    }
}
