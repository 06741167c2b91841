//! The streaming scan encoder: header frames, then one data frame whenever one is full,
//! then the trailer (SPEC section 2). It holds one data frame, never a scan.
//!
//! This module holds the encoder's API ([`ScanEncoder`]: begin, runs, finish, abort), its
//! types and the state of the scan in progress; the coding paths have files of their own:
//! - `point`: a point at a time;
//! - `fixed`: runs in the fixed-width encodings, and coding a block of points;
//! - `classic`: the fixed-width runs framed into classic CAN frames;
//! - `lossless`: the lossless coding.

use crate::abort::{Abort, AbortReason};
use crate::crc::ScanCrc;
use crate::data::{data_frame_len, DATA_HEADER_LEN};
use crate::encoding::{Distance, DistanceCoder, Packer};
use crate::frame::{is_valid_len, Frame, CLASSIC_LEN, MAX_LEN};
use crate::header::ScanHeader;
use crate::id::{Kind, NodeIds};
use crate::lossless::stream::ScanStream;
use crate::trailer::{Trailer, TrailerFlags};
use crate::Error;

mod classic;
mod fixed;
mod lossless;
mod point;

use lossless::Lossless;

/// Classic CAN or CAN FD, and the data frame size.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameFormat {
    /// Classic CAN: 8-byte data frames.
    Classic,
    /// CAN FD: data frames up to `max_len` bytes (12, 16, 20, 24, 32, 48 or 64).
    Fd {
        /// Full data frame length.
        max_len: u8,
    },
}

impl FrameFormat {
    /// CAN FD with 64-byte frames.
    pub const FD64: FrameFormat = FrameFormat::Fd { max_len: 64 };

    /// Check that an FD length is a valid FD length above 8.
    pub fn validate(&self) -> Result<(), Error> {
        match *self {
            FrameFormat::Classic => Ok(()),
            FrameFormat::Fd { max_len } if max_len > 8 && is_valid_len(usize::from(max_len)) => {
                Ok(())
            }
            FrameFormat::Fd { .. } => Err(Error::FrameTooLong),
        }
    }

    /// Length of a full data frame.
    pub fn max_len(&self) -> usize {
        match *self {
            FrameFormat::Classic => CLASSIC_LEN,
            FrameFormat::Fd { max_len } => usize::from(max_len).min(MAX_LEN),
        }
    }

    /// Whether frames are sent as CAN FD frames.
    pub fn is_fd(&self) -> bool {
        matches!(self, FrameFormat::Fd { .. })
    }
}

/// Frames returned by [`ScanEncoder::finish`]: at most a last data frame and the trailer,
/// in transmit order.
pub type Emitted = heapless::Vec<Frame, 2>;

#[derive(Debug, Clone)]
struct InProgress {
    header: ScanHeader,
    crc: ScanCrc,
    /// Points pushed so far.
    pushed: u16,
    /// Points in data frames already returned.
    sent: u16,
    /// Valid distance codes pushed so far.
    valid: u16,
    /// Points in `packer`.
    buffered: u16,
    /// The data frame being filled (its header bytes are written at flush).
    packer: Packer,
    /// Fixed for the scan: points per data frame, the distance coding, bits per distance
    /// and per intensity.
    capacity: u16,
    coder: DistanceCoder,
    /// `16 - intensity bits`, 16 without the channel (the code is then 0).
    intensity_shift: u32,
    distance_bits: u32,
    intensity_bits: u32,
    /// Length of a full data frame (`capacity` points).
    full_len: usize,
    /// Points taken by a classic run whose codes wait at the front of the encoder's code
    /// buffer, not yet in the CRC or the packer (counted in `pushed` and `buffered`).
    pending: usize,
    /// The run being pushed: its points' count and, for a
    /// [`ScanEncoder::push_checked_run`], how many of them are no range (0). A block of exactly that
    /// many points is the whole run, and is coded without a test per point.
    checked: (usize, Option<u32>),
}

/// Points a run codes at a time: two data lines' worth (a SCIP line holds at most 33
/// values; a bridge hands the filtered lines of a UART chunk over as one run, and a
/// checked run of one block is coded without a test per point).
const BLOCK: usize = 66;

