//! The single-point path: a point at a time into the data frame being filled (fixed-width
//! encodings) or the segment stream (lossless), and the frame it makes due.

use super::fixed::flush;
use super::{FrameSink, Open, Run, RunStop, ScanEncoder};
use crate::encoding::Distance;
use crate::frame::Frame;
use crate::lossless::bits::Out;
use crate::lossless::code;
use crate::Error;

impl ScanEncoder {
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
    pub(super) fn settle_pending(&mut self) {
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
    pub(super) fn add(&mut self, distance: Distance, intensity: u16) -> Result<bool, Error> {
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

    /// Turn the buffered points into a data frame (written into `out`).
    #[inline(never)]
    pub(super) fn flush_into(&mut self, out: &mut Frame) -> Result<(), Error> {
        let id = self.data_id;
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
            let mut out = Out::new(sink, self.data_id, self.format.is_fd());
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
}
