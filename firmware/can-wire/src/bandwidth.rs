//! Worst-case bus time of frames and scans (SPEC section 8).

use crate::data::data_frame_len;
use crate::encoder::FrameFormat;
use crate::encoding::Encoding;
use crate::frame::padded_len;
use crate::header::HEADER_LEN;
use crate::trailer::TRAILER_LEN;

/// Bit rates: nominal (arbitration) and data phase, bit/s. Classic CAN uses `nominal`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BitRates {
    /// Arbitration (and classic CAN) bit rate.
    pub nominal: u32,
    /// CAN FD data phase bit rate.
    pub data: u32,
}

impl BitRates {
    /// Classic CAN at 1 Mbit/s.
    pub const CLASSIC_1M: BitRates = BitRates {
        nominal: 1_000_000,
        data: 1_000_000,
    };
    /// CAN FD, 1 Mbit/s arbitration, 2 Mbit/s data.
    pub const FD_1M_2M: BitRates = BitRates {
        nominal: 1_000_000,
        data: 2_000_000,
    };
    /// CAN FD, 1 Mbit/s arbitration, 5 Mbit/s data.
    pub const FD_1M_5M: BitRates = BitRates {
        nominal: 1_000_000,
        data: 5_000_000,
    };
}

/// Worst-case bits of one frame, split by phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameBits {
    /// Bits at the nominal rate (all of a classic frame), incl. interframe space.
    pub nominal: u32,
    /// Bits at the data rate (CAN FD with bit rate switch; 0 for classic).
    pub data: u32,
}

impl FrameBits {
    /// Time on the bus in nanoseconds at `rates`.
    #[inline(never)]
    pub fn time_ns(&self, rates: BitRates) -> u64 {
        let ns = |bits: u32, rate: u32| {
            (u64::from(bits) * 1_000_000_000).div_ceil(u64::from(rate.max(1)))
        };
        ns(self.nominal, rates.nominal).saturating_add(if self.data > 0 {
            ns(self.data, rates.data)
        } else {
            0
        })
    }
}

/// Worst-case bits of a classic CAN frame with `len` (0..=8) data bytes:
/// `g + 8n + 13 + floor((g + 8n - 1) / 4)`, `g` = 34 (11-bit ID) or 54 (29-bit ID).
pub const fn classic_frame_bits(len: usize, extended: bool) -> FrameBits {
    let g = if extended { 54 } else { 34 };
    // Bit counts saturate (no frame comes near); `body` is at least 34.
    let body = (len as u32).saturating_mul(8).saturating_add(g);
    FrameBits {
        nominal: body
            .saturating_add(13)
            .saturating_add(body.wrapping_sub(1) / 4),
        data: 0,
    }
}

/// Worst-case bits of a CAN FD frame with bit rate switching and `len` data bytes (a
/// valid FD length), see SPEC section 8.
pub const fn fd_frame_bits(len: usize, extended: bool) -> FrameBits {
    let a: u32 = if extended { 36 } else { 17 };
    let n = len as u32;
    let crc = if len <= 16 { 17 } else { 21 };
    // `a` is 17 or 36 and `crc` 17 or 21: only the data length can be large, and bit
    // counts saturate (no frame comes near).
    let arb_stuff = a.wrapping_sub(1) / 4;
    let data_bits = n.saturating_mul(8);
    let total_stuff = a.wrapping_add(4).saturating_add(data_bits) / 4;
    FrameBits {
        nominal: a.wrapping_add(13).wrapping_add(arb_stuff),
        data: data_bits
            .saturating_add(5)
            .saturating_add(total_stuff.saturating_sub(arb_stuff))
            .saturating_add(4u32.wrapping_add(crc))
            .saturating_add(4u32.wrapping_add(crc).div_ceil(4)),
    }
}

/// Worst-case bits of a frame of `len` bytes in `format`.
pub const fn frame_bits(len: usize, fd: bool, extended: bool) -> FrameBits {
    if fd {
        fd_frame_bits(len, extended)
    } else {
        classic_frame_bits(len, extended)
    }
}

/// What one scan costs on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanCost {
    /// Bits per point (distance + intensity).
    pub bits_per_point: u32,
    /// Points in a full data frame.
    pub points_per_frame: u32,
    /// Data frames per scan.
    pub data_frames: u32,
    /// All frames per scan (2 headers + data + trailer).
    pub frames: u32,
    /// Worst-case bits per scan at the nominal rate.
    pub nominal_bits: u32,
    /// Worst-case bits per scan at the data rate.
    pub data_bits: u32,
    /// Worst-case time per scan, ns.
    pub time_ns: u64,
}

impl ScanCost {
    /// Bus load in parts per million at `scans_per_s_milli` / 1000 scans per second.
    pub fn load_ppm(&self, scans_per_s_milli: u32) -> u64 {
        // time_ns * rate / 1e9 * 1e6 = time_ns * rate_milli / 1e6
        self.time_ns
            .saturating_mul(u64::from(scans_per_s_milli))
            .div_ceil(1_000_000)
    }
}