/// The code buffer: a block and the codes pending before it (fewer than a classic
/// frame's 4 points at most).
const CODES: usize = BLOCK + 4;

impl InProgress {
    /// One point's codes (distance in the low 16 bits, intensity above) into the CRC
    /// and the packer, at the scan's widths.
    #[inline(always)]
    fn take_code(&mut self, code: u32) {
        self.crc.point_code(code, self.intensity_bits > 0);
        self.packer.put_point(
            code & 0xFFFF,
            code >> 16,
            self.distance_bits,
            self.intensity_bits,
        );
    }
}

/// The scan in progress, if any. The variants share their room on purpose (the bridge
/// lives in a static of a 24 KiB MCU, and no_std has no box to put the larger in).
#[derive(Debug, Clone, Default)]
#[allow(clippy::large_enum_variant)]
enum Open {
    /// None.
    #[default]
    None,
    /// In a fixed-width encoding.
    Fixed(InProgress),
    /// In the lossless coding.
    Lossless(Lossless),
}

impl Open {
    fn fixed(&self) -> Option<&InProgress> {
        match self {
            Open::Fixed(s) => Some(s),
            _ => None,
        }
    }

    fn fixed_mut(&mut self) -> Option<&mut InProgress> {
        match self {
            Open::Fixed(s) => Some(s),
            _ => None,
        }
    }

    fn lossless(&self) -> Option<&Lossless> {
        match self {
            Open::Lossless(l) => Some(l),
            _ => None,
        }
    }

    fn lossless_mut(&mut self) -> Option<&mut Lossless> {
        match self {
            Open::Lossless(l) => Some(l),
            _ => None,
        }
    }
}

/// Where [`ScanEncoder::push_run`] puts data frames as they fill: typically a transmit
/// queue, whose new back slot the frame is written into in place (on a 32-bit MCU a
/// frame moved by value is a 76-byte copy).
///
/// Every slot it hands out holds no payload byte past the 8th (a classic frame, a
/// default one, or one cleared with [`Frame::clear_fd_bytes`], as a queue does when a
/// CAN FD frame leaves its slot): a run of classic frames writes each with plain stores
/// ([`Frame::set_classic_as`]).
pub trait FrameSink {
    /// A slot for the next data frame, or `None` when there is no room for it.
    fn data_slot(&mut self) -> Option<&mut Frame>;

    /// Slots for the next data frames, in order: at most `n`, at least one when the
    /// sink has room (none when it has not), each taken like [`FrameSink::data_slot`]'s,
    /// so the caller writes a data frame into every one it is given. A run that has
    /// several frames due asks once, not once per frame. The default hands out
    /// [`FrameSink::data_slot`]'s one.
    fn data_slots(&mut self, n: usize) -> &mut [Frame] {
        if n == 0 {
            return &mut [];
        }
        match self.data_slot() {
            Some(frame) => core::slice::from_mut(frame),
            None => &mut [],
        }
    }
}

/// A growing list of frames is a sink with room for every frame (host side).
#[cfg(any(test, feature = "std"))]
impl FrameSink for std::vec::Vec<Frame> {
    fn data_slot(&mut self) -> Option<&mut Frame> {
        self.push(Frame::default());
        self.last_mut()
    }

    fn data_slots(&mut self, n: usize) -> &mut [Frame] {
        let from = self.len();
        self.resize(from.saturating_add(n), Frame::default());
        self.get_mut(from..).unwrap_or_default()
    }
}

/// Why [`ScanEncoder::push_run`] stopped before the end of its points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RunStop {
    /// The sink had no slot for a due data frame: the frame was lost (the scan goes on
    /// as if it had been sent, like [`ScanEncoder::push_point_into`]).
    NoSlot,
    /// More points than the header announced: the points after those taken were not.
    TooManyPoints,
}

