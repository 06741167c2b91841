//! The long streams the decoder benchmarks and the instruction-count example decode:
//! one real response, repeated.
//!
//! The responses come from the real captures in `../shared/recordings` (beside the
//! repository); when that folder is missing, an equivalent response (same command,
//! steps, line layout and size) is written with [`scip::ResponseWriter`].
//!
//! Shared by the criterion bench and the `decode_stream` example; each uses part of it.
#![allow(dead_code)]

use std::path::PathBuf;

use scip::{Command, DataSet, Request, ResponseWriter, ScanMode, ScanRequest};

/// A response to benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Which {
    /// URG-04LX `GD0044072501`: 682 steps, 3-char distances (2134 bytes).
    Gd,
    /// UTM-30LX `ME0000108001100` scan frame: 1081 steps, distance + intensity.
    Me,
}

impl Which {
    /// Both, in report order.
    pub const ALL: [Which; 2] = [Which::Gd, Which::Me];

    /// Short name for reports and command lines.
    pub fn name(self) -> &'static str {
        match self {
            Which::Gd => "gd",
            Which::Me => "me",
        }
    }

    /// From a short name.
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|w| w.name() == s)
    }

    fn recording(self) -> (&'static str, &'static [u8]) {
        match self {
            Which::Gd => ("hokuyoaist_example_urg_04lx.rx.scip", b"GD0044072501"),
            Which::Me => ("hokuyoaist_example_utm_30lx.rx.scip", b"ME0000108001100"),
        }
    }
}

/// Where the real captures are.
fn recordings_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/recordings")
}

/// One response, LF LF included, and whether it came from a real capture.
pub fn response(which: Which) -> (Vec<u8>, bool) {
    let (file, echo) = which.recording();
    let path = recordings_dir().join(file);
    if let Ok(bytes) = std::fs::read(&path) {
        if let Some(r) = find_response(&bytes, echo) {
            return (r, true);
        }
    }
    eprintln!(
        "{}: {} not found; using an equivalent written response",
        which.name(),
        path.display()
    );
    (written(which), false)
}

/// The response whose echo line is `echo` (first one), from its echo to its empty line.
fn find_response(stream: &[u8], echo: &[u8]) -> Option<Vec<u8>> {
    let mut at = 0;
    // Responses start at the beginning or right after an empty line.
    while at < stream.len() {
        let rest = &stream[at..];
        let end = rest.windows(2).position(|w| w == b"\n\n")? + 2;
        let resp = &rest[..end];
        if resp.starts_with(echo) && resp.get(echo.len()) == Some(&b'\n') {
            return Some(resp.to_vec());
        }
        at += end;
    }
    None
}

/// An equivalent response written with the crate's own writer.
fn written(which: Which) -> Vec<u8> {
    let (mode, data, start, end, status) = match which {
        Which::Gd => (ScanMode::Single, DataSet::Distance, 44, 725, *b"00"),
        Which::Me => (
            ScanMode::Continuous,
            DataSet::DistanceIntensity,
            0,
            1080,
            *b"99",
        ),
    };
    let scan = ScanRequest {
        mode,
        data,
        multi_echo: false,
        start,
        end,
        cluster: 1,
        skip: if which == Which::Me { 1 } else { 0 },
        count: 0,
    };
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    w.echo(&Request::new(Command::Scan(scan)));
    w.status(status);
    w.timestamp(0x0012_3456);
    for step in 0..=u32::from(end - start) {
        // Ranges of a room a few metres across, intensities of a few thousand.
        let distance = 400 + (step * 37) % 4000;
        w.step(distance, 2000 + (step * 53) % 3000);
    }
    w.end();
    out
}

/// `response(which)` repeated `times` times. The copies of a stream frame (`ME`) carry
/// timestamps 25 ms apart (a UTM-30LX's scan period), as a sensor sends them: the same
/// timestamp again fails the decoder's sequence check, which would leave every other
/// frame's lines undecoded (sum-checked and skipped) and the measure flattering.
pub fn stream(which: Which, times: usize) -> (Vec<u8>, usize, bool) {
    let (one, real) = response(which);
    let mut out = Vec::with_capacity(one.len() * times);
    for i in 0..times {
        match which {
            Which::Gd => out.extend_from_slice(&one),
            Which::Me => out.extend_from_slice(&retimed(&one, 25 * i as u32)),
        }
    }
    (out, one.len(), real)
}

/// A stream frame with `later_ms` added to its timestamp (third line: 4 chars of 6 bits
/// and the line's sum char).
fn retimed(frame: &[u8], later_ms: u32) -> Vec<u8> {
    let mut out = frame.to_vec();
    let mut lines = frame.split(|&b| b == b'\n');
    let start = lines.next().map_or(0, |l| l.len() + 1) + lines.next().map_or(0, |l| l.len() + 1);
    let t = &mut out[start..start + 5];
    let ts = t[..4]
        .iter()
        .fold(0u32, |acc, &c| (acc << 6) | u32::from(c - 0x30));
    let ts = ts.wrapping_add(later_ms) & 0xFF_FFFF;
    for (k, c) in t[..4].iter_mut().enumerate() {
        *c = ((ts >> (6 * (3 - k))) & 0x3F) as u8 + 0x30;
    }
    let sum = t[..4].iter().fold(0u32, |acc, &c| acc + u32::from(c));
    t[4] = (sum & 0x3F) as u8 + 0x30;
    out
}

/// What decoding a stream yielded, so that none of the work can be optimised away.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Tally {
    /// Intact responses.
    pub responses: u64,
    /// Errors.
    pub errors: u64,
    /// Readings.
    pub readings: u64,
    /// Sum of every distance.
    pub distance_sum: u64,
}

/// Decodes `stream` with a fresh decoder, feeding at most `chunk` bytes per call
/// (`usize::MAX`: the whole stream as one slice).
pub fn decode(stream: &[u8], chunk: usize) -> Tally {
    let mut dec = scip::Decoder::new();
    let mut t = Tally::default();
    for piece in stream.chunks(chunk.max(1)) {
        let mut rest = piece;
        while !rest.is_empty() {
            let (used, ev) = dec.feed(rest);
            rest = &rest[used..];
            match ev {
                Some(scip::Event::Data(line)) => {
                    t.readings += line.readings.len() as u64;
                    t.distance_sum += line
                        .readings
                        .iter()
                        .map(|r| u64::from(r.distance))
                        .sum::<u64>();
                }
                Some(scip::Event::End(_)) => t.responses += 1,
                Some(scip::Event::Error(_)) => t.errors += 1,
                _ => {}
            }
        }
    }
    t
}
