//! The bridge shared by the tasks of one executor.
//!
//! All tasks of a board run on the one thread-mode executor and never touch the bridge
//! from an interrupt, so a no-op mutex is enough: the lock only hands out the `&mut`
//! and never masks interrupts. A lock is held for one bridge call (one UART chunk, one
//! received frame, one `poll`), never across an `.await`.

use core::cell::RefCell;

use can_wire::Frame;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;

use crate::config::Bridge;

/// The bridge and the signal that wakes the CAN transmit task.
pub struct Shared {
    bridge: Mutex<NoopRawMutex, RefCell<Bridge>>,
    queued: Signal<NoopRawMutex, ()>,
}

impl Shared {
    /// Shares `bridge`.
    pub fn new(bridge: Bridge) -> Self {
        Self {
            bridge: Mutex::new(RefCell::new(bridge)),
            queued: Signal::new(),
        }
    }

    /// Runs `f` on the bridge. `f` must not call `with` again (the bridge is borrowed).
    pub fn with<R>(&self, f: impl FnOnce(&mut Bridge) -> R) -> R {
        self.bridge.lock(|cell| f(&mut cell.borrow_mut()))
    }

    /// Tells the transmit task that frames may have been queued.
    pub fn notify_frames(&self) {
        self.queued.signal(());
    }

    /// The next frame to transmit, in the bridge's order; waits for
    /// [`Shared::notify_frames`] while the queue is empty.
    pub async fn next_frame(&self) -> Frame {
        loop {
            if let Some(frame) = self.with(|b| b.pop_frame()) {
                return frame;
            }
            self.queued.wait().await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{bridge, node_ids, CanBus};
    use can_wire::control::Command;
    use can_wire::{Answer, Control, Kind, Outcome};
    use core::future::Future;
    use core::pin::pin;
    use core::task::{Context, Poll, Waker};

    fn control_frame(token: u8, command: Command) -> Frame {
        let mut buf = [0u8; can_wire::control::MAX_CONTROL_LEN];
        let n = Control { token, command }.emit(&mut buf).expect("emit");
        let id = node_ids().expect("ids").id(Kind::Control);
        Frame::new(id, &buf[..n], false).expect("frame")
    }

    #[test]
    fn next_frame_waits_for_a_queued_frame_and_is_woken() {
        let shared = Shared::new(bridge(CanBus::CLASSIC_1M).expect("bridge"));
        let mut cx = Context::from_waker(Waker::noop());
        let mut next = pin!(shared.next_frame());
        // Nothing queued: the transmit task waits.
        assert!(next.as_mut().poll(&mut cx).is_pending());
        // A control frame arrives; its answer is queued and the task is told.
        let stop = control_frame(7, Command::Stop);
        assert!(shared.with(|b| b.on_can_frame(&stop, 10)));
        shared.notify_frames();
        let Poll::Ready(frame) = next.as_mut().poll(&mut cx) else {
            panic!("the queued answer must be returned");
        };
        assert_eq!(frame.id(), node_ids().expect("ids").id(Kind::ControlAnswer));
        let answer = Answer::parse(frame.data()).expect("answer");
        assert_eq!((answer.token, answer.outcome), (7, Outcome::Accepted));
        assert_eq!(shared.with(|b| b.queued()), 0);
    }

    /// One stream response (`MD`, status 99) of `n` steps at 1000 + i mm.
    fn scan_response(n: u16) -> Vec<u8> {
        use scip::{Command as Scip, Request, ResponseWriter, ScanMode, ScanRequest};
        let mut out = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
        let mut s = ScanRequest::distance(ScanMode::Continuous, 0, n - 1);
        s.count = 0;
        w.echo(&Request::new(Scip::Scan(s)));
        w.status(*b"99");
        w.timestamp(1234);
        for i in 0..u32::from(n) {
            w.step(1000 + i, 0);
        }
        w.end();
        let _ = w.into_inner();
        out
    }

    #[test]
    fn a_scan_leaves_header_data_trailer_in_order() {
        let shared = Shared::new(bridge(CanBus::CLASSIC_1M).expect("bridge"));
        // 40 steps, 1000..=1039 mm, in the lossless coding (the boards' default).
        let bytes = scan_response(40);
        for chunk in bytes.chunks(crate::config::UART_CHUNK) {
            shared.with(|b| b.on_uart(chunk, 0));
        }
        let mut cx = Context::from_waker(Waker::noop());
        let ids = node_ids().expect("ids");
        let mut kinds = Vec::new();
        while let Poll::Ready(frame) = pin!(shared.next_frame()).poll(&mut cx) {
            let kind = ids.window().classify(frame.id()).map(|(_, k)| k);
            kinds.push(kind.expect("one of ours"));
        }
        // By hand from SPEC 4.2.3: 9 header bits, the anchor 1128 (5 + 11 bits), then
        // blocks of 16, 16 and 7 values that each grow by 1: second-order residuals 0,
        // k = 0, one bit each (2 + 4 + 16, 2 + 4 + 16, 2 + 4 + 7 bits); 82 bits, padded
        // to 11 bytes, and 2 CRC bytes: 13 stream bytes, 7 + 6 in two classic frames.
        let data = 2;
        let mut expected = vec![Kind::HeaderA, Kind::HeaderB];
        expected.extend(std::iter::repeat_n(Kind::Data, data));
        expected.push(Kind::Trailer);
        assert_eq!(kinds, expected);
    }
}
