#!/usr/bin/env bash
# The rustc wrapper of the board workspace (`build.rustc-wrapper` in .cargo/config.toml):
# runs the compiler (with clippy, clippy-driver and then rustc) with the source paths of
# the crate registry and of this repository written short:
#   <cargo home>/registry/src/<index>/embassy-stm32-0.6.0/src/can/fdcan.rs -> embassy-stm32-0.6.0/src/can/fdcan.rs
#   <this repository>/firmware/can-wire/src/frame.rs                       -> firmware/can-wire/src/frame.rs
# Every place that can panic keeps its file name in flash, and the registry paths are
# long: written short they take about 1.3 KB less of the STM32 boards' 96 KiB. The images
# also no longer depend on where the checkout and the cargo home are (the same sizes.txt
# on every machine). Debug info carries the short paths too. A RUSTC_WRAPPER set in the
# environment replaces this wrapper (the images are then that much bigger).
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cargo_home=${CARGO_HOME:-$HOME/.cargo}
remap=("--remap-path-prefix=$repo/=")
for index in "$cargo_home"/registry/src/*/ "$cargo_home"/git/checkouts/*/*/; do
    [ -d "$index" ] && remap+=("--remap-path-prefix=$index=")
done
# After the compiler's own arguments: with clippy, "$1" is clippy-driver and "$2" rustc.
exec "$@" "${remap[@]}"
