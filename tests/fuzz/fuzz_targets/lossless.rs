//! Fuzzes the lossless coding (SPEC 4.2) both ways. The first byte picks a mode:
//! - decode: the rest is a segment's stream, decoded for a scan of up to 4095 points with
//!   or without intensity; and the same bytes cut into data frames for the receiver. No
//!   input may panic, and a segment that decodes must encode back to the same codes.
//! - round trip: the rest is read as distance and intensity codes, coded into frames and
//!   reassembled: the scan must come back intact with every value.
#![no_main]

use can_wire::lossless::receive::Receiver;
use can_wire::lossless::segment;
use can_wire::lossless::SEGMENT_POINTS;
use can_wire::{
    Completeness, Decoder, Distance, DistanceEncoding, Encoding, Event, Frame, FrameFormat,
    FrameSink, Grouping, IdWindow, IntensityEncoding, ScanEncoder, ScanHeader, TrailerFlags,
};
use libfuzzer_sys::fuzz_target;

struct Sink(Vec<Frame>);
impl FrameSink for Sink {
    fn data_slot(&mut self) -> Option<&mut Frame> {
        self.0.push(Frame::default());
        self.0.last_mut()
    }
}

fn header(n: u16, intensity: bool) -> ScanHeader {
    ScanHeader {
        seq: 5,
        timestamp_ms: 0,
        point_count: n,
        encoding: Encoding {
            distance: DistanceEncoding::Lossless,
            intensity: if intensity {
                IntensityEncoding::I16
            } else {
                IntensityEncoding::None
            },
            unit_exp: 0,
        },
        time_synced: false,
        time_estimated: false,
        time_master: false,
        grouping: Grouping::Single,
        step_increment: 1,
        first_step: 0,
        ares: 1440,
    }
}

fuzz_target!(|data: &[u8]| {
    let [mode, rest @ ..] = data else {
        return;
    };
    let intensity = mode & 1 != 0;
    if mode & 2 == 0 {
        let count = u16::from_le_bytes([rest.first().copied().unwrap_or(0), mode >> 4]);
        let (mut d, mut i) = ([0u32; SEGMENT_POINTS], [0u32; SEGMENT_POINTS]);
        let _ = segment::decode(rest, count, intensity, &mut d, &mut i);
        let h = header(count.clamp(1, 4095), intensity);
        let mut rx = Receiver::default();
        for chunk in rest.chunks(8) {
            let _ = rx.frame(chunk, &h, |_, _, _| {});
        }
        return;
    }
    // Round trip of arbitrary codes (3 bytes a point: distance 18 bits, intensity 16).
    let points: Vec<(Distance, u16)> = rest
        .chunks_exact(4)
        .take(4095)
        .map(|c| {
            let v = u32::from(c[0]) | u32::from(c[1]) << 8 | u32::from(c[2] & 3) << 16;
            let d = match c[2] >> 6 {
                0 => Distance::SensorError(v % 100),
                1 => Distance::Invalid,
                _ => Distance::Mm(v),
            };
            (d, u16::from(c[3]) << 8 | u16::from(c[0]))
        })
        .collect();
    if points.is_empty() {
        return;
    }
    let h = header(points.len() as u16, intensity);
    let format = if mode & 4 == 0 {
        FrameFormat::Classic
    } else {
        FrameFormat::FD64
    };
    let ids = IdWindow::DEFAULT.node(0).unwrap();
    let mut enc = ScanEncoder::new(ids, format).unwrap();
    let mut sink = Sink(enc.begin(&h).unwrap().to_vec());
    for &(d, i) in &points {
        enc.push_point_to(d, i, &mut sink).unwrap();
    }
    sink.0.extend(enc.finish(TrailerFlags::default()).unwrap());
    let mut dec: Box<Decoder<4095, 1>> = Box::new(Decoder::new(IdWindow::DEFAULT));
    let mut seen = false;
    for f in &sink.0 {
        if let Ok(Some(Event::Scan { scan, .. })) = dec.push_frame(f) {
            assert_eq!(scan.completeness(), Completeness::Intact);
            for (p, (d, i)) in scan.points().zip(&points) {
                let p = p.unwrap();
                assert_eq!(p.distance, *d);
                assert_eq!(p.intensity, intensity.then_some(*i));
            }
            seen = true;
        }
    }
    assert!(seen);
});
