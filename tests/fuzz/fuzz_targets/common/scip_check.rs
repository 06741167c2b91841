//! The SCIP decoder check shared by the `decoder` and `decoder_small` targets: arbitrary
//! bytes, fed whole, byte by byte and in a chunking derived from the first input byte,
//! must never panic, must keep the response framing rules, and must give the same events
//! and counters every way, and the same as the char-by-char reference decoder (no
//! whole-step fast path).
//!
//! Events are compared by a 64-bit digest (FNV-1a) of their contents rather than as text:
//! the data lines' readings are hashed as numbers, the other (rare) events through their
//! `Debug` form written into the hasher, so no event allocates. Formatting every reading
//! as text made the target run at about 300 inputs per second.

use core::fmt::Write as _;
use scip::{Decoder, DecoderStats, ErrorKind, Event};

/// FNV-1a over bytes; also a `fmt::Write` sink, so `Debug` output hashes without a String.
struct Fnv(u64);

impl Fnv {
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 = (self.0 ^ u64::from(x)).wrapping_mul(0x100_0000_01b3);
        }
    }
    fn word(&mut self, w: u64) {
        self.bytes(&w.to_le_bytes());
    }
}

impl core::fmt::Write for Fnv {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        self.bytes(s.as_bytes());
        Ok(())
    }
}

/// The digest of one event.
fn digest(ev: &Event<'_>) -> u64 {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    match ev {
        Event::Data(line) => {
            h.word(0xDA7A);
            let _ = write!(h, "{:?}{:?}{}", line.data, line.limits, line.line);
            for r in line.indexed() {
                h.word(u64::from(r.index) | u64::from(r.echo) << 16);
                h.word(u64::from(r.distance) | u64::from(r.aux) << 32);
            }
        }
        other => {
            let _ = write!(h, "{other:?}");
        }
    }
    h.0
}

/// The digest of one reading of a data event, with the line's data set and limits
/// (not its line number): the entry of a reading in [`Checker::flat`].
fn reading_digest(line: &scip::DataLine<'_>, r: &scip::IndexedReading) -> u64 {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    h.word(0x8EAD);
    let _ = write!(h, "{:?}{:?}", line.data, line.limits);
    h.word(u64::from(r.index) | u64::from(r.echo) << 16);
    h.word(u64::from(r.distance) | u64::from(r.aux) << 32);
    h.0
}

/// Checks the event order rules while recording every event's digest.
#[derive(Default)]
struct Checker {
    log: Vec<u64>,
    /// The events with each data event's readings as entries of their own: the same for
    /// `feed` and `feed_runs`, whose data events may carry several lines.
    flat: Vec<u64>,
    /// A response started and has not ended (End or its first Error).
    open: bool,
    /// The open response already reported its first Error.
    failed: bool,
    /// Values (first echoes) and extra echoes published in the open response.
    values: u32,
    extra: u32,
    /// Bytes consumed so far.
    fed: u64,
}

impl Checker {
    fn event(&mut self, ev: &Event<'_>) {
        self.log.push(digest(ev));
        match ev {
            Event::Data(line) => {
                assert!(line.readings.len() <= scip::MAX_RUN_READINGS);
                self.flat
                    .extend(line.indexed().map(|r| reading_digest(line, &r)));
            }
            other => self.flat.push(digest(other)),
        }
        let live = self.open && !self.failed;
        match ev {
            Event::Start { .. } => {
                assert!(!live, "Start while the previous response is still open");
                self.open = true;
                self.failed = false;
                self.values = 0;
                self.extra = 0;
            }
            Event::End(summary) => {
                assert!(live, "End outside a live response");
                self.open = false;
                assert_eq!(u32::from(summary.values), self.values, "End values");
                assert_eq!(u32::from(summary.extra_echoes), self.extra, "End echoes");
            }
            Event::Error(e) => {
                assert!(e.offset <= self.fed, "error offset beyond the bytes fed");
                if live {
                    self.failed = true;
                }
            }
            Event::Data(line) => {
                assert!(live, "Data outside a live response (or after its Error)");
                for r in line.indexed() {
                    if r.echo == 0 {
                        assert_eq!(u32::from(r.index), self.values, "value index");
                        self.values += 1;
                    } else {
                        assert!(r.echo < 3, "echo number");
                        assert_eq!(u32::from(r.index) + 1, self.values, "echo index");
                        self.extra += 1;
                    }
                }
            }
            Event::Status(_) | Event::Field(_) | Event::Timestamp(_) | Event::Payload(_) => {
                assert!(live, "payload event outside a live response");
            }
        }
    }
}

