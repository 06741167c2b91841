//! The reassembling decoder: frames of up to 16 bridges in any interleaving in, whole
//! scans with per-point presence and a completeness verdict out (SPEC section 7).
//!
//! # Receiving scans in your own program
//!
//! [`Decoder`] is the receiver API: no_std, no allocation, no I/O. Give it every frame
//! your CAN driver receives, as `(identifier, data)` with [`Decoder::push`] (or a
//! [`Frame`] with [`Decoder::push_frame`]); frames outside the identifier window are
//! ignored. A frame that completes something returns an [`Event`]: a [`Scan`] of bridge
//! `node` (when its trailer or abort arrives, or when the bridge's next scan begins), a
//! [`Status`] page, a control answer or request. Time is yours: the receive time of the
//! frame that returned the event is the event's receive time; a scan's own time is its
//! header's `timestamp_ms` (sensor time, or the bridge's clock when `time_synced`).
//!
//! - Sizing: `Decoder<P, B>` holds `B` bridges of up to `P` points (`P =`
//!   [`crate::MAX_POINTS`] takes any scan), about `B * 2 * 5 * P` bytes: keep a large
//!   one in a `static` or a `Box`.
//! - Use a scan's points only when [`Scan::completeness`] is `Intact` or `Incomplete`
//!   (missing points are `None`); a CRC mismatch, corrupt or aborted scan's points are
//!   not the values sent. [`Scan::points`] lists the points the scan has (the trailer's
//!   count when it arrived); [`ScanHeader::angle`] gives each point's angle (`None`
//!   when the bridge did not know the sensor's geometry).
//! - The scan of an [`Event::Scan`] borrows the decoder: copy out what you need before
//!   the next push.
//! - A bridge that stops mid-scan leaves it in progress: [`Decoder::flush`] finishes it
//!   as incomplete (after a timeout of your choosing, or at the end of a log).
//! - [`Decoder::stats`] counts per bridge what was lost, duplicated or corrupt.
//!
//! The crate's example `receive` reads a candump log (or standard input) this way and
//! prints every scan with its time: `cargo run -p can-wire --example receive -- LOG`.

use embedded_can::Id;

use crate::abort::{Abort, AbortReason};
use crate::control::{Answer, Control};
use crate::crc::ScanCrc;
use crate::data::DataFrame;
use crate::encoding::Distance;
use crate::frame::Frame;
use crate::header::{HeaderA, HeaderB, ScanHeader, HEADER_LEN};
use crate::id::{IdWindow, Kind, NODES};
use crate::lossless::code as lossless_code;
use crate::lossless::receive::{Received, Receiver};
use crate::status::Status;
use crate::trailer::{Trailer, TRAILER_CRC_PREFIX};
use crate::Error;

/// Per-bridge loss statistics (all counters wrap).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LossStats {
    /// Scans reported intact.
    pub scans_intact: u32,
    /// Scans not intact: incomplete, CRC mismatch, corrupt; also those whose header B
    /// never arrived (SPEC 7: incomplete, but with no header to decode them by they are
    /// not reported).
    pub scans_damaged: u32,
    /// Scans reported aborted by the bridge.
    pub scans_aborted: u32,
    /// Scans of which nothing arrived: sequence gaps between headers A.
    pub scans_lost: u32,
    /// Frames known or estimated to be lost: missing header B and trailer frames, and
    /// missing data frames estimated from the runs of missing points.
    pub frames_lost: u32,
    /// Scan frames that belong to no scan in progress (e.g. their header was lost).
    pub frames_orphaned: u32,
    /// Frames received twice with equal content.
    pub duplicates: u32,
    /// Frames with a bad layout, conflicting duplicates, CRC mismatches.
    pub corrupt: u32,
    /// Times the sequence number went backwards (bridge restarted).
    pub sequence_resets: u32,
}

/// How complete and trustworthy a reassembled scan is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Completeness {
    /// Every sent point, both headers and the trailer arrived, and the CRC matches.
    /// (Check [`Scan::trailer`] flags for what the bridge says about the content.)
    Intact,
    /// Frames are missing.
    Incomplete {
        /// Points that did not arrive (or did not fit the decoder).
        missing_points: u16,
        /// The trailer did not arrive.
        trailer_missing: bool,
    },
    /// All frames arrived but the CRC does not match.
    CrcMismatch,
    /// Conflicting frames or counts that contradict the header or the points.
    Corrupt,
    /// The bridge abandoned the scan.
    Aborted {
        /// Why.
        reason: AbortReason,
        /// Reason-specific detail.
        detail: u8,
    },
}

/// One decoded point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Point {
    /// The distance.
    pub distance: Distance,
    /// The 16-bit intensity, if the scan has the channel.
    pub intensity: Option<u16>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// No scan (or the last one was reported).
    Idle,
    /// Header A arrived, waiting for header B.
    HaveA,
    /// Both headers arrived; collecting points.
    Active,
    /// Reported; kept for duplicate detection.
    Done,
}