/// Which raw distances of a [`ScanEncoder::push_run`] are ranges: those at least `min`
/// that are none of `except` (error codes above `min`; `u32::MAX` fills an unused
/// place) and not in the band of three values from `band` (the Ethernet models'
/// 65533..=65535). The others are [`Distance::Invalid`] (in the lossless coding, sensor
/// error codes by their value: see [`crate::lossless::code::error_code`]). A range
/// outside `window` (a filter's range window) is no range either; a run counts those
/// apart ([`Run::rejected`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RangeRule {
    /// The smallest range.
    pub min: u32,
    /// Error codes at or above `min`.
    pub except: [u32; 2],
    /// The first of three consecutive error codes at or above `min`, if any.
    pub band: Option<u32>,
    /// The ranges kept, both ends included (`[0, u32::MAX]`: every range).
    pub window: [u32; 2],
}

impl RangeRule {
    /// Every distance of at least `min` is a range.
    pub const fn at_least(min: u32) -> RangeRule {
        RangeRule {
            min,
            except: [u32::MAX; 2],
            band: None,
            window: [0, u32::MAX],
        }
    }

    /// The distance `d` as the rule classifies it.
    #[inline(always)]
    pub fn distance(&self, d: u32) -> Distance {
        if self.is_range(d) {
            Distance::Mm(d)
        } else {
            Distance::Invalid
        }
    }

    /// Whether the raw distance `d` is a range (inside the window).
    #[inline(always)]
    pub fn is_range(&self, d: u32) -> bool {
        let [lo, hi] = self.window;
        self.is_sensor_range(d) && d >= lo && d <= hi
    }

    /// Whether the raw distance `d` is a range before the window.
    #[inline(always)]
    pub fn is_sensor_range(&self, d: u32) -> bool {
        let [a, b] = self.except;
        d >= self.min && d != a && d != b && self.band.is_none_or(|s| d.wrapping_sub(s) > 2)
    }

    /// Whether `d` is a range that the window rejects.
    #[inline(always)]
    fn rejects(&self, d: u32) -> bool {
        let [lo, hi] = self.window;
        self.is_sensor_range(d) && (d < lo || d > hi)
    }
}

/// What [`ScanEncoder::push_run`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Run {
    /// Points taken: the first `points` of the run.
    pub points: u32,
    /// Points taken that were no range.
    pub invalid: u32,
    /// Points among the `invalid` ones that were ranges outside the rule's window.
    pub rejected: u32,
    /// Data frames written into the sink.
    pub frames: u32,
    /// Why the run stopped early, if it did.
    pub stop: Option<RunStop>,
}

/// Turns a scan, point by point, into frames (see the crate docs for an example).
#[derive(Debug, Clone)]
pub struct ScanEncoder {
    ids: NodeIds,
    /// The data frames' CAN identifier, `ids.id(Kind::Data)`: the ids are fixed at
    /// [`ScanEncoder::new`], so it is worked out there, not at every run.
    data_id: embedded_can::Id,
    format: FrameFormat,
    /// The scan in progress: its fixed-width or lossless state share their room.
    open: Open,
    /// The codes of the block of points a run is framing (see [`code_block`]), after
    /// the pending codes of a classic frame begun by the last run.
    ///
    /// [`code_block`]: fixed::code_block
    codes: [u32; CODES],
}

impl ScanEncoder {
    /// An encoder for bridge `ids` sending `format` frames.
    pub fn new(ids: NodeIds, format: FrameFormat) -> Result<ScanEncoder, Error> {
        format.validate()?;
        Ok(ScanEncoder {
            ids,
            data_id: ids.id(Kind::Data),
            format,
            open: Open::None,
            codes: [0; CODES],
        })
    }

    /// Change the frame format (between scans only).
    pub fn set_format(&mut self, format: FrameFormat) -> Result<(), Error> {
        if self.in_progress() {
            return Err(Error::ScanInProgress);
        }
        format.validate()?;
        self.format = format;
        Ok(())
    }

    /// The frame format.
    pub fn format(&self) -> FrameFormat {
        self.format
    }

    /// Whether a scan is in progress.
    pub fn in_progress(&self) -> bool {
        !matches!(self.open, Open::None)
    }

