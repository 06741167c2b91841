//! Fuzzes the reassembling CAN decoder: any sequence of frames (any identifier in and
//! around the window, any payload) must be taken without a panic, and a scan it reports
//! as intact must be self-consistent (every announced point present).
#![no_main]

use can_wire::reassembly::{Completeness, Decoder, Event};
use can_wire::IdWindow;
use embedded_can::{Id, StandardId};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // Input: records of [id_lo, id_hi_and_len, payload...]: 11-bit id, payload ≤ 64 bytes.
    let mut dec: Box<Decoder<256, 2>> = Box::new(Decoder::new(IdWindow::DEFAULT));
    let mut rest = data;
    while let [lo, hi, tail @ ..] = rest {
        let raw = u16::from(*lo) | (u16::from(*hi & 0x07) << 8);
        let len = usize::from(*hi >> 3).min(tail.len()) * 2;
        let len = len.min(tail.len()).min(64);
        let (payload, next) = tail.split_at(len);
        rest = next;
        let Some(id) = StandardId::new(raw) else {
            continue;
        };
        if let Ok(Some(Event::Scan { scan, .. })) = dec.push(Id::Standard(id), payload) {
            if scan.completeness() == Completeness::Intact {
                let count = scan.header().point_count;
                assert!(scan.received() <= count);
                assert!(scan.trailer().is_some(), "intact without a trailer");
            }
        }
    }
    for node in 0..16 {
        let _ = dec.flush(node);
    }
});