/// A scan being reassembled or just reported, with room for `P` points.
#[derive(Debug, Clone)]
pub struct Scan<const P: usize> {
    state: State,
    a: HeaderA,
    a_bytes: [u8; HEADER_LEN],
    b_bytes: [u8; HEADER_LEN],
    header: ScanHeader,
    trailer: Option<Trailer>,
    trailer_bytes: [u8; 8],
    completeness: Completeness,
    /// Distance codes (16 bits at most, except in the lossless coding).
    distance: [u32; P],
    intensity: [u16; P],
    present: [bool; P],
    received: u16,
    frame_capacity: u16,
    conflict: bool,
    /// The data frames of a lossless scan.
    lossless: Receiver,
}

impl<const P: usize> Scan<P> {
    fn new() -> Self {
        Scan {
            state: State::Idle,
            a: HeaderA {
                seq: 0,
                timestamp_ms: 0,
                point_count: 0,
                unit_exp: 0,
            },
            a_bytes: [0; HEADER_LEN],
            b_bytes: [0; HEADER_LEN],
            header: ScanHeader {
                seq: 0,
                timestamp_ms: 0,
                point_count: 0,
                encoding: crate::Encoding::PLAIN_MM,
                time_synced: false,
                time_estimated: false,
                time_master: false,
                grouping: crate::Grouping::Single,
                step_increment: 1,
                first_step: 0,
                ares: 1,
            },
            trailer: None,
            trailer_bytes: [0; 8],
            completeness: Completeness::Incomplete {
                missing_points: 0,
                trailer_missing: true,
            },
            distance: [0; P],
            intensity: [0; P],
            present: [false; P],
            received: 0,
            frame_capacity: 0,
            conflict: false,
            lossless: Receiver::default(),
        }
    }

    fn start(&mut self, a: HeaderA, bytes: &[u8]) {
        self.state = State::HaveA;
        self.a = a;
        self.a_bytes
            .copy_from_slice(bytes.get(..HEADER_LEN).unwrap_or(&[0; HEADER_LEN]));
        self.trailer = None;
        self.present = [false; P];
        self.received = 0;
        self.frame_capacity = 0;
        self.conflict = false;
        self.lossless.reset();
    }

    fn in_progress(&self) -> bool {
        matches!(self.state, State::HaveA | State::Active)
    }

    /// The scan's header.
    pub fn header(&self) -> &ScanHeader {
        &self.header
    }

    /// The verdict.
    pub fn completeness(&self) -> Completeness {
        self.completeness
    }

    /// Whether the scan arrived intact.
    pub fn is_intact(&self) -> bool {
        self.completeness == Completeness::Intact
    }

    /// The trailer, if it arrived.
    pub fn trailer(&self) -> Option<&Trailer> {
        self.trailer.as_ref()
    }

    /// Number of points that arrived.
    pub fn received(&self) -> u16 {
        self.received
    }

    /// Number of points the scan lists: none for an aborted scan (SPEC 3.5: the receiver
    /// discards its points), the trailer's `points_sent` when it arrived (a truncated
    /// scan has no more), else the header's `point_count`.
    pub fn listed(&self) -> u16 {
        match (self.completeness, &self.trailer) {
            (Completeness::Aborted { .. }, _) => 0,
            (_, Some(t)) => t.points_sent.min(self.header.point_count),
            (_, None) => self.header.point_count,
        }
    }

    /// Point `index`, or `None` if it did not arrive or is not listed
    /// ([`Scan::listed`]).
    pub fn point(&self, index: u16) -> Option<Point> {
        let i = usize::from(index);
        if index >= self.listed() || !self.present.get(i).copied().unwrap_or(false) {
            return None;
        }
        let enc = self.header.encoding;
        let dc = self.distance.get(i).copied().unwrap_or(0);
        let ic = self.intensity.get(i).copied().unwrap_or(0);
        let distance = if enc.distance.is_lossless() {
            // Reserved codes never reach the scan (their segment is rejected).
            lossless_code::decode_distance(dc, enc.unit_exp).unwrap_or(Distance::Invalid)
        } else {
            enc.decode_distance(dc as u16)
        };
        Some(Point {
            distance,
            intensity: enc.intensity.is_present().then(|| enc.intensity.decode(ic)),
        })
    }

