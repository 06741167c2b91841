//! Property tests: encoder → decoder round trips, loss, duplication, corruption.

use can_wire::*;
use proptest::prelude::*;

const P: usize = 1440;
type Dec = Decoder<P, 4>;

fn decoder() -> Box<Dec> {
    Box::new(Decoder::new(IdWindow::DEFAULT))
}

fn distance() -> impl Strategy<Value = Distance> {
    prop_oneof![
        1 => Just(Distance::Invalid),
        1 => Just(Distance::OutOfRange),
        8 => (0u32..70_000).prop_map(Distance::Mm),
    ]
}

fn encoding() -> impl Strategy<Value = Encoding> {
    (
        prop::sample::select(DistanceEncoding::ALL.to_vec()),
        prop::sample::select(IntensityEncoding::ALL.to_vec()),
        0u8..=4,
    )
        .prop_map(|(distance, intensity, unit_exp)| Encoding {
            distance,
            intensity,
            unit_exp,
        })
}

fn format() -> impl Strategy<Value = FrameFormat> {
    prop_oneof![
        Just(FrameFormat::Classic),
        prop::sample::select(vec![12u8, 16, 20, 24, 32, 48, 64])
            .prop_map(|max_len| FrameFormat::Fd { max_len }),
    ]
}

#[derive(Debug, Clone)]
struct Case {
    header: ScanHeader,
    format: FrameFormat,
    points: Vec<(Distance, u16)>,
}

fn case(max_points: usize) -> impl Strategy<Value = Case> {
    (
        encoding(),
        format(),
        prop::collection::vec((distance(), any::<u16>()), 0..=max_points),
        any::<u16>(),
        any::<u32>(),
        -540i16..=0,
        1u8..=4,
    )
        .prop_map(
            |(encoding, format, points, seq, ts, first_step, inc)| Case {
                header: ScanHeader {
                    seq,
                    timestamp_ms: ts,
                    point_count: points.len() as u16,
                    encoding,
                    time_synced: false,
                    time_estimated: false,
                    time_master: false,
                    grouping: Grouping::Single,
                    step_increment: inc,
                    first_step,
                    ares: 1440,
                },
                format,
                points,
            },
        )
}

/// Frames of one scan, with the number of points in each frame (0 for non-data).
fn encode(c: &Case, node: u8) -> Vec<(Frame, u16)> {
    let ids = IdWindow::DEFAULT.node(node).unwrap();
    let mut enc = ScanEncoder::new(ids, c.format).unwrap();
    let mut out: Vec<(Frame, u16)> = enc
        .begin(&c.header)
        .unwrap()
        .into_iter()
        .map(|f| (f, 0))
        .collect();
    let mut in_frame = 0u16;
    for (d, i) in &c.points {
        in_frame += 1;
        if let Some(f) = enc.push_point(*d, *i).unwrap() {
            assert!(f.data().len() <= c.format.max_len());
            out.push((f, in_frame));
            in_frame = 0;
        }
    }
    assert_eq!(in_frame, 0, "every point left in a data frame");
    for f in enc.finish(TrailerFlags::default()).unwrap() {
        out.push((f, 0));
    }
    out
}

fn expected(c: &Case, i: usize) -> Point {
    let e = c.header.encoding;
    let (d, n) = c.points[i];
    Point {
        distance: e.decode_distance(e.encode_distance(d)),
        intensity: e
            .intensity
            .is_present()
            .then(|| e.intensity.decode(e.intensity.encode(n))),
    }
}

