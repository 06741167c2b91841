//! The streaming scan encoder: header frames, then one data frame whenever one is full,
//! then the trailer (SPEC section 2). It holds one data frame, never a scan.

use crate::abort::{Abort, AbortReason};
use crate::crc::ScanCrc;
use crate::data::{data_frame_len, DataHeader, DATA_HEADER_LEN};
use crate::encoding::{Distance, DistanceCoder, Packer};
use crate::frame::{is_valid_len, Frame, CLASSIC_LEN, MAX_LEN};
use crate::header::{put, ScanHeader};
use crate::id::{Kind, NodeIds};
use crate::lossless::bits::Out;
use crate::lossless::code;
use crate::lossless::stream::ScanStream;
use crate::trailer::{Trailer, TrailerFlags};
use crate::Error;

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
}

/// Points a run codes at a time: a data line's worth.
const BLOCK: usize = 36;

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

/// The most range units a lossless distance code carries.
const MAX_RANGE_UNITS: u32 = crate::lossless::MAX_VALUE - code::RANGE_BASE;

/// A scan in the lossless coding: its header and its segment stream.
#[derive(Debug, Clone)]
struct Lossless {
    header: ScanHeader,
    stream: ScanStream,
}

/// Where [`ScanEncoder::push_run`] puts data frames as they fill: typically a transmit
/// queue, whose new back slot the frame is written into in place (on a 32-bit MCU a
/// frame moved by value is a 76-byte copy).
pub trait FrameSink {
    /// A slot for the next data frame, or `None` when there is no room for it.
    fn data_slot(&mut self) -> Option<&mut Frame>;
}

