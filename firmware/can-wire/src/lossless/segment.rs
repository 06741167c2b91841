//! The receiver's side of one segment: its bytes (the stream parts of its frames, in
//! order) back to point codes, checked by the segment's CRC.

use super::bits::Reader;
use super::block::{read_block, History, ReadError};
use super::code::{ERROR_CODES, INVALID};
use super::{
    segment_points, BLOCK_POINTS, SEGMENT_HEADER_BITS, SEGMENT_POINTS, VALUE_BITS, WIDTH_BITS,
};
use crate::crc::ScanCrc;

/// A segment read whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decoded {
    /// `seq & 0xF` of its scan.
    pub seq_low: u8,
    /// Its number: its first point is `128 × index`.
    pub index: u8,
    /// Its points (the first `points` codes of the output arrays).
    pub points: usize,
    /// Bytes of the stream it took, CRC included.
    pub used: usize,
    /// Its CRC.
    pub crc: u16,
}

/// The header fields of a segment's first frame: `(seq & 0xF, segment number)`; `None`
/// when the stream is shorter than the header.
pub fn header(bytes: &[u8]) -> Option<(u8, u8)> {
    let mut r = Reader::new(bytes);
    let seq = r.read(4)? as u8;
    let index = r.read(5)? as u8;
    Some((seq, index))
}

fn anchor(r: &mut Reader<'_>) -> Result<u32, ReadError> {
    let w = r.read(WIDTH_BITS).ok_or(ReadError::NeedMore)?;
    if w > VALUE_BITS {
        return Err(ReadError::Corrupt);
    }
    r.read(w).ok_or(ReadError::NeedMore)
}

/// Read the segment at the start of `bytes` of a scan of `point_count` points (with an
/// intensity channel if `intensity`): codes into `distance` and `intensity_out`.
/// `NeedMore` while the stream is shorter than the segment; `Corrupt` for a malformed
/// segment, a reserved distance code, padding bits that are not zero or a CRC mismatch.
pub fn decode(
    bytes: &[u8],
    point_count: u16,
    intensity: bool,
    distance: &mut [u32; SEGMENT_POINTS],
    intensity_out: &mut [u32; SEGMENT_POINTS],
) -> Result<Decoded, ReadError> {
    let mut r = Reader::new(bytes);
    let seq_low = r.read(4).ok_or(ReadError::NeedMore)? as u8;
    let index = r.read(5).ok_or(ReadError::NeedMore)? as u8;
    debug_assert_eq!(r.position(), SEGMENT_HEADER_BITS as usize);
    let n = segment_points(usize::from(point_count), usize::from(index));
    if n == 0 {
        return Err(ReadError::Corrupt);
    }
    let d0 = anchor(&mut r)?;
    let mut hd = History::anchor(d0);
    if let Some(x) = distance.first_mut() {
        *x = d0;
    }
    let mut hi = History::default();
    if intensity {
        let i0 = anchor(&mut r)?;
        hi = History::anchor(i0);
        if let Some(x) = intensity_out.first_mut() {
            *x = i0;
        }
    }
    let mut start = 1;
    while start < n {
        let end = start.wrapping_add(BLOCK_POINTS).min(n); // start < n
        let block = distance.get_mut(start..end).ok_or(ReadError::Corrupt)?;
        read_block(&mut r, &mut hd, block)?;
        if intensity {
            let block = intensity_out
                .get_mut(start..end)
                .ok_or(ReadError::Corrupt)?;
            read_block(&mut r, &mut hi, block)?;
        }
        start = end;
    }
    let codes = distance.get(..n).unwrap_or(&[]);
    if codes.iter().any(|&c| (ERROR_CODES..INVALID).contains(&c)) {
        return Err(ReadError::Corrupt);
    }
    // Rounding up never goes below the position.
    let pad = r.position().next_multiple_of(8).wrapping_sub(r.position());
    if r.read(pad as u32).ok_or(ReadError::NeedMore)? != 0 {
        return Err(ReadError::Corrupt);
    }
    let body = r.position() / 8;
    // `body` is at most `usize::MAX / 8`: adding 2 cannot wrap.
    let used = body.wrapping_add(2);
    let sent = bytes.get(body..used).ok_or(ReadError::NeedMore)?;
    let sent = u16::from_le_bytes([
        sent.first().copied().unwrap_or(0),
        sent.get(1).copied().unwrap_or(0),
    ]);
    let mut crc = ScanCrc::start();
    crc.bytes(bytes.get(..body).unwrap_or(&[]));
    if crc.value() != sent {
        return Err(ReadError::Corrupt);
    }
    Ok(Decoded {
        seq_low,
        index,
        points: n,
        used,
        crc: sent,
    })
}

#[cfg(test)]
mod tests {
    use super::super::bits::Out;
    use super::super::stream::ScanStream;
    use super::*;
    use crate::frame::Frame;
    use crate::id::{IdWindow, Kind};

    type Frames = std::vec::Vec<Frame>;

