//! Property tests of the codec: requests round-trip through encode → parse, and streams
//! built from random scans (every data set, 2/3/4-char values, cluster, multi-echo, tags,
//! G and M forms) decode back to the same values, whatever the chunking.

use proptest::prelude::*;
use scip::{
    Command, DataSet, Decoder, Event, Request, ResponseWriter, ScanMode, ScanRequest, TimeMode,
    BIT_RATES, REQUEST_MAX,
};

fn data_set() -> impl Strategy<Value = DataSet> {
    prop_oneof![
        Just(DataSet::Distance),
        Just(DataSet::ShortDistance),
        Just(DataSet::DistanceIntensity),
        Just(DataSet::DistanceReflectance),
        Just(DataSet::DistanceAux),
    ]
}

fn scan_request() -> impl Strategy<Value = ScanRequest> {
    (
        prop_oneof![Just(ScanMode::Single), Just(ScanMode::Continuous)],
        data_set(),
        any::<bool>(),
        0u16..1500,
        0u16..400,
        1u8..=99,
        0u8..=9,
        0u8..=99,
    )
        .prop_map(|(mode, data, multi, start, span, cluster, skip, count)| {
            let multi_echo =
                multi && matches!(data, DataSet::Distance | DataSet::DistanceIntensity);
            let continuous = mode == ScanMode::Continuous;
            ScanRequest {
                mode,
                data,
                multi_echo,
                start,
                end: start + span,
                cluster,
                skip: if continuous { skip } else { 0 },
                count: if continuous { count } else { 0 },
            }
        })
}

fn tag() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(0x21u8..=0x7E, 0..=16)
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Scip20),
        Just(Command::Version),
        Just(Command::Parameters),
        Just(Command::Info),
        Just(Command::LaserOn),
        Just(Command::LaserOff),
        Just(Command::Reset),
        Just(Command::PartialReset),
        Just(Command::State),
        Just(Command::Sleep),
        prop::sample::select(BIT_RATES.to_vec()).prop_map(Command::BitRate),
        prop_oneof![0u8..=10, Just(99u8)].prop_map(Command::MotorSpeed),
        prop_oneof![
            Just(TimeMode::Enter),
            Just(TimeMode::Read),
            Just(TimeMode::Leave)
        ]
        .prop_map(Command::Time),
        any::<bool>().prop_map(Command::Sensitivity),
        scan_request().prop_map(Command::Scan),
    ]
}

proptest! {
    #[test]
    fn request_encode_then_parse_round_trips(cmd in command(), tag in tag()) {
        let req = Request::new(cmd).with_tag(&tag).expect("valid tag");
        let mut buf = [0u8; REQUEST_MAX];
        let n = req.encode(&mut buf).expect("valid request");
        prop_assert_eq!(buf[n - 1], b'\n');
        prop_assert_eq!(Request::parse(&buf[..n - 1]), Ok(req));
        // The echo form writes the same bytes.
        let mut echo = [0u8; REQUEST_MAX];
        let m = req.encode_echo(&mut echo).expect("echo");
        prop_assert_eq!(&echo[..m], &buf[..n]);
    }
}

/// One random scan: per value, its echoes (distance, aux).
#[derive(Debug, Clone)]
struct Scan {
    request: Request,
    status: [u8; 2],
    timestamp: u32,
    steps: Vec<Vec<(u32, u32)>>,
}

fn scan() -> impl Strategy<Value = Scan> {
    (scan_request(), tag(), any::<u32>()).prop_flat_map(|(req, tag, ts)| {
        let n = usize::from(req.value_count());
        let dmax = (1u32 << (6 * u32::from(req.data.distance_width()))) - 1;
        let amax = match req.data.aux_width() {
            0 => 0,
            w => (1u32 << (6 * u32::from(w))) - 1,
        };
        let echoes = if req.multi_echo {
            1usize..=3
        } else {
            1usize..=1
        };
        let step = prop::collection::vec((0..=dmax, 0..=amax), echoes);
        let status = if req.mode == ScanMode::Continuous {
            *b"99"
        } else {
            *b"00"
        };
        prop::collection::vec(step, n).prop_map(move |steps| Scan {
            request: Request::new(Command::Scan(req))
                .with_tag(&tag)
                .expect("tag"),
            status,
            timestamp: ts & 0xFF_FFFF,
            steps,
        })
    })
}

