//! The bridge settings of the STM32 boards and the timing of their main loop.
//!
//! Everything here is a compile-time default; at run time the pipeline, the point
//! encoding and the frame size change through CAN control frames (handled by the core).

use bridge::engine::{BridgeConfig, BridgeError};
use bridge::governor::Budget;
use bridge::session::SessionConfig;
use can_wire::bandwidth::BitRates;
use can_wire::{Encoding, FrameFormat, IdWindow};

/// Capacity of the CAN transmit queue, in frames.
///
/// The governor admits a scan only when the queue, plus what the bus drains while the
/// scan is still arriving on the UART, can take all of its frames; the UART is far
/// slower than the bus, so a small queue suffices. What it must absorb is one UART
/// chunk's burst ([`UART_CHUNK`] bytes ≈ 40 points ≈ 14 classic frames) plus status
/// pages and control answers, which go ahead of scan frames. 32 frames of 76 bytes
/// each keep the bridge at about 3.5 KiB.
pub const QUEUE: usize = 32;

/// The bridge of the STM32 boards.
pub type Bridge = bridge::engine::Bridge<QUEUE>;

/// The sensor's UART bit rate at power-up: a URG-04LX on RS-232 starts at 19 200 bit/s
/// (the session restores it after every sensor reset).
pub const SENSOR_POWER_UP_BIT_RATE: u32 = 19_200;

/// The bit rate the session switches to with `SS` once the sensor is identified:
/// 250 000 bit/s, the fastest an ordinary RS-232 transceiver (MAX3232 class) is
/// specified for, and enough for a URG-04LX's full stream (about 23 kB/s).
pub const SENSOR_BIT_RATE: u32 = 250_000;

/// The sensor link's speed on Ethernet, bit/s: [`bridge::link::NETWORK_BIT_RATE`].
pub const ETHERNET_BIT_RATE: u32 = bridge::link::NETWORK_BIT_RATE;

/// The bridge's node number in the default identifier window (0x100).
pub const NODE: u8 = 0;

/// Period of the heartbeat and counter status frames, ms.
pub const STATUS_PERIOD_MS: u32 = 1000;

/// The bridge's share of the bus, permille: half, leaving the rest to the robot.
pub const BUS_SHARE_PERMILLE: u16 = 500;

/// Period of the main loop's tick (session timeouts, status, watchdog, bus state), ms.
pub const TICK_MS: u64 = 5;

/// Bus-off recovery waits this long after entering bus-off, and as long again between
/// two attempts, ms.
pub const BUS_OFF_RETRY_MS: u64 = 100;

/// Independent watchdog timeout, ms: the tick feeds it, so it bites when the main loop
/// stalls for this long (100 ticks).
pub const WATCHDOG_TIMEOUT_MS: u32 = 500;

/// Window over which the CPU load is averaged, ms.
pub const LOAD_WINDOW_MS: u64 = 1000;

/// Size of the UART DMA ring buffer, bytes: 20 ms of data at [`SENSOR_BIT_RATE`].
pub const UART_RING: usize = 512;

/// Bytes taken from the ring buffer per read (the buffer's read wakes at half and full,
/// and at an idle line).
pub const UART_CHUNK: usize = 128;

// The ring buffer's read wakes at half full, so a chunk fits in a half; and the ring
// holds 20 ms at the streaming rate (10 bits per byte).
const _: () = assert!(UART_CHUNK <= UART_RING / 2);
const _: () = assert!(UART_RING as u32 >= SENSOR_BIT_RATE / 10 / 50);

/// The CAN bus a board is wired to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanBus {
    /// Nominal (and, for CAN FD, data phase) bit rates.
    pub rates: BitRates,
    /// Frame format at start-up.
    pub format: FrameFormat,
    /// Whether the controller can send CAN FD frames (a control frame may switch to FD).
    pub fd_capable: bool,
}

