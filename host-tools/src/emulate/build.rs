//! Building the QEMU firmware in the board workspace, and finding its ELF.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use anyhow::{bail, Context};

use super::{FIRMWARE, FIRMWARE_ETH};

/// The board workspace: that of the checkout the current directory lies in, else that
/// of the checkout this binary was built from (so a binary copied into, or run from,
/// another checkout builds and runs that checkout's firmware, not its own).
pub fn boards_dir() -> PathBuf {
    std::env::current_dir()
        .ok()
        .and_then(|dir| checkout_of(&dir))
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".."))
        .join("firmware/boards")
}

/// The root of the scip2can checkout that `dir` lies in: the nearest folder holding
/// both the board workspace and the host tools.
fn checkout_of(dir: &Path) -> Option<PathBuf> {
    dir.ancestors()
        .find(|a| {
            a.join("firmware/boards/Cargo.toml").is_file()
                && a.join("host-tools/Cargo.toml").is_file()
        })
        .map(Path::to_path_buf)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_checkout_is_found_from_any_folder_inside_it() {
        let root = std::env::temp_dir().join(format!("scip2can-checkout-{}", std::process::id()));
        let deep = root.join("tests/it");
        std::fs::create_dir_all(&deep).unwrap();
        // Not a checkout yet: only the board workspace.
        std::fs::create_dir_all(root.join("firmware/boards")).unwrap();
        std::fs::write(root.join("firmware/boards/Cargo.toml"), "").unwrap();
        assert_eq!(checkout_of(&deep), None);
        std::fs::create_dir_all(root.join("host-tools")).unwrap();
        std::fs::write(root.join("host-tools/Cargo.toml"), "").unwrap();
        assert_eq!(checkout_of(&deep), Some(root.clone()));
        assert_eq!(checkout_of(&root), Some(root.clone()));
        std::fs::remove_dir_all(&root).unwrap();
    }
}
