//! Build number for status page 3 (SPEC 5): the first 6 hex digits of the git commit
//! the firmware is built from, as `SCIP2CAN_BUILD` (a number, 0..=0xFFFFFF).
//!
//! `SCIP2CAN_BUILD` set in the environment (6 hex digits) wins, for builds outside a
//! git checkout or reproducible ones. Without it and without git (or outside a checkout)
//! the build number is 0. Never fails the build.

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    if !out.status.success() {
        return None;
    }
    let text = String::from_utf8(out.stdout).ok()?;
    Some(text.trim().to_owned())
}

/// The value of up to 6 hex digits, if `text` is that.
fn hex24(text: &str) -> Option<u32> {
    let text = text.trim();
    if text.is_empty() || text.len() > 6 {
        return None;
    }
    u32::from_str_radix(text, 16).ok()
}

fn main() {
    println!("cargo:rerun-if-env-changed=SCIP2CAN_BUILD");
    let build = match std::env::var("SCIP2CAN_BUILD") {
        Ok(v) => hex24(&v).unwrap_or(0),
        Err(_) => {
            // Rebuild when the commit changes: HEAD, the branch it names, packed refs
            // (those that exist: cargo reruns a script always for a missing path).
            let branch = git(&["symbolic-ref", "-q", "HEAD"]);
            let refs = ["HEAD", "packed-refs"].into_iter().chain(branch.as_deref());
            for path in refs {
                if let Some(p) = git(&["rev-parse", "--git-path", path]) {
                    if std::path::Path::new(&p).exists() {
                        println!("cargo:rerun-if-changed={p}");
                    }
                }
            }
            git(&["rev-parse", "--short=6", "HEAD"])
                .and_then(|h| hex24(h.get(..6).unwrap_or(&h)))
                .unwrap_or(0)
        }
    };
    println!("cargo:rustc-env=SCIP2CAN_BUILD={build}");
}
