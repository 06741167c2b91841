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

/// Build number reported on status page 3: the first 6 hex digits of the git commit the
/// firmware was built from (0 when built outside a git checkout), or the
/// `SCIP2CAN_BUILD` environment variable of the build (6 hex digits).
pub const FIRMWARE_BUILD: u32 = parse_u32(env!("SCIP2CAN_BUILD")) & 0xFF_FFFF;

const fn parse_u8(s: &str) -> u8 {
    let v = parse_u32(s);
    if v > 255 {
        255
    } else {
        v as u8
    }
}

/// A decimal number (digits only; anything else ends it), saturating.
const fn parse_u32(s: &str) -> u32 {
    let mut rest = s.as_bytes();
    let mut v: u32 = 0;
    while let [c @ b'0'..=b'9', tail @ ..] = rest {
        v = v
            .saturating_mul(10)
            .saturating_add(c.wrapping_sub(b'0') as u32);
        rest = tail;
    }
    v
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
    /// Frames handed to the board in this status period, classic and CAN FD, by data
    /// length code. Their bus time is worked out once per period ([`Health::close_period`]):
    /// per frame that would cost a 32-bit MCU a 64-bit division (about 150 instructions).
    pub period_frames: [[u32; 16]; 2],
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
            period_frames: [[0; 16]; 2],
            bus_permille: 0,
            last_status_ms: None,
            boot_ms: None,
        }
    }

    /// Accounts a frame handed to the bus.
    #[inline]
    pub fn sent(&mut self, frame: &Frame) {
        let len = frame.len();
        let dlc = if len <= 8 { len } else { fd_dlc(len) };
        if let Some(n) = self
            .period_frames
            .get_mut(usize::from(frame.is_fd()))
            .and_then(|by_dlc| by_dlc.get_mut(dlc))
        {
            *n = n.saturating_add(1);
        }
    }

    /// Closes a status period of `period_ms`: the bus load of the period at `rates`, the
    /// worst-case bus time of its frames (with 29-bit identifiers if `extended`).
    pub fn close_period(
        &mut self,
        period_ms: u64,
        rates: can_wire::bandwidth::BitRates,
        extended: bool,
    ) {
        let counts = core::mem::take(&mut self.period_frames);
        let (mut nominal, mut data) = (0u64, 0u64);
        for (fd, by_dlc) in [false, true].into_iter().zip(counts) {
            for (dlc, n) in by_dlc.into_iter().enumerate() {
                let bits = frame_bits(dlc_len(dlc), fd, extended);
                // Two 32-bit factors: the product fits 64 bits.
                nominal =
                    nominal.saturating_add(u64::from(n).wrapping_mul(u64::from(bits.nominal)));
                data = data.saturating_add(u64::from(n).wrapping_mul(u64::from(bits.data)));
            }
        }
        let ns = |bits: u64, rate: u32| {
            bits.saturating_mul(1_000_000_000)
                .div_ceil(u64::from(rate.max(1)))
        };
        let busy = ns(nominal, rates.nominal).saturating_add(ns(data, rates.data));
        let period_ns = period_ms.saturating_mul(1_000_000).max(1);
        self.bus_permille = (busy
            .saturating_mul(1000)
            .checked_div(period_ns)
            .unwrap_or(0))
        .min(1000) as u16;
    }

    fn bus_state(&self) -> BusState {
        BusState::from(self.bus_state)
    }
}

/// The data length code of a CAN FD length above 8 (9..=15; the next longer valid
/// length for any other).
fn fd_dlc(len: usize) -> usize {
    let at = can_wire::frame::FD_LENGTHS
        .iter()
        .position(|&l| usize::from(l) >= len)
        .unwrap_or(can_wire::frame::FD_LENGTHS.len().saturating_sub(1));
    // `at` is below the table's length (7).
    at.wrapping_add(9)
}

/// The data length of a data length code.
fn dlc_len(dlc: usize) -> usize {
    match dlc.checked_sub(9) {
        None => dlc,
        Some(i) => can_wire::frame::FD_LENGTHS
            .get(i)
            .map_or(64, |&l| usize::from(l)),
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
        SessionState::Resetting | SessionState::Backoff | SessionState::LinkDown => {
            BridgeState::Recovering
        }
    }
}

/// The model a `MODL` (PP, II) or `PROD` (VV) text names, if one of those SPEC 5 lists.
pub fn model_from_text(text: &[u8]) -> Option<SensorModel> {
    let has = |needle: &[u8]| text.windows(needle.len()).any(|w| w == needle);
    [
        (&b"URG-04LX"[..], SensorModel::Urg04lx),
        (b"UTM-30LX", SensorModel::Utm30lx),
        (b"UXM-30LX-E", SensorModel::Uxm30lxE),
        (b"UST-10LX", SensorModel::Ust10lx),
        (b"UST-20LX", SensorModel::Ust20lx),
    ]
    .into_iter()
    .find(|(name, _)| has(name))
    .map(|(_, model)| model)
}

