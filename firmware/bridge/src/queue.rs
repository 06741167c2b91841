//! The CAN transmit queue: a ring of `Q` frames whose slots are written in place.
//!
//! A `heapless::Deque` takes frames by value, so queueing a data frame built in place
//! first writes a whole default frame (76 bytes) into the slot and then the frame's own
//! bytes over it. Here every slot always holds an initialised frame, and
//! [`FrameQueue::push_back_slot`] hands out the next one as it is: [`Frame::set`] then
//! writes only the new frame's bytes (and zeroes what an older, longer frame left), so a
//! classic data frame costs its 8 bytes. A CAN FD frame's bytes past the 8th are
//! cleared as it leaves its slot: a free slot holds none, as the encoder's
//! [`can_wire::FrameSink`] wants of the slots it writes classic frames into.

use can_wire::Frame;

/// A double-ended queue of at most `Q` frames.
#[derive(Debug, Clone)]
pub struct FrameQueue<const Q: usize> {
    slots: [Frame; Q],
    /// Slot of the front frame.
    head: usize,
    len: usize,
}

impl<const Q: usize> Default for FrameQueue<Q> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const Q: usize> FrameQueue<Q> {
    /// An empty queue.
    pub fn new() -> Self {
        Self {
            slots: [Frame::default(); Q],
            head: 0,
            len: 0,
        }
    }

    /// Frames queued.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no frame is queued.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Slots free.
    pub fn free(&self) -> usize {
        // `len <= Q` always.
        Q.wrapping_sub(self.len)
    }

    /// Slot index of position `i` from the front (`i <= Q`).
    #[inline(always)]
    fn slot(&self, i: usize) -> usize {
        // `head < Q` and `i <= Q`: no overflow, and `k - Q` only when `k >= Q`.
        let k = self.head.wrapping_add(i);
        if k >= Q {
            k.wrapping_sub(Q)
        } else {
            k
        }
    }

    /// A new back slot, counted as queued, holding whatever frame it last held: the
    /// caller overwrites it (with [`Frame::set`]). `None` when the queue is full.
    #[inline]
    pub fn push_back_slot(&mut self) -> Option<&mut Frame> {
        if self.len >= Q {
            return None;
        }
        let k = self.slot(self.len);
        // `len < Q` here.
        self.len = self.len.wrapping_add(1);
        self.slots.get_mut(k)
    }

    /// Up to `n` new back slots, counted as queued, in order, each holding whatever frame
    /// it last held (the caller overwrites every one): as many as are free up to the
    /// end of the ring, so fewer than `n` when the free slots wrap (ask again for the
    /// rest), none when the queue is full.
    #[inline]
    pub fn push_back_slots(&mut self, n: usize) -> &mut [Frame] {
        let k = self.slot(self.len);
        // `len <= Q` and `k < Q` (or `k == 0` when `Q == 0`): no wrap.
        let n = n.min(Q.wrapping_sub(self.len)).min(Q.wrapping_sub(k));
        match self.slots.get_mut(k..k.wrapping_add(n)) {
            Some(slots) => {
                self.len = self.len.wrapping_add(n);
                slots
            }
            None => &mut [],
        }
    }

    /// Queues a frame at the back; gives it back when the queue is full.
    pub fn push_back(&mut self, frame: Frame) -> Result<(), Frame> {
        match self.push_back_slot() {
            Some(slot) => {
                put(slot, &frame);
                Ok(())
            }
            None => Err(frame),
        }
    }

    /// Queues a frame at the front (it leaves next); gives it back when the queue is full.
    pub fn push_front(&mut self, frame: Frame) -> Result<(), Frame> {
        if self.len >= Q || Q == 0 {
            return Err(frame);
        }
        // `Q > 0` and `len < Q` here.
        let k = self.slot(Q.wrapping_sub(1));
        match self.slots.get_mut(k) {
            Some(slot) => {
                put(slot, &frame);
                self.head = k;
                self.len = self.len.wrapping_add(1);
                Ok(())
            }
            None => Err(frame),
        }
    }

