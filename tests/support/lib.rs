//! Shared helpers for the integration tests: where the real recordings lie, and what to
//! do when they are missing.

use std::path::PathBuf;

/// The folder of real sensor captures: `../shared/recordings` beside the repository.
pub fn recordings_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/recordings")
}

/// The recordings folder, or `None` when it is missing.
///
/// Missing recordings fail the test under `CI=true` (CI must test against real data);
/// elsewhere the test says why it does nothing and returns.
pub fn recordings_or_skip(test: &str) -> Option<PathBuf> {
    let dir = recordings_dir();
    if dir.is_dir() {
        return Some(dir);
    }
    let msg = format!(
        "{test}: the real recordings are not at {} (a checkout of shared/ beside the repo)",
        dir.display()
    );
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{msg}; CI=true, so this is a failure");
    }
    eprintln!("{msg}; not run");
    None
}

/// Every sensor-to-host stream among the recordings (`*.scip` except the `.tx.scip`
/// host-to-sensor sides), sorted by name.
pub fn sensor_streams(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        name.ends_with(".scip") && !name.ends_with(".tx.scip")
    });
    files.sort();
    files
}
