//! Embeds the commit this crate is built from as `NTG_BUILD_COMMIT`, so a
//! run record names the code that trained it, not whatever the checkout
//! holds when the record is written. `<12 hex digits>`, `-dirty` when the
//! workspace's code (`crates/`, `xtask/`, `Cargo.toml`, `Cargo.lock`) had
//! uncommitted changes at build time, or `unknown` outside a git checkout.

use std::path::Path;
use std::process::Command;

fn git(dir: &Path, args: &[&str]) -> Option<String> {
    Command::new("git")
        .arg("-C")
        .arg(dir)
        .args(args)
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
}

fn main() {
    let manifest = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let crate_dir = Path::new(&manifest);
    let workspace = crate_dir.join("../..");
    println!("cargo:rerun-if-changed=build.rs");
    let commit = match (
        git(&workspace, &["rev-parse", "--short=12", "HEAD"]),
        git(&workspace, &["rev-parse", "--absolute-git-dir"]),
    ) {
        (Some(head), Some(git_dir)) => {
            // Rebuild when HEAD moves, the index changes, or code is edited.
            for path in ["HEAD", "index", "packed-refs", "refs"] {
                let path = Path::new(&git_dir).join(path);
                if path.exists() {
                    println!("cargo:rerun-if-changed={}", path.display());
                }
            }
            let code = ["crates", "xtask", "Cargo.toml", "Cargo.lock"];
            for path in code {
                println!("cargo:rerun-if-changed={}", workspace.join(path).display());
            }
            let mut status = vec!["status", "--porcelain", "--untracked-files=no", "--"];
            status.extend(code);
            match git(&workspace, &status) {
                Some(changes) if !changes.is_empty() => format!("{head}-dirty"),
                _ => head,
            }
        }
        _ => "unknown".to_owned(),
    };
    println!("cargo:rustc-env=NTG_BUILD_COMMIT={commit}");
}
