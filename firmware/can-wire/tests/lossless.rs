//! The lossless coding (SPEC 4.2) end to end: encoder → frames → reassembling decoder.
//! Expected values are the points put in (the coding is exact), never the decoder's.

use can_wire::*;
use proptest::prelude::*;

const P: usize = 4095;
type Dec = Decoder<P, 2>;

struct Sink(Vec<Frame>);
impl FrameSink for Sink {
    fn data_slot(&mut self) -> Option<&mut Frame> {
        self.0.push(Frame::default());
        self.0.last_mut()
    }
}

/// What a receiver must report for a point put in as `d` with unit `2^e` mm.
fn expected(d: Distance, e: u8) -> Distance {
    match d {
        Distance::Mm(mm) => {
            let q = (u64::from(mm) + ((1u64 << e) >> 1)) >> e;
            if q + 128 > (1 << 20) - 1 {
                Distance::OutOfRange
            } else {
                Distance::Mm((q << e) as u32)
            }
        }
        Distance::SensorError(v) if v < 100 || (65533..=65535).contains(&v) => d,
        Distance::SensorError(_) => Distance::OutOfRange,
        other => other,
    }
}

fn header(n: usize, intensity: IntensityEncoding, unit_exp: u8, seq: u16) -> ScanHeader {
    ScanHeader {
        seq,
        timestamp_ms: 77,
        point_count: n as u16,
        encoding: Encoding {
            distance: DistanceEncoding::Lossless,
            intensity,
            unit_exp,
        },
        time_synced: false,
        time_estimated: false,
        time_master: false,
        grouping: Grouping::Single,
        step_increment: 1,
        first_step: -540,
        ares: 1440,
    }
}

fn encode(h: &ScanHeader, format: FrameFormat, points: &[(Distance, u16)]) -> Vec<Frame> {
    let ids = IdWindow::DEFAULT.node(1).unwrap();
    let mut enc = ScanEncoder::new(ids, format).unwrap();
    let mut sink = Sink(enc.begin(h).unwrap().to_vec());
    for &(d, i) in points {
        let run = enc.push_point_to(d, i, &mut sink).unwrap();
        assert_eq!(run.stop, None);
    }
    sink.0.extend(enc.finish(TrailerFlags::default()).unwrap());
    sink.0
}

/// Decode frames; the one scan reported: completeness and points.
fn decode(frames: &[Frame]) -> (Completeness, Vec<Option<Point>>) {
    let mut dec: Box<Dec> = Box::new(Decoder::new(IdWindow::DEFAULT));
    let mut out = None;
    for f in frames {
        if let Ok(Some(Event::Scan { scan, .. })) = dec.push_frame(f) {
            out = Some((scan.completeness(), scan.points().collect()));
        }
    }
    out.expect("a scan is reported")
}

fn distance() -> impl Strategy<Value = Distance> {
    prop_oneof![
        1 => Just(Distance::Invalid),
        1 => Just(Distance::OutOfRange),
        2 => (0u32..100).prop_map(Distance::SensorError),
        1 => (65533u32..=65535).prop_map(Distance::SensorError),
        8 => (0u32..(1 << 18)).prop_map(Distance::Mm),
    ]
}

/// Smooth runs, plateaus and jumps, like a scan (and white noise from `distance`).
fn scan_like() -> impl Strategy<Value = Vec<(Distance, u16)>> {
    prop::collection::vec((0u32..60_000, -40i32..40, 1usize..200, any::<u16>()), 1..12).prop_map(
        |runs| {
            let mut v = vec![];
            for (start, slope, len, i) in runs {
                for k in 0..len {
                    let d = (start as i64 + slope as i64 * k as i64).clamp(0, 65_000) as u32;
                    v.push((Distance::Mm(d), i.wrapping_add(k as u16)));
                }
            }
            v.truncate(4095);
            v
        },
    )
}

fn points() -> impl Strategy<Value = Vec<(Distance, u16)>> {
    prop_oneof![
        prop::collection::vec((distance(), any::<u16>()), 1..600),
        scan_like(),
        (distance(), any::<u16>(), 1usize..700).prop_map(|(d, i, n)| vec![(d, i); n]),
    ]
}

