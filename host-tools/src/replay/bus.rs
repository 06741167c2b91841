//! A one-sender CAN bus in virtual time: each frame occupies the bus for its worst-case
//! length (bit stuffing included, `can_wire::bandwidth::frame_bits`), frames leave one
//! after the other, and the log time of a frame is the end of its transmission.

use can_wire::bandwidth::{frame_bits, BitRates};
use can_wire::{Frame, IdWindow, Kind};

/// What went over the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BusTotals {
    /// Frames sent.
    pub frames: u64,
    /// Frames by kind (index = `Kind as usize`); frames outside the window are not counted.
    pub by_kind: [u64; 8],
    /// Payload bytes.
    pub payload_bytes: u64,
    /// Worst-case bits at the nominal rate.
    pub nominal_bits: u64,
    /// Worst-case bits at the data rate (CAN FD with bit rate switch).
    pub data_bits: u64,
    /// Worst-case bus time, ns.
    pub busy_ns: u64,
    /// Worst-case bus time of the scan frames (headers, data, trailers, aborts), ns.
    pub scan_ns: u64,
}

/// The bus.
#[derive(Debug, Clone)]
pub struct Bus {
    rates: BitRates,
    extended: bool,
    window: IdWindow,
    free_at_ns: u64,
    totals: BusTotals,
}

impl Bus {
    /// An idle bus at `rates`; `window` names the frames' kinds in the totals.
    pub fn new(rates: BitRates, window: IdWindow) -> Self {
        Self {
            rates,
            extended: window.is_extended(),
            window,
            free_at_ns: 0,
            totals: BusTotals::default(),
        }
    }

    /// When the bus is next free, ns.
    pub fn free_at_ns(&self) -> u64 {
        self.free_at_ns
    }

    /// Sends `frame`, ready at `ready_ns`: it starts when both it and the bus are ready;
    /// returns the end of its transmission.
    pub fn transmit(&mut self, ready_ns: u64, frame: &Frame) -> u64 {
        let bits = frame_bits(frame.data().len(), frame.is_fd(), self.extended);
        let time = bits.time_ns(self.rates);
        let start = ready_ns.max(self.free_at_ns);
        self.free_at_ns = start + time;
        let t = &mut self.totals;
        t.frames += 1;
        if let Some((_, kind)) = self.window.classify(frame.id()) {
            if let Some(c) = t.by_kind.get_mut(kind as usize) {
                *c += 1;
            }
            if SCAN_KINDS.contains(&kind) {
                t.scan_ns += time;
            }
        }
        t.payload_bytes += frame.data().len() as u64;
        t.nominal_bits += u64::from(bits.nominal);
        t.data_bits += u64::from(bits.data);
        t.busy_ns += time;
        self.free_at_ns
    }

    /// The totals so far.
    pub fn totals(&self) -> &BusTotals {
        &self.totals
    }
}

/// The kinds that belong to scans (headers, data, trailer, abort).
pub const SCAN_KINDS: [Kind; 5] = [
    Kind::HeaderA,
    Kind::HeaderB,
    Kind::Data,
    Kind::Trailer,
    Kind::Abort,
];

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::{Id, StandardId};

    #[test]
    fn frames_queue_behind_each_other_at_worst_case_length() {
        let id = Id::Standard(StandardId::new(0x150).unwrap());
        let mut bus = Bus::new(BitRates::CLASSIC_1M, IdWindow::DEFAULT);
        let f = Frame::new(id, &[0; 8], false).unwrap();
        // 8 bytes, 11-bit ID: g + 8n = 98 bits, + 13 + floor(97 / 4) = 135 bits = 135 µs.
        assert_eq!(bus.transmit(1_000, &f), 136_000);
        assert_eq!(bus.transmit(1_000, &f), 271_000);
        assert_eq!(bus.transmit(1_000_000, &f), 1_135_000);
        let t = bus.totals();
        assert_eq!((t.frames, t.payload_bytes, t.busy_ns), (3, 24, 405_000));
        assert_eq!(t.nominal_bits, 405);
        // 0x150 = window 0x100 + node 0 + 0x10 * 5: data frames.
        assert_eq!(t.by_kind[Kind::Data as usize], 3);
        assert_eq!(t.scan_ns, 405_000);
    }
}