/// Feed frames; return (completeness, points) of every reported scan.
fn run(dec: &mut Dec, frames: &[Frame]) -> Vec<(u8, Completeness, Vec<Option<Point>>)> {
    let mut scans = Vec::new();
    for f in frames {
        if let Ok(Some(Event::Scan { node, scan })) = dec.push_frame(f) {
            scans.push((node, scan.completeness(), scan.points().collect()));
        }
    }
    scans
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    #[test]
    fn round_trip(c in case(P)) {
        let frames: Vec<Frame> = encode(&c, 0).into_iter().map(|(f, _)| f).collect();
        let mut dec = decoder();
        let scans = run(&mut dec, &frames);
        prop_assert_eq!(scans.len(), 1);
        let (_, completeness, points) = &scans[0];
        prop_assert_eq!(*completeness, Completeness::Intact);
        prop_assert_eq!(points.len(), c.points.len());
        for (i, p) in points.iter().enumerate() {
            prop_assert_eq!(*p, Some(expected(&c, i)), "point {}", i);
        }
        let s = dec.stats(0).unwrap();
        prop_assert_eq!(s.scans_intact, 1);
        prop_assert_eq!(s.frames_lost + s.corrupt + s.duplicates + s.frames_orphaned, 0);
    }

    #[test]
    fn dropping_one_frame_costs_only_its_points(c in case(300), pick in any::<prop::sample::Index>()) {
        let frames = encode(&c, 0);
        let k = pick.index(frames.len());
        let kept: Vec<Frame> = frames.iter().enumerate().filter(|(i, _)| *i != k).map(|(_, f)| f.0).collect();
        let mut dec = decoder();
        let mut scans = run(&mut dec, &kept);
        let kind = IdWindow::DEFAULT.classify(frames[k].0.id()).unwrap().1;
        if kind == Kind::Trailer {
            // Reported only when the receiver gives up on it.
            let s = dec.flush(0).unwrap();
            scans.push((0, s.completeness(), s.points().collect()));
        }
        let stats = *dec.stats(0).unwrap();
        match kind {
            Kind::HeaderA | Kind::HeaderB => {
                prop_assert!(scans.is_empty(), "a scan without its header cannot be decoded");
                prop_assert_eq!(stats.scans_intact, 0);
                if kind == Kind::HeaderB {
                    // SPEC 7: its header A arrived, so the scan is incomplete (damaged),
                    // not lost (lost scans are sequence gaps).
                    prop_assert_eq!((stats.scans_damaged, stats.scans_lost), (1, 0));
                }
            }
            Kind::Data | Kind::Trailer => {
                prop_assert_eq!(scans.len(), 1);
                let (_, completeness, points) = &scans[0];
                let lost = frames[k].1;
                prop_assert_eq!(*completeness, Completeness::Incomplete {
                    missing_points: lost,
                    trailer_missing: kind == Kind::Trailer,
                });
                prop_assert_eq!(points.iter().filter(|p| p.is_none()).count(), usize::from(lost));
                for (i, p) in points.iter().enumerate() {
                    if let Some(p) = p {
                        prop_assert_eq!(*p, expected(&c, i));
                    }
                }
                prop_assert!(stats.frames_lost >= 1);
                prop_assert_eq!(stats.scans_damaged, 1);
            }
            other => prop_assert!(false, "unexpected kind {:?}", other),
        }
    }

    #[test]
    fn duplicated_frame_is_harmless(c in case(300), pick in any::<prop::sample::Index>()) {
        let frames: Vec<Frame> = encode(&c, 0).into_iter().map(|(f, _)| f).collect();
        let k = pick.index(frames.len());
        let mut dup = frames.clone();
        dup.insert(k + 1, frames[k]);
        let mut dec = decoder();
        let scans = run(&mut dec, &dup);
        prop_assert_eq!(scans.len(), 1);
        prop_assert_eq!(scans[0].1, Completeness::Intact);
        prop_assert_eq!(dec.stats(0).unwrap().duplicates, 1);
    }

    #[test]
    fn corrupted_frame_never_yields_an_intact_scan(
        c in case(200),
        pick in any::<prop::sample::Index>(),
        byte in any::<prop::sample::Index>(),
        mask in 1u8..=255,
    ) {
        let mut frames: Vec<Frame> = encode(&c, 0).into_iter().map(|(f, _)| f).collect();
        let k = pick.index(frames.len());
        let f = frames[k];
        let mut data = f.data().to_vec();
        let j = byte.index(data.len());
        data[j] ^= mask;
        frames[k] = Frame::new(f.id(), &data, f.is_fd()).unwrap();
        let mut dec = decoder();
        let mut scans = run(&mut dec, &frames);
        if let Some(s) = dec.flush(0) {
            scans.push((0, s.completeness(), Vec::new()));
        }
        for (_, completeness, _) in &scans {
            prop_assert_ne!(*completeness, Completeness::Intact, "frame {} byte {} mask {:#x}", k, j, mask);
        }
        prop_assert_eq!(dec.stats(0).unwrap().scans_intact, 0);
    }

    #[test]
    fn interleaved_bridges(a in case(200), b in case(200), order in prop::collection::vec(any::<bool>(), 0..600)) {
        let fa: Vec<Frame> = encode(&a, 0).into_iter().map(|(f, _)| f).collect();
        let fb: Vec<Frame> = encode(&b, 5).into_iter().map(|(f, _)| f).collect();
        // Merge keeping each bridge's own order (FIFO per bridge).
        let (mut ia, mut ib) = (0, 0);
        let mut merged = Vec::new();
        let mut choices = order.into_iter();
        while ia < fa.len() || ib < fb.len() {
            let take_a = ib >= fb.len() || (ia < fa.len() && choices.next().unwrap_or(true));
            if take_a { merged.push(fa[ia]); ia += 1; } else { merged.push(fb[ib]); ib += 1; }
        }
        let mut dec = decoder();
        let scans = run(&mut dec, &merged);
        prop_assert_eq!(scans.len(), 2);
        for (node, completeness, points) in &scans {
            prop_assert_eq!(*completeness, Completeness::Intact);
            let c = if *node == 0 { &a } else { &b };
            for (i, p) in points.iter().enumerate() {
                prop_assert_eq!(*p, Some(expected(c, i)));
            }
        }
    }

    #[test]
    fn decoder_never_panics_on_any_bytes(
        frames in prop::collection::vec((0x0F0u16..0x190, prop::collection::vec(any::<u8>(), 0..=64)), 0..64)
    ) {
        let mut dec = decoder();
        for (id, data) in frames {
            let id = embedded_can::Id::Standard(embedded_can::StandardId::new(id).unwrap());
            let _ = dec.push(id, &data);
        }
        for node in 0..16 {
            let _ = dec.flush(node);
        }
    }

    #[test]
    fn control_parser_never_panics(data in prop::collection::vec(any::<u8>(), 0..=64)) {
        match Control::parse(&data) {
            Ok(c) => {
                let mut buf = [0u8; 8];
                let len = c.emit(&mut buf).unwrap();
                prop_assert_eq!(&buf[..len], &data[..]);
            }
            Err(e) => {
                let a = Answer::reject(&data, &e);
                prop_assert_ne!(a.outcome, Outcome::Accepted);
            }
        }
    }
}