    /// Takes the front frame.
    #[inline]
    pub fn pop_front(&mut self) -> Option<Frame> {
        if self.len == 0 {
            return None;
        }
        let frame = self.slots.get_mut(self.head).map(|slot| {
            let frame = *slot;
            slot.clear_fd_bytes();
            frame
        });
        self.head = self.slot(1);
        // `len > 0` here.
        self.len = self.len.wrapping_sub(1);
        frame
    }

    /// Takes the front frame, handing it to `f` in its slot (no copy of the whole
    /// frame); `None` without calling `f` when the queue is empty.
    #[inline]
    pub fn pop_front_with<R>(&mut self, f: impl FnOnce(&Frame) -> R) -> Option<R> {
        if self.len == 0 {
            return None;
        }
        let out = self.slots.get_mut(self.head).map(|slot| {
            let out = f(slot);
            slot.clear_fd_bytes();
            out
        });
        self.head = self.slot(1);
        // `len > 0` here.
        self.len = self.len.wrapping_sub(1);
        out
    }

    /// Drops the back frame (one just pushed that turned out not to be wanted).
    pub fn pop_back(&mut self) {
        if self.len == 0 {
            return;
        }
        // `len > 0` here.
        self.len = self.len.wrapping_sub(1);
        let k = self.slot(self.len);
        if let Some(slot) = self.slots.get_mut(k) {
            slot.clear_fd_bytes();
        }
    }

    /// The frames, front first.
    pub fn iter(&self) -> impl Iterator<Item = &Frame> + '_ {
        (0..self.len).filter_map(move |i| self.slots.get(self.slot(i)))
    }
}