    /// Code a scan, then decode each segment from its frames.
    fn round_trip(d: &[u32], i: Option<&[u32]>, full: usize) {
        let mut sink = Frames::new();
        let id = IdWindow::DEFAULT.node(0).unwrap().id(Kind::Data);
        let fd = full > 8;
        let mut out = Out::new(&mut sink, id, fd);
        let mut s = ScanStream::new(0x1234, d.len() as u16, i.is_some(), full, &[0; 8], &[0; 8]);
        for (k, &v) in d.iter().enumerate() {
            let iv = i.map_or(0, |i| i[k] as u16);
            s.push(v, iv, &mut out).unwrap();
        }
        assert_eq!(s.sent() as usize, d.len());
        // Split the frames into segments by their start flag.
        let mut segs: std::vec::Vec<std::vec::Vec<u8>> = vec![];
        for (n, f) in sink.iter().enumerate() {
            let b = f.data();
            assert_eq!(b[0] & 0x7F, (n % 128) as u8, "frame counter");
            if b[0] & 0x80 != 0 {
                segs.push(vec![]);
            }
            segs.last_mut().unwrap().extend_from_slice(&b[1..]);
        }
        assert_eq!(segs.len(), super::super::segments(d.len()));
        for (k, seg) in segs.iter().enumerate() {
            let (mut dd, mut ii) = ([0; SEGMENT_POINTS], [0; SEGMENT_POINTS]);
            // Every prefix short of the CRC needs more.
            let whole = decode(seg, d.len() as u16, i.is_some(), &mut dd, &mut ii).unwrap();
            assert_eq!(whole.seq_low, 4);
            assert_eq!(whole.index as usize, k);
            assert!(
                seg[whole.used..].iter().all(|b| *b == 0),
                "only FD padding after"
            );
            for cut in [0, whole.used / 2, whole.used - 1] {
                assert_eq!(
                    decode(&seg[..cut], d.len() as u16, i.is_some(), &mut dd, &mut ii),
                    Err(ReadError::NeedMore)
                );
            }
            let first = k * SEGMENT_POINTS;
            assert_eq!(&dd[..whole.points], &d[first..first + whole.points]);
            if let Some(i) = i {
                assert_eq!(&ii[..whole.points], &i[first..first + whole.points]);
            }
        }
    }

    #[test]
    fn scans_round_trip() {
        let d: std::vec::Vec<u32> = (0..682).map(|k| 128 + 1000 + (k * 13 % 29)).collect();
        round_trip(&d, None, 8);
        round_trip(&d, None, 64);
        let i: std::vec::Vec<u32> = (0..682).map(|k| k * 7919 % 65536).collect();
        round_trip(&d, Some(&i), 8);
        round_trip(&d[..1], Some(&i[..1]), 8);
        round_trip(&d[..129], None, 12);
    }

    /// A sink with room for `room` frames that hands out at most `batch` slots per
    /// request, each holding a stale
    /// CAN FD frame cleared past its 8th byte (as a queue's reused slot), and records
    /// the requests.
    struct Batches {
        frames: Frames,
        room: usize,
        batch: usize,
        single: usize,
        asked: std::vec::Vec<usize>,
    }

    /// A queue's reused slot: a CAN FD frame that left it, its bytes past the 8th
    /// cleared (as [`crate::encoder::FrameSink`] wants).
    fn stale() -> Frame {
        let mut f = Frame::new(Frame::default().id(), &[0xEE; 64], true).unwrap();
        f.clear_fd_bytes();
        f
    }

    impl crate::encoder::FrameSink for Batches {
        fn data_slot(&mut self) -> Option<&mut Frame> {
            self.single += 1;
            if self.frames.len() >= self.room {
                return None;
            }
            self.frames.push(stale());
            self.frames.last_mut()
        }

        fn data_slots(&mut self, n: usize) -> &mut [Frame] {
            self.asked.push(n);
            let from = self.frames.len();
            let k = n.min(self.batch).min(self.room.saturating_sub(from));
            self.frames.resize(from + k, stale());
            &mut self.frames[from..]
        }
    }

