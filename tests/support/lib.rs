//! Shared helpers for the integration tests: where the real recordings lie, what to do
//! when they are missing, and an independent SCIP value decoder (the tests' oracle).

use std::path::{Path, PathBuf};

pub mod oracle;

/// The folder of real sensor captures: `../shared/recordings` beside the repository.
pub fn recordings_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/recordings")
}

/// Every file of the recordings folder the tests read (its README lists them).
pub const RECORDINGS: [&str; 13] = [
    "README.md",
    "eeros_md_0046_0600.scip",
    "frmg5_matlab_urg04lxug01_vv_bm.scip",
    "hokuyoaist_example_urg_04lx.flexiport.logr",
    "hokuyoaist_example_urg_04lx.flexiport.logw",
    "hokuyoaist_example_urg_04lx.rx.scip",
    "hokuyoaist_example_urg_04lx.tx.scip",
    "hokuyoaist_example_utm_30lx.flexiport.logr",
    "hokuyoaist_example_utm_30lx.flexiport.logw",
    "hokuyoaist_example_utm_30lx.rx.scip",
    "hokuyoaist_example_utm_30lx.tx.scip",
    "snark_gd_0000_0010_tag.scip",
    "urgnetwork_wiki_urg04lx_vv_pp_ii.scip",
];

/// The sensor-to-host streams among [`RECORDINGS`], sorted by name.
pub const SENSOR_STREAMS: [&str; 6] = [
    "eeros_md_0046_0600.scip",
    "frmg5_matlab_urg04lxug01_vv_bm.scip",
    "hokuyoaist_example_urg_04lx.rx.scip",
    "hokuyoaist_example_utm_30lx.rx.scip",
    "snark_gd_0000_0010_tag.scip",
    "urgnetwork_wiki_urg04lx_vv_pp_ii.scip",
];

/// What is wrong with a recordings folder: `None` when every file of [`RECORDINGS`] is
/// there and not empty.
pub fn recordings_problem(dir: &Path) -> Option<String> {
    if !dir.is_dir() {
        return Some(format!(
            "the real recordings are not at {} (a checkout of shared/ beside the repo)",
            dir.display()
        ));
    }
    let missing: Vec<&str> = RECORDINGS
        .iter()
        .copied()
        .filter(|name| std::fs::metadata(dir.join(name)).map_or(true, |m| m.len() == 0))
        .collect();
    (!missing.is_empty()).then(|| {
        format!(
            "the recordings folder {} lacks (or has empty) {missing:?}",
            dir.display()
        )
    })
}

/// The recordings folder, or `None` when it is missing, incomplete or empty.
///
/// Missing recordings fail the test under `CI=true` (CI must test against real data);
/// elsewhere the test says why it does nothing and returns.
pub fn recordings_or_skip(test: &str) -> Option<PathBuf> {
    let dir = recordings_dir();
    let Some(problem) = recordings_problem(&dir) else {
        return Some(dir);
    };
    let msg = format!("{test}: {problem}");
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{msg}; CI=true, so this is a failure");
    }
    eprintln!("{msg}; not run");
    None
}

/// Every sensor-to-host stream among the recordings (`*.scip` except the `.tx.scip`
/// host-to-sensor sides), sorted by name. Panics unless they are exactly
/// [`SENSOR_STREAMS`]: a test that iterates them must not pass on fewer.
pub fn sensor_streams(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        name.ends_with(".scip") && !name.ends_with(".tx.scip")
    });
    files.sort();
    let names: Vec<&str> = files
        .iter()
        .filter_map(|p| p.file_name().and_then(|n| n.to_str()))
        .collect();
    assert_eq!(
        names,
        SENSOR_STREAMS,
        "the sensor streams in {}",
        dir.display()
    );
    files
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_or_partial_recordings_folder_is_a_problem() {
        let dir = std::env::temp_dir().join(format!("scip2can-rec-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let problem = recordings_problem(&dir).expect("empty folder");
        assert!(problem.contains("README.md"), "{problem}");
        for name in RECORDINGS {
            std::fs::write(dir.join(name), b"x").expect("write");
        }
        assert_eq!(recordings_problem(&dir), None);
        // An empty file is as bad as a missing one.
        std::fs::write(dir.join(SENSOR_STREAMS[0]), b"").expect("write");
        let problem = recordings_problem(&dir).expect("empty file");
        assert!(problem.contains(SENSOR_STREAMS[0]), "{problem}");
        std::fs::remove_dir_all(&dir).expect("clean up");
        assert!(recordings_problem(&dir).is_some());
    }

    #[test]
    fn the_real_recordings_are_complete() {
        if let Some(dir) = recordings_or_skip("complete") {
            assert_eq!(sensor_streams(&dir).len(), SENSOR_STREAMS.len());
        }
    }
}