impl CanBus {
    /// Classic CAN at 1 Mbit/s (bxCAN).
    pub const CLASSIC_1M: CanBus = CanBus {
        rates: BitRates::CLASSIC_1M,
        format: FrameFormat::Classic,
        fd_capable: false,
    };

    /// CAN FD, 1 Mbit/s arbitration and 5 Mbit/s data phase, 64-byte frames (FDCAN).
    pub const FD_1M_5M: CanBus = CanBus {
        rates: BitRates::FD_1M_5M,
        format: FrameFormat::FD64,
        fd_capable: true,
    };
}

/// The scan encoding: the lossless predictive coding (SPEC 4.2), millimetre-exact and
/// about 6 bits per point on real scans; a control frame (opcode 0x20) selects another.
pub const ENCODING: Encoding = Encoding {
    distance: can_wire::DistanceEncoding::Lossless,
    intensity: can_wire::IntensityEncoding::I16,
    unit_exp: 0,
};

/// The bridge configuration of a board on `bus`.
pub fn bridge_config(bus: CanBus) -> Result<BridgeConfig, BridgeError> {
    let base = BridgeConfig::new(node_ids()?, bus.format);
    Ok(BridgeConfig {
        session: SessionConfig {
            bit_rate: Some(SENSOR_BIT_RATE),
            initial_bit_rate: SENSOR_POWER_UP_BIT_RATE,
            ..base.session
        },
        encoding: ENCODING,
        budget: Budget {
            rates: bus.rates,
            share_permille: BUS_SHARE_PERMILLE,
            ..base.budget
        },
        uart_bit_rate: SENSOR_BIT_RATE,
        status_period_ms: STATUS_PERIOD_MS,
        fd_capable: bus.fd_capable,
        ..base
    })
}

/// The bridge of a board on `bus`, with [`bridge_config`]; its session is not started.
/// It estimates scan times in the board's clock (`time_estimated` headers) when built
/// with the `time-estimate` feature.
pub fn bridge(bus: CanBus) -> Result<Bridge, BridgeError> {
    #[cfg_attr(not(feature = "time-estimate"), allow(unused_mut))]
    let mut bridge = Bridge::new(bridge_config(bus)?);
    #[cfg(feature = "time-estimate")]
    if let Ok(b) = bridge.as_mut() {
        b.set_time_estimation(true);
    }
    bridge
}

/// The bridge configuration of a board whose sensor is on Ethernet (a TCP connection to
/// a UST-10LX/20LX, UTM-30LX-EW, ...): as [`bridge_config`], but no SCIP bit-rate steps
/// (`SS` is for serial links; the session's `bit_rate` is `None`), the link's speed
/// is [`ETHERNET_BIT_RATE`] and the link a TCP stream ([`bridge::link::LinkKind::Tcp`]:
/// the session starts when the board reports the connection up):
/// [`BridgeConfig::on_network`].
pub fn ethernet_bridge_config(bus: CanBus) -> Result<BridgeConfig, BridgeError> {
    Ok(bridge_config(bus)?.on_network())
}

/// The bridge of an Ethernet board on `bus`, with [`ethernet_bridge_config`]; its session
/// is not started.
pub fn ethernet_bridge(bus: CanBus) -> Result<Bridge, BridgeError> {
    #[cfg_attr(not(feature = "time-estimate"), allow(unused_mut))]
    let mut bridge = Bridge::new(ethernet_bridge_config(bus)?);
    #[cfg(feature = "time-estimate")]
    if let Ok(b) = bridge.as_mut() {
        b.set_time_estimation(true);
    }
    bridge
}

/// The identifiers a board's CAN acceptance filter must let through: this bridge's
/// control frames and, when the bridge follows a time master (SPEC 9), the master's SYNC
/// and FOLLOW-UP identifier. Without a time master the control identifier fills both
/// entries, so a filter of two entries always takes both.
pub fn accepted_ids(bridge: &Bridge) -> [embedded_can::Id; 2] {
    let control = bridge.config().ids.id(can_wire::Kind::Control);
    [control, bridge.time_id().unwrap_or(control)]
}