/// `*dst = *src`, out of line: as a function's `&mut` and `&` parameters the two are
/// distinct frames to the compiler, which copies with `memcpy`. Inlined into the engine
/// it could not tell, and called `memmove` for the 64 data bytes, which then linked
/// 1.5 KB of M4 code that nothing else needs.
#[inline(never)]
fn put(dst: &mut Frame, src: &Frame) {
    *dst = *src;
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::{Id, StandardId};
    use proptest::prelude::*;
    use std::collections::VecDeque;

    fn frame(n: u16, len: usize) -> Frame {
        let id = Id::Standard(StandardId::new(n & 0x7FF).unwrap());
        Frame::new(id, &[n as u8; 8][..len], false).unwrap()
    }

    #[test]
    fn wraps_and_keeps_order_from_both_ends() {
        let mut q = FrameQueue::<3>::new();
        assert_eq!(q.pop_front(), None);
        q.push_back(frame(1, 8)).unwrap();
        q.push_back(frame(2, 8)).unwrap();
        q.push_front(frame(0, 8)).unwrap();
        assert_eq!(q.push_back(frame(9, 8)), Err(frame(9, 8)));
        assert_eq!(q.push_front(frame(9, 8)), Err(frame(9, 8)));
        assert!(q.push_back_slot().is_none());
        assert_eq!(q.pop_front_with(|f| *f), Some(frame(0, 8)));
        let slot = q.push_back_slot().unwrap();
        // The reused slot still holds the frame popped from it; a shorter frame set over
        // it keeps no byte of the old one.
        slot.set(frame(3, 2).id(), &[3, 3], false).unwrap();
        assert_eq!(
            q.iter().copied().collect::<Vec<_>>(),
            [frame(1, 8), frame(2, 8), frame(3, 2)]
        );
        q.pop_back();
        assert_eq!(q.len(), 2);
        assert_eq!(q.free(), 1);
    }

    /// A CAN FD frame leaves its slot (by each of the three pops) with its bytes past
    /// the 8th cleared: a classic frame then set there with plain stores (the
    /// encoder's `set_classic_as`) is the frame `Frame::new` makes, every byte; the
    /// frame popped is the FD frame whole.
    #[test]
    fn a_free_slot_holds_no_fd_byte() {
        let id = Id::Standard(StandardId::new(0x155).unwrap());
        let fd = Frame::new(id, &[0xEE; 64], true).unwrap();
        let fd12 = Frame::new(id, &[0xDD; 12], true).unwrap();
        let classic = Frame::new(id, &[1, 2, 3, 4, 5, 6, 7, 8], false).unwrap();
        let shape = Frame::classic_shape(8);
        for pop in 0..3 {
            let mut q = FrameQueue::<2>::new();
            q.push_back(fd).unwrap();
            q.push_back(fd12).unwrap();
            match pop {
                0 => {
                    assert_eq!(q.pop_front(), Some(fd));
                    assert_eq!(q.pop_front(), Some(fd12));
                }
                1 => {
                    assert_eq!(q.pop_front_with(|f| *f), Some(fd));
                    assert_eq!(q.pop_front_with(|f| *f), Some(fd12));
                }
                _ => {
                    q.pop_back();
                    q.pop_back();
                }
            }
            assert!(q.is_empty());
            // Both slots again, from wherever the ring's back is now.
            let mut n = 0;
            while n < 2 {
                let slots = q.push_back_slots(2 - n);
                assert!(!slots.is_empty());
                n += slots.len();
                for slot in slots {
                    slot.set_classic_as(id, [1, 2, 3, 4, 5, 6, 7, 8], shape);
                }
            }
            assert_eq!(q.iter().copied().collect::<Vec<_>>(), [classic, classic]);
        }
    }

    #[test]
    fn slots_in_batches_stop_at_the_ring_end() {
        let mut q = FrameQueue::<3>::new();
        q.push_back(frame(1, 8)).unwrap();
        q.push_back(frame(2, 8)).unwrap();
        assert_eq!(q.pop_front(), Some(frame(1, 8)));
        assert_eq!(q.pop_front(), Some(frame(2, 8)));
        // The next back slot is the ring's last: one slot, then the two at its start.
        let first = q.push_back_slots(3);
        assert_eq!(first.len(), 1);
        first[0].set(frame(3, 1).id(), &[3], false).unwrap();
        let rest = q.push_back_slots(3);
        assert_eq!(rest.len(), 2);
        for (slot, n) in rest.iter_mut().zip([4u16, 5]) {
            slot.set(frame(n, 2).id(), &[n as u8; 2], false).unwrap();
        }
        assert!(q.push_back_slots(1).is_empty());
        assert!(q.push_back_slots(0).is_empty());
        assert_eq!(
            q.iter().copied().collect::<Vec<_>>(),
            [frame(3, 1), frame(4, 2), frame(5, 2)]
        );
    }

    proptest! {
        /// Any sequence of operations does what a `VecDeque` of capacity `Q` does.
        #[test]
        fn behaves_like_a_bounded_vecdeque(ops in proptest::collection::vec((0u8..6, 0u16..0x7FF, 0usize..9), 0..200)) {
            let mut q = FrameQueue::<5>::new();
            let mut model: VecDeque<Frame> = VecDeque::new();
            for (op, n, len) in ops {
                let f = frame(n, len);
                match op {
                    0 => {
                        let ok = model.len() < 5;
                        if ok { model.push_back(f) }
                        prop_assert_eq!(q.push_back(f).is_ok(), ok);
                    }
                    1 => {
                        let ok = model.len() < 5;
                        if ok { model.push_front(f) }
                        prop_assert_eq!(q.push_front(f).is_ok(), ok);
                    }
                    2 => prop_assert_eq!(q.pop_front(), model.pop_front()),
                    3 => {
                        match q.push_back_slot() {
                            Some(slot) => {
                                slot.set(f.id(), f.data(), false).unwrap();
                                model.push_back(f);
                            }
                            None => prop_assert_eq!(model.len(), 5),
                        }
                    }
                    4 => {
                        // `len` slots wanted, each written with its own frame.
                        let slots = q.push_back_slots(len);
                        let k = slots.len();
                        let room = len.min(5 - model.len());
                        // Up to the ring's end, at least one when any is free.
                        prop_assert!(k <= room && (k > 0 || room == 0));
                        for (m, slot) in slots.iter_mut().enumerate() {
                            let g = frame(n.wrapping_add(m as u16), len.min(8));
                            slot.set(g.id(), g.data(), false).unwrap();
                            model.push_back(g);
                        }
                    }
                    _ => {
                        q.pop_back();
                        model.pop_back();
                    }
                }
                prop_assert_eq!(q.len(), model.len());
                prop_assert_eq!(q.iter().copied().collect::<Vec<_>>(), model.iter().copied().collect::<Vec<_>>());
            }
        }
    }
}
