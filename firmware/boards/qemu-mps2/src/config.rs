//! The bridge settings of the emulated board.

use bridge::engine::BridgeConfig;
use bridge::session::SessionConfig;
use can_wire::{Encoding, FrameFormat, IdWindow, NodeIds};

/// Capacity of the CAN transmit queue, in frames (76 bytes each).
pub const QUEUE: usize = 64;

/// Bit rate of both UARTs (QEMU ignores it; it still tells the governor how
/// long a scan takes to arrive).
pub const BAUD: u32 = 115_200;

/// Watchdog time-out: the main loop feeds it every millisecond.
pub const WATCHDOG_MS: u32 = 500;

/// The node number of this bridge in the default identifier window (0x100).
pub const NODE: u8 = 0;

/// What `V` answers: hardware 01, software 00.
pub const SLCAN_VERSION: [u8; 4] = *b"0100";

/// What `N` answers.
pub const SLCAN_SERIAL: [u8; 4] = *b"QEMU";

/// The scan encoding: the lossless predictive coding (SPEC 4.2), millimetre-exact.
pub const ENCODING: Encoding = Encoding {
    distance: can_wire::DistanceEncoding::Lossless,
    intensity: can_wire::IntensityEncoding::I16,
    unit_exp: 0,
};

/// The bridge: a full-range distance stream (`MD`, steps AMIN..AMAX learned from
/// `PP`, 0..1080 until then; no `SS`, QEMU's UART has no bit rate), the lossless coding
/// ([`ENCODING`]), classic CAN at 1 Mbit/s of which the bridge may use all (the
/// emulated bus has no other node), status pages every second. The SLCAN port can
/// carry CAN FD, so a control frame may switch to FD frames.
pub fn bridge() -> Option<BridgeConfig> {
    bridge_with(ENCODING)
}

/// [`bridge()`] with another scan encoding.
pub fn bridge_with(encoding: Encoding) -> Option<BridgeConfig> {
    let ids: NodeIds = IdWindow::DEFAULT.node(NODE).ok()?;
    Some(BridgeConfig {
        session: SessionConfig {
            initial_bit_rate: BAUD,
            ..SessionConfig::default()
        },
        encoding,
        uart_bit_rate: BAUD,
        // The SLCAN port carries CAN FD although the bus starts classic.
        fd_capable: true,
        ..BridgeConfig::new(ids, FrameFormat::Classic)
    })
}