/// The sensor model reported: the one the sensor's text named
/// ([`model_from_text`]), else a guess from the PP `MODL` family and DMAX.
pub fn sensor_model(params: &scip::SensorParams, named: Option<SensorModel>) -> SensorModel {
    if let Some(model) = named {
        return model;
    }
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
pub fn info_pages(params: &scip::SensorParams, named: Option<SensorModel>) -> [Status; 4] {
    let (major, minor, patch) = FIRMWARE_VERSION;
    let u16c = |v: Option<u32>| v.map_or(0, |v| u16::try_from(v).unwrap_or(u16::MAX));
    [
        Status::Firmware {
            protocol: can_wire::status::PROTOCOL_VERSION,
            major,
            minor,
            patch,
            build: FIRMWARE_BUILD,
        },
        Status::SensorRange {
            model: sensor_model(params, named),
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

#[cfg(test)]
mod tests {
    use super::*;
    use can_wire::bandwidth::{frame_bits, BitRates};
    use can_wire::frame::FD_LENGTHS;
    use embedded_can::{Id, StandardId};

    #[test]
    fn models_are_told_by_their_text() {
        // PP MODL / VV PROD texts as the sensors give them.
        let cases: [(&[u8], Option<SensorModel>); 7] = [
            (
                b"URG-04LX(Hokuyo Automatic Co.,Ltd.)",
                Some(SensorModel::Urg04lx),
            ),
            (
                b"SOKUIKI Sensor TOP-URG UTM-30LX",
                Some(SensorModel::Utm30lx),
            ),
            (
                b"UXM-30LX-E(Hokuyo Automatic Co.,Ltd.)",
                Some(SensorModel::Uxm30lxE),
            ),
            (b"UST-10LX", Some(SensorModel::Ust10lx)),
            (b"SOKUIKI Sensor UST-20LX", Some(SensorModel::Ust20lx)),
            (
                b"UST-20LX(Hokuyo Automatic Co.,Ltd.)",
                Some(SensorModel::Ust20lx),
            ),
            (b"foo", None),
        ];
        for (text, model) in cases {
            assert_eq!(model_from_text(text), model, "{text:?}");
        }
        // The named model wins over the guess from family and DMAX (a UST-20LX is an
        // Ethernet model with DMAX 60000, which alone would read as a UTM-30LX-EW).
        let params = scip::SensorParams {
            family: Some(scip::ModelFamily::Ethernet),
            dmax: Some(60_000),
            ..Default::default()
        };
        assert_eq!(sensor_model(&params, None), SensorModel::Utm30lx);
        assert_eq!(
            sensor_model(&params, Some(SensorModel::Ust20lx)),
            SensorModel::Ust20lx
        );
    }

    #[test]
    fn page_3_carries_the_build_number() {
        let [fw, ..] = info_pages(&scip::SensorParams::default(), None);
        let Status::Firmware { build, .. } = fw else {
            panic!("page 3 first");
        };
        assert_eq!(build, FIRMWARE_BUILD);
        // The commit the tests were built from, asked of git here (as the build script
        // did), unless the build was given a number.
        if std::env::var_os("SCIP2CAN_BUILD").is_none() {
            let git = std::process::Command::new("git")
                .args(["rev-parse", "--short=6", "HEAD"])
                .output()
                .ok()
                .filter(|o| o.status.success());
            let want = git.map_or(0, |o| {
                let text = String::from_utf8(o.stdout).unwrap();
                u32::from_str_radix(&text.trim()[..6], 16).unwrap()
            });
            assert_eq!(build, want);
            if want != 0 {
                assert_ne!(build, 0);
            }
        }
        assert_eq!(parse_u32("3372080"), 3_372_080);
        assert_eq!(parse_u32(""), 0);
    }

    #[test]
    fn data_length_codes_round_trip() {
        for len in 0..=8 {
            assert_eq!(dlc_len(len), len);
        }
        for (i, &l) in FD_LENGTHS.iter().enumerate() {
            assert_eq!(fd_dlc(usize::from(l)), 9 + i);
            assert_eq!(dlc_len(9 + i), usize::from(l));
        }
    }

    #[test]
    fn the_period_load_is_the_frames_worst_case_time() {
        let id = Id::Standard(StandardId::new(0x123).unwrap());
        let rates = BitRates {
            nominal: 500_000,
            data: 2_000_000,
        };
        let mut h = Health::new();
        let mut nominal = 0u64;
        let mut data = 0u64;
        let frames: Vec<Frame> = (0..=8)
            .map(|n| Frame::new(id, &[0xA5; 8][..n], false).unwrap())
            .chain(
                FD_LENGTHS
                    .iter()
                    .map(|&l| Frame::new(id, &[0x5A; 64][..usize::from(l)], true).unwrap()),
            )
            .cycle()
            .take(400)
            .collect();
        for f in &frames {
            h.sent(f);
            let bits = frame_bits(f.len(), f.is_fd(), false);
            nominal += u64::from(bits.nominal);
            data += u64::from(bits.data);
        }
        // Bus time, ns, rounded up per rate; over a period of 100 ms.
        let busy = (nominal * 1_000_000_000).div_ceil(500_000)
            + (data * 1_000_000_000).div_ceil(2_000_000);
        h.close_period(100, rates, false);
        assert_eq!(
            u64::from(h.bus_permille),
            (busy * 1000 / 100_000_000).min(1000)
        );
        assert!(h.bus_permille > 0);
        // The period starts over.
        h.close_period(100, rates, false);
        assert_eq!(h.bus_permille, 0);
    }
}
