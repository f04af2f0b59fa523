//! The library's architecture invariant (its `lib.rs`): no environment
//! crate, command-line parser, plotting library or allocator among its
//! normal dependencies, direct or not, as `cargo tree` resolves them.

use std::process::Command;

#[test]
fn the_library_depends_on_no_env_crate_clap_plotters_or_allocator() {
    let manifest = concat!(env!("CARGO_MANIFEST_DIR"), "/../../Cargo.toml");
    let output = Command::new(env!("CARGO"))
        .args([
            "tree",
            "--offline",
            "-p",
            "ntg-train",
            "-e",
            "normal",
            "--prefix",
            "none",
        ])
        .args(["--manifest-path", manifest])
        .output()
        .expect("cargo runs");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let tree = String::from_utf8_lossy(&output.stdout);
    let names: Vec<&str> = tree
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert!(
        names.contains(&"ntg-model") && names.contains(&"ctg-graph"),
        "{tree}"
    );
    let forbidden = |name: &str| {
        name.starts_with("env-") || ["ntg-trainer", "clap", "plotters", "mimalloc"].contains(&name)
    };
    let found: Vec<&&str> = names.iter().filter(|n| forbidden(n)).collect();
    assert!(found.is_empty(), "ntg-train depends on {found:?}");
}
