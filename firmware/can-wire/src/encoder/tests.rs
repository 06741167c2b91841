//! Unit tests of the scan encoder.

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

/// A sink over a vector that has room for `room` frames, handing out at most `batch` of
/// them at a time to [`FrameSink::data_slots`] (0: the trait's default, one at a time).
struct VecSink {
    frames: Vec<Frame>,
    room: usize,
    batch: usize,
}

/// A stale slot, as a queue's reused one: a CAN FD frame that left it, its bytes past
/// the 8th cleared (as [`FrameSink`] wants); nothing of it may remain.
fn stale() -> Frame {
    let mut f = Frame::new(sid(0x7FF), &[0xEE; 64], true).unwrap();
    f.clear_fd_bytes();
    f
}

impl FrameSink for VecSink {
    fn data_slot(&mut self) -> Option<&mut Frame> {
        if self.frames.len() >= self.room {
            return None;
        }
        self.frames.push(stale());
        self.frames.last_mut()
    }

    fn data_slots(&mut self, n: usize) -> &mut [Frame] {
        if self.batch == 0 {
            return match self.data_slot() {
                Some(frame) if n > 0 => core::slice::from_mut(frame),
                Some(_) => panic!("a slot was taken for no frame"),
                None => &mut [],
            };
        }
        let from = self.frames.len();
        let k = n.min(self.batch).min(self.room.saturating_sub(from));
        self.frames.resize(from + k, stale());
        &mut self.frames[from..]
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
        batch in 0usize..5,
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
        // Raw distances: some below the minimum (error codes), some exactly an
        // exception.
        let points: Vec<(u32, u16)> = seed
            .iter()
            .take(usize::from(count) + extra)
            .map(|&(mm, int)| match mm % 50 {
                0 => (4095, int),
                1 => (65533, int),
                2 => (65534, int),
                3 => (65535, int),
                4..=9 => (mm % 48, int),
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
        let mut sink = VecSink { frames: Vec::new(), room, batch };
        let mut rest = &points[..];
        let (mut run_stop, mut run_lost, mut frames) = (None, 0, 0);
        // The window's rejections among the points the runs took, as the rule says.
        let (mut rejected, mut expected_rejected) = (0, 0);
        // The same for the points that were no range.
        let (mut invalid, mut expected_invalid) = (0, 0);
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
                invalid += run.invalid;
                expected_invalid += taken.iter().filter(|p| !rule.is_range(p.0)).count();
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
        proptest::prop_assert_eq!(invalid as usize, expected_invalid);
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

/// A lossless run counts the ranges its rule's window takes away (as the fixed-width
/// runs do), among the points it took only.
#[test]
fn lossless_run_counts_the_window_rejections_it_took() {
    let enc = Encoding {
        distance: DistanceEncoding::Lossless,
        intensity: IntensityEncoding::None,
        unit_exp: 0,
    };
    let ids = IdWindow::DEFAULT.node(2).unwrap();
    let rule = RangeRule {
        window: [1000, 5000],
        ..RangeRule::at_least(20)
    };
    // 500 and 6000: ranges outside the window; 10: an error code (below `min`);
    // 1500 and 3000 kept; 7000 outside too, but the scan of 5 points does not take it.
    let points = [
        (500, 0),
        (1500, 0),
        (6000, 0),
        (10, 0),
        (3000, 0),
        (7000, 0),
    ];
    let mut e = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
    e.begin(&header(5, enc)).unwrap();
    let mut sink = VecSink {
        frames: Vec::new(),
        room: 100,
        batch: 1,
    };
    let run = e
        .push_run(&points, rule, |p: &(u32, u16)| *p, &mut sink)
        .unwrap();
    assert_eq!(run.points, 5);
    assert_eq!(run.stop, Some(RunStop::TooManyPoints));
    assert_eq!(run.invalid, 3);
    assert_eq!(run.rejected, 2);
}

/// A lossless run codes each raw distance as SPEC 4.2's code table says, whichever of
/// the run's paths takes it (the ranges of the common span, the error codes below the
/// rule's minimum, the full test): written here from the table, for minimums below,
/// at and above the sensors' 100 error codes, with exceptions, a band and a window,
/// and the distances around each bound.
#[test]
fn lossless_runs_code_every_distance_as_the_code_table_says() {
    use crate::reassembly::{Decoder, Event};
    let enc = Encoding {
        distance: DistanceEncoding::Lossless,
        intensity: IntensityEncoding::None,
        unit_exp: 0,
    };
    let ids = IdWindow::DEFAULT.node(4).unwrap();
    // The code table: a range inside the window keeps its millimetres (below
    // 2^20 - 128 with unit 1 mm), a range outside it is invalid, and what is no range
    // keeps its error code if it has one (0..=99, 65533..=65535), out of range or
    // invalid otherwise.
    let reference = |rule: &RangeRule, d: u32| {
        let sensor_range = d >= rule.min
            && d != rule.except[0]
            && d != rule.except[1]
            && rule.band.is_none_or(|s| d < s || d > s + 2);
        if sensor_range {
            if d < rule.window[0] || d > rule.window[1] {
                Distance::Invalid
            } else if d > (1 << 20) - 129 {
                Distance::OutOfRange
            } else {
                Distance::Mm(d)
            }
        } else if d < 100 || (65533..=65535).contains(&d) {
            Distance::SensorError(d)
        } else if d >= 1 << 24 {
            Distance::Invalid
        } else {
            Distance::OutOfRange
        }
    };
    let mut raw: Vec<u32> = (0..=210).collect();
    raw.extend([
        4095,
        65532,
        65533,
        65534,
        65535,
        65536,
        (1 << 20) - 130,
        (1 << 20) - 129,
        (1 << 20) - 128,
        (1 << 24) - 1,
        1 << 24,
        u32::MAX,
    ]);
    for min in [0, 1, 20, 23, 99, 100, 101, 150] {
        for (except, band, window) in [
            ([u32::MAX; 2], None, [0, u32::MAX]),
            ([0, 21], Some(65533), [0, u32::MAX]),
            ([4095, 120], None, [22, 180]),
            ([u32::MAX; 2], Some(98), [0, 65534]),
        ] {
            let rule = RangeRule {
                min,
                except,
                band,
                window,
            };
            let mut e = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
            let count = raw.len() as u16;
            let mut frames: Vec<Frame> = e.begin(&header(count, enc)).unwrap().to_vec();
            let mut sink = VecSink {
                frames: Vec::new(),
                room: usize::MAX,
                batch: 3,
            };
            // Runs of a data line's length.
            let (mut invalid, mut rejected) = (0, 0);
            for line in raw.chunks(21) {
                let run = e
                    .push_run(line, rule, |&d: &u32| (d, 0), &mut sink)
                    .unwrap();
                assert_eq!(run.points as usize, line.len());
                invalid += run.invalid as usize;
                rejected += run.rejected as usize;
            }
            let what = format!("min {min} except {except:?} band {band:?} window {window:?}");
            // No range: every code but a range's (too long ones included).
            assert_eq!(
                invalid,
                raw.iter()
                    .filter(|&&d| !matches!(reference(&rule, d), Distance::Mm(_)))
                    .count(),
                "{what}"
            );
            assert_eq!(
                rejected,
                raw.iter().filter(|&&d| rule.rejects(d)).count(),
                "{what}"
            );
            frames.extend(sink.frames);
            frames.extend(e.finish(TrailerFlags::default()).unwrap().iter().cloned());
            let mut dec: Box<Decoder<512, 1>> = Box::new(Decoder::new(IdWindow::DEFAULT));
            let mut got = None;
            for f in &frames {
                if let Ok(Some(Event::Scan { scan, .. })) = dec.push_frame(f) {
                    assert!(scan.is_intact(), "{what}");
                    got = Some(
                        scan.points()
                            .map(|p| p.map_or(Distance::Invalid, |p| p.distance))
                            .collect::<Vec<_>>(),
                    );
                }
            }
            let want: Vec<Distance> = raw.iter().map(|&d| reference(&rule, d)).collect();
            assert_eq!(got.as_ref(), Some(&want), "{what}");
        }
    }
}

/// The intensity widths share one coding loop, each intensity cut to its top bits
/// first: a run's data bytes for D16 with I8, I12 and I16, written here by hand (little
/// endian, least significant bit first; the 2-byte data header, then per point the
/// 16-bit distance code and the intensity code above it). Both coding loops: the 1 mm
/// one (`at_least(20)`: 5 mm is an error code, no range, code 0) and the general one
/// (`at_least(0)`: 5 mm is a range); intensities at both ends (0x00FF has no top bits,
/// 0xFFFF all), a range past the largest code (0xFFFF). CAN FD (one frame) and classic
/// (the payloads of its frames, whole points each for I8 and I16).
#[test]
fn the_intensity_widths_keep_their_top_bits() {
    let points = [
        (0x1234u32, 0xABCDu16),
        (0x0567, 0x00FF),
        (5, 0x8001),
        (70_000, 0xFFFF),
    ];
    // Per rule minimum, the third point's distance code.
    for (min, p3) in [(20u32, 0x00u8), (0, 0x05)] {
        let i8 = [
            0x34, 0x12, 0xAB, 0x67, 0x05, 0x00, p3, 0x00, 0x80, 0xFF, 0xFF, 0xFF,
        ];
        // 28 bits a point: 0x1234, 0xABC; 0x0567, 0x00F; p3, 0x800; 0xFFFF, 0xFFF.
        let i12 = [
            0x34, 0x12, 0xBC, 0x7A, 0x56, 0xF0, 0x00, p3, 0x00, 0x00, 0xF8, 0xFF, 0xFF, 0xFF,
        ];
        let i16 = [
            0x34, 0x12, 0xCD, 0xAB, 0x67, 0x05, 0xFF, 0x00, p3, 0x00, 0x01, 0x80, 0xFF, 0xFF, 0xFF,
            0xFF,
        ];
        let cases: [(IntensityEncoding, &[u8]); 3] = [
            (IntensityEncoding::I8, &i8),
            (IntensityEncoding::I12, &i12),
            (IntensityEncoding::I16, &i16),
        ];
        for (intensity, bytes) in cases {
            let enc = Encoding {
                distance: DistanceEncoding::D16,
                intensity,
                unit_exp: 0,
            };
            let rule = RangeRule::at_least(min);
            for format in [FrameFormat::FD64, FrameFormat::Classic] {
                let ids = IdWindow::DEFAULT.node(1).unwrap();
                let mut e = ScanEncoder::new(ids, format).unwrap();
                e.begin(&header(4, enc)).unwrap();
                let mut frames: Vec<Frame> = Vec::new();
                let run = e.push_run(&points, rule, |p| *p, &mut frames).unwrap();
                assert_eq!(run.points, 4);
                assert_eq!(run.invalid, u32::from(min > 5), "{intensity:?} {min}");
                let mut payload = Vec::new();
                for f in &frames {
                    // Data header: the first point's index (low 12 bits), sequence 7.
                    assert_eq!(f.data()[1] >> 4, 7);
                    payload.extend_from_slice(&f.data()[2..]);
                }
                if format.is_fd() {
                    assert_eq!(frames.len(), 1);
                    assert_eq!(&frames[0].data()[..2], &[0x00, 0x70]);
                    assert_eq!(&payload[..bytes.len()], bytes, "{intensity:?} {min}");
                } else if intensity != IntensityEncoding::I12 {
                    assert_eq!(payload, bytes, "{intensity:?} {min}");
                }
            }
        }
    }
}

/// The data frames of runs (the fixed-width loops, classic and CAN FD, the D16 loop
/// compiled for its width and the shared one; the lossless coding's) and of single
/// points carry the node's data identifier, written here by hand: the window's base
/// plus the node, plus 0x10 times the data kind (5). Standard and extended windows,
/// nodes at both ends.
#[test]
fn the_data_frames_carry_the_nodes_data_id() {
    use embedded_can::ExtendedId;
    let cases = [
        (IdWindow::DEFAULT, 2u8, sid(0x152)),
        (IdWindow::standard(0x780).unwrap(), 0, sid(0x7D0)),
        (
            IdWindow::extended(0x1ABC_0000).unwrap(),
            15,
            Id::Extended(ExtendedId::new(0x1ABC_005F).unwrap()),
        ),
    ];
    let encodings = [
        DistanceEncoding::D16,
        DistanceEncoding::D12,
        DistanceEncoding::Lossless,
    ];
    let formats = [FrameFormat::Classic, FrameFormat::FD64];
    for (window, node, data_id) in cases {
        let ids = window.node(node).unwrap();
        for distance in encodings {
            for format in formats {
                let encoding = Encoding {
                    distance,
                    intensity: IntensityEncoding::None,
                    unit_exp: 0,
                };
                let mut e = ScanEncoder::new(ids, format).unwrap();
                e.begin(&header(40, encoding)).unwrap();
                let mut frames: Vec<Frame> = Vec::new();
                // Two runs (the second goes on from codes the first left pending),
                // then the last points one by one.
                let points: Vec<u32> = (0..38).map(|i| 20 + 7 * i).collect();
                for line in points.chunks(19) {
                    let rule = RangeRule::at_least(20);
                    let run = e.push_run(line, rule, |&d: &u32| (d, 0), &mut frames);
                    assert_eq!(run.unwrap().points, 19);
                }
                for d in [Distance::Mm(1000), Distance::Invalid] {
                    e.push_point_to(d, 0, &mut frames).unwrap();
                }
                assert!(!frames.is_empty());
                for f in &frames {
                    assert_eq!(
                        f.id(),
                        data_id,
                        "{window:?} node {node} {distance:?} {format:?}"
                    );
                }
            }
        }
    }
}

/// A classic run takes a frame's points as 48 bits over the point's bits and checks no
/// more that the scan's capacity (made by `begin`) is the same, and for widths known at
/// compile time takes a full frame's length as the header and the points' bytes, not the
/// scan's `full_len`: both hand-counted for every fixed-width encoding (6 payload bytes
/// after the 2-byte data header).
#[test]
fn classic_capacity_is_the_runs_points_per_frame() {
    // Points per classic frame, by distance (D16, D14, D12) and intensity (none, I16,
    // I12, I8): 48 / (16 + 0, 16 + 16, 16 + 12, 16 + 8) and so on.
    let expected = [[3, 1, 1, 2], [3, 1, 1, 2], [4, 1, 2, 2]];
    // A full frame's bytes: 2 + the points' bits rounded up to bytes (D16: 48, 32, 28
    // and 48 bits; D14: 42, 30, 26, 44; D12: 48, 28, 48, 40).
    let lens = [[8, 6, 6, 8], [8, 6, 6, 8], [8, 6, 8, 7]];
    let ids = IdWindow::DEFAULT.node(1).unwrap();
    for (d, row) in expected.iter().enumerate() {
        for (i, &points) in row.iter().enumerate() {
            let enc = Encoding {
                distance: DistanceEncoding::ALL[d],
                intensity: IntensityEncoding::ALL[i],
                unit_exp: 0,
            };
            let mut e = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
            e.begin(&header(10, enc)).unwrap();
            let s = e.open.fixed().unwrap();
            assert_eq!(s.capacity, points, "{enc:?}");
            let bits = s.distance_bits + s.intensity_bits;
            assert_eq!(48 / bits, u32::from(points));
            let len = lens[d][i];
            assert_eq!(s.full_len, len, "{enc:?}");
            assert_eq!(2 + (usize::from(points) * bits as usize).div_ceil(8), len);
        }
    }
}

proptest::proptest! {
    /// A checked run (`push_checked_run`: 0 no range, any other distance a range, the
    /// count of zeros given) makes the frames, trailer, counts and stops of pushing
    /// the points one by one by that rule written plainly (0 invalid, else a range in
    /// millimetres), and the same `Run`s as the general `push_run` with the rule
    /// "at least 1": in every encoding and frame format, with runs cut anywhere (one
    /// point to more than a block), lost frames, and runs of small ranges (each
    /// distance its own code) or with edge values (0, the out-of-range codes and their
    /// neighbours, 2^15, 2^31 and the largest values, u32::MAX no range) among them.
    #[test]
    fn checked_runs_equal_point_by_point(
        d in 0usize..3,
        i in 0usize..4,
        unit_exp in 0u8..3,
        format in proptest::sample::select(vec![
            FrameFormat::Classic,
            FrameFormat::Fd { max_len: 12 },
            FrameFormat::Fd { max_len: 24 },
            FrameFormat::FD64,
        ]),
        count in 1u16..150,
        extra in 0usize..3,
        seed in proptest::collection::vec(
            (0u32..4095, proptest::prelude::any::<u16>(), 0usize..40),
            160,
        ),
        edgy in proptest::collection::vec(proptest::prelude::any::<bool>(), 8),
        cuts in proptest::collection::vec(1usize..45, 1..8),
        room in 0usize..80,
        batch in 0usize..5,
        mix in proptest::prelude::any::<bool>(),
    ) {
        const EDGES: [u32; 24] = [
            0, 1, 2, 4094, 4095, 4096, 16382, 16383, 16384, 32767, 32768, 65533, 65534,
            65535, 65536, 65537, 131_071, 262_143, (1 << 31) - 1, 1 << 31,
            (1 << 31) + 1, u32::MAX - 2, u32::MAX - 1, u32::MAX,
        ];
        let enc = Encoding {
            distance: DistanceEncoding::ALL[d],
            intensity: IntensityEncoding::ALL[i],
            unit_exp,
        };
        let ids = IdWindow::DEFAULT.node(3).unwrap();
        let at_least_1 = RangeRule::at_least(1);
        // Per run (by the cut's index), small ranges and zeros only, or edge values
        // now and then too.
        let mut points: Vec<(u32, u16)> = Vec::new();
        let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
        let total = usize::from(count) + extra;
        for (n, &cut) in cuts.iter().cycle().enumerate() {
            if points.len() >= total {
                break;
            }
            let from = points.len();
            let to = (from + cut).min(total);
            for j in from..to {
                let (mm, int, pick) = seed[j % seed.len()];
                let d = if mm % 9 == 0 {
                    0
                } else if edgy[n % edgy.len()] && pick < EDGES.len() && mm % 3 == 0 {
                    EDGES[pick]
                } else {
                    mm
                };
                points.push((d, int));
            }
            runs.push(from..to);
        }
        // The rule "at least 1" written plainly: 0 is no range, and so is u32::MAX
        // (the filler of a rule's unused exceptions: no rule takes it for a range).
        let plain = |d: u32| {
            if d == 0 || d == u32::MAX {
                Distance::Invalid
            } else {
                Distance::Mm(d)
            }
        };
        // Point by point by the plain rule, with the same room for frames.
        let mut one = ScanEncoder::new(ids, format).unwrap();
        one.begin(&header(count, enc)).unwrap();
        let mut expected = Vec::new();
        let (mut stop, mut lost) = (None, 0);
        for &(r, i) in &points {
            match one.push_point(plain(r), i) {
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
        // Checked runs (`two`), beside general runs with the rule "at least 1"
        // (`three`), each into a sink of the same room; with `mix` every other run
        // point by point into both.
        let mut two = ScanEncoder::new(ids, format).unwrap();
        two.begin(&header(count, enc)).unwrap();
        let mut three = ScanEncoder::new(ids, format).unwrap();
        three.begin(&header(count, enc)).unwrap();
        let mut sink = VecSink { frames: Vec::new(), room, batch };
        let mut sink3 = VecSink { frames: Vec::new(), room, batch };
        let (mut run_stop, mut run_lost, mut frames) = (None, 0, 0);
        let (mut invalid, mut expected_invalid) = (0, 0);
        let mut at = 0;
        for n in 0.. {
            if run_stop.is_some() || at >= points.len() {
                break;
            }
            // After a lost frame the next run starts at the first point not taken (and
            // after the last cut, the rest is one run).
            let end = runs.get(n).map_or(points.len(), |r| r.end).max(at);
            let now = &points[at..end];
            if now.is_empty() {
                continue;
            }
            if mix && n % 2 == 1 {
                for &(r, i) in now {
                    let mut got = false;
                    let pushed = two.push_point_into(plain(r), i, || {
                        let slot = sink.data_slot();
                        got = slot.is_some();
                        slot
                    });
                    let pushed3 = three.push_point_into(plain(r), i, || sink3.data_slot());
                    proptest::prop_assert_eq!(pushed.is_ok(), pushed3.is_ok());
                    match pushed {
                        Ok(true) if got => frames += 1,
                        Ok(true) => run_lost += 1,
                        Ok(false) => {}
                        Err(_) => {
                            run_stop = Some(RunStop::TooManyPoints);
                            break;
                        }
                    }
                }
                at = end;
            } else {
                let zeros = now.iter().filter(|p| p.0 == 0).count() as u32;
                let got = two
                    .push_checked_run(now, zeros, |p: &(u32, u16)| *p, &mut sink)
                    .unwrap();
                let general = three
                    .push_run(now, at_least_1, |p: &(u32, u16)| *p, &mut sink3)
                    .unwrap();
                proptest::prop_assert_eq!(got, general);
                proptest::prop_assert_eq!(got.rejected, 0);
                frames += got.frames;
                let taken = &now[..got.points as usize];
                invalid += got.invalid;
                expected_invalid += taken.iter().filter(|p| plain(p.0) == Distance::Invalid).count();
                match got.stop {
                    Some(RunStop::NoSlot) => {
                        run_lost += 1;
                        at += got.points as usize;
                    }
                    other => {
                        run_stop = other;
                        at = end;
                    }
                }
            }
        }
        proptest::prop_assert_eq!(run_stop, stop);
        proptest::prop_assert_eq!(run_lost, lost);
        proptest::prop_assert_eq!(invalid as usize, expected_invalid);
        proptest::prop_assert_eq!(frames as usize, sink.frames.len());
        proptest::prop_assert_eq!(&sink.frames, &expected);
        proptest::prop_assert_eq!(&sink3.frames, &expected);
        let t1 = one.finish(TrailerFlags::default()).unwrap();
        let t2 = two.finish(TrailerFlags::default()).unwrap();
        let t3 = three.finish(TrailerFlags::default()).unwrap();
        proptest::prop_assert_eq!(&t1, &t2);
        proptest::prop_assert_eq!(t1, t3);
    }
}

/// Checked runs by hand (D16 in 1 mm, classic frames, 3 points a frame): a block of
/// small ranges and zeros, each distance its own code; a block with a range at the
/// out-of-range code 65535 and past it, coded 65535 and not counted valid; the
/// largest distances (u32::MAX is no range to every rule: code 0). The payloads and
/// the trailer's valid count written out.
#[test]
fn checked_runs_by_hand() {
    let ids = IdWindow::DEFAULT.node(3).unwrap();
    let d16 = Encoding::PLAIN_MM;
    // Each distance its own code (the OR below 65535); the general rule for a range
    // at or past 65535 and for u32::MAX; each its own code, an odd point last; the
    // general rule for an OR of 65535 (all of them below it).
    let lines: [&[u32]; 4] = [
        &[0, 1, 65534, 300, 0, 7],
        &[65535, 65536, 1 << 31, 2, u32::MAX, 0],
        &[32768, 4095, 7],
        &[32768, 32767, 65533],
    ];
    let mut e = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
    e.begin(&header(18, d16)).unwrap();
    let mut frames = Vec::new();
    let mut runs = Vec::new();
    for line in lines {
        let zeros = line.iter().filter(|&&d| d == 0).count() as u32;
        runs.push(
            e.push_checked_run(line, zeros, |&d: &u32| (d, 0), &mut frames)
                .unwrap(),
        );
    }
    let run = |points, invalid, frames| Run {
        points,
        invalid,
        rejected: 0,
        frames,
        stop: None,
    };
    assert_eq!(
        runs,
        [run(6, 2, 2), run(6, 2, 2), run(3, 0, 1), run(3, 0, 1)]
    );
    // Codes per frame (data header first: first index, then the sequence's low bits).
    let payload = |first: u16, codes: [u16; 3]| {
        let mut b = vec![];
        b.extend_from_slice(&(first | 0x7 << 12).to_le_bytes());
        for c in codes {
            b.extend_from_slice(&c.to_le_bytes());
        }
        b
    };
    let want = [
        payload(0, [0, 1, 65534]),
        payload(3, [300, 0, 7]),
        payload(6, [65535, 65535, 65535]),
        payload(9, [2, 0, 0]),
        payload(12, [32768, 4095, 7]),
        payload(15, [32768, 32767, 65533]),
    ];
    let got: Vec<&[u8]> = frames.iter().map(|f| f.data()).collect();
    assert_eq!(got, want.iter().map(|w| &w[..]).collect::<Vec<_>>());
    // Valid: 18 points, 3 zeros and u32::MAX no range, 3 at or past the
    // out-of-range code.
    let t = e.finish(TrailerFlags::default()).unwrap();
    let trailer = crate::trailer::Trailer::parse(t.last().unwrap().data()).unwrap();
    assert_eq!(trailer.points_sent, 18);
    assert_eq!(trailer.points_valid, 11);
}