/// The identifiers of this bridge: node [`NODE`] of the default window.
pub fn node_ids() -> Result<can_wire::NodeIds, BridgeError> {
    IdWindow::DEFAULT.node(NODE).map_err(BridgeError::Wire)
}

#[cfg(test)]
mod tests {
    use super::*;
    use can_wire::Kind;

    #[test]
    fn both_buses_give_a_valid_bridge() {
        for bus in [CanBus::CLASSIC_1M, CanBus::FD_1M_5M] {
            let config = bridge_config(bus).expect("config");
            assert_eq!(config.budget.format, bus.format);
            assert_eq!(config.fd_capable, bus.fd_capable);
            assert_eq!(config.session.initial_bit_rate, 19_200);
            assert_eq!(config.session.bit_rate, Some(250_000));
            assert!(bridge(bus).is_ok(), "{bus:?}");
        }
    }

    #[test]
    fn an_ethernet_bridge_has_no_bit_rate_steps() {
        let config = ethernet_bridge_config(CanBus::FD_1M_5M).expect("config");
        assert_eq!(config.session.bit_rate, None);
        assert_eq!(config.uart_bit_rate, 100_000_000);
        assert!(config.fd_capable);
        assert!(ethernet_bridge(CanBus::FD_1M_5M).is_ok());
    }

    #[test]
    fn sensor_rates_are_scip_rates() {
        assert!(scip::BIT_RATES.contains(&SENSOR_POWER_UP_BIT_RATE));
        assert!(scip::BIT_RATES.contains(&SENSOR_BIT_RATE));
    }

    /// Time sync worked on the QEMU board (which filters nothing) but not on the STM32
    /// boards, whose filters took only the control identifier: the SYNC / FOLLOW-UP pair
    /// of a master (SPEC 9) never reached the bridge.
    #[test]
    fn the_filters_let_the_time_masters_frames_through() {
        use can_wire::timesync::DEFAULT_TIME_ID;
        use can_wire::TimeFrame;
        for bus in [CanBus::CLASSIC_1M, CanBus::FD_1M_5M] {
            let mut b = bridge(bus).expect("bridge");
            let ids = accepted_ids(&b);
            let time = embedded_can::StandardId::new(DEFAULT_TIME_ID).expect("11 bits");
            assert!(ids.contains(&embedded_can::Id::Standard(time)), "{ids:?}");
            assert!(ids.contains(&node_ids().expect("node").id(Kind::Control)));
            // A SYNC and its FOLLOW-UP on the accepted identifier give a mapping to the
            // master's clock: the master sent at 1 000 000 µs, the bridge took the SYNC at
            // its 5 000 µs, so bridge 6 000 µs is master 1 001 000 µs.
            let id = ids[1];
            let sync = TimeFrame::Sync { seq: 3 }.to_frame(id).expect("sync");
            let follow = TimeFrame::FollowUp {
                seq: 3,
                master_us: 1_000_000,
            }
            .to_frame(id)
            .expect("follow-up");
            b.on_can_frame_at(&sync, 5_000);
            b.on_can_frame_at(&follow, 5_400);
            assert_eq!(b.to_master(6_000), Some(1_001_000), "{bus:?}");
        }
    }

    #[test]
    fn control_id_is_base_plus_node() {
        // Default window 0x100, node 0: control 0x100, answers 0x110, status 0x120.
        let ids = node_ids().expect("node 0");
        assert_eq!(ids.base(), 0x100);
        let raw = |k| match ids.id(k) {
            embedded_can::Id::Standard(s) => u32::from(s.as_raw()),
            embedded_can::Id::Extended(e) => e.as_raw(),
        };
        assert_eq!(raw(Kind::Control), 0x100);
        assert_eq!(raw(Kind::ControlAnswer), 0x110);
        assert_eq!(raw(Kind::Status), 0x120);
    }
}