    /// The [listed](Scan::listed) points in order, `None` for the missing ones.
    pub fn points(&self) -> impl Iterator<Item = Option<Point>> + '_ {
        (0..self.listed()).map(|i| self.point(i))
    }

    fn missing_in(&self, count: u16) -> u16 {
        let stored = usize::from(count).min(P);
        let missing_stored = self
            .present
            .get(..stored)
            .map_or(0, |s| s.iter().filter(|p| !**p).count());
        // stored <= count, and the sum is at most count.
        missing_stored.wrapping_add(usize::from(count).wrapping_sub(stored)) as u16
    }

    /// Estimated data frames needed for the missing points among the first `count`.
    fn missing_frames(&self, count: u16) -> u32 {
        // A full frame holds at least a classic frame's points; the largest frame seen
        // tells more on CAN FD.
        let cap = usize::from(self.frame_capacity)
            .max(self.header.encoding.capacity(8))
            .max(1);
        // Both stay at most `count` (a u16): no wrap.
        let mut frames = 0u32;
        let mut run = 0usize;
        for i in 0..usize::from(count) {
            if self.present.get(i).copied().unwrap_or(false) {
                frames = frames.wrapping_add(run.div_ceil(cap) as u32);
                run = 0;
            } else {
                run = run.wrapping_add(1);
            }
        }
        frames.wrapping_add(run.div_ceil(cap) as u32)
    }

    fn crc_matches(&self, t: &Trailer) -> bool {
        let mut crc = ScanCrc::new(&self.a_bytes, &self.b_bytes);
        let head = self.trailer_bytes.get(..TRAILER_CRC_PREFIX).unwrap_or(&[]);
        if self.header.encoding.distance.is_lossless() {
            // Headers, each segment's CRC, the trailer (SPEC 4.2.4).
            let sent = usize::from(t.points_sent);
            let whole = sent % crate::lossless::SEGMENT_POINTS == 0
                || t.points_sent == self.header.point_count;
            if !whole {
                return false;
            }
            let n = crate::lossless::segments(sent);
            let Some(crcs) = self.lossless.crcs(n) else {
                return false;
            };
            for c in crcs {
                crc.bytes(&c.to_le_bytes());
            }
            return crc.finish(head) == t.crc;
        }
        let with_intensity = self.header.encoding.intensity.is_present();
        let sent = usize::from(t.points_sent);
        for (d, i) in self.distance.iter().zip(self.intensity.iter()).take(sent) {
            crc.point(*d as u16, with_intensity.then_some(*i));
        }
        crc.finish(head) == t.crc
    }

    fn valid_count(&self, sent: u16) -> u16 {
        let enc = self.header.encoding;
        let lossless = enc.distance.is_lossless();
        self.distance
            .iter()
            .take(usize::from(sent))
            .filter(|d| {
                if lossless {
                    lossless_code::is_range(**d)
                } else {
                    enc.is_valid_code(**d as u16)
                }
            })
            .count() as u16
    }
}

/// What one frame produced.
#[derive(Debug)]
pub enum Event<'a, const P: usize> {
    /// A scan finished (by its trailer or abort, or because the next scan began).
    Scan {
        /// The bridge's node number.
        node: u8,
        /// The scan; valid until the next call into the decoder.
        scan: &'a Scan<P>,
    },
    /// A status frame.
    Status {
        /// The bridge's node number.
        node: u8,
        /// Its content.
        status: Status,
    },
    /// A control answer.
    Answer {
        /// The bridge's node number.
        node: u8,
        /// Its content.
        answer: Answer,
    },
    /// A control request (sent by some host to the bridge).
    Control {
        /// The addressed bridge's node number.
        node: u8,
        /// Its content.
        control: Control,
    },
}

#[derive(Debug, Clone)]
struct Bridge<const P: usize> {
    node: u8,
    last_seq: Option<u16>,
    slots: [Scan<P>; 2],
    cur: usize,
}

/// Reassembles scans of up to `B` bridges with up to `P` points each.
///
/// Memory: about `B * 2 * 5 * P` bytes; keep it in a `static` or a `Box` for large `P`.
#[derive(Debug)]
pub struct Decoder<const P: usize, const B: usize> {
    window: IdWindow,
    stats: [LossStats; NODES as usize],
    bridges: [Option<Bridge<P>>; B],
}

impl<const P: usize, const B: usize> Decoder<P, B> {
    /// A decoder for the bridges of `window`.
    pub fn new(window: IdWindow) -> Self {
        Decoder {
            window,
            stats: [LossStats::default(); NODES as usize],
            bridges: core::array::from_fn(|_| None),
        }
    }

    /// Loss statistics of bridge `node`.
    pub fn stats(&self, node: u8) -> Option<&LossStats> {
        self.stats.get(usize::from(node))
    }