/// Worst-case cost of a scan of `points` points in `encoding`, sent in `format` (for the
/// lossless coding: [`lossless_cost`] at its worst case).
pub fn scan_cost(
    points: u16,
    encoding: &Encoding,
    format: FrameFormat,
    extended: bool,
    rates: BitRates,
) -> ScanCost {
    if encoding.distance.is_lossless() {
        return lossless_cost(points, encoding, None, format, extended, rates);
    }
    let fd = format.is_fd();
    let max_len = format.max_len();
    let per_frame = encoding.capacity(max_len).max(1);
    let points = usize::from(points);
    // `per_frame` is at least 1.
    let full = points.checked_div(per_frame).unwrap_or(points);
    let rest = points.checked_rem(per_frame).unwrap_or(0);
    let mut nominal = 0u32;
    let mut data = 0u32;
    let mut add = |len: usize, count: u32| {
        let b = frame_bits(len, fd, extended);
        nominal = nominal.saturating_add(b.nominal.saturating_mul(count));
        data = data.saturating_add(b.data.saturating_mul(count));
    };
    add(HEADER_LEN, 2);
    add(TRAILER_LEN, 1);
    let full_len = data_frame_len(encoding, per_frame).unwrap_or(max_len);
    add(full_len, full as u32);
    if rest > 0 {
        add(data_frame_len(encoding, rest).unwrap_or(max_len), 1);
    }
    // At most 65535 points: no wrap.
    let data_frames = full.wrapping_add(usize::from(rest > 0)) as u32;
    let bits = FrameBits { nominal, data };
    ScanCost {
        bits_per_point: encoding.bits_per_point(),
        points_per_frame: per_frame as u32,
        data_frames,
        frames: data_frames.saturating_add(3),
        nominal_bits: nominal,
        data_bits: data,
        time_ns: bits.time_ns(rates),
    }
}

/// Bits of one segment of `n` points in the lossless coding (SPEC 4.2.3) at worst: the
/// header, an anchor and a verbatim block of 20-bit values per block for each of
/// `channels` channels, the padding and the CRC.
pub const fn lossless_worst_segment_bits(n: u32, channels: u32) -> u32 {
    use crate::lossless::{BLOCK_POINTS, MODE_BITS, VALUE_BITS, WIDTH_BITS};
    let blocks = n.saturating_sub(1).div_ceil(BLOCK_POINTS as u32);
    // Bit counts saturate (no segment comes near).
    let per_channel = (WIDTH_BITS + VALUE_BITS)
        .saturating_add(blocks.saturating_mul(MODE_BITS + WIDTH_BITS))
        .saturating_add(n.saturating_sub(1).saturating_mul(VALUE_BITS));
    crate::lossless::SEGMENT_HEADER_BITS
        .saturating_add(channels.saturating_mul(per_channel))
        .saturating_add(7 + 16)
}