/// Feeds `stream` in pieces of the sizes `sizes` yields (the last piece takes the rest),
/// then finishes; returns the events as text and the counters.
fn run(stream: &[u8], sizes: impl FnMut() -> usize) -> (Vec<u64>, DecoderStats) {
    run_with(Decoder::new(), stream, sizes)
}

fn run_with(dec: Decoder, stream: &[u8], sizes: impl FnMut() -> usize) -> (Vec<u64>, DecoderStats) {
    let (ck, stats) = run_checked(dec, stream, sizes, false);
    (ck.log, stats)
}

/// As [`run_with`] through [`Decoder::feed_runs`]: the events with each data event's
/// readings as entries of their own ([`Checker::flat`]), and the counters.
fn run_runs(dec: Decoder, stream: &[u8], sizes: impl FnMut() -> usize) -> (Vec<u64>, DecoderStats) {
    let (ck, stats) = run_checked(dec, stream, sizes, true);
    (ck.flat, stats)
}

fn run_checked(
    mut dec: Decoder,
    stream: &[u8],
    mut sizes: impl FnMut() -> usize,
    runs: bool,
) -> (Checker, DecoderStats) {
    let mut ck = Checker::default();
    let mut rest = stream;
    while !rest.is_empty() {
        let n = sizes().clamp(1, rest.len());
        let (mut chunk, tail) = rest.split_at(n);
        rest = tail;
        while !chunk.is_empty() {
            let (used, ev) = if runs {
                dec.feed_runs(chunk)
            } else {
                dec.feed(chunk)
            };
            assert!(used >= 1, "feed made no progress");
            assert!(used <= chunk.len(), "feed consumed more than it got");
            ck.fed += used as u64;
            if let Some(ev) = ev {
                ck.event(&ev);
            }
            chunk = &chunk[used..];
        }
    }
    let live = ck.open && !ck.failed;
    match dec.finish() {
        Some(ev) => {
            assert!(matches!(ev, Event::Error(e) if e.kind == ErrorKind::Truncated));
            ck.event(&ev);
        }
        None => assert!(!live, "finish left a response open"),
    }
    assert!(dec.is_idle(), "not idle after finish");
    let stats = *dec.stats();
    assert_eq!(stats.bytes, stream.len() as u64);
    (ck, stats)
}

/// Checks one input: the first byte selects the chunking, the rest is the stream.
pub fn check(data: &[u8]) {
    let Some((&sel, stream)) = data.split_first() else {
        return;
    };
    // One-shot: its events, and the same with each data event's readings as entries of
    // their own (what runs of lines are compared with below).
    let (ck, stats) = run_checked(Decoder::new(), stream, || usize::MAX, false);
    let lines = (ck.flat, stats);
    let whole = (ck.log, stats);
    let reference = run_with(Decoder::char_by_char(), stream, || usize::MAX);
    assert_eq!(
        whole, reference,
        "fast path differs from the char-by-char reference"
    );
    let bytewise = run(stream, || 1);
    assert_eq!(
        whole, bytewise,
        "byte-by-byte feeding differs from one-shot"
    );
    let chunked = run(stream, chunking(sel));
    assert_eq!(
        whole, chunked,
        "chunked feeding (selector {sel}) differs from one-shot"
    );
    // The paths of 32-bit targets (the line copy that checks and sums), as the
    // Cortex-M boards take them.
    let m4 = run_with(Decoder::m4_paths(), stream, chunking(sel));
    assert_eq!(
        whole, m4,
        "the 32-bit paths (selector {sel}) differ from one-shot"
    );
    // Runs of lines, on both paths: the same events and readings, line by line, as
    // one-shot feeding line by line gives them; in pieces three times the selector's
    // (runs join the full lines that lie whole in one piece) and one-shot.
    for (paths, make) in [
        ("host", Decoder::new as fn() -> Decoder),
        ("32-bit", Decoder::m4_paths),
    ] {
        let mut sizes = chunking(sel);
        let runs = run_runs(make(), stream, move || sizes().saturating_mul(3));
        assert_eq!(
            lines, runs,
            "runs of lines on the {paths} paths (selector {sel}) differ from lines"
        );
        let runs = run_runs(make(), stream, || usize::MAX);
        assert_eq!(
            lines, runs,
            "runs of lines on the {paths} paths one-shot differ from lines"
        );
    }
}

/// The chunk sizes of selector `sel`: fixed chunks of 1..=128 bytes below 0x80, else
/// varying chunks of 1..=80 bytes from a small xorshift sequence.
fn chunking(sel: u8) -> impl FnMut() -> usize {
    let fixed = (sel < 0x80).then_some(usize::from(sel) + 1);
    let mut x = u32::from(sel) | 0x9E37_7900;
    move || match fixed {
        Some(size) => size,
        None => {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x % 80) as usize + 1
        }
    }
}