/// A growing list of frames is a sink with room for every frame (host side).
#[cfg(any(test, feature = "std"))]
impl FrameSink for std::vec::Vec<Frame> {
    fn data_slot(&mut self) -> Option<&mut Frame> {
        self.push(Frame::default());
        self.last_mut()
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
/// outside `window` (a filter's range window) is no range either; the fixed-width
/// encodings count those apart ([`Run::rejected`]).
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

/// The points of `points` whose distance `rule`'s window rejects (points given back
/// after a lost frame).
#[cold]
fn count_rejected<T, F: Fn(&T) -> (u32, u16)>(rule: &RangeRule, points: &[T], point: &F) -> u32 {
    let n = points.iter().filter(|p| rule.rejects(point(p).0)).count();
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// The lossless distance code of raw distance `d` as `rule` classifies it, ranges in
/// units of `2^e` mm: the full test, for the distances outside the span a run codes
/// without one (error codes, the band, too long ones).
#[cold]
#[inline(never)]
fn lossless_code(rule: &RangeRule, d: u32, e: u32) -> u32 {
    let e = e & 0xF;
    if rule.rejects(d) {
        // A range the window takes away has no sensor value.
        return code::INVALID;
    }
    if !rule.is_range(d) {
        return code::error_code(d);
    }
    let q = d.saturating_add((1u32 << e) >> 1) >> e;
    if q <= MAX_RANGE_UNITS {
        q.wrapping_add(code::RANGE_BASE) // q <= MAX_RANGE_UNITS: no wrap
    } else {
        code::OUT_OF_RANGE
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
    /// Points among the `invalid` ones that were ranges outside the rule's window
    /// (fixed-width encodings; 0 in the lossless coding).
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
    format: FrameFormat,
    /// The scan in progress: its fixed-width or lossless state share their room.
    open: Open,
    /// The codes of the block of points a run is framing (see [`code_block`]), after
    /// the pending codes of a classic frame begun by the last run.
    codes: [u32; CODES],
}

impl ScanEncoder {
    /// An encoder for bridge `ids` sending `format` frames.
    pub fn new(ids: NodeIds, format: FrameFormat) -> Result<ScanEncoder, Error> {
        format.validate()?;
        Ok(ScanEncoder {
            ids,
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
            self.open = Open::Lossless(Lossless {
                header: *header,
                stream: ScanStream::new(
                    header.seq,
                    header.point_count,
                    enc.intensity.is_present(),
                    self.format.max_len(),
                    &a,
                    &b,
                ),
            });
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
        });
        Ok(frames)
    }

    /// Add the next point. Returns a data frame when one is full or the point was the
    /// scan's last.
    #[inline]
    pub fn push_point(
        &mut self,
        distance: Distance,
        intensity: u16,
    ) -> Result<Option<Frame>, Error> {
        if matches!(self.open, Open::Lossless(_)) {
            return Err(Error::NeedsSink);
        }
        if !self.add(distance, intensity)? {
            return Ok(None);
        }
        let mut frame = Frame::default();
        self.flush_into(&mut frame)?;
        Ok(Some(frame))
    }

    /// Add the next point, like [`ScanEncoder::push_point`], but a due data frame is
    /// written in place into the frame `slot` returns (typically a queue's new back
    /// slot), so no frame moves by value: on a 32-bit MCU each move is a 76-byte copy.
    /// When `slot` returns `None` the frame is built and dropped, and the scan goes on
    /// as if it had been sent. Returns whether a data frame was due; on an error after
    /// `slot` was called, the slot's frame is left as it was.
    #[inline]
    pub fn push_point_into<'f>(
        &mut self,
        distance: Distance,
        intensity: u16,
        slot: impl FnOnce() -> Option<&'f mut Frame>,
    ) -> Result<bool, Error> {
        if matches!(self.open, Open::Lossless(_)) {
            return Err(Error::NeedsSink);
        }
        if !self.add(distance, intensity)? {
            return Ok(false);
        }
        match slot() {
            Some(frame) => self.flush_into(frame)?,
            None => self.flush_into(&mut Frame::default())?,
        }
        Ok(true)
    }

    /// Puts the codes a classic run left pending into the CRC and the packer, where
    /// point-by-point pushing and [`ScanEncoder::finish`] expect a frame's points.
    #[cold]
    fn settle_pending(&mut self) {
        let Some(s) = self.open.fixed_mut() else {
            return;
        };
        let n = core::mem::take(&mut s.pending);
        for &code in self.codes.get(..n).unwrap_or(&[]) {
            s.take_code(code);
        }
    }

    /// Packs a point; returns whether a data frame is due (full, or the scan's last).
    #[inline(always)]
    fn add(&mut self, distance: Distance, intensity: u16) -> Result<bool, Error> {
        if self.open.fixed().is_some_and(|s| s.pending > 0) {
            self.settle_pending();
        }
        let s = self.open.fixed_mut().ok_or(Error::NoScan)?;
        if s.pushed >= s.header.point_count {
            return Err(Error::TooManyPoints);
        }
        let dc = s.coder.code(distance);
        let ic = u32::from(intensity) >> s.intensity_shift;
        s.take_code(u32::from(dc) | ic << 16);
        // pushed < point_count (at most 4096) was checked, and valid <= pushed,
        // buffered <= pushed: no wrap.
        s.valid = s.valid.wrapping_add(u16::from(s.coder.is_valid(dc)));
        s.pushed = s.pushed.wrapping_add(1);
        s.buffered = s.buffered.wrapping_add(1);
        Ok(s.buffered >= s.capacity || s.pushed == s.header.point_count)
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
        if matches!(self.open, Open::Lossless(_)) {
            return self.run_lossless(points, rule, &point, sink);
        }
        let s = self.open.fixed().ok_or(Error::NoScan)?;
        let classic = !self.format.is_fd();
        let (db, ib) = (s.distance_bits, s.intensity_bits);
        // D16 without intensity on classic CAN gets a loop compiled for its width; the
        // other fixed-width cases share one per frame kind with the widths as values
        // (smaller, a bit slower: flash is the boards' tight budget, and the lossless
        // coding is the compact one).
        match (classic, db, ib) {
            (false, _, _) => {
                self.run_fixed::<false, 0, 0, _, _, _>(db, ib, points, rule, &point, sink)
            }
            (true, 16, 0) => {
                self.run_fixed::<true, 16, 0, _, _, _>(db, ib, points, rule, &point, sink)
            }
            (true, _, _) => {
                self.run_fixed::<true, 0, 0, _, _, _>(db, ib, points, rule, &point, sink)
            }
        }
    }

    /// [`Self::run_with`] (CAN FD, `CLASSIC` false) or [`Self::run_classic_with`] for
    /// `DB`-bit distances and `IB`-bit intensities compiled in; `DB` = 0 takes the widths
    /// `db` and `ib` as values instead (one loop for the rarer encodings).
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    fn run_fixed<const CLASSIC: bool, const DB: u32, const IB: u32, T, F, S>(
        &mut self,
        db: u32,
        ib: u32,
        points: &[T],
        rule: RangeRule,
        point: &F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        let (db, ib) = if DB == 0 { (db, ib) } else { (DB, IB) };
        if CLASSIC {
            self.run_classic_with(db, ib, points, rule, point, sink)
        } else {
            self.run_with(db, ib, points, rule, point, sink)
        }
    }

    /// [`ScanEncoder::push_run`] for CAN FD frames with `DB`-bit distances and `IB`-bit
    /// intensities: points are coded a block at a time ([`code_block`]), then packed.
    #[inline(always)]
    fn run_with<T, F, S>(
        &mut self,
        db: u32,
        ib: u32,
        points: &[T],
        rule: RangeRule,
        point: &F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        let id = self.ids.id(Kind::Data);
        let fd = self.format.is_fd();
        let codes_buf = &mut self.codes;
        let s = self.open.fixed_mut().ok_or(Error::NoScan)?;
        let mut run = Run::default();
        let (count, capacity) = (s.header.point_count, s.capacity);
        // The arithmetic below counts points of one scan (at most 4096, a u16) and the
        // frames they make: `valid + invalid <= block <= BLOCK`, `j <= block`, the
        // counters of the scan below its point count and those of the run below the
        // run's points. Nothing wraps, and the wrapping ops compile to the plain ones.
        let bits = db.wrapping_add(ib);
        let mut rest = points;
        loop {
            let left = rest.len();
            if left == 0 {
                break;
            }
            if s.pushed >= count {
                run.stop = Some(RunStop::TooManyPoints);
                break;
            }
            let block = left
                .min(BLOCK)
                .min(usize::from(count.wrapping_sub(s.pushed)));
            let (now, later) = rest.split_at(block);
            rest = later;
            let (mut valid, mut invalid, mut rejected) =
                code_block_any(ib, now, rule, point, s, codes_buf);
            let mut j = 0;
            while j < block {
                // Points until a frame is due: the frame is full or the scan's last is in.
                let room = capacity
                    .saturating_sub(s.buffered)
                    .min(count.saturating_sub(s.pushed));
                let k = usize::from(room).min(block.wrapping_sub(j));
                let codes = codes_buf.get(j..j.wrapping_add(k)).unwrap_or(&[]);
                let mut crc = s.crc;
                for &code in codes {
                    crc.point_code(code, ib > 0);
                }
                s.crc = crc;
                let whole = (bits / 8) as usize;
                if bits % 8 == 0 {
                    // Whole bytes per point: straight into their place, no bit position.
                    let Some(bytes) = s.packer.take_bytes(k.saturating_mul(whole)) else {
                        return Err(Error::FrameTooLong);
                    };
                    for (&code, out) in codes.iter().zip(bytes.chunks_exact_mut(whole)) {
                        let word = (code & 0xFFFF) | (code >> 16) << db;
                        if let Some(field) = word.to_le_bytes().get(..whole) {
                            out.copy_from_slice(field);
                        }
                    }
                } else {
                    for &code in codes {
                        s.packer.put_point(code & 0xFFFF, code >> 16, db, ib);
                    }
                }
                // k <= room, a u16.
                let k16 = k as u16;
                s.pushed = s.pushed.wrapping_add(k16);
                s.buffered = s.buffered.wrapping_add(k16);
                j = j.wrapping_add(k);
                if usize::from(room) != k {
                    continue;
                }
                let slot = sink.data_slot();
                let lost = slot.is_none();
                match slot {
                    Some(frame) => flush(s, id, fd, frame)?,
                    None => flush(s, id, fd, &mut Frame::default())?,
                }
                if lost {
                    let rest = codes_buf.get(j..block).unwrap_or(&[]);
                    let (v, i) = untake(s, rest);
                    // The untaken points are among the block's counted ones.
                    valid = valid.wrapping_sub(v);
                    invalid = invalid.wrapping_sub(i);
                    let given_back = now.get(j..).unwrap_or(&[]);
                    rejected = rejected.wrapping_sub(count_rejected(&rule, given_back, point));
                    run.rejected = run.rejected.wrapping_add(rejected);
                    s.valid = s.valid.wrapping_add(valid);
                    run.points = run.points.wrapping_add(j as u32);
                    run.invalid = run.invalid.wrapping_add(invalid);
                    run.stop = Some(RunStop::NoSlot);
                    return Ok(run);
                }
                run.frames = run.frames.wrapping_add(1);
            }
            s.valid = s.valid.wrapping_add(valid);
            run.points = run.points.wrapping_add(block as u32);
            run.invalid = run.invalid.wrapping_add(invalid);
            run.rejected = run.rejected.wrapping_add(rejected);
        }
        Ok(run)
    }

    /// [`ScanEncoder::push_run`] for classic frames. Points are coded a block at a time
    /// (one data line is one block), then framed: whole frames go into their 64-bit
    /// payload word at shifts known at compile time. The codes of a frame not yet full
    /// at the end of a run wait, uncounted by the CRC, at the front of the code buffer
    /// for the next run (`pending`), so frames that straddle data lines are built whole
    /// too. Only a frame begun by [`ScanEncoder::push_point`] (its points already in the
    /// packer) or the scan's short last frame take their points one by one.
    #[inline(always)]
    fn run_classic_with<T, F, S>(
        &mut self,
        db: u32,
        ib: u32,
        points: &[T],
        rule: RangeRule,
        point: &F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        let id = self.ids.id(Kind::Data);
        let codes_buf = &mut self.codes;
        let s = self.open.fixed_mut().ok_or(Error::NoScan)?;
        let mut run = Run::default();
        // As in `run_fd_with`, the arithmetic below counts points of one scan (at most
        // 4096) and frames: `before + k <= cap`, `j <= end = pending + block`, the
        // scan's counters below its point count, the run's below its points, and
        // what is given back was counted before. Nothing wraps.
        let bits = db.wrapping_add(ib);
        // Points in a full classic frame: 48 bits after the data header (a point has
        // at least 12 bits; 0 fails the capacity check below).
        let cap = 48u32.checked_div(bits).unwrap_or(0) as usize;
        let count = s.header.point_count;
        if usize::from(s.capacity) != cap || s.pending >= cap {
            return Err(Error::FrameTooLong);
        }
        let seq_bits = u64::from(s.header.seq & 0xF) << 12;
        let mut crc = s.crc;
        let mut rest = points;
        while !rest.is_empty() {
            if s.pushed >= count {
                run.stop = Some(RunStop::TooManyPoints);
                break;
            }
            let block = rest
                .len()
                .min(BLOCK)
                .min(usize::from(count.wrapping_sub(s.pushed)));
            let (now, later) = rest.split_at(block);
            rest = later;
            // The pending codes, then this block's.
            let p = s.pending;
            let end = p.wrapping_add(block);
            let fresh = codes_buf.get_mut(p..end).unwrap_or(&mut []);
            let (valid, invalid, rejected) = code_block_any(ib, now, rule, point, s, fresh);
            let codes = codes_buf.get(..end).unwrap_or(&[]);
            // The block is taken; a lost frame gives back what follows it.
            let before = usize::from(s.buffered).wrapping_sub(p);
            s.pushed = s.pushed.wrapping_add(block as u16);
            s.buffered = s.buffered.wrapping_add(block as u16);
            s.valid = s.valid.wrapping_add(valid);
            run.points = run.points.wrapping_add(block as u32);
            run.invalid = run.invalid.wrapping_add(invalid);
            run.rejected = run.rejected.wrapping_add(rejected);
            let mut j = 0;
            let mut lost = false;
            if before > 0 {
                // A frame begun by `push_point`, in the packer (then nothing is pending):
                // its next points one by one, sent if that makes it due.
                let k = cap.wrapping_sub(before).min(block);
                let at = (before as u32).wrapping_mul(bits).wrapping_add(16);
                let word =
                    s.packer.word64() & !0xFFFF & (u64::MAX >> 64u32.wrapping_sub(at.min(64)));
                let taking = codes.get(..k).unwrap_or(&[]);
                let (mut word, at) = place_points(db, ib, taking, word, at, &mut crc);
                j = k;
                let n = before.wrapping_add(k);
                if n == cap || usize::from(s.sent).wrapping_add(n) == usize::from(count) {
                    let len = if n == cap {
                        s.full_len
                    } else {
                        data_frame_len(&s.header.encoding, n).ok_or(Error::FrameTooLong)?
                    };
                    word |= u64::from(s.sent & 0x0FFF) | seq_bits;
                    s.packer.reset(DATA_HEADER_LEN);
                    s.sent = s.sent.wrapping_add(n as u16);
                    s.buffered = s.buffered.wrapping_sub(n as u16);
                    match sink.data_slot() {
                        Some(frame) => {
                            frame.set_classic(id, word.to_le_bytes(), len);
                            run.frames = run.frames.wrapping_add(1);
                        }
                        None => lost = true,
                    }
                } else {
                    s.packer.set_word64(word, at);
                }
            }
            // Whole frames.
            if !lost {
                let whole = codes.get(j..).unwrap_or(&[]);
                let mut sent = s.sent;
                for chunk in whole.chunks_exact(cap) {
                    let header = u64::from(sent & 0x0FFF) | seq_bits;
                    let word = whole_frame(db, ib, chunk, cap, header, &mut crc)
                        .ok_or(Error::FrameTooLong)?;
                    sent = sent.wrapping_add(cap as u16);
                    j = j.wrapping_add(cap);
                    match sink.data_slot() {
                        Some(frame) => {
                            frame.set_classic(id, word.to_le_bytes(), s.full_len);
                            run.frames = run.frames.wrapping_add(1);
                        }
                        None => {
                            lost = true;
                            break;
                        }
                    }
                }
                s.buffered = s.buffered.wrapping_sub(sent.wrapping_sub(s.sent));
                s.sent = sent;
            }
            // The rest: the scan's last frame, or codes pending for the next run.
            let r = end.wrapping_sub(j);
            s.pending = 0;
            // (A frame begun in the packer and not yet due took the whole block: r = 0.)
            if !lost && r > 0 {
                if usize::from(s.sent).wrapping_add(r) == usize::from(count) {
                    let header = u64::from(s.sent & 0x0FFF) | seq_bits;
                    let last = codes.get(j..end).unwrap_or(&[]);
                    let (word, _) = place_points(db, ib, last, header, 16, &mut crc);
                    let len = data_frame_len(&s.header.encoding, r).ok_or(Error::FrameTooLong)?;
                    s.sent = s.sent.wrapping_add(r as u16);
                    s.buffered = 0;
                    j = end;
                    match sink.data_slot() {
                        Some(frame) => {
                            frame.set_classic(id, word.to_le_bytes(), len);
                            run.frames = run.frames.wrapping_add(1);
                        }
                        None => lost = true,
                    }
                } else {
                    codes_buf.copy_within(j..end, 0);
                    s.pending = r;
                    j = end;
                }
            }
            if lost {
                // The points after the lost frame are not taken.
                let untaken = codes_buf.get(j..end).unwrap_or(&[]);
                let (v, i) = untake(s, untaken);
                s.valid = s.valid.wrapping_sub(v);
                s.pushed = s.pushed.wrapping_sub(untaken.len() as u16);
                s.buffered = 0;
                run.points = run.points.wrapping_sub(untaken.len() as u32);
                run.invalid = run.invalid.wrapping_sub(i);
                // The block's points given back (codes pending from the last run that
                // are given back were counted by it).
                let given_back = now.get(j.saturating_sub(p)..).unwrap_or(&[]);
                run.rejected = run
                    .rejected
                    .saturating_sub(count_rejected(&rule, given_back, point));
                s.crc = crc;
                run.stop = Some(RunStop::NoSlot);
                return Ok(run);
            }
        }
        s.crc = crc;
        Ok(run)
    }

    /// Turn the buffered points into a data frame (written into `out`).
    #[inline(never)]
    fn flush_into(&mut self, out: &mut Frame) -> Result<(), Error> {
        let id = self.ids.id(Kind::Data);
        let fd = self.format.is_fd();
        let s = self.open.fixed_mut().ok_or(Error::NoScan)?;
        flush(s, id, fd, out)
    }

    /// Add the next point like [`ScanEncoder::push_point_into`], with due data frames
    /// written into slots of `sink`; the one form that takes points of every encoding
    /// one by one (a point of a lossless scan can make several frames due).
    pub fn push_point_to<S: FrameSink + ?Sized>(
        &mut self,
        distance: Distance,
        intensity: u16,
        sink: &mut S,
    ) -> Result<Run, Error> {
        if let Some(l) = self.open.lossless_mut() {
            let enc = l.header.encoding;
            let mut out = Out::new(sink, self.ids.id(Kind::Data), self.format.is_fd());
            let d = code::distance_code(distance, enc.unit_exp);
            let i = enc.intensity.encode(intensity);
            l.stream.push(d, i, &mut out)?;
            return Ok(Run {
                points: 1,
                invalid: u32::from(!code::is_range(d)),
                frames: out.frames,
                stop: (out.lost > 0).then_some(RunStop::NoSlot),
                rejected: 0,
            });
        }
        let mut frames = 0;
        let mut lost = false;
        let due = self.push_point_into(distance, intensity, || {
            let slot = sink.data_slot();
            lost = slot.is_none();
            frames = u32::from(!lost);
            slot
        })?;
        let valid = matches!(distance, Distance::Mm(_))
            && self
                .open
                .fixed()
                .is_some_and(|s| s.coder.code_valid(distance).1);
        Ok(Run {
            points: 1,
            invalid: u32::from(!valid),
            frames,
            stop: (due && lost).then_some(RunStop::NoSlot),
            rejected: 0,
        })
    }

    /// [`ScanEncoder::push_run`] of a lossless scan: each point's codes into the scan's
    /// segment stream.
    fn run_lossless<T, F, S>(
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
        let l = self.open.lossless_mut().ok_or(Error::NoScan)?;
        let enc = l.header.encoding;
        let mut out = Out::new(sink, self.ids.id(Kind::Data), self.format.is_fd());
        // The per-point work with every constant worked out once: the rule's band, the
        // unit's rounding, the intensity code as a shift and a mask (none: mask 0).
        let (min, [a, b]) = (rule.min, rule.except);
        let e = u32::from(enc.unit_exp & 0xF);
        let half = (1u32 << e) >> 1;
        let ishift = 16u32.wrapping_sub(enc.intensity.bits().min(16));
        let imask = if enc.intensity.is_present() {
            u32::MAX
        } else {
            0
        };
        // The common case in one test: the distances from `min` up to (not including)
        // the first of the rule's error codes, its band and the first distance too long
        // for a code are ranges, coded `(d + half + 128·2^e) >> e` (the rounded units
        // plus the range base) without any further check. An error code or band below
        // `min` leaves the span empty: every distance takes the full test.
        let bias = half.wrapping_add(code::RANGE_BASE << e); // at most 2^14 + 2^22
        let too_long = (u64::from(MAX_RANGE_UNITS) + 1) << e;
        let too_long = too_long
            .saturating_sub(u64::from(half))
            .min(u64::from(u32::MAX.wrapping_sub(bias))) as u32; // bias < 2^23
        let first_other = a.min(b).min(rule.band.unwrap_or(u32::MAX));
        let [lo, hi] = rule.window;
        let low = min.max(lo);
        let span = first_other
            .min(too_long)
            .min(hi.saturating_add(1))
            .saturating_sub(low);
        let code = |p: &T| {
            let (d, i) = point(p);
            let dc = if d.wrapping_sub(low) < span {
                // d < too_long: d + bias stays below 2^32 and the code below MAX_VALUE.
                d.wrapping_add(bias) >> e
            } else {
                lossless_code(&rule, d, e)
            };
            (dc, ((u32::from(i) >> ishift) & imask) as u16)
        };
        let (taken, invalid) = l.stream.push_run(points, code, &mut out);
        let stop = if out.lost > 0 {
            Some(RunStop::NoSlot)
        } else if taken < points.len() {
            Some(RunStop::TooManyPoints)
        } else {
            None
        };
        Ok(Run {
            points: taken as u32,
            invalid: invalid as u32,
            frames: out.frames,
            stop,
            rejected: 0,
        })
    }

    /// The trailer of a lossless scan: the points of its whole segments count as sent.
    fn finish_lossless(&mut self, l: Lossless, flags: TrailerFlags) -> Result<Emitted, Error> {
        let sent = l.stream.sent();
        let mut t = Trailer {
            seq: l.header.seq,
            points_sent: sent,
            points_valid: l.stream.valid_sent(),
            flags: TrailerFlags {
                truncated: sent < l.header.point_count,
                ..flags
            },
            crc: 0,
        };
        t.crc = l.stream.crc(&t.emit_head()?);
        let mut out = Emitted::new();
        let f = self.frame(Kind::Trailer, &t.emit()?)?;
        out.push(f).map_err(|_| Error::FrameTooLong)?;
        Ok(out)
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

/// [`code_block`] for an intensity width given as a value.
#[inline(always)]
fn code_block_any<T, F: Fn(&T) -> (u32, u16)>(
    ib: u32,
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    match ib {
        0 => code_block::<0, T, F>(points, rule, point, s, codes),
        8 => code_block::<8, T, F>(points, rule, point, s, codes),
        12 => code_block::<12, T, F>(points, rule, point, s, codes),
        _ => code_block::<16, T, F>(points, rule, point, s, codes),
    }
}

/// Codes `points` (at most [`BLOCK`]) into `codes`: per point its distance code in the
/// low 16 bits and its intensity code (`IB` bits) above. Returns the valid distance codes,
/// the points that are no range (as `rule` says) and those of them that were ranges
/// outside the rule's window. Kept out of line: in a function of
/// its own the loop keeps its counters and constants in registers; the usual cases (no
/// error code above DMIN, 1 mm units) get loops of their own.
#[inline(never)]
fn code_block<const IB: u32, T, F: Fn(&T) -> (u32, u16)>(
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    if s.coder.is_mm() && rule.min > 0 && rule.min <= s.coder.max_code() {
        return code_mm::<IB, T, F>(points, rule, point, s, codes);
    }
    code_points::<IB, T, F>(points, rule, point, s, codes)
}

/// The loop of [`code_block`] for the usual cases: the unit is 1 mm and `rule.min` is
/// not 0 and below the out-of-range code. The distances from DMIN (and the window's
/// start) below the rule's first error code, band, the window's end and the
/// out-of-range code are ranges coded as they are, found by one test; the others take
/// the full one ([`slow_code`], out of line: one copy for every loop). An empty span
/// sends every distance that way.
#[inline(always)]
fn code_mm<const IB: u32, T, F: Fn(&T) -> (u32, u16)>(
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    let max = s.coder.max_code();
    let [a, b] = rule.except;
    let [lo, hi] = rule.window;
    let first = a
        .min(b)
        .min(rule.band.unwrap_or(u32::MAX))
        .min(max)
        .min(hi.saturating_add(1));
    let low = rule.min.max(lo);
    let plain = first.saturating_sub(low);
    let (mut flags, mut n) = ([0u32; 3], 0u32);
    for (code, p) in codes.iter_mut().zip(points) {
        let (d, intensity) = point(p);
        let dc = if d.wrapping_sub(low) < plain {
            d
        } else {
            let (dc, k) = slow_code(&rule, d, max);
            // Counts of at most a block's points: no wrap.
            for (f, bit) in flags.iter_mut().zip(0u32..) {
                *f = f.wrapping_add((k >> bit) & 1);
            }
            dc
        };
        n = n.wrapping_add(1);
        *code = if IB > 0 {
            // IB is an intensity code width, 8..=16 here.
            dc | (u32::from(intensity) >> 16u32.wrapping_sub(IB)) << 16
        } else {
            dc
        };
    }
    let [invalid, over, rejected] = flags;
    // n <= BLOCK; the points at or past the out-of-range code counted are ranges.
    let valid = n.wrapping_sub(invalid).wrapping_sub(over) as u16;
    (valid, invalid, rejected)
}

/// The distance code (1 mm units) of a raw distance `d` outside [`code_mm`]'s span, and
/// what it is: bit 0 no range, bit 1 a range at or past the out-of-range code `max`,
/// bit 2 a range the window rejects.
#[inline(never)]
fn slow_code(rule: &RangeRule, d: u32, max: u32) -> (u32, u32) {
    let [lo, hi] = rule.window;
    let sensor = rule.is_sensor_range(d);
    let outside = d < lo || d > hi;
    let is_range = sensor && !outside;
    // Ranges (at least `min`, so never 0 mm) at or past the out-of-range code are
    // coded so.
    let dc = if is_range { d.min(max) } else { 0 };
    let k = u32::from(!is_range)
        | u32::from(is_range && d >= max) << 1
        | u32::from(sensor && outside) << 2;
    (dc, k)
}

/// The loop of [`code_block`] for any rule and unit.
#[inline(always)]
fn code_points<const IB: u32, T, F: Fn(&T) -> (u32, u16)>(
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    let coder = s.coder;
    let (mut valid, mut invalid, mut rejected) = (0u16, 0u32, 0u32);
    for (code, p) in codes.iter_mut().zip(points) {
        let (raw, intensity) = point(p);
        let distance = rule.distance(raw);
        let (dc, is_valid) = coder.code_valid(distance);
        // Counts of at most a block's points: no wrap.
        invalid = invalid.wrapping_add(u32::from(distance == Distance::Invalid));
        rejected = rejected.wrapping_add(u32::from(
            distance == Distance::Invalid && rule.rejects(raw),
        ));
        valid = valid.wrapping_add(u16::from(is_valid));
        *code = if IB > 0 {
            // IB is an intensity code width, 8..=16 here.
            u32::from(dc) | (u32::from(intensity) >> 16u32.wrapping_sub(IB)) << 16
        } else {
            u32::from(dc)
        };
    }
    (valid, invalid, rejected)
}

/// The valid distance codes and the points that were no range among `codes` (of points
/// a lost frame left untaken, to be given back).
#[cold]
fn untake(s: &InProgress, codes: &[u32]) -> (u16, u32) {
    let (mut valid, mut invalid) = (0u16, 0u32);
    for &code in codes {
        let dc = code as u16;
        // Counts of at most a block's points: no wrap.
        valid = valid.wrapping_add(u16::from(s.coder.is_valid(dc)));
        invalid = invalid.wrapping_add(u32::from(dc == 0));
    }
    (valid, invalid)
}

/// `codes` (distance code in the low 16 bits, intensity above) put one by one into the
/// classic payload `word` from bit `at` on, their codes into `crc`; returns the word and
/// the bit after them.
fn place_points(
    db: u32,
    ib: u32,
    codes: &[u32],
    mut word: u64,
    mut at: u32,
    crc: &mut ScanCrc,
) -> (u64, u32) {
    for &code in codes {
        crc.point_code(code, ib > 0);
        word |= (u64::from(code & 0xFFFF) | u64::from(code >> 16) << db) << (at & 63);
        // At most 4 points of at most 32 bits after 16: no wrap.
        at = at.wrapping_add(db).wrapping_add(ib);
    }
    (word, at)
}

/// The payload word of a whole classic frame of `n` points (1 to 4; `header` in its
/// low 16 bits) from the first `n` of `codes` (distance code in the low 16 bits,
/// intensity above), their codes into `crc`; `None` when fewer than `n` codes are there.
/// Written out per `n`, so every point goes in at a shift known at compile time.
#[inline(always)]
fn whole_frame(
    db: u32,
    ib: u32,
    codes: &[u32],
    n: usize,
    header: u64,
    crc: &mut ScanCrc,
) -> Option<u64> {
    let mut add = |code: u32| crc.point_code(code, ib > 0);
    // Point `i` of the frame, in place.
    let place = |code: u32, i: u32| {
        // At most 4 points of at most 32 bits: no wrap.
        let at = i.wrapping_mul(db.wrapping_add(ib)).wrapping_add(16);
        (u64::from(code & 0xFFFF) | u64::from(code >> 16) << db) << at
    };
    let word = match n {
        1 => {
            let &[a] = codes.first_chunk::<1>()?;
            add(a);
            place(a, 0)
        }
        2 => {
            let &[a, b] = codes.first_chunk::<2>()?;
            add(a);
            add(b);
            place(a, 0) | place(b, 1)
        }
        3 => {
            let &[a, b, c] = codes.first_chunk::<3>()?;
            add(a);
            add(b);
            add(c);
            place(a, 0) | place(b, 1) | place(c, 2)
        }
        4 => {
            let &[a, b, c, d] = codes.first_chunk::<4>()?;
            add(a);
            add(b);
            add(c);
            add(d);
            place(a, 0) | place(b, 1) | place(c, 2) | place(d, 3)
        }
        _ => return None,
    };
    Some(header | word)
}

/// The buffered points of `s` as a data frame with identifier `id`, written into `out`.
#[inline]
fn flush(s: &mut InProgress, id: embedded_can::Id, fd: bool, out: &mut Frame) -> Result<(), Error> {
    let len = if s.buffered == s.capacity {
        s.full_len
    } else {
        data_frame_len(&s.header.encoding, usize::from(s.buffered)).ok_or(Error::FrameTooLong)?
    };
    let dh = DataHeader {
        first_index: s.sent,
        seq_low: (s.header.seq & 0xF) as u8,
    };
    put(s.packer.bytes_mut(), 0..DATA_HEADER_LEN, &dh.emit());
    // Both count points of the scan (at most 4096 together): no wrap.
    s.sent = s.sent.wrapping_add(s.buffered);
    s.buffered = 0;
    let done = out.set(
        id,
        s.packer.frame_bytes(len).ok_or(Error::FrameTooLong)?,
        fd,
    );
    s.packer.reset(DATA_HEADER_LEN);
    done
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoding::{DistanceEncoding, Encoding, IntensityEncoding};
    use crate::header::Grouping;
    use crate::id::IdWindow;
    use embedded_can::{Id, StandardId};

    fn header(count: u16, encoding: Encoding) -> ScanHeader {
        ScanHeader {
            seq: 0x0107,
            timestamp_ms: 1000,
            point_count: count,
            encoding,
            time_synced: false,
            time_estimated: false,
            time_master: false,
            grouping: Grouping::Single,
            step_increment: 1,
            first_step: -2,
            ares: 1024,
        }
    }

    fn sid(raw: u16) -> Id {
        Id::Standard(StandardId::new(raw).unwrap())
    }

    const D12: Encoding = Encoding {
        distance: DistanceEncoding::D12,
        intensity: IntensityEncoding::None,
        unit_exp: 0,
    };

    #[test]
    fn in_place_frames_equal_returned_frames_and_a_dropped_one_still_counts() {
        let ids = IdWindow::DEFAULT.node(2).unwrap();
        let mut a = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
        let mut b = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
        a.begin(&header(5, D12)).unwrap();
        b.begin(&header(5, D12)).unwrap();
        let pts = [
            Distance::Mm(0xABC),
            Distance::Invalid,
            Distance::OutOfRange,
            Distance::Mm(0x123),
            Distance::Mm(5000),
        ];
        let mut returned = Vec::new();
        // A stale slot: the frame written into it must not keep old bytes.
        let mut slot = Frame::new(sid(0x7FF), &[0xEE; 8], false).unwrap();
        let mut due = Vec::new();
        for p in pts {
            returned.extend(a.push_point(p, 0).unwrap());
            due.push(b.push_point_into(p, 0, || Some(&mut slot)).unwrap());
        }
        assert_eq!(due, [false, false, false, true, true]);
        assert_eq!(slot, returned[1]);
        assert_eq!(slot.data(), &[0x04, 0x70, 0xFF, 0x0F]);
        // Dropped frames (no slot) advance the scan the same: same trailer.
        let mut c = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
        c.begin(&header(5, D12)).unwrap();
        for p in pts {
            c.push_point_into(p, 0, || None).unwrap();
        }
        let tb = b.finish(TrailerFlags::default()).unwrap();
        assert_eq!(c.finish(TrailerFlags::default()).unwrap()[0], tb[0]);
        assert_eq!(a.finish(TrailerFlags::default()).unwrap()[0], tb[0]);
        assert_eq!(
            b.push_point_into(Distance::Invalid, 0, || None),
            Err(Error::NoScan)
        );
    }

    /// A sink over a vector that has room for `room` frames.
    struct VecSink {
        frames: Vec<Frame>,
        room: usize,
    }

    impl FrameSink for VecSink {
        fn data_slot(&mut self) -> Option<&mut Frame> {
            if self.frames.len() >= self.room {
                return None;
            }
            // A stale slot, as a queue's reused one: nothing of it may remain.
            self.frames
                .push(Frame::new(sid(0x7FF), &[0xEE; 64], true).unwrap());
            self.frames.last_mut()
        }
    }

    proptest::proptest! {
        /// A run gives the frames, trailer and stops of point-by-point pushing, in every
        /// encoding and frame format, with runs cut anywhere and (`mix`) runs and single
        /// points taking turns within a frame.
        #[test]
        fn push_run_equals_push_point(
            d in 0usize..3,
            i in 0usize..4,
            unit_exp in 0u8..3,
            format in proptest::sample::select(vec![
                FrameFormat::Classic,
                FrameFormat::Fd { max_len: 12 },
                FrameFormat::Fd { max_len: 24 },
                FrameFormat::FD64,
            ]),
            count in 1u16..120,
            extra in 0usize..3,
            seed in proptest::collection::vec((0u32..70_000, proptest::prelude::any::<u16>()), 130),
            cuts in proptest::collection::vec(1usize..40, 1..8),
            room in 0usize..60,
            mix in proptest::prelude::any::<bool>(),
            rule_min in 0u32..40,
            rule_except in 0usize..4,
            band in proptest::prelude::any::<bool>(),
            window in proptest::option::of((0u32..3000, 0u32..70_000)),
        ) {
            let enc = Encoding {
                distance: DistanceEncoding::ALL[d],
                intensity: IntensityEncoding::ALL[i],
                unit_exp,
            };
            let ids = IdWindow::DEFAULT.node(3).unwrap();
            let rule = RangeRule {
                min: rule_min,
                except: [
                    [u32::MAX; 2],
                    [4095, u32::MAX],
                    [u32::MAX, 65533],
                    [65533, 4095],
                ][rule_except],
                band: band.then_some(65533),
                window: window.map_or([0, u32::MAX], |(lo, hi)| [lo, hi]),
            };
            // Raw distances: some below the minimum, some exactly an exception.
            let points: Vec<(u32, u16)> = seed
                .iter()
                .take(usize::from(count) + extra)
                .map(|&(mm, int)| match mm % 50 {
                    0 => (4095, int),
                    1 => (65533, int),
                    2 => (65534, int),
                    3 => (65535, int),
                    _ => (mm, int),
                })
                .collect();
            let raw = |&(r, i): &(u32, u16)| (r, i);
            // Point by point, with the same room for frames: once it is used up, every
            // due frame is lost and pushing goes on.
            let mut one = ScanEncoder::new(ids, format).unwrap();
            one.begin(&header(count, enc)).unwrap();
            let mut expected = Vec::new();
            let (mut stop, mut lost) = (None, 0);
            for &(r, i) in &points {
                match one.push_point(rule.distance(r), i) {
                    Ok(Some(f)) if expected.len() < room => expected.push(f),
                    Ok(Some(_)) => lost += 1,
                    Ok(None) => {}
                    Err(e) => {
                        proptest::prop_assert_eq!(e, Error::TooManyPoints);
                        stop = Some(RunStop::TooManyPoints);
                        break;
                    }
                }
            }
            // In runs (after a lost frame, the next run starts at the first point not
            // taken), and with `mix` point by point now and then.
            let mut two = ScanEncoder::new(ids, format).unwrap();
            two.begin(&header(count, enc)).unwrap();
            let mut sink = VecSink { frames: Vec::new(), room };
            let mut rest = &points[..];
            let (mut run_stop, mut run_lost, mut frames) = (None, 0, 0);
            // The window's rejections among the points the runs took, as the rule says.
            let (mut rejected, mut expected_rejected) = (0, 0);
            for (n, &cut) in cuts.iter().cycle().enumerate() {
                if rest.is_empty() || run_stop.is_some() {
                    break;
                }
                let (now, later) = rest.split_at(cut.min(rest.len()));
                if mix && n % 2 == 1 {
                    // Point by point into the same sink: the two ways share a frame.
                    for &(r, i) in now {
                        let mut got = false;
                        match two.push_point_into(rule.distance(r), i, || {
                            let slot = sink.data_slot();
                            got = slot.is_some();
                            slot
                        }) {
                            Ok(true) if got => frames += 1,
                            Ok(true) => run_lost += 1,
                            Ok(false) => {}
                            Err(_) => {
                                run_stop = Some(RunStop::TooManyPoints);
                                break;
                            }
                        }
                    }
                    rest = later;
                } else {
                    let run = two.push_run(now, rule, raw, &mut sink).unwrap();
                    frames += run.frames;
                    rejected += run.rejected;
                    let taken = &now[..run.points as usize];
                    expected_rejected += taken.iter().filter(|p| rule.rejects(p.0)).count();
                    match run.stop {
                        Some(RunStop::NoSlot) => {
                            run_lost += 1;
                            rest = &rest[run.points as usize..];
                        }
                        other => {
                            run_stop = other;
                            rest = later;
                        }
                    }
                }
            }
            proptest::prop_assert_eq!(run_stop, stop);
            proptest::prop_assert_eq!(run_lost, lost);
            proptest::prop_assert_eq!(rejected as usize, expected_rejected);
            proptest::prop_assert_eq!(frames as usize, sink.frames.len());
            proptest::prop_assert_eq!(&sink.frames, &expected);
            let t1 = one.finish(TrailerFlags::default()).unwrap();
            let t2 = two.finish(TrailerFlags::default()).unwrap();
            proptest::prop_assert_eq!(t1, t2);
        }
    }

    #[test]
    fn golden_scan_classic() {
        let ids = IdWindow::DEFAULT.node(2).unwrap();
        let mut e = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
        let h = e.begin(&header(5, D12)).unwrap();
        assert_eq!(h[0].id(), sid(0x132));
        assert_eq!(h[0].data(), &[0x07, 0x01, 0xE8, 0x03, 0, 0, 0x05, 0x00]);
        assert_eq!(h[1].id(), sid(0x142));
        assert_eq!(
            h[1].data(),
            &[0x07, 0x03, 0x00, 0x01, 0xFE, 0xFF, 0x00, 0x04]
        );
        let pts = [
            Distance::Mm(0xABC),
            Distance::Invalid,
            Distance::OutOfRange,
            Distance::Mm(0x123),
            Distance::Mm(5000), // > 4094 mm in D12/1 mm: out of range
        ];
        let mut frames = Vec::new();
        for p in pts {
            if let Some(f) = e.push_point(p, 0).unwrap() {
                frames.push(f);
            }
        }
        assert_eq!(frames.len(), 2);
        assert_eq!(frames[0].id(), sid(0x152));
        // seq low 7, index 0; codes ABC 000 FFF 123
        assert_eq!(
            frames[0].data(),
            &[0x00, 0x70, 0xBC, 0x0A, 0x00, 0xFF, 0x3F, 0x12]
        );
        // index 4; code FFF in 2 bytes
        assert_eq!(frames[1].data(), &[0x04, 0x70, 0xFF, 0x0F]);
        let t = e.finish(TrailerFlags::default()).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!(t[0].id(), sid(0x162));
        let d = t[0].data();
        // seq, sent 5, valid 2 (ABC and 123), CRC
        assert_eq!(&d[..6], &[0x07, 0x01, 0x05, 0x00, 0x02, 0x00]);
        let mut crc = ScanCrc::new(h[0].data(), h[1].data());
        for c in [0xABC, 0, 0xFFF, 0x123, 0xFFF] {
            crc.point(c, None);
        }
        assert_eq!(u16::from_le_bytes([d[6], d[7]]), crc.finish(&d[..6]));
        assert!(!e.in_progress());
    }

    #[test]
    fn truncated_and_abort() {
        let ids = IdWindow::DEFAULT.node(0).unwrap();
        let mut e = ScanEncoder::new(ids, FrameFormat::FD64).unwrap();
        e.begin(&header(100, D12)).unwrap();
        for _ in 0..45 {
            e.push_point(Distance::Mm(1000), 0).unwrap();
        }
        let out = e.finish(TrailerFlags::default()).unwrap();
        assert_eq!(out.len(), 2);
        assert!(out[0].is_fd());
        // 45 - 41 = 4 points → 6 + 2 = 8 bytes
        assert_eq!(out[0].data().len(), 8);
        let t = Trailer::parse(out[1].data()).unwrap();
        assert_eq!(t.points_sent, 45);
        assert!(t.flags.truncated);

        e.begin(&header(100, D12)).unwrap();
        for _ in 0..45 {
            e.push_point(Distance::Mm(1000), 0).unwrap();
        }
        let f = e.abort(AbortReason::Timeout, 0).unwrap();
        let a = Abort::parse(f.data()).unwrap();
        assert_eq!(a.points_sent, 41); // only the full frame went out
        assert_eq!(a.reason, AbortReason::Timeout);
    }

    #[test]
    fn misuse() {
        let ids = IdWindow::DEFAULT.node(0).unwrap();
        assert_eq!(
            ScanEncoder::new(ids, FrameFormat::Fd { max_len: 13 }).map(|_| ()),
            Err(Error::FrameTooLong)
        );
        let mut e = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
        assert_eq!(e.push_point(Distance::Invalid, 0), Err(Error::NoScan));
        assert_eq!(e.finish(TrailerFlags::default()), Err(Error::NoScan));
        assert_eq!(e.abort(AbortReason::Stopped, 0), Err(Error::NoScan));
        e.begin(&header(1, D12)).unwrap();
        assert_eq!(e.begin(&header(1, D12)), Err(Error::ScanInProgress));
        assert_eq!(e.set_format(FrameFormat::FD64), Err(Error::ScanInProgress));
        assert!(e.push_point(Distance::Invalid, 0).unwrap().is_some());
        assert_eq!(
            e.push_point(Distance::Invalid, 0),
            Err(Error::TooManyPoints)
        );
        let mut bad = header(1, D12);
        bad.step_increment = 0;
        e.finish(TrailerFlags::default()).unwrap();
        assert_eq!(e.begin(&bad), Err(Error::OutOfRange { offset: 3 }));
        assert!(!e.in_progress());
    }
}
