//! Single faults in a real PP answer, replayed through a listening bridge: every byte of
//! the answer flipped in every bit (the flips of bit 6 and 7, which the 6-bit line sum
//! cannot see, included) and every byte dropped. Whatever the fault, no scan may leave
//! the bridge with a geometry other than the one the capture's PP text states.
//!
//! The truth is the literal numbers of the capture's PP lines (checked to be there), and
//! the scan's start step is the literal number of its echo: never the parser under test.

use bridge::engine::{Bridge, BridgeConfig};
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{DistanceEncoding, Encoding, Frame, FrameFormat, IdWindow, IntensityEncoding};
use scip2can_tests::recordings_or_skip;

const Q: usize = 512;

/// A capture, the geometry its PP text states, and the start step of its scan's echo.
struct Case {
    file: &'static str,
    /// The PP lines the truth is read from, exactly as in the capture.
    pp_lines: [&'static str; 2],
    ares: u16,
    afrt: i32,
    /// Start step of the measurement echo (`ME0000...` = 0, `GD0044...` = 44).
    start: i32,
}

const CASES: [Case; 2] = [
    Case {
        file: "hokuyoaist_example_utm_30lx.rx.scip",
        pp_lines: ["ARES:1440;^\n", "AFRT:540;0\n"],
        ares: 1440,
        afrt: 540,
        start: 0,
    },
    Case {
        file: "hokuyoaist_example_urg_04lx.rx.scip",
        pp_lines: ["ARES:1024;\\\n", "AFRT:384;6\n"],
        ares: 1024,
        afrt: 384,
        start: 44,
    },
];

fn config() -> BridgeConfig {
    BridgeConfig {
        encoding: Encoding {
            distance: DistanceEncoding::D16,
            intensity: IntensityEncoding::I16,
            unit_exp: 0,
        },
        status_period_ms: 0,
        ..BridgeConfig::new(
            IdWindow::DEFAULT.node(0).expect("node 0"),
            FrameFormat::Fd { max_len: 64 },
        )
    }
}

/// What became of one faulted stream.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
struct Outcome {
    /// Intact scans published with the true geometry.
    right: usize,
    /// Intact scans published with another geometry.
    wrong: usize,
}

/// Replays `bytes` through a listening bridge; sorts the intact scans by geometry.
fn replay(bytes: &[u8], case: &Case) -> Outcome {
    let mut bridge: Bridge<Q> = Bridge::new(config()).expect("valid config");
    let mut frames: Vec<Frame> = Vec::new();
    for (t, chunk) in bytes.chunks(64).enumerate() {
        bridge.on_uart(chunk, t as u64);
        while let Some(f) = bridge.pop_frame() {
            frames.push(f);
        }
    }
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut out = Outcome::default();
    let mut judge = |scan: &can_wire::reassembly::Scan<1440>| {
        if !scan.is_intact() {
            return;
        }
        let h = scan.header();
        if h.ares == case.ares && i32::from(h.first_step) == case.start - case.afrt {
            out.right += 1;
        } else {
            out.wrong += 1;
        }
    };
    for f in &frames {
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(f) {
            judge(scan);
        }
    }
    if let Some(scan) = dec.flush(0) {
        judge(scan);
    }
    out
}

/// The stream from the capture's last PP answer to its end, and that answer's length.
fn last_pp_onwards(bytes: &[u8]) -> (&[u8], usize) {
    let at = bytes
        .windows(7)
        .rposition(|w| w == b"\n\nPP\n00")
        .expect("a PP answer")
        + 2;
    let rest = &bytes[at..];
    let len = rest
        .windows(2)
        .position(|w| w == b"\n\n")
        .expect("the PP answer ends")
        + 2;
    (rest, len)
}

/// Every single fault of the PP answer: 8 bit flips per byte, then the byte dropped.
fn faults(stream: &[u8], pp_len: usize) -> impl Iterator<Item = Vec<u8>> + '_ {
    (0..pp_len).flat_map(move |i| {
        (0..9).map(move |k| {
            let mut s = stream.to_vec();
            if k < 8 {
                s[i] ^= 1 << k;
            } else {
                s.remove(i);
            }
            s
        })
    })
}

#[test]
fn no_single_fault_in_pp_publishes_a_wrong_geometry() {
    let Some(dir) = recordings_or_skip("no_single_fault_in_pp_publishes_a_wrong_geometry") else {
        return;
    };
    let mut failures = Vec::new();
    for case in &CASES {
        let bytes = std::fs::read(dir.join(case.file)).expect("recording");
        let (stream, pp_len) = last_pp_onwards(&bytes);
        let pp_text = &stream[..pp_len];
        for line in case.pp_lines {
            assert!(
                pp_text.windows(line.len()).any(|w| w == line.as_bytes()),
                "{}: the truth {line:?} is in the capture's PP answer",
                case.file
            );
        }
        // The fault-free stream publishes its scan with the true geometry.
        let clean = replay(stream, case);
        assert_eq!(clean, Outcome { right: 1, wrong: 0 }, "{}", case.file);
        let (mut n, mut wrong, mut published) = (0, 0, 0);
        for faulted in faults(stream, pp_len) {
            let o = replay(&faulted, case);
            n += 1;
            wrong += usize::from(o.wrong > 0);
            published += usize::from(o.right > 0);
        }
        eprintln!(
            "{}: {n} single faults in a {pp_len}-byte PP answer: {wrong} publish a wrong \
             geometry, {published} publish the true one, {} publish nothing",
            case.file,
            n - wrong - published
        );
        if wrong > 0 {
            failures.push((case.file, wrong));
        }
    }
    assert!(
        failures.is_empty(),
        "scans published with a wrong geometry: {failures:?}"
    );
}