/// Cost of a lossless scan of `points` points whose segments take `bits_x16 / 16` bits
/// per point on average (headers, anchors, padding and CRCs included), or, with
/// `bits_x16 = None`, the worst case (every block verbatim at 20 bits per value).
pub fn lossless_cost(
    points: u16,
    encoding: &Encoding,
    bits_x16: Option<u32>,
    format: FrameFormat,
    extended: bool,
    rates: BitRates,
) -> ScanCost {
    use crate::lossless::SEGMENT_POINTS;
    let fd = format.is_fd();
    let payload = format.max_len().saturating_sub(1).max(1) as u32;
    let channels = 1u32.wrapping_add(u32::from(encoding.intensity.is_present()));
    let mut nominal = 0u32;
    let mut data = 0u32;
    let mut add = |len: usize, count: u32| {
        let b = frame_bits(len, fd, extended);
        nominal = nominal.saturating_add(b.nominal.saturating_mul(count));
        data = data.saturating_add(b.data.saturating_mul(count));
    };
    add(HEADER_LEN, 2);
    add(TRAILER_LEN, 1);
    let mut data_frames = 0u32;
    let mut total_bits = 0u64;
    let n_points = usize::from(points);
    // Every segment but the last has SEGMENT_POINTS points and the same cost: the full
    // segments are worked out once (32-bit arithmetic: the MCU divides those in one
    // instruction), then the last, shorter one if any.
    let full = (n_points / SEGMENT_POINTS) as u32; // at most 512
    let rest = (n_points % SEGMENT_POINTS) as u32;
    for (n, count) in [(SEGMENT_POINTS as u32, full), (rest, u32::from(rest > 0))] {
        if count == 0 {
            continue;
        }
        let bits = match bits_x16 {
            Some(b) => u64::from(n).saturating_mul(u64::from(b)) / 16,
            None => u64::from(lossless_worst_segment_bits(n, channels)),
        };
        total_bits = total_bits.saturating_add(bits.saturating_mul(u64::from(count)));
        // Saturated to 32 bits (only an absurd estimate comes near).
        let bytes = u32::try_from(bits.div_ceil(8)).unwrap_or(u32::MAX).max(1);
        // At least one frame (`bytes` >= 1), and all but the last full: the last holds
        // 1..=payload bytes.
        let frames = bytes.div_ceil(payload);
        let before_last = frames.wrapping_sub(1);
        let last = bytes.wrapping_sub(before_last.wrapping_mul(payload));
        add(format.max_len(), before_last.saturating_mul(count));
        add(
            padded_len((last as usize).wrapping_add(1)).unwrap_or(format.max_len()),
            count,
        );
        data_frames = data_frames.saturating_add(frames.saturating_mul(count));
    }
    let bits = FrameBits { nominal, data };
    ScanCost {
        // A divisor of 0 counts as 1.
        bits_per_point: total_bits
            .checked_div(n_points as u64)
            .unwrap_or(total_bits) as u32,
        points_per_frame: u64::from(points)
            .checked_div(u64::from(data_frames))
            .unwrap_or(u64::from(points)) as u32,
        data_frames,
        frames: data_frames.saturating_add(3),
        nominal_bits: nominal,
        data_bits: data,
        time_ns: bits.time_ns(rates),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoding::{DistanceEncoding, IntensityEncoding};

    #[test]
    fn lossless_costs() {
        let dl = Encoding {
            distance: DistanceEncoding::Lossless,
            intensity: IntensityEncoding::None,
            unit_exp: 0,
        };
        // 128 points at 7 bits: 112 bytes, 16 classic frames of 7 stream bytes.
        let c = lossless_cost(
            128,
            &dl,
            Some(7 * 16),
            FrameFormat::Classic,
            false,
            BitRates::CLASSIC_1M,
        );
        assert_eq!((c.data_frames, c.frames), (16, 19));
        assert_eq!(
            c.nominal_bits,
            18 * 135 + classic_frame_bits(8, false).nominal
        );
        // Worst case of one point: 9 + 25 + 7 + 16 bits = 57 bits, 8 bytes: 2 frames.
        assert_eq!(lossless_worst_segment_bits(1, 1), 57);
        let w = lossless_cost(
            1,
            &dl,
            None,
            FrameFormat::Classic,
            false,
            BitRates::CLASSIC_1M,
        );
        assert_eq!(w.data_frames, 2);
        // A full segment at worst: 9 + 25 + 8 × 7 + 127 × 20 + 23 bits.
        assert_eq!(lossless_worst_segment_bits(128, 1), 9 + 25 + 56 + 2540 + 23);
    }

    /// Several segments and a shorter last one, by hand: 300 points at 7 bits are
    /// segments of 128, 128 and 44 points, 896, 896 and 308 bits, 112, 112 and 39 bytes:
    /// 16 + 16 + 6 classic data frames, all of 8 bytes but the last (4 stream bytes
    /// after the framing byte: 5 bytes).
    #[test]
    fn lossless_cost_of_several_segments() {
        let dl = Encoding {
            distance: DistanceEncoding::Lossless,
            intensity: IntensityEncoding::None,
            unit_exp: 0,
        };
        let c = lossless_cost(
            300,
            &dl,
            Some(7 * 16),
            FrameFormat::Classic,
            false,
            BitRates::CLASSIC_1M,
        );
        assert_eq!((c.data_frames, c.frames), (38, 41));
        assert_eq!(c.bits_per_point, 7);
        assert_eq!(
            c.nominal_bits,
            40 * 135 + classic_frame_bits(5, false).nominal
        );
    }

    #[test]
    fn classic_frame() {
        assert_eq!(classic_frame_bits(8, false).nominal, 135);
        assert_eq!(classic_frame_bits(0, false).nominal, 34 + 13 + 8);
        assert_eq!(classic_frame_bits(8, true).nominal, 160);
        assert_eq!(
            classic_frame_bits(8, false).time_ns(BitRates::CLASSIC_1M),
            135_000
        );
    }

    #[test]
    fn fd_frame() {
        let b = fd_frame_bits(64, false);
        assert_eq!(
            b,
            FrameBits {
                nominal: 34,
                data: 678
            }
        );
        assert_eq!(b.time_ns(BitRates::FD_1M_5M), 34_000 + 135_600);
        assert_eq!(b.time_ns(BitRates::FD_1M_2M), 34_000 + 339_000);
        // 8 bytes, CRC-17: 5 + 64 + (floor(85/4) - 4) + 4 + 17 + 6
        assert_eq!(fd_frame_bits(8, false).data, 5 + 64 + 17 + 4 + 17 + 6);
    }

    #[test]
    fn scan_costs() {
        let d12 = Encoding {
            distance: DistanceEncoding::D12,
            intensity: IntensityEncoding::None,
            unit_exp: 1,
        };
        let c = scan_cost(682, &d12, FrameFormat::Classic, false, BitRates::CLASSIC_1M);
        // 170 full frames of 4 points + 1 frame of 2 points (5 bytes).
        assert_eq!((c.points_per_frame, c.data_frames, c.frames), (4, 171, 174));
        let last = classic_frame_bits(5, false).nominal;
        assert_eq!(c.nominal_bits, 173 * 135 + last);
        assert_eq!(c.data_bits, 0);
        assert_eq!(c.time_ns, u64::from(c.nominal_bits) * 1000);
        assert_eq!(c.load_ppm(10_000), u64::from(c.nominal_bits) * 10);
    }
}
