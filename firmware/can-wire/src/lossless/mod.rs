//! The lossless predictive coding of scans (SPEC section 4.2, distance encoding `DL`).
//!
//! A scan is cut into *segments* of [`SEGMENT_POINTS`] points. Each segment is one
//! continuous LSB-first bit stream that begins in a fresh data frame: the segment's
//! first point verbatim (the *anchor*), then blocks of [`BLOCK_POINTS`] values per
//! channel, each coded in one of four modes chosen by the sender (verbatim, constant,
//! first- or second-order prediction with a Rice code of the residuals, as lossless
//! audio coders do), then zero bits to a byte boundary and a CRC-16 over the segment's bytes. A data
//! frame spends one byte on framing: a segment-start flag and a frame counter.
//!
//! - [`code`]: what a distance value becomes (sensor error codes keep their identity).
//! - [`bits`]: the bit writer that cuts a segment's stream into data frames, and the
//!   bit reader of the receiver.
//! - [`block`]: choosing, writing and reading one block's coding.
//! - [`stream`]: the sender's per-scan state, fed a point at a time or a run at a time.
//! - [`segment`]: the receiver's decoding of one segment's bytes.
//! - [`receive`]: the receiver's gathering of a scan's frames into segments.

pub mod bits;
pub mod block;
pub mod code;
pub mod receive;
pub mod segment;
pub mod stream;

/// Points per segment (the last segment of a scan may have fewer).
pub const SEGMENT_POINTS: usize = 128;

/// Values per block (a segment's anchor is not in a block, so a full segment has seven
/// blocks of 16 and one of 15).
pub const BLOCK_POINTS: usize = 16;

/// Width of a value field: every distance and intensity code is below `2^VALUE_BITS`.
pub const VALUE_BITS: u32 = 20;

/// The largest code a channel can carry.
pub const MAX_VALUE: u32 = (1 << VALUE_BITS) - 1;

/// Segments a scan can have (`ceil(4095 / 128)`).
pub const MAX_SEGMENTS: usize = 32;

/// Bits of a segment header: `seq & 0xF` and the segment number.
pub const SEGMENT_HEADER_BITS: u32 = 9;

/// Bits of a width field (verbatim blocks and anchors), 0..=20.
pub const WIDTH_BITS: u32 = 5;

/// Bits of a Rice parameter field, 0..=15.
pub const K_BITS: u32 = 4;

/// Bits of a block mode.
pub const MODE_BITS: u32 = 2;

/// Quotients of at least this many are escaped: that many one bits, then the value.
pub const ESCAPE_ONES: u32 = 16;

/// Most bytes one segment's stream can take (anchors, eight blocks of two channels at
/// their verbatim bound, the padding and the CRC), with some room: the receiver's
/// segment buffer.
pub const MAX_SEGMENT_BYTES: usize = 704;

/// Number of segments of a scan of `points` points.
pub const fn segments(points: usize) -> usize {
    points.div_ceil(SEGMENT_POINTS)
}

/// Points in segment `index` of a scan of `points` points (0 past the last).
pub const fn segment_points(points: usize, index: usize) -> usize {
    let start = index.saturating_mul(SEGMENT_POINTS);
    if start >= points {
        0
    } else {
        let left = points.wrapping_sub(start); // start < points here
        if left < SEGMENT_POINTS {
            left
        } else {
            SEGMENT_POINTS
        }
    }
}

/// A block's coding (2 bits on the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// A width `w` (5 bits, 0..=20), then each value in `w` bits.
    Verbatim = 0,
    /// Residuals from the previous value, Rice-coded with parameter `k` (4 bits).
    Order1 = 1,
    /// Residuals from the line through the two previous values, Rice-coded.
    Order2 = 2,
    /// Every value equals the previous one; nothing follows.
    Constant = 3,
}

impl Mode {
    /// The mode of a 2-bit field.
    pub const fn from_bits(bits: u32) -> Mode {
        match bits & 3 {
            0 => Mode::Verbatim,
            1 => Mode::Order1,
            2 => Mode::Order2,
            _ => Mode::Constant,
        }
    }
}

/// Zig-zag: residual `e` to an unsigned value (0, -1, 1, -2, ... to 0, 1, 2, 3, ...).
#[inline(always)]
pub const fn zigzag(e: i32) -> u32 {
    ((e << 1) ^ (e >> 31)) as u32
}

/// The inverse of [`zigzag`].
#[inline(always)]
pub const fn unzigzag(u: u32) -> i32 {
    ((u >> 1) as i32) ^ ((u & 1) as i32).wrapping_neg()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zigzag_pairs() {
        for (e, u) in [
            (0, 0),
            (-1, 1),
            (1, 2),
            (-2, 3),
            (2, 4),
            (-3_000_000, 5_999_999),
        ] {
            assert_eq!(zigzag(e), u);
            assert_eq!(unzigzag(u), e);
        }
    }

    #[test]
    fn segment_arithmetic() {
        assert_eq!(segments(682), 6);
        assert_eq!(segments(1081), 9);
        assert_eq!(segments(128), 1);
        assert_eq!(segments(0), 0);
        assert_eq!(segment_points(682, 5), 42);
        assert_eq!(segment_points(682, 4), 128);
        assert_eq!(segment_points(682, 6), 0);
        assert_eq!(segments(4095), MAX_SEGMENTS);
    }
}