    /// On classic CAN a scan's full data frames go into slots asked for a batch at a
    /// time (only a segment's last, shorter frame takes a slot of its own), in runs of
    /// a data line's points, and they are the frames SPEC 4.2 describes: counted in
    /// order, 8 bytes but a segment's last, no stale byte, every point decoded back.
    #[test]
    fn classic_frames_take_their_slots_in_batches() {
        let d: std::vec::Vec<u32> = (0..682).map(|k| 128 + 1000 + (k * 37 % 301)).collect();
        let mut sink = Batches {
            frames: Frames::new(),
            room: usize::MAX,
            batch: 3,
            single: 0,
            asked: vec![],
        };
        let id = IdWindow::DEFAULT.node(0).unwrap().id(Kind::Data);
        let mut out = Out::new(&mut sink, id, false);
        let mut s = ScanStream::new(0x1234, d.len() as u16, false, 8, &[0; 8], &[0; 8]);
        let misses = core::cell::Cell::new(0);
        for line in d.chunks(21) {
            let (taken, _) = s.push_run(line, |&v: &u32| (v, 0), &misses, &mut out);
            assert_eq!(taken, line.len());
        }
        assert_eq!((out.lost, s.sent() as usize), (0, d.len()));
        let frames = out.frames as usize;
        let segments = super::super::segments(d.len());
        assert_eq!(sink.frames.len(), frames);
        assert!(sink.single <= segments, "{} single slots", sink.single);
        assert!(sink.asked.iter().any(|&n| n >= 2), "asked {:?}", sink.asked);
        let mut segs: std::vec::Vec<std::vec::Vec<u8>> = vec![];
        for (n, f) in sink.frames.iter().enumerate() {
            let b = f.data();
            assert!(!f.is_fd());
            assert_eq!(b[0] & 0x7F, (n % 128) as u8, "frame counter");
            if b[0] & 0x80 != 0 {
                segs.push(vec![]);
            }
            let last = sink
                .frames
                .get(n + 1)
                .is_none_or(|g| g.data()[0] & 0x80 != 0);
            assert!(last || f.len() == 8, "only a segment's last frame is short");
            segs.last_mut().unwrap().extend_from_slice(&b[1..]);
        }
        assert_eq!(segs.len(), segments);
        for (k, seg) in segs.iter().enumerate() {
            let (mut dd, mut ii) = ([0; SEGMENT_POINTS], [0; SEGMENT_POINTS]);
            let whole = decode(seg, d.len() as u16, false, &mut dd, &mut ii).unwrap();
            assert_eq!(whole.used, seg.len(), "segment {k}: no byte after its CRC");
            let first = k * SEGMENT_POINTS;
            assert_eq!(&dd[..whole.points], &d[first..first + whole.points]);
        }
    }

    /// A batch of classic frames the sink has no room for is lost whole and counted,
    /// the run stops, and the frames that did get a slot are the scan's first ones.
    #[test]
    fn classic_frames_without_a_slot_are_counted_and_stop_the_run() {
        let d: std::vec::Vec<u32> = (0..300).map(|k| 128 + 1000 + (k * 37 % 301)).collect();
        let id = IdWindow::DEFAULT.node(0).unwrap().id(Kind::Data);
        let code = |&v: &u32| (v, 0);
        let misses = core::cell::Cell::new(0);
        let mut all = Frames::new();
        let mut out = Out::new(&mut all, id, false);
        let mut s = ScanStream::new(7, d.len() as u16, false, 8, &[0; 8], &[0; 8]);
        for line in d.chunks(21) {
            s.push_run(line, code, &misses, &mut out);
        }
        // Room for 10 frames, handed out 4 at a time: the run that needs the 11th stops
        // there, with every frame it had due and no slot for counted as lost.
        let mut sink = Batches {
            frames: Frames::new(),
            room: 10,
            batch: 4,
            single: 0,
            asked: vec![],
        };
        let mut out = Out::new(&mut sink, id, false);
        let mut s = ScanStream::new(7, d.len() as u16, false, 8, &[0; 8], &[0; 8]);
        let mut stopped = None;
        for (n, line) in d.chunks(21).enumerate() {
            let (taken, _) = s.push_run(line, code, &misses, &mut out);
            if out.lost > 0 {
                stopped = Some((n, taken));
                break;
            }
            assert_eq!(taken, line.len());
        }
        let (n, taken) = stopped.expect("a run ran out of slots");
        assert!(taken <= 21 && n > 0);
        assert_eq!(out.frames, 10);
        assert!(out.lost >= 1);
        assert_eq!(&sink.frames[..], &all[..10]);
    }

    #[test]
    fn reserved_codes_and_bad_crc_are_corrupt() {
        let mut sink = Frames::new();
        let id = IdWindow::DEFAULT.node(0).unwrap().id(Kind::Data);
        let mut out = Out::new(&mut sink, id, true);
        let mut s = ScanStream::new(0, 3, false, 64, &[0; 8], &[0; 8]);
        for v in [200, 110, 200] {
            s.push(v, 0, &mut out).unwrap();
        }
        let seg = sink[0].data()[1..].to_vec();
        let (mut dd, mut ii) = ([0; SEGMENT_POINTS], [0; SEGMENT_POINTS]);
        assert_eq!(
            decode(&seg, 3, false, &mut dd, &mut ii),
            Err(ReadError::Corrupt)
        );

        let mut sink = Frames::new();
        let mut out = Out::new(&mut sink, id, true);
        let mut s = ScanStream::new(0, 3, false, 64, &[0; 8], &[0; 8]);
        for v in [200, 300, 200] {
            s.push(v, 0, &mut out).unwrap();
        }
        let mut seg = sink[0].data()[1..].to_vec();
        assert!(decode(&seg, 3, false, &mut dd, &mut ii).is_ok());
        for bit in 0..(seg.len() * 8) {
            seg[bit / 8] ^= 1 << (bit % 8);
            let r = decode(&seg, 3, false, &mut dd, &mut ii);
            assert!(
                r.is_err()
                    || r.unwrap().used < seg.len()
                        && seg[r.unwrap().used..].iter().any(|b| *b != 0)
                    || dd[..3] == [200, 300, 200],
                "flip {bit} decoded wrongly: {:?}",
                &dd[..3]
            );
            seg[bit / 8] ^= 1 << (bit % 8);
        }
    }
}