    /// Decode one frame. Frames outside the window give `Ok(None)`; frames that fail
    /// validation give an error (and are counted as corrupt).
    pub fn push(&mut self, id: Id, data: &[u8]) -> Result<Option<Event<'_, P>>, Error> {
        let Some((node, kind)) = self.window.classify(id) else {
            return Ok(None);
        };
        match self.dispatch(node, kind, data) {
            Err(e) => {
                if let Some(s) = self.stats.get_mut(usize::from(node)) {
                    bump(&mut s.corrupt);
                }
                Err(e)
            }
            Ok(None) => Ok(None),
            Ok(Some(out)) => Ok(self.event(node, out)),
        }
    }

    fn event(&self, node: u8, out: Out) -> Option<Event<'_, P>> {
        Some(match out {
            Out::Scan { bridge, slot } => Event::Scan {
                node,
                scan: self.bridges.get(bridge)?.as_ref()?.slots.get(slot)?,
            },
            Out::Status(status) => Event::Status { node, status },
            Out::Answer(answer) => Event::Answer { node, answer },
            Out::Control(control) => Event::Control { node, control },
        })
    }

    /// [`Decoder::push`] for a [`Frame`].
    pub fn push_frame(&mut self, frame: &Frame) -> Result<Option<Event<'_, P>>, Error> {
        self.push(frame.id(), frame.data())
    }

    /// Finish bridge `node`'s scan in progress as incomplete (e.g. after a timeout) and
    /// return it; `None` if there is none or it never got its header B.
    pub fn flush(&mut self, node: u8) -> Option<&Scan<P>> {
        let idx = self.find(node)?;
        let stats = self.stats.get_mut(usize::from(node))?;
        let bridge = self.bridges.get_mut(idx)?.as_mut()?;
        let cur = bridge.cur;
        let scan = bridge.slots.get_mut(cur)?;
        if !scan.in_progress() {
            return None;
        }
        finish_incomplete(scan, stats).then_some(&*scan)
    }

    fn find(&self, node: u8) -> Option<usize> {
        self.bridges
            .iter()
            .position(|b| b.as_ref().is_some_and(|b| b.node == node))
    }

    fn bridge_index(&mut self, node: u8) -> Result<usize, Error> {
        if let Some(i) = self.find(node) {
            return Ok(i);
        }
        let free = self
            .bridges
            .iter()
            .position(|b| b.is_none())
            .ok_or(Error::TooManyBridges)?;
        if let Some(slot) = self.bridges.get_mut(free) {
            *slot = Some(Bridge {
                node,
                last_seq: None,
                slots: [Scan::new(), Scan::new()],
                cur: 0,
            });
        }
        Ok(free)
    }

    fn dispatch(&mut self, node: u8, kind: Kind, data: &[u8]) -> Result<Option<Out>, Error> {
        match kind {
            Kind::Control => Ok(Some(Out::Control(Control::parse(data)?))),
            Kind::ControlAnswer => Ok(Some(Out::Answer(Answer::parse(data)?))),
            Kind::Status => Ok(Some(Out::Status(Status::parse(data)?))),
            _ => {
                let idx = self.bridge_index(node)?;
                let stats = self
                    .stats
                    .get_mut(usize::from(node))
                    .ok_or(Error::ForeignId)?;
                let bridge = self
                    .bridges
                    .get_mut(idx)
                    .and_then(|b| b.as_mut())
                    .ok_or(Error::TooManyBridges)?;
                let done = scan_frame(bridge, stats, kind, data)?;
                Ok(done.map(|slot| Out::Scan { bridge: idx, slot }))
            }
        }
    }
}

/// An event without borrows, turned into an [`Event`] at the end of `push`.
enum Out {
    Scan { bridge: usize, slot: usize },
    Status(Status),
    Answer(Answer),
    Control(Control),
}

fn bump(c: &mut u32) {
    *c = c.wrapping_add(1);
}

/// Report a scan in progress without its trailer. Returns whether it is reportable
/// (had both headers).
fn finish_incomplete<const P: usize>(scan: &mut Scan<P>, stats: &mut LossStats) -> bool {
    let reportable = scan.state == State::Active;
    scan.state = State::Done;
    bump(&mut stats.frames_lost); // the trailer
    if !reportable {
        // Header B was lost: the scan is incomplete, but cannot be decoded.
        bump(&mut stats.frames_lost); // header B
        bump(&mut stats.scans_damaged);
        return false;
    }
    let count = scan.header.point_count;
    stats.frames_lost = stats.frames_lost.wrapping_add(scan.missing_frames(count));
    scan.completeness = if scan.conflict {
        Completeness::Corrupt
    } else {
        Completeness::Incomplete {
            missing_points: scan.missing_in(count),
            trailer_missing: true,
        }
    };
    bump(&mut stats.scans_damaged);
    true
}

/// A data frame of a lossless scan (SPEC 4.2.5): into its segment; a whole, checked
/// segment's points into the scan.
fn lossless_frame<const P: usize>(
    scan: &mut Scan<P>,
    stats: &mut LossStats,
    data: &[u8],
) -> Result<(), Error> {
    let header = scan.header;
    let (distance, intensity, present) =
        (&mut scan.distance, &mut scan.intensity, &mut scan.present);
    let mut stored = 0u16;
    let got = scan.lossless.frame(data, &header, |i, d, n| {
        let i = usize::from(i);
        if let (Some(pd), Some(pi), Some(pp)) = (
            distance.get_mut(i),
            intensity.get_mut(i),
            present.get_mut(i),
        ) {
            *pd = d;
            // Intensity codes are 16 bits at most.
            *pi = n as u16;
            *pp = true;
            stored = stored.saturating_add(1);
        }
    })?;
    scan.received = scan.received.wrapping_add(stored);
    match got {
        Received::Duplicate => bump(&mut stats.duplicates),
        Received::Orphan => bump(&mut stats.frames_orphaned),
        Received::Corrupt => bump(&mut stats.corrupt),
        Received::Pending => {}
        Received::Segment { points, frames, .. } => {
            let per_frame = points.div_ceil(frames.max(1));
            scan.frame_capacity = scan.frame_capacity.max(per_frame);
        }
    }
    Ok(())
}