    /// For a lossless scan in progress: its points taken so far and the stream bytes
    /// they took (what a bandwidth governor learns the coding's real cost from).
    pub fn lossless_progress(&self) -> Option<(u16, u32)> {
        self.open
            .lossless()
            .as_ref()
            .map(|l| (l.stream.pushed(), l.stream.stream_bytes()))
    }

    fn frame(&self, kind: Kind, data: &[u8]) -> Result<Frame, Error> {
        Frame::new(self.ids.id(kind), data, self.format.is_fd())
    }

    /// Start a scan: returns header A and header B, to be sent in that order.
    pub fn begin(&mut self, header: &ScanHeader) -> Result<[Frame; 2], Error> {
        if self.in_progress() {
            return Err(Error::ScanInProgress);
        }
        let a = header.emit_a()?;
        let b = header.emit_b()?;
        let frames = [
            self.frame(Kind::HeaderA, &a)?,
            self.frame(Kind::HeaderB, &b)?,
        ];
        let enc = header.encoding;
        if enc.distance.is_lossless() {
            self.open = Open::Lossless(Lossless::new(
                *header,
                ScanStream::new(
                    header.seq,
                    header.point_count,
                    enc.intensity.is_present(),
                    self.format.max_len(),
                    &a,
                    &b,
                ),
            ));
            return Ok(frames);
        }
        let distance_bits = enc.distance.bits();
        let intensity_bits = enc.intensity.bits();
        let capacity = u16::try_from(enc.capacity(self.format.max_len()))
            .unwrap_or(u16::MAX)
            .max(1);
        self.open = Open::Fixed(InProgress {
            header: *header,
            crc: ScanCrc::new(&a, &b),
            pushed: 0,
            sent: 0,
            valid: 0,
            buffered: 0,
            packer: Packer::new(DATA_HEADER_LEN),
            capacity,
            coder: enc.distance_coder(),
            // An intensity code has at most 16 bits.
            intensity_shift: 16u32.wrapping_sub(intensity_bits),
            distance_bits,
            intensity_bits,
            full_len: data_frame_len(&enc, usize::from(capacity)).ok_or(Error::FrameTooLong)?,
            pending: 0,
            checked: (0, None),
        });
        Ok(frames)
    }

    /// Adds `points` in order, each turned by `point` into a raw distance (a range or
    /// not, as `rule` says) and an intensity, like [`ScanEncoder::push_point_into`] for
    /// each, with every due data frame written
    /// into a slot of `sink`. The loops are compiled once per encoding and frame kind,
    /// and points are coded a block at a time and then framed, so a point costs a few
    /// instructions. It stops at the first point the scan cannot take, or after the
    /// first frame `sink` had no slot for.
    #[inline]
    pub fn push_run<T, F, S>(
        &mut self,
        points: &[T],
        rule: RangeRule,
        point: F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        self.push_run_with(points, rule, None, point, sink)
    }

    /// [`ScanEncoder::push_run`] with the rule [`RangeRule::at_least`]`(1)` for points
    /// already checked (a filter's output): each point's distance is 0 for no range or
    /// a range (any other value but `u32::MAX`, which no rule takes for a range), and
    /// `no_range` is the number of points whose distance is 0. The frames, counts and
    /// stops are those of `push_run` with that rule. A
    /// fixed-width scan in 1 mm units without intensities codes such a run (when it is
    /// one block, a data line's worth) with no test per point: each distance is its
    /// own code, and only the OR of the distances is checked, once, for a range at or
    /// past the out-of-range code (such a block is coded by the general rule). A wrong
    /// `no_range` leaves the points' codes right but miscounts the valid points (the
    /// trailer's count) and the run's `invalid`.
    #[inline]
    pub fn push_checked_run<T, F, S>(
        &mut self,
        points: &[T],
        no_range: u32,
        point: F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        self.push_run_with(points, RangeRule::at_least(1), Some(no_range), point, sink)
    }

