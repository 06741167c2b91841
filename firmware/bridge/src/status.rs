//! The bridge's health: bus state and counters, loads, and the status (heartbeat) frames
//! built from them.

use can_wire::bandwidth::frame_bits;
use can_wire::{BridgeState, BusState, Frame, SensorModel, Status};

use crate::session::State as SessionState;

/// Firmware version reported on status page 3 (from the crate version).
pub const FIRMWARE_VERSION: (u8, u8, u8) = (
    parse_u8(env!("CARGO_PKG_VERSION_MAJOR")),
    parse_u8(env!("CARGO_PKG_VERSION_MINOR")),
    parse_u8(env!("CARGO_PKG_VERSION_PATCH")),
);

const fn parse_u8(s: &str) -> u8 {
    let b = s.as_bytes();
    let mut i = 0;
    let mut v: u32 = 0;
    while i < b.len() {
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    if v > 255 {
        255
    } else {
        v as u8
    }
}

/// Bus-side counters and loads, kept by the engine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Health {
    /// CAN bus errors reported by the board.
    pub bus_errors: u32,
    /// Bus-off events reported by the board.
    pub bus_off_events: u32,
    /// Frames that did not fit the transmit queue (status, answers).
    pub tx_overflows: u32,
    /// The CAN controller's error state.
    pub bus_state: BusStateCode,
    /// CPU load, permille, as the board measured it.
    pub cpu_permille: u16,
    /// Worst-case bus time of the frames handed to the board in this status period, ns.
    pub period_bus_ns: u64,
    /// Bus load of the last full status period, permille.
    pub bus_permille: u16,
    /// When the last status frames were queued, ms.
    pub last_status_ms: Option<u64>,
    /// When the engine started, ms.
    pub boot_ms: Option<u64>,
}

/// The bus error state as a plain code (0 active, 1 passive, 2 bus-off), so that
/// [`Health`] stays `Default`.
pub type BusStateCode = u8;

impl Health {
    /// Zero counters.
    pub const fn new() -> Self {
        Self {
            bus_errors: 0,
            bus_off_events: 0,
            tx_overflows: 0,
            bus_state: 0,
            cpu_permille: 0,
            period_bus_ns: 0,
            bus_permille: 0,
            last_status_ms: None,
            boot_ms: None,
        }
    }

    /// Accounts a frame handed to the bus.
    pub fn sent(&mut self, frame: &Frame, rates: can_wire::bandwidth::BitRates, extended: bool) {
        let bits = frame_bits(frame.data().len(), frame.is_fd(), extended);
        self.period_bus_ns = self.period_bus_ns.saturating_add(bits.time_ns(rates));
    }

    /// Closes a status period of `period_ms`: the bus load of the period.
    pub fn close_period(&mut self, period_ms: u64) {
        let ns = period_ms.saturating_mul(1_000_000).max(1);
        self.bus_permille = (self.period_bus_ns.saturating_mul(1000) / ns).min(1000) as u16;
        self.period_bus_ns = 0;
    }

    fn bus_state(&self) -> BusState {
        BusState::from(self.bus_state)
    }
}

/// The bridge state reported for a session state.
pub fn bridge_state(state: SessionState) -> BridgeState {
    match state {
        SessionState::Off => BridgeState::Idle,
        SessionState::Probe | SessionState::Switch => BridgeState::Detecting,
        SessionState::Version
        | SessionState::Parameters
        | SessionState::Info
        | SessionState::BitRate
        | SessionState::Start
        | SessionState::SyncStop
        | SessionState::SyncEnter
        | SessionState::SyncRead
        | SessionState::SyncLeave
        | SessionState::Stopping => BridgeState::Configuring,
        SessionState::Streaming => BridgeState::Streaming,
        SessionState::Resetting | SessionState::Backoff => BridgeState::Recovering,
    }
}

/// The sensor model reported for a PP `MODL` family and DMAX.
pub fn sensor_model(params: &scip::SensorParams) -> SensorModel {
    match (params.family, params.dmax) {
        (Some(scip::ModelFamily::Urg04lx), _) => SensorModel::Urg04lx,
        (Some(scip::ModelFamily::Utm), Some(100_000)) => SensorModel::Uxm30lxE,
        (Some(scip::ModelFamily::Utm), _) => SensorModel::Utm30lx,
        (Some(scip::ModelFamily::Ethernet), Some(100_000)) => SensorModel::Uxm30lxE,
        (Some(scip::ModelFamily::Ethernet), Some(60_000)) => SensorModel::Utm30lx,
        (Some(scip::ModelFamily::Ethernet), _) => SensorModel::Ust10lx,
        _ => SensorModel::Unidentified,
    }
}

fn w16(v: u32) -> u16 {
    (v & 0xFFFF) as u16
}

/// The three periodic pages: heartbeat, sensor counters, bus counters.
pub fn periodic_pages(
    health: &Health,
    state: BridgeState,
    now_ms: u64,
    sum_errors: u32,
    resyncs: u32,
    dropped_scans: u32,
    recoveries: u32,
) -> [Status; 3] {
    let uptime_ms = now_ms.saturating_sub(health.boot_ms.unwrap_or(now_ms));
    [
        Status::Heartbeat {
            state,
            cpu_load: (health.cpu_permille / 5).min(200) as u8,
            bus_load: (health.bus_permille / 5).min(200) as u8,
            uptime_s: u32::try_from(uptime_ms / 1000).unwrap_or(u32::MAX),
        },
        Status::SensorCounters {
            sum_errors: w16(sum_errors),
            resyncs: w16(resyncs),
            dropped_scans: w16(dropped_scans),
            recoveries: (recoveries & 0xFF) as u8,
        },
        Status::BusCounters {
            bus_errors: w16(health.bus_errors),
            bus_off_events: w16(health.bus_off_events),
            tx_overflows: w16(health.tx_overflows),
            error_state: health.bus_state(),
        },
    ]
}

/// The four sensor-information pages (firmware, range, steps, timing).
pub fn info_pages(params: &scip::SensorParams) -> [Status; 4] {
    let (major, minor, patch) = FIRMWARE_VERSION;
    let u16c = |v: Option<u32>| v.map_or(0, |v| u16::try_from(v).unwrap_or(u16::MAX));
    [
        Status::Firmware {
            protocol: can_wire::status::PROTOCOL_VERSION,
            major,
            minor,
            patch,
            build: 0,
        },
        Status::SensorRange {
            model: sensor_model(params),
            dmin_mm: u16c(params.dmin),
            dmax_mm: params.dmax.unwrap_or(0).min(0xFF_FFFF),
        },
        Status::SensorSteps {
            ares: u16c(params.ares),
            amin: u16c(params.amin),
            amax: u16c(params.amax),
        },
        Status::SensorTiming {
            afrt: u16c(params.afrt),
            scan_rpm: u16c(params.scan_rpm),
        },
    ]
}
