//! What the QEMU tests share: QEMU present (or the test skipped, and failed under
//! `CI=true`), and a firmware ELF built once per test run.

use std::path::PathBuf;
use std::sync::OnceLock;

use scip2can_host::emulate;

/// The QEMU binary the tests run.
pub const QEMU: &str = "qemu-system-arm";

/// The ELF `build` makes, built once into `cell`; `None` (the test is skipped) without
/// QEMU, a failure under `CI=true`.
pub fn firmware<E: std::fmt::Display>(
    cell: &'static OnceLock<Result<PathBuf, String>>,
    build: impl FnOnce() -> Result<PathBuf, E>,
) -> Option<PathBuf> {
    if !emulate::qemu_available(QEMU) {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "{QEMU} is missing (CI=true): apt-get install qemu-system-arm"
        );
        eprintln!("skipped: {QEMU} is not installed (apt-get install qemu-system-arm)");
        return None;
    }
    let elf = cell.get_or_init(|| build().map_err(|e| format!("{e:#}")));
    match elf {
        Ok(p) => Some(p.clone()),
        Err(e) => panic!("building the firmware: {e}"),
    }
}
