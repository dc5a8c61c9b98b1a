//! Build script: records the git commit the binary is built from (`BIFIRST_GIT_REVISION`),
//! logged in every run's metadata. Builds outside a git checkout simply have none.

use std::path::Path;
use std::process::Command;

fn main() {
    let git = |args: &[&str]| Command::new("git").args(args).output().ok().filter(|o| o.status.success()).map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
    if let Some(rev) = git(&["rev-parse", "--short=12", "HEAD"]) {
        println!("cargo:rustc-env=BIFIRST_GIT_REVISION={rev}");
    }
    // Rerun when HEAD moves: HEAD itself, and the branch file it points to.
    println!("cargo:rerun-if-changed=src/build.rs");
    if let Some(dir) = git(&["rev-parse", "--git-dir"]) {
        let dir = Path::new(&dir);
        for file in ["HEAD".to_string(), git(&["symbolic-ref", "-q", "HEAD"]).unwrap_or_default(), "packed-refs".to_string()] {
            let path = dir.join(&file);
            if !file.is_empty() && path.is_file() {
                println!("cargo:rerun-if-changed={}", path.display());
            }
        }
    }
}