fn format() -> impl Strategy<Value = FrameFormat> {
    prop_oneof![
        Just(FrameFormat::Classic),
        prop::sample::select(vec![12u8, 16, 32, 64])
            .prop_map(|max_len| FrameFormat::Fd { max_len }),
    ]
}

fn intensity() -> impl Strategy<Value = IntensityEncoding> {
    prop::sample::select(IntensityEncoding::ALL.to_vec())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    /// Every value comes back exactly, every error code by its identity.
    #[test]
    fn round_trip(points in points(), format in format(), ienc in intensity(), unit in prop_oneof![3 => Just(0u8), 1 => 0u8..=15], seq in any::<u16>()) {
        let h = header(points.len(), ienc, unit, seq);
        let frames = encode(&h, format, &points);
        for f in &frames[2..frames.len() - 1] {
            prop_assert!(f.len() <= format.max_len());
        }
        let (c, got) = decode(&frames);
        prop_assert_eq!(c, Completeness::Intact);
        for (k, ((d, i), g)) in points.iter().zip(&got).enumerate() {
            let g = g.expect("every point present");
            prop_assert_eq!(g.distance, expected(*d, unit), "point {}", k);
            prop_assert_eq!(g.intensity, ienc.is_present().then(|| ienc.decode(ienc.encode(*i))));
        }
    }

    /// Losing, repeating or corrupting any one frame never yields a wrong value in a
    /// scan reported intact; a lost, repeated or corrupt *data* frame never makes any
    /// point decode to a wrong value (a corrupt header can: the scan's CRC then fails, so
    /// it is not intact); and a scan missing anything is not intact.
    #[test]
    fn one_bad_frame(points in scan_like(), format in format(), which in any::<prop::sample::Index>(), fault in 0u8..3, bit in 0usize..512) {
        let h = header(points.len(), IntensityEncoding::None, 0, 9);
        let mut frames = encode(&h, format, &points);
        let k = which.index(frames.len());
        let ids = IdWindow::DEFAULT.node(1).unwrap();
        let data_frame = frames[k].id() == ids.id(Kind::Data);
        match fault {
            0 => { frames.remove(k); }
            1 => { let f = frames[k]; frames.insert(k, f); }
            _ => {
                let f = frames[k];
                let mut data = f.data().to_vec();
                let b = bit % (data.len() * 8);
                data[b / 8] ^= 1 << (b % 8);
                frames[k] = Frame::new(f.id(), &data, f.is_fd()).unwrap();
            }
        }
        let mut dec: Box<Dec> = Box::new(Decoder::new(IdWindow::DEFAULT));
        for f in &frames {
            if let Ok(Some(Event::Scan { scan, .. })) = dec.push_frame(f) {
                let all_present = scan.points().all(|p| p.is_some());
                if data_frame || scan.is_intact() {
                    for (p, (d, _)) in scan.points().zip(&points) {
                        if let Some(p) = p {
                            prop_assert_eq!(p.distance, *d, "a wrong value reported");
                        }
                    }
                }
                if fault == 1 {
                    prop_assert!(scan.is_intact(), "a repeated frame is ignored");
                }
                if scan.is_intact() {
                    prop_assert!(all_present);
                }
            }
        }
    }
}

/// A scan of real-looking ranges costs far fewer bits than D16, on both frame formats,
/// and its frames stay within the worst-case bound.
#[test]
fn smooth_scans_are_small_and_bounded() {
    let points: Vec<(Distance, u16)> = (0..1081)
        .map(|k| {
            (
                Distance::Mm(2000 + (k as u32 * 3) % 400 + (k as u32 * 7919 % 5)),
                0,
            )
        })
        .collect();
    let h = header(points.len(), IntensityEncoding::None, 0, 1);
    let frames = encode(&h, FrameFormat::Classic, &points);
    let data = frames.len() - 3;
    // D16: 3 points per classic frame.
    assert!(data * 3 < 1081 / 2, "{data} data frames");
    // White noise over 16 bits: never more than D16's payload plus a small constant.
    let noise: Vec<(Distance, u16)> = (0..1081u32)
        .map(|k| (Distance::Mm(k.wrapping_mul(2_654_435_761) >> 16), 0))
        .collect();
    let frames = encode(&h, FrameFormat::Classic, &noise);
    let bytes: usize = frames[2..frames.len() - 1]
        .iter()
        .map(|f| f.len() - 1)
        .sum();
    let d16 = 1081 * 2;
    assert!(bytes <= d16 + d16 / 16 + 9 * 8, "{bytes} bytes vs {d16}");
}