    /// [`ScanEncoder::push_run`] (`checked` `None`) or
    /// [`ScanEncoder::push_checked_run`] (`checked` its `no_range`; `rule` must then be
    /// [`RangeRule::at_least`]`(1)` for a fixed-width scan) by a value: a caller that
    /// takes both kinds of run has one copy of the dispatch. A lossless scan codes by
    /// `rule` either way (`checked` is not used).
    #[inline]
    pub fn push_run_with<T, F, S>(
        &mut self,
        points: &[T],
        rule: RangeRule,
        checked: Option<u32>,
        point: F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        let s = match &mut self.open {
            Open::Fixed(s) => s,
            Open::Lossless(_) => return self.run_lossless_apart(points, rule, &point, sink),
            Open::None => return Err(Error::NoScan),
        };
        // Every run says whether it is checked (only a run's blocks read it).
        s.checked = (points.len(), checked);
        let classic = !self.format.is_fd();
        let (db, ib) = (s.distance_bits, s.intensity_bits);
        // D16 without intensity on classic CAN gets a loop compiled for its width (not
        // with the `compact` feature: about 4 KB of M4 code); the other fixed-width
        // cases share one per frame kind with the widths as values (smaller, a bit
        // slower: flash is the boards' tight budget, and the lossless coding is the
        // compact one). The frames are the same either way.
        match (classic, db, ib) {
            (false, _, _) => {
                self.run_fixed::<false, 0, 0, _, _, _>(db, ib, points, rule, &point, sink)
            }
            #[cfg(not(feature = "compact"))]
            (true, 16, 0) => {
                self.run_fixed::<true, 16, 0, _, _, _>(db, ib, points, rule, &point, sink)
            }
            (true, _, _) => {
                self.run_fixed::<true, 0, 0, _, _, _>(db, ib, points, rule, &point, sink)
            }
        }
    }

    /// [`ScanEncoder::run_lossless`], never inlined into [`ScanEncoder::push_run`]: the
    /// lossless run's state would make every run's entry save and set up more (a
    /// fixed-width run's entry is then a few tests and a jump).
    #[inline(never)]
    fn run_lossless_apart<T, F, S>(
        &mut self,
        points: &[T],
        rule: RangeRule,
        point: &F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        self.run_lossless(points, rule, point, sink)
    }

    /// End the scan: returns the last data frame if points are still buffered (only when
    /// the scan is truncated) and the trailer. `flags.truncated` is set from the counts.
    /// A truncated lossless scan sends the points of its whole segments only.
    pub fn finish(&mut self, flags: TrailerFlags) -> Result<Emitted, Error> {
        if matches!(self.open, Open::Lossless(_)) {
            if let Open::Lossless(l) = core::mem::take(&mut self.open) {
                return self.finish_lossless(l, flags);
            }
        }
        self.settle_pending();
        let mut out = Emitted::new();
        let buffered = self.open.fixed().ok_or(Error::NoScan)?.buffered;
        if buffered > 0 {
            let mut f = Frame::default();
            self.flush_into(&mut f)?;
            out.push(f).map_err(|_| Error::FrameTooLong)?;
        }
        let Open::Fixed(s) = core::mem::take(&mut self.open) else {
            return Err(Error::NoScan);
        };
        let mut t = Trailer {
            seq: s.header.seq,
            points_sent: s.sent,
            points_valid: s.valid,
            flags: TrailerFlags {
                truncated: s.sent < s.header.point_count,
                ..flags
            },
            crc: 0,
        };
        t.crc = s.crc.finish(&t.emit_head()?);
        let f = self.frame(Kind::Trailer, &t.emit()?)?;
        out.push(f).map_err(|_| Error::FrameTooLong)?;
        Ok(out)
    }

    /// Abandon the scan: buffered points are dropped; returns the abort frame.
    pub fn abort(&mut self, reason: AbortReason, detail: u8) -> Result<Frame, Error> {
        let (seq, sent) = match core::mem::take(&mut self.open) {
            Open::Lossless(l) => (l.header.seq, l.stream.sent()),
            Open::Fixed(s) => (s.header.seq, s.sent),
            Open::None => return Err(Error::NoScan),
        };
        let a = Abort {
            seq,
            reason,
            detail,
            points_sent: sent,
        };
        self.frame(Kind::Abort, &a.emit()?)
    }
}

#[cfg(test)]
mod tests;