#[test]
fn sequence_gaps_count_lost_scans() {
    let ids = IdWindow::DEFAULT.node(1).unwrap();
    let mut enc = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
    let mut dec = decoder();
    let header = |seq| ScanHeader {
        seq,
        timestamp_ms: 0,
        point_count: 2,
        encoding: Encoding::PLAIN_MM,
        time_synced: false,
        time_estimated: false,
        time_master: false,
        grouping: Grouping::Single,
        step_increment: 1,
        first_step: 0,
        ares: 1024,
    };
    let mut intact = 0;
    for seq in [65534u16, 65535, 2, 3, 1] {
        let mut frames: Vec<Frame> = enc.begin(&header(seq)).unwrap().into();
        frames.extend(enc.push_point(Distance::Mm(10), 0).unwrap());
        frames.extend(enc.push_point(Distance::Mm(20), 0).unwrap());
        frames.extend(enc.finish(TrailerFlags::default()).unwrap());
        for f in &frames {
            if let Some(Event::Scan { scan, .. }) = dec.push_frame(f).unwrap() {
                intact += usize::from(scan.is_intact());
            }
        }
    }
    assert_eq!(intact, 5);
    let s = dec.stats(1).unwrap();
    assert_eq!(s.scans_lost, 2); // 0 and 1 skipped after 65535
    assert_eq!(s.sequence_resets, 1); // 3 → 1
}

#[test]
fn abort_is_reported() {
    let ids = IdWindow::DEFAULT.node(0).unwrap();
    let mut enc = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
    let mut dec = decoder();
    let header = ScanHeader {
        seq: 9,
        timestamp_ms: 0,
        point_count: 10,
        encoding: Encoding::PLAIN_MM,
        time_synced: false,
        time_estimated: false,
        time_master: false,
        grouping: Grouping::Single,
        step_increment: 1,
        first_step: 0,
        ares: 1024,
    };
    let mut frames: Vec<Frame> = enc.begin(&header).unwrap().into();
    for _ in 0..4 {
        frames.extend(enc.push_point(Distance::Mm(1), 0).unwrap());
    }
    frames.push(enc.abort(AbortReason::Checksum, 0).unwrap());
    let mut got = None;
    for f in &frames {
        if let Some(Event::Scan { scan, .. }) = dec.push_frame(f).unwrap() {
            got = Some(scan.completeness());
        }
    }
    assert_eq!(
        got,
        Some(Completeness::Aborted {
            reason: AbortReason::Checksum,
            detail: 0
        })
    );
    assert_eq!(dec.stats(0).unwrap().scans_aborted, 1);
}
