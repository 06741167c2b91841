//! Fuzzes the SLCAN codec as the emulated board and the host's adapters use it: arbitrary
//! bytes split into lines (whole and in a chunking picked by the first byte: both must give
//! the same lines), each line handled by an adapter (never a panic; every line gets exactly
//! one reply), and every line that parses as a command, a frame or a reply emits back to a
//! line that parses to the same value.
#![no_main]

use libfuzzer_sys::fuzz_target;
use slcan::line::Line;
use slcan::{Adapter, Command, Frame, LineBuffer, Outcome, Reply, LINE_MAX};

/// A line as owned bytes, or what ended it otherwise.
#[derive(Debug, PartialEq)]
enum Owned {
    Text(Vec<u8>),
    Bell,
    TooLong,
}

fn lines(stream: &[u8], mut size: impl FnMut() -> usize) -> Vec<Owned> {
    let mut lb = LineBuffer::new();
    let mut out = Vec::new();
    let mut rest = stream;
    while !rest.is_empty() {
        let n = size().clamp(1, rest.len());
        let (mut chunk, tail) = rest.split_at(n);
        rest = tail;
        while !chunk.is_empty() {
            let (used, line) = lb.feed(chunk);
            assert!(
                used >= 1 && used <= chunk.len(),
                "feed used {used} of {}",
                chunk.len()
            );
            chunk = &chunk[used..];
            match line {
                Some(Line::Text(t)) => {
                    assert!(t.len() < LINE_MAX, "a line longer than LINE_MAX - 1");
                    assert!(!t.contains(&b'\r') && !t.contains(&b'\n') && !t.contains(&7));
                    out.push(Owned::Text(t.to_vec()));
                }
                Some(Line::Bell) => out.push(Owned::Bell),
                Some(Line::Error(_)) => out.push(Owned::TooLong),
                None => {}
            }
        }
    }
    out
}

/// Every form a line can parse as round-trips through its emitter.
fn round_trips(text: &[u8]) {
    let mut buf = [0u8; LINE_MAX + 8];
    if let Ok(cmd) = Command::parse(text) {
        if let Ok(n) = cmd.emit(&mut buf) {
            let line = buf[..n].strip_suffix(b"\r").unwrap_or(&buf[..n]);
            assert_eq!(Command::parse(line), Ok(cmd), "command round trip");
        }
    }
    for ts in [false, true] {
        if let Ok((frame, stamp)) = Frame::parse(text, ts) {
            let n = frame.emit(stamp, &mut buf).expect("a parsed frame emits");
            assert_eq!(buf[n - 1], b'\r');
            assert_eq!(
                Frame::parse(&buf[..n - 1], ts),
                Ok((frame, stamp)),
                "frame round trip"
            );
        }
    }
    if let Ok(reply) = Reply::parse(text) {
        if let Ok(n) = reply.emit(&mut buf) {
            let line = buf[..n].strip_suffix(b"\r").unwrap_or(&buf[..n]);
            assert_eq!(Reply::parse(line), Ok(reply), "reply round trip");
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&sel, stream)) = data.split_first() else {
        return;
    };
    let whole = lines(stream, || usize::MAX);
    let size = usize::from(sel % 16) + 1;
    assert_eq!(
        whole,
        lines(stream, || size),
        "chunking {size} changed the lines"
    );
    let mut adapter = Adapter::new(*b"V101", *b"N001", sel & 0x80 != 0);
    let mut errors = 0u32;
    for line in &whole {
        let outcome = match line {
            Owned::Text(t) => {
                round_trips(t);
                adapter.line(Line::Text(t))
            }
            Owned::Bell => adapter.line(Line::Bell),
            Owned::TooLong => adapter.line(Line::Error(slcan::Error::LineTooLong)),
        };
        if outcome.reply() == Reply::Error {
            errors += 1;
        }
        if let Outcome::Transmit(frame, _) = outcome {
            // What the adapter would hand the host for the same frame parses back to it.
            let mut buf = [0u8; LINE_MAX];
            if let Some(n) = adapter.received(&frame, 123_456, &mut buf) {
                let (back, _) = Frame::parse(&buf[..n - 1], adapter.timestamps())
                    .expect("the adapter's own line parses");
                assert_eq!(back, frame, "received line round trip");
            }
        }
    }
    assert_eq!(adapter.errors(), errors, "every BEL reply is counted");
});