fn write(scans: &[Scan]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    for s in scans {
        w.echo(&s.request);
        w.status(s.status);
        w.timestamp(s.timestamp);
        for echoes in &s.steps {
            let mut it = echoes.iter();
            if let Some(&(d, a)) = it.next() {
                w.step(d, a);
            }
            for &(d, a) in it {
                w.extra_echo(d, a);
            }
        }
        w.end();
    }
    let _ = w.into_inner();
    out
}

/// A decoded response: its request, timestamp and per-step echoes.
type Decoded = (Request, u32, Vec<Vec<(u32, u32)>>);

/// Decodes a stream fed in `chunk`-byte pieces into (request, timestamp, steps) per
/// intact response; any error fails.
fn read(bytes: &[u8], chunk: usize) -> Result<Vec<Decoded>, String> {
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    let mut cur: Option<Decoded> = None;
    for piece in bytes.chunks(chunk.max(1)) {
        let mut rest = piece;
        while !rest.is_empty() {
            let (used, ev) = dec.feed(rest);
            rest = &rest[used..];
            match ev {
                Some(Event::Start { request, .. }) => {
                    cur = Some((request.ok_or("unknown echo")?, 0, Vec::new()));
                }
                Some(Event::Timestamp(t)) => cur.as_mut().ok_or("ts")?.1 = t,
                Some(Event::Data(line)) => {
                    let steps = &mut cur.as_mut().ok_or("data")?.2;
                    for r in line.indexed() {
                        if r.echo == 0 {
                            if usize::from(r.index) != steps.len() {
                                return Err(format!("index {} at {}", r.index, steps.len()));
                            }
                            steps.push(vec![(r.distance, r.aux)]);
                        } else {
                            let n = steps.len();
                            let last = steps.last_mut().ok_or("echo first")?;
                            if usize::from(r.index) + 1 != n || usize::from(r.echo) != last.len() {
                                return Err("echo numbering".into());
                            }
                            last.push((r.distance, r.aux));
                        }
                    }
                }
                Some(Event::End(_)) => out.push(cur.take().ok_or("end")?),
                Some(Event::Error(e)) => return Err(e.to_string()),
                _ => {}
            }
        }
    }
    if let Some(Event::Error(e)) = dec.finish() {
        return Err(e.to_string());
    }
    Ok(out)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn random_scans_decode_back(scans in prop::collection::vec(scan(), 1..4), chunk in 1usize..300) {
        let bytes = write(&scans);
        let got = read(&bytes, chunk).map_err(TestCaseError::fail)?;
        prop_assert_eq!(got.len(), scans.len());
        for (g, s) in got.iter().zip(&scans) {
            prop_assert_eq!(g.0, s.request);
            prop_assert_eq!(g.1, s.timestamp);
            prop_assert_eq!(&g.2, &s.steps);
        }
    }

    #[test]
    fn any_single_byte_flip_in_a_scan_is_never_decoded_as_intact(
        s in scan(), pos in any::<prop::sample::Index>(), bit in 0u8..8
    ) {
        let mut bytes = write(std::slice::from_ref(&s));
        let i = pos.index(bytes.len());
        bytes[i] ^= 1 << bit;
        // Either an error is reported, or (a flip inside the echo's tag or digits that
        // still parses) the response decodes to a different request — never the same
        // request with different values.
        if let Ok(got) = read(&bytes, 7) {
            for g in got {
                prop_assert!(g.0 != s.request || (g.1 == s.timestamp && g.2 == s.steps),
                    "flip at {} bit {} gave wrong values as intact", i, bit);
            }
        }
    }
}
