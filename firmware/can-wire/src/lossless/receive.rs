//! The receiver's state for the data frames of one lossless scan (SPEC 4.2.5): frames
//! gathered into segments by their framing byte, each segment decoded and checked
//! when its last frame arrives, its CRC kept for the scan CRC.

use super::bits::{COUNTER_MASK, SEGMENT_START};
use super::block::ReadError;
use super::{segment, segments, MAX_SEGMENTS, MAX_SEGMENT_BYTES, SEGMENT_POINTS};
use crate::frame::{is_valid_len, padded_len, MAX_LEN};
use crate::header::ScanHeader;
use crate::Error;

/// What a data frame did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Received {
    /// The frame repeats the previous one: ignored.
    Duplicate,
    /// The frame belongs to no segment being gathered (another scan's, or one whose
    /// earlier frames were lost): its points cannot be decoded.
    Orphan,
    /// Part of a segment; more frames are due.
    Pending,
    /// The frame completed a segment, whose codes were stored.
    Segment {
        /// Its first point.
        first: u16,
        /// Its points.
        points: u16,
        /// Its frames.
        frames: u16,
    },
    /// A segment that was begun again, or that fails its checks (malformed, CRC): its
    /// points stay missing.
    Corrupt,
}

/// Frames of a lossless scan being gathered.
#[derive(Debug, Clone)]
pub struct Receiver {
    buf: [u8; MAX_SEGMENT_BYTES],
    len: usize,
    /// Bytes of `buf` before the last frame's.
    before_last: usize,
    open: bool,
    frames: u16,
    next_counter: u8,
    last: [u8; MAX_LEN],
    last_len: usize,
    crcs: [Option<u16>; MAX_SEGMENTS],
}

impl Default for Receiver {
    fn default() -> Self {
        Receiver {
            buf: [0; MAX_SEGMENT_BYTES],
            len: 0,
            before_last: 0,
            open: false,
            frames: 0,
            next_counter: 0,
            last: [0; MAX_LEN],
            last_len: 0,
            crcs: [None; MAX_SEGMENTS],
        }
    }
}

impl Receiver {
    /// Forget everything (a new scan).
    pub fn reset(&mut self) {
        self.len = 0;
        self.before_last = 0;
        self.open = false;
        self.frames = 0;
        self.last_len = 0;
        self.crcs = [None; MAX_SEGMENTS];
    }

    /// The CRCs of segments `0..n` if all of them arrived, for the scan CRC.
    pub fn crcs(&self, n: usize) -> Option<impl Iterator<Item = u16> + '_> {
        let crcs = self.crcs.get(..n)?;
        crcs.iter()
            .all(Option::is_some)
            .then(|| crcs.iter().map(|c| c.unwrap_or(0)))
    }

    /// Take a data frame of the scan `header`; a decoded segment's codes go to `store`
    /// as `(index, distance code, intensity code)`. Errors are frames whose layout is
    /// invalid (length, segment number).
    pub fn frame(
        &mut self,
        data: &[u8],
        header: &ScanHeader,
        mut store: impl FnMut(u16, u32, u32),
    ) -> Result<Received, Error> {
        let (&head, payload) = data.split_first().ok_or(Error::BadLength {
            expected: 2,
            actual: 0,
        })?;
        if payload.is_empty() || !is_valid_len(data.len()) {
            return Err(Error::BadLength {
                expected: 2,
                actual: data.len() as u8,
            });
        }
        if self.last.get(..self.last_len) == Some(data) {
            return Ok(Received::Duplicate);
        }
        let counter = head & COUNTER_MASK;
        let count = usize::from(header.point_count);
        if head & SEGMENT_START != 0 {
            let (seq_low, index) = segment::header(payload).ok_or(Error::BadLength {
                expected: 3,
                actual: data.len() as u8,
            })?;
            if u16::from(seq_low) != header.seq & 0xF {
                return Ok(Received::Orphan);
            }
            if usize::from(index) >= segments(count) {
                return Err(Error::PointIndex);
            }
            self.open = true;
            self.len = 0;
            self.frames = 0;
        } else if !self.open || counter != self.next_counter {
            self.open = false;
            return Ok(Received::Orphan);
        }
        self.remember(data);
        self.next_counter = counter.wrapping_add(1) & COUNTER_MASK;
        self.frames = self.frames.saturating_add(1);
        self.before_last = self.len;
        let end = self.len.saturating_add(payload.len());
        let Some(dst) = self.buf.get_mut(self.len..end) else {
            self.open = false;
            return Ok(Received::Corrupt);
        };
        dst.copy_from_slice(payload);
        self.len = end;
        let mut d = [0u32; SEGMENT_POINTS];
        let mut i = [0u32; SEGMENT_POINTS];
        let intensity = header.encoding.intensity.is_present();
        let bytes = self.buf.get(..self.len).unwrap_or(&[]);
        let seg = match segment::decode(bytes, header.point_count, intensity, &mut d, &mut i) {
            Err(ReadError::NeedMore) => return Ok(Received::Pending),
            Err(ReadError::Corrupt) => {
                self.open = false;
                return Ok(Received::Corrupt);
            }
            Ok(seg) => seg,
        };
        self.open = false;
        // The segment ends in this frame, which is no longer than it needs to be.
        let used_here = seg.used.checked_sub(self.before_last).filter(|u| *u > 0);
        let tidy = used_here.is_some_and(|u| {
            u.checked_add(1).and_then(padded_len) == Some(data.len())
                && payload
                    .get(u..)
                    .is_some_and(|rest| rest.iter().all(|b| *b == 0))
        });
        let slot = self.crcs.get_mut(usize::from(seg.index));
        let fresh = slot.as_ref().is_some_and(|c| c.is_none());
        if !tidy || !fresh {
            return Ok(Received::Corrupt);
        }
        if let Some(c) = slot {
            *c = Some(seg.crc);
        }
        let first = usize::from(seg.index) * SEGMENT_POINTS;
        for (k, (&dc, &ic)) in d.iter().zip(i.iter()).take(seg.points).enumerate() {
            // At most 4096 points a scan: no wrap.
            store(first.wrapping_add(k) as u16, dc, ic);
        }
        Ok(Received::Segment {
            first: first as u16,
            points: seg.points as u16,
            frames: self.frames,
        })
    }

    fn remember(&mut self, data: &[u8]) {
        if let Some(dst) = self.last.get_mut(..data.len()) {
            dst.copy_from_slice(data);
            self.last_len = data.len();
        }
    }
}
