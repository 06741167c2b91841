//! Building the QEMU firmware in the board workspace, and finding its ELF.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use anyhow::{bail, Context};

use super::{FIRMWARE, FIRMWARE_ETH};

/// The board workspace, from this crate's folder.
pub fn boards_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/boards")
}

/// Where `cargo build --release` in the board workspace puts the firmware (its own
/// target folder, whatever `CARGO_TARGET_DIR` says: see [`build_firmware`]).
pub fn default_firmware() -> PathBuf {
    boards_dir()
        .join("target/thumbv7em-none-eabihf/release")
        .join(FIRMWARE)
}

/// The command that builds the firmware, for messages.
pub const BUILD_COMMAND: &str =
    "(cd firmware/boards && CARGO_TARGET_DIR=target cargo build --release -p scip2can-qemu)";

/// Builds the firmware in the board workspace, into that workspace's own `target`
/// folder (a nested cargo with its own target folder cannot wait on the lock of the
/// cargo that runs us). Returns the ELF's path.
pub fn build_firmware() -> anyhow::Result<PathBuf> {
    build_in_boards(&["-p", FIRMWARE], "the firmware", BUILD_COMMAND)?;
    Ok(default_firmware())
}

/// Runs `cargo build --release ARGS` in the board workspace, into its own `target`
/// folder; on failure says that building `what` failed and which command to try.
pub fn build_in_boards(args: &[&str], what: &str, hint: &str) -> anyhow::Result<()> {
    let dir = boards_dir();
    let status = Process::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args(["build", "--release"])
        .args(args)
        .current_dir(&dir)
        .env("CARGO_TARGET_DIR", dir.join("target"))
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_BUILD_TARGET")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .status()
        .with_context(|| format!("running cargo in {}", dir.display()))?;
    if !status.success() {
        bail!("building {what} failed; try {hint}");
    }
    Ok(())
}

/// [`build_firmware`], returning the Ethernet binary's path.
pub fn build_firmware_eth() -> anyhow::Result<PathBuf> {
    build_firmware()?;
    Ok(default_firmware().with_file_name(FIRMWARE_ETH))
}

/// The ELF to run: `path` if given (it must exist), else the board workspace's release
/// build, brought up to date first (cargo does nothing when it is; a stale ELF of an
/// older checkout is never run).
pub fn firmware(path: Option<&Path>) -> anyhow::Result<PathBuf> {
    match path {
        Some(p) if p.exists() => Ok(p.to_owned()),
        Some(p) => bail!(
            "firmware {} not found; build it with {BUILD_COMMAND}",
            p.display()
        ),
        None => build_firmware(),
    }
}