/// Handle a scan frame; returns the slot index of a scan to report.
fn scan_frame<const P: usize>(
    bridge: &mut Bridge<P>,
    stats: &mut LossStats,
    kind: Kind,
    data: &[u8],
) -> Result<Option<usize>, Error> {
    let cur = bridge.cur;
    match kind {
        Kind::HeaderA => {
            let a = HeaderA::parse(data)?;
            let scan = bridge.slots.get_mut(cur).ok_or(Error::NoScan)?;
            if scan.state != State::Idle && scan.a.seq == a.seq {
                if scan.a_bytes.as_slice() == data {
                    bump(&mut stats.duplicates);
                } else {
                    scan.conflict = true;
                    bump(&mut stats.corrupt);
                }
                return Ok(None);
            }
            if let Some(last) = bridge.last_seq {
                let gap = a.seq.wrapping_sub(last).wrapping_sub(1);
                if gap < 0x8000 {
                    stats.scans_lost = stats.scans_lost.wrapping_add(u32::from(gap));
                } else {
                    bump(&mut stats.sequence_resets);
                }
            }
            bridge.last_seq = Some(a.seq);
            let mut report = None;
            if scan.in_progress() && finish_incomplete(scan, stats) {
                report = Some(cur);
                bridge.cur = cur ^ 1;
            }
            let next = bridge.slots.get_mut(bridge.cur).ok_or(Error::NoScan)?;
            next.start(a, data);
            Ok(report)
        }
        Kind::HeaderB => {
            let b = HeaderB::parse(data)?;
            let scan = bridge.slots.get_mut(cur).ok_or(Error::NoScan)?;
            match scan.state {
                State::HaveA if scan.a.seq as u8 == b.seq_low => {
                    scan.header = ScanHeader::join(&scan.a, &b)?;
                    scan.b_bytes.copy_from_slice(data);
                    scan.state = State::Active;
                }
                State::Active | State::Done if scan.a.seq as u8 == b.seq_low => {
                    if scan.b_bytes.as_slice() == data {
                        bump(&mut stats.duplicates);
                    } else {
                        scan.conflict = true;
                        bump(&mut stats.corrupt);
                    }
                }
                _ => bump(&mut stats.frames_orphaned),
            }
            Ok(None)
        }
        Kind::Data => {
            let scan = bridge.slots.get_mut(cur).ok_or(Error::NoScan)?;
            if scan.state != State::Active {
                bump(&mut stats.frames_orphaned);
                return Ok(None);
            }
            let header = scan.header;
            if header.encoding.distance.is_lossless() {
                lossless_frame(scan, stats, data)?;
                return Ok(None);
            }
            let frame = DataFrame::parse(data, &header)?;
            if frame.header().seq_low != (header.seq & 0xF) as u8 {
                bump(&mut stats.frames_orphaned);
                return Ok(None);
            }
            let (mut equal, mut differ) = (0u16, 0u16);
            for (i, d, n) in frame.codes() {
                let i = usize::from(i);
                if scan.present.get(i).copied().unwrap_or(false) {
                    let same = scan.distance.get(i) == Some(&u32::from(d))
                        && scan.intensity.get(i) == Some(&n);
                    // At most a frame's points: no wrap.
                    if same {
                        equal = equal.wrapping_add(1);
                    } else {
                        differ = differ.wrapping_add(1);
                    }
                }
            }
            if differ == 0 && equal == frame.len() {
                bump(&mut stats.duplicates);
                return Ok(None);
            }
            if differ > 0 || equal > 0 {
                // Frames never overlap: this one is corrupt, and so may be the scan.
                scan.conflict = true;
                bump(&mut stats.corrupt);
                return Ok(None);
            }
            for (i, d, n) in frame.codes() {
                let i = usize::from(i);
                if let (Some(pd), Some(pi), Some(pp)) = (
                    scan.distance.get_mut(i),
                    scan.intensity.get_mut(i),
                    scan.present.get_mut(i),
                ) {
                    *pd = u32::from(d);
                    *pi = n;
                    *pp = true;
                    scan.received = scan.received.saturating_add(1);
                }
            }
            scan.frame_capacity = scan.frame_capacity.max(frame.len());
            Ok(None)
        }
        Kind::Trailer => {
            let t = Trailer::parse(data)?;
            let scan = bridge.slots.get_mut(cur).ok_or(Error::NoScan)?;
            if scan.state == State::Done && scan.a.seq == t.seq {
                if scan.trailer_bytes.as_slice() == data {
                    bump(&mut stats.duplicates);
                } else {
                    bump(&mut stats.corrupt);
                }
                return Ok(None);
            }
            if !scan.in_progress() || scan.a.seq != t.seq {
                bump(&mut stats.frames_orphaned);
                return Ok(None);
            }
            if scan.state == State::HaveA {
                // Header B was lost: the scan is incomplete, but cannot be decoded.
                scan.state = State::Done;
                bump(&mut stats.frames_lost);
                bump(&mut stats.scans_damaged);
                return Ok(None);
            }
            scan.trailer_bytes.copy_from_slice(data);
            scan.trailer = Some(t);
            scan.state = State::Done;
            let count = scan.header.point_count;
            scan.completeness = if t.check_count(count).is_err() || scan.conflict {
                Completeness::Corrupt
            } else {
                let missing = scan.missing_in(t.points_sent);
                if missing > 0 {
                    stats.frames_lost = stats
                        .frames_lost
                        .wrapping_add(scan.missing_frames(t.points_sent));
                    Completeness::Incomplete {
                        missing_points: missing,
                        trailer_missing: false,
                    }
                } else if !scan.crc_matches(&t) {
                    Completeness::CrcMismatch
                } else if scan.valid_count(t.points_sent) != t.points_valid {
                    Completeness::Corrupt
                } else {
                    Completeness::Intact
                }
            };
            match scan.completeness {
                Completeness::Intact => bump(&mut stats.scans_intact),
                Completeness::CrcMismatch | Completeness::Corrupt => {
                    bump(&mut stats.corrupt);
                    bump(&mut stats.scans_damaged);
                }
                _ => bump(&mut stats.scans_damaged),
            }
            Ok(Some(cur))
        }
        Kind::Abort => {
            let a = Abort::parse(data)?;
            let scan = bridge.slots.get_mut(cur).ok_or(Error::NoScan)?;
            if !scan.in_progress() || scan.a.seq != a.seq {
                if scan.state == State::Done && scan.a.seq == a.seq {
                    bump(&mut stats.duplicates);
                } else {
                    bump(&mut stats.frames_orphaned);
                }
                return Ok(None);
            }
            let reportable = scan.state == State::Active;
            scan.state = State::Done;
            scan.completeness = Completeness::Aborted {
                reason: a.reason,
                detail: a.detail,
            };
            bump(&mut stats.scans_aborted);
            Ok(reportable.then_some(cur))
        }
        Kind::Control | Kind::ControlAnswer | Kind::Status => Ok(None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::id::NodeIds;
    use crate::{DistanceEncoding, Encoding, Grouping, IntensityEncoding};
    use embedded_can::StandardId;

    const D12: Encoding = Encoding {
        distance: DistanceEncoding::D12,
        intensity: IntensityEncoding::None,
        unit_exp: 0,
    };

    fn ids(node: u8) -> NodeIds {
        IdWindow::DEFAULT.node(node).unwrap()
    }

    // Scan seq 0x0107, 5 D12 points (ABC, invalid, out of range, 123, out of range), as
    // in the encoder's golden test.
    const A: [u8; 8] = [0x07, 0x01, 0xE8, 0x03, 0, 0, 0x05, 0x00];
    const B: [u8; 8] = [0x07, 0x03, 0x00, 0x01, 0xFE, 0xFF, 0x00, 0x04];
    const D0: [u8; 8] = [0x00, 0x70, 0xBC, 0x0A, 0x00, 0xFF, 0x3F, 0x12];
    const D1: [u8; 4] = [0x04, 0x70, 0xFF, 0x0F];

    fn trailer() -> [u8; 8] {
        let mut crc = ScanCrc::new(&A, &B);
        for c in [0xABC, 0, 0xFFF, 0x123, 0xFFF] {
            crc.point(c, None);
        }
        let head = [0x07, 0x01, 0x05, 0x00, 0x02, 0x00];
        let c = crc.finish(&head).to_le_bytes();
        [
            head[0], head[1], head[2], head[3], head[4], head[5], c[0], c[1],
        ]
    }

    fn feed(dec: &mut Decoder<16, 2>, node: u8, kind: Kind, data: &[u8]) -> Option<Completeness> {
        match dec.push(ids(node).id(kind), data) {
            Ok(Some(Event::Scan { scan, .. })) => Some(scan.completeness()),
            _ => None,
        }
    }

    #[test]
    fn golden_scan_decodes() {
        let mut dec: Decoder<16, 2> = Decoder::new(IdWindow::DEFAULT);
        assert_eq!(feed(&mut dec, 2, Kind::HeaderA, &A), None);
        assert_eq!(feed(&mut dec, 2, Kind::HeaderB, &B), None);
        assert_eq!(feed(&mut dec, 2, Kind::Data, &D0), None);
        assert_eq!(feed(&mut dec, 2, Kind::Data, &D1), None);
        let t = trailer();
        let id = ids(2).id(Kind::Trailer);
        let Ok(Some(Event::Scan { node, scan })) = dec.push(id, &t) else {
            panic!("no scan");
        };
        assert_eq!(node, 2);
        assert!(scan.is_intact());
        assert_eq!(scan.header().point_count, 5);
        assert_eq!(scan.header().encoding, D12);
        assert_eq!(scan.header().grouping, Grouping::Single);
        let pts: Vec<_> = scan.points().map(|p| p.map(|p| p.distance)).collect();
        assert_eq!(
            pts,
            vec![
                Some(Distance::Mm(0xABC)),
                Some(Distance::Invalid),
                Some(Distance::OutOfRange),
                Some(Distance::Mm(0x123)),
                Some(Distance::OutOfRange),
            ]
        );
        assert_eq!(scan.point(5), None);
        assert_eq!(scan.point(0).unwrap().intensity, None);
        // A repeated trailer is a duplicate.
        assert_eq!(feed(&mut dec, 2, Kind::Trailer, &t), None);
        assert_eq!(dec.stats(2).unwrap().duplicates, 1);
        assert_eq!(dec.stats(2).unwrap().scans_intact, 1);
    }

    #[test]
    fn crc_mismatch_and_valid_count() {
        let mut dec: Decoder<16, 2> = Decoder::new(IdWindow::DEFAULT);
        for (k, d) in [
            (Kind::HeaderA, &A[..]),
            (Kind::HeaderB, &B),
            (Kind::Data, &D0),
        ] {
            feed(&mut dec, 0, k, d);
        }
        // Last point changed from out of range to 0xFFE: valid count 3 ≠ 2 and CRC differs.
        feed(&mut dec, 0, Kind::Data, &[0x04, 0x70, 0xFE, 0x0F]);
        assert_eq!(
            feed(&mut dec, 0, Kind::Trailer, &trailer()),
            Some(Completeness::CrcMismatch)
        );
        assert_eq!(dec.stats(0).unwrap().corrupt, 1);
    }

    #[test]
    fn conflicting_and_orphan_frames() {
        let mut dec: Decoder<16, 2> = Decoder::new(IdWindow::DEFAULT);
        // Data before any header: orphan.
        assert_eq!(feed(&mut dec, 1, Kind::Data, &D0), None);
        assert_eq!(dec.stats(1).unwrap().frames_orphaned, 1);
        feed(&mut dec, 1, Kind::HeaderA, &A);
        // Header B of another scan: orphan.
        let mut b = B;
        b[0] = 0x08;
        feed(&mut dec, 1, Kind::HeaderB, &b);
        assert_eq!(dec.stats(1).unwrap().frames_orphaned, 2);
        feed(&mut dec, 1, Kind::HeaderB, &B);
        feed(&mut dec, 1, Kind::Data, &D0);
        // Same index, other codes: conflict → the scan cannot be intact.
        let mut d = D0;
        d[2] ^= 1;
        feed(&mut dec, 1, Kind::Data, &d);
        feed(&mut dec, 1, Kind::Data, &D1);
        assert_eq!(
            feed(&mut dec, 1, Kind::Trailer, &trailer()),
            Some(Completeness::Corrupt)
        );
        // Data frame of another scan (sequence low bits 8): orphan.
        feed(&mut dec, 1, Kind::HeaderA, &[0x08, 0x01, 0, 0, 0, 0, 5, 0]);
        feed(&mut dec, 1, Kind::HeaderB, &b);
        let before = dec.stats(1).unwrap().frames_orphaned;
        feed(&mut dec, 1, Kind::Data, &D0);
        assert_eq!(dec.stats(1).unwrap().frames_orphaned, before + 1);
    }

    #[test]
    fn next_header_reports_the_unfinished_scan() {
        let mut dec: Decoder<16, 2> = Decoder::new(IdWindow::DEFAULT);
        feed(&mut dec, 0, Kind::HeaderA, &A);
        feed(&mut dec, 0, Kind::HeaderB, &B);
        feed(&mut dec, 0, Kind::Data, &D1);
        let next = [0x08, 0x01, 0, 0, 0, 0, 5, 0];
        assert_eq!(
            feed(&mut dec, 0, Kind::HeaderA, &next),
            Some(Completeness::Incomplete {
                missing_points: 4,
                trailer_missing: true
            })
        );
        let s = dec.stats(0).unwrap();
        assert_eq!(s.frames_lost, 2); // the trailer and the 4-point frame
        assert_eq!(s.scans_damaged, 1);
        assert!(dec.flush(0).is_none()); // the new scan has no header B yet
    }

    #[test]
    fn scan_larger_than_decoder() {
        let mut dec: Decoder<4, 1> = Decoder::new(IdWindow::DEFAULT);
        let push = |dec: &mut Decoder<4, 1>, k: Kind, d: &[u8]| match dec.push(ids(0).id(k), d) {
            Ok(Some(Event::Scan { scan, .. })) => Some(scan.completeness()),
            _ => None,
        };
        push(&mut dec, Kind::HeaderA, &A);
        push(&mut dec, Kind::HeaderB, &B);
        push(&mut dec, Kind::Data, &D0);
        push(&mut dec, Kind::Data, &D1);
        assert_eq!(
            push(&mut dec, Kind::Trailer, &trailer()),
            Some(Completeness::Incomplete {
                missing_points: 1,
                trailer_missing: false
            })
        );
        // A second bridge does not fit.
        assert_eq!(
            dec.push(ids(1).id(Kind::HeaderA), &A).map(|e| e.is_some()),
            Err(Error::TooManyBridges)
        );
    }

    /// Feeds frames to node 0; the completeness and points of the scan the last one
    /// reports.
    fn scan_of(
        dec: &mut Decoder<16, 2>,
        frames: &[(Kind, &[u8])],
    ) -> Option<(Completeness, Vec<Option<Distance>>)> {
        let mut got = None;
        for (k, d) in frames {
            if let Ok(Some(Event::Scan { scan, .. })) = dec.push(ids(0).id(*k), d) {
                let pts = scan.points().map(|p| p.map(|p| p.distance)).collect();
                got = Some((scan.completeness(), pts));
            }
        }
        got
    }

    #[test]
    fn an_aborted_scan_lists_no_points() {
        // SPEC 3.5: the receiver discards the points of an aborted scan. Abort of seq
        // 0x0107, reason 2 (line checksum), detail 0, 4 points sent.
        let abort = [0x07, 0x01, 0x02, 0x00, 0x04, 0x00];
        let mut dec: Decoder<16, 2> = Decoder::new(IdWindow::DEFAULT);
        let frames = [
            (Kind::HeaderA, &A[..]),
            (Kind::HeaderB, &B),
            (Kind::Data, &D0),
            (Kind::Abort, &abort),
        ];
        let (c, pts) = scan_of(&mut dec, &frames).expect("reported");
        assert!(matches!(c, Completeness::Aborted { .. }), "{c:?}");
        assert_eq!(pts, vec![]);
        assert_eq!(dec.stats(0).unwrap().scans_aborted, 1);
    }

    #[test]
    fn a_truncated_scan_lists_the_points_sent() {
        // Header A announces 5 points; the trailer says 4 were sent (truncated flag,
        // bit 12 of bytes 2..4), 2 of them valid. CRC-16/IBM-3740 over A, B, the codes
        // ABC 000 FFF 123 as u16 LE and the trailer's bytes 0..6, computed by hand.
        let t = [0x07, 0x01, 0x04, 0x10, 0x02, 0x00, 0x79, 0x7C];
        let mut dec: Decoder<16, 2> = Decoder::new(IdWindow::DEFAULT);
        let frames = [
            (Kind::HeaderA, &A[..]),
            (Kind::HeaderB, &B),
            (Kind::Data, &D0),
            (Kind::Trailer, &t),
        ];
        let (c, pts) = scan_of(&mut dec, &frames).expect("reported");
        assert_eq!(c, Completeness::Intact);
        assert_eq!(
            pts,
            vec![
                Some(Distance::Mm(0xABC)),
                Some(Distance::Invalid),
                Some(Distance::OutOfRange),
                Some(Distance::Mm(0x123)),
            ]
        );
    }

    #[test]
    fn a_scan_without_header_b_is_damaged_not_lost() {
        // SPEC 7: its header A arrived, so the scan is incomplete; "lost" is for
        // sequence gaps. Ended by its trailer, and by the next header A.
        let mut dec: Decoder<16, 2> = Decoder::new(IdWindow::DEFAULT);
        scan_of(
            &mut dec,
            &[(Kind::HeaderA, &A[..]), (Kind::Trailer, &trailer())],
        );
        let s = *dec.stats(0).unwrap();
        assert_eq!((s.scans_damaged, s.scans_lost, s.frames_lost), (1, 0, 1));
        let next = [0x08, 0x01, 0, 0, 0, 0, 5, 0];
        scan_of(
            &mut dec,
            &[
                (Kind::HeaderA, &next),
                (Kind::HeaderA, &[0x09, 0x01, 0, 0, 0, 0, 5, 0]),
            ],
        );
        let s = *dec.stats(0).unwrap();
        // Header B and trailer of 0x0108 lost.
        assert_eq!((s.scans_damaged, s.scans_lost, s.frames_lost), (2, 0, 3));
    }

    #[test]
    fn other_frames() {
        let mut dec: Decoder<16, 1> = Decoder::new(IdWindow::DEFAULT);
        let foreign = Id::Standard(StandardId::new(0x0FF).unwrap());
        assert!(matches!(dec.push(foreign, &[1, 2]), Ok(None)));
        let hb = [0, 3, 10, 20, 1, 0, 0, 0];
        assert!(matches!(
            dec.push(ids(4).id(Kind::Status), &hb),
            Ok(Some(Event::Status { node: 4, .. }))
        ));
        assert!(matches!(
            dec.push(ids(4).id(Kind::ControlAnswer), &[1, 2, 0, 0]),
            Ok(Some(Event::Answer { node: 4, .. }))
        ));
        assert!(matches!(
            dec.push(ids(4).id(Kind::Control), &[1, 2]),
            Ok(Some(Event::Control { node: 4, .. }))
        ));
        assert_eq!(
            dec.push(ids(4).id(Kind::Status), &hb[..7])
                .map(|e| e.is_some()),
            Err(Error::BadLength {
                expected: 8,
                actual: 7
            })
        );
        assert_eq!(dec.stats(4).unwrap().corrupt, 1);
        assert_eq!(dec.stats(16), None);
    }
}