/// Golden frames written by hand from SPEC 4.2 (not by the encoder): scan 0x0102 of three
/// points, 1000 mm, 1002 mm and the sensor's error code 0, on classic CAN at node 1.
///
/// Codes 1128, 1130, 0. Stream: seq_low 2 (4 bits), segment 0 (5), anchor width 11 (5)
/// and 1128 (11); one block of two values: first-order residuals 2 and −1130 (u = 4 and
/// 2259, k = 10: 11 + 13 bits, 4 + 24 with k) against verbatim width 11 (5 + 22 = 27
/// bits): verbatim, mode 0 (2 bits), width 11 (5), 1130 (11), 0 (11). 54 bits, two zero
/// bits of padding: 7 bytes, then the segment CRC: 7 stream bytes in the first frame
/// (framing byte 0x80) and the CRC in the second (framing byte 0x01, 3 bytes).
#[test]
fn golden_frames_from_the_spec() {
    let crc16 = ::crc::Crc::<u16>::new(&::crc::CRC_16_IBM_3740);
    let stream = [0x02, 0x16, 0x1A, 0x59, 0x6A, 0x04, 0x00];
    let seg_crc = crc16.checksum(&stream).to_le_bytes();
    let a = [0x02, 0x01, 0x4D, 0, 0, 0, 0x03, 0x00];
    let b = [0x02, 0x04, 0x00, 0x01, 0xE4, 0xFD, 0xA0, 0x05];
    let head = [0x02, 0x01, 0x03, 0x00, 0x02, 0x00];
    let mut scan_crc = crc16.digest();
    scan_crc.update(&a);
    scan_crc.update(&b);
    scan_crc.update(&seg_crc);
    scan_crc.update(&head);
    let t = scan_crc.finalize().to_le_bytes();
    let mut d0 = vec![0x80];
    d0.extend_from_slice(&stream);
    let d1 = [0x01, seg_crc[0], seg_crc[1]];
    let trailer = [
        head[0], head[1], head[2], head[3], head[4], head[5], t[0], t[1],
    ];

    let h = header(3, IntensityEncoding::None, 0, 0x0102);
    let points = [
        (Distance::Mm(1000), 0),
        (Distance::Mm(1002), 0),
        (Distance::SensorError(0), 0),
    ];
    let frames = encode(&h, FrameFormat::Classic, &points);
    let ids = IdWindow::DEFAULT.node(1).unwrap();
    let golden: [(Kind, &[u8]); 5] = [
        (Kind::HeaderA, &a),
        (Kind::HeaderB, &b),
        (Kind::Data, &d0),
        (Kind::Data, &d1),
        (Kind::Trailer, &trailer),
    ];
    assert_eq!(frames.len(), golden.len());
    for (f, (kind, bytes)) in frames.iter().zip(golden) {
        assert_eq!(f.id(), ids.id(kind));
        assert_eq!(f.data(), bytes, "{kind:?}");
    }
    // And the golden frames decode to the points.
    let golden_frames: Vec<Frame> = golden
        .iter()
        .map(|(k, b)| Frame::new(ids.id(*k), b, false).unwrap())
        .collect();
    let (c, got) = decode(&golden_frames);
    assert_eq!(c, Completeness::Intact);
    let got: Vec<Distance> = got.iter().map(|p| p.unwrap().distance).collect();
    assert_eq!(
        got,
        [
            Distance::Mm(1000),
            Distance::Mm(1002),
            Distance::SensorError(0)
        ]
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// A run of raw readings (`push_run`, the engine's direct path) makes the frames that
    /// pushing the same points one by one makes, however the run is cut.
    #[test]
    fn runs_equal_single_points(
        raw in prop::collection::vec((prop_oneof![0u32..30, 20u32..70_000, 65530u32..=65537, Just(4095u32)], any::<u16>()), 1..700),
        cuts in prop::collection::vec(1usize..80, 0..20),
        format in format(),
        ienc in intensity(),
    ) {
        let rule = RangeRule { min: 20, except: [4095, u32::MAX], band: Some(65533), window: [0, u32::MAX] };
        let h = header(raw.len(), ienc, 0, 3);
        let points: Vec<(Distance, u16)> = raw
            .iter()
            .map(|&(d, i)| (if matches!(rule.distance(d), Distance::Mm(_)) { Distance::Mm(d) } else { Distance::SensorError(d) }, i))
            .collect();
        let single = encode(&h, format, &points);
        let ids = IdWindow::DEFAULT.node(1).unwrap();
        let mut enc = ScanEncoder::new(ids, format).unwrap();
        let mut sink = Sink(enc.begin(&h).unwrap().to_vec());
        let mut rest: &[(u32, u16)] = &raw;
        let mut cut = cuts.iter().cycle();
        let mut invalid = 0;
        while !rest.is_empty() {
            let n = (*cut.next().unwrap_or(&7)).min(rest.len());
            let (now, later) = rest.split_at(n);
            let run = enc.push_run(now, rule, |p: &(u32, u16)| *p, &mut sink).unwrap();
            prop_assert_eq!(run.points as usize, n);
            invalid += run.invalid;
            rest = later;
        }
        sink.0.extend(enc.finish(TrailerFlags::default()).unwrap());
        prop_assert_eq!(sink.0, single);
        let ranges = points.iter().filter(|p| matches!(p.0, Distance::Mm(_))).count();
        prop_assert_eq!(invalid as usize, raw.len() - ranges);
    }
}

/// A run classifies and codes raw distances at every edge of the range rule and of the
/// code space as the SPEC says (values worked out by hand): below DMIN an error code, the
/// rule's error code and band as themselves, ranges rounded half up in units of 2 mm up
/// to the largest code (1 048 447 units: 2 096 894 mm), longer ones out of range. The
/// first run has an error code and the band, the second a rule with neither (its ranges
/// reach the longest code).
#[test]
fn a_run_codes_the_edges_of_the_rule() {
    let ethernet = RangeRule {
        min: 20,
        except: [4095, u32::MAX],
        band: Some(65533),
        window: [0, u32::MAX],
    };
    let first: [(u32, Distance); 11] = [
        (0, Distance::SensorError(0)),
        (19, Distance::SensorError(19)),
        (20, Distance::Mm(20)),
        (21, Distance::Mm(22)),
        (4094, Distance::Mm(4094)),
        (4095, Distance::OutOfRange),
        (4096, Distance::Mm(4096)),
        (65532, Distance::Mm(65532)),
        (65533, Distance::SensorError(65533)),
        (65535, Distance::SensorError(65535)),
        (65536, Distance::Mm(65536)),
    ];
    let second: [(u32, Distance); 6] = [
        (19, Distance::SensorError(19)),
        (65533, Distance::Mm(65534)),
        (2_096_893, Distance::Mm(2_096_894)),
        (2_096_894, Distance::Mm(2_096_894)),
        (2_096_895, Distance::OutOfRange),
        (u32::MAX - 1, Distance::OutOfRange),
    ];
    let n = first.len() + second.len();
    let h = header(n, IntensityEncoding::None, 1, 9);
    let ids = IdWindow::DEFAULT.node(1).unwrap();
    let mut enc = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
    let mut sink = Sink(enc.begin(&h).unwrap().to_vec());
    let raw = |c: &[(u32, Distance)]| c.iter().map(|&(d, _)| (d, 0)).collect::<Vec<(u32, u16)>>();
    let run = enc
        .push_run(&raw(&first), ethernet, |p: &(u32, u16)| *p, &mut sink)
        .unwrap();
    // Ranges: 20, 21, 4094, 4096, 65532, 65536.
    assert_eq!((run.points, run.invalid), (11, 5));
    let run = enc
        .push_run(
            &raw(&second),
            RangeRule::at_least(20),
            |p: &(u32, u16)| *p,
            &mut sink,
        )
        .unwrap();
    // No range: 19 and the two too long.
    assert_eq!((run.points, run.invalid), (6, 3));
    sink.0.extend(enc.finish(TrailerFlags::default()).unwrap());
    let (completeness, got) = decode(&sink.0);
    assert_eq!(completeness, Completeness::Intact);
    let got: Vec<Distance> = got.iter().map(|p| p.unwrap().distance).collect();
    let want: Vec<Distance> = first.iter().chain(&second).map(|&(_, d)| d).collect();
    assert_eq!(got, want);
}
