//! Property tests: any frame → text → the same frame, in both directions and through the
//! line splitter in any chunking.

use embedded_can::{ExtendedId, Id, StandardId};
use proptest::prelude::*;
use slcan::line::Line;
use slcan::{Command, Frame, FrameKind, LineBuffer, Reply, LINE_MAX};

fn id() -> impl Strategy<Value = Id> {
    prop_oneof![
        (0u16..=0x7FF).prop_map(|r| Id::Standard(StandardId::new(r).unwrap())),
        (0u32..=0x1FFF_FFFF).prop_map(|r| Id::Extended(ExtendedId::new(r).unwrap())),
    ]
}

fn frame() -> impl Strategy<Value = Frame> {
    let classic = (id(), prop::collection::vec(any::<u8>(), 0..=8))
        .prop_map(|(id, d)| Frame::new(id, FrameKind::Data, &d).unwrap());
    let remote = (id(), 0u8..=8).prop_map(|(id, dlc)| Frame::remote(id, dlc).unwrap());
    let fd = (id(), 0u8..=15, any::<bool>(), any::<[u8; 64]>()).prop_map(|(id, dlc, brs, d)| {
        let len = slcan::dlc_to_len(dlc).unwrap();
        let kind = if brs { FrameKind::FdBrs } else { FrameKind::Fd };
        Frame::new(id, kind, &d[..len]).unwrap()
    });
    prop_oneof![classic, remote, fd]
}

proptest! {
    #[test]
    fn frame_text_frame(f in frame(), ts in prop::option::of(0u16..60_000)) {
        let mut buf = [0u8; LINE_MAX];
        // Host → adapter: a transmit command.
        let n = Command::Transmit(f).emit(&mut buf).unwrap();
        prop_assert_eq!(buf[n - 1], b'\r');
        prop_assert_eq!(Command::parse(&buf[..n - 1]), Ok(Command::Transmit(f)));
        // Adapter → host: a received frame, with or without timestamp.
        let n = Reply::Frame(f, ts).emit(&mut buf).unwrap();
        prop_assert_eq!(Reply::parse(&buf[..n - 1]), Ok(Reply::Frame(f, ts)));
    }

    #[test]
    fn a_stream_of_frames_survives_any_chunking(
        frames in prop::collection::vec(frame(), 1..20),
        cut in prop::collection::vec(1usize..50, 1..40),
    ) {
        let mut stream = Vec::new();
        for f in &frames {
            let mut buf = [0u8; LINE_MAX];
            let n = Reply::Frame(*f, None).emit(&mut buf).unwrap();
            stream.extend_from_slice(&buf[..n]);
        }
        let mut lb = LineBuffer::new();
        let mut got = Vec::new();
        let mut rest = stream.as_slice();
        let mut i = 0;
        while !rest.is_empty() {
            let take = cut[i % cut.len()].min(rest.len());
            i += 1;
            let mut chunk = &rest[..take];
            rest = &rest[take..];
            while !chunk.is_empty() {
                let (used, line) = lb.feed(chunk);
                chunk = &chunk[used..];
                if let Some(Line::Text(t)) = line {
                    got.push(Reply::parse(t).unwrap());
                }
            }
        }
        let want: Vec<Reply> = frames.iter().map(|f| Reply::Frame(*f, None)).collect();
        prop_assert_eq!(got, want);
    }

    #[test]
    fn no_line_panics(bytes in prop::collection::vec(any::<u8>(), 0..200)) {
        let _ = Command::parse(&bytes);
        let _ = Reply::parse(&bytes);
        let mut a = slcan::Adapter::new(*b"0100", *b"TEST", true);
        let mut lb = LineBuffer::new();
        let mut rest = bytes.as_slice();
        while !rest.is_empty() {
            let (used, line) = lb.feed(rest);
            prop_assert!(used > 0);
            rest = &rest[used..];
            if let Some(line) = line {
                let _ = a.line(line);
            }
        }
    }
}
