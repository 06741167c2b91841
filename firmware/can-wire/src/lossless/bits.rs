//! Bits of a segment's stream: the sender's writer, which cuts the stream into data
//! frames as they fill, and the receiver's reader.

use super::{ESCAPE_ONES, SEGMENT_HEADER_BITS};
use crate::crc::ScanCrc;
use crate::encoder::FrameSink;
use crate::frame::{padded_len, Frame, CLASSIC_LEN, MAX_LEN};
use embedded_can::Id;

/// Flag of the framing byte: the frame begins a segment.
pub const SEGMENT_START: u8 = 0x80;
/// The frame counter's bits in the framing byte.
pub const COUNTER_MASK: u8 = 0x7F;

/// Stream bytes of a full classic data frame (its framing byte not counted).
const CLASSIC_STREAM_BYTES: usize = CLASSIC_LEN - 1;

/// On classic CAN the writer gathers up to this many bytes (the first frame's framing
/// byte and eight frames' stream bytes) before it must cut frames: whole frames are cut
/// a batch at a time, into slots the sink hands out a batch at a time.
const CLASSIC_BATCH_LEN: usize = 1 + 8 * CLASSIC_STREAM_BYTES;

/// Where the frames of a scan go, and what happened to them.
pub struct Out<'a, S: ?Sized> {
    /// The frames' destination.
    pub sink: &'a mut S,
    /// The data frames' identifier.
    pub id: Id,
    /// Whether frames are CAN FD frames.
    pub fd: bool,
    /// Frames written into the sink.
    pub frames: u32,
    /// Frames the sink had no slot for.
    pub lost: u32,
}

impl<'a, S: ?Sized> Out<'a, S> {
    /// Frames with identifier `id` (CAN FD frames if `fd`) into `sink`, none yet.
    pub fn new(sink: &'a mut S, id: Id, fd: bool) -> Self {
        Out {
            sink,
            id,
            fd,
            frames: 0,
            lost: 0,
        }
    }
}

/// Writes a scan's segments into data frames: a framing byte, then the stream's bytes,
/// LSB first (stream bit `k` of a frame's payload is bit `k % 8` of byte `1 + k / 8`).
///
/// Fields gather in a 32-bit word that goes into the frame when full (32-bit operations
/// only: the MCU has no 64-bit shifts); the
/// segment's CRC takes each full word from the register, 16 bits at a time, and the
/// segment's last bytes before the CRC goes in.
#[derive(Debug, Clone)]
pub struct Writer {
    /// Bits not yet in the frame (`nbits` of them, fewer than 32 between calls).
    acc: u32,
    nbits: u32,
    /// The frame being filled: the framing byte, then `len - 1` stream bytes (and room
    /// for a word past the longest frame).
    buf: [u8; MAX_LEN + 4],
    len: usize,
    /// Length of a full frame.
    full: usize,
    /// The length at which a word cuts the full frames gathered: a full frame's on CAN
    /// FD, `CLASSIC_BATCH_LEN` (eight frames) on classic CAN (whose whole frames wait for
    /// [`Writer::flush`], the segment's end or this length; set at the segment's start,
    /// where the writer learns the frame format).
    limit: usize,
    /// Counter of the next data frame of the scan.
    counter: u8,
    /// The open segment's CRC.
    crc: ScanCrc,
    /// Stream bytes of frames sent, and of frames sent without a slot.
    bytes: u32,
}

impl Writer {
    /// A writer for a scan whose full data frames are `full` bytes long (8 on classic
    /// CAN; 9..=64 would be accepted, the CAN FD lengths are the sensible ones).
    pub fn new(full: usize) -> Writer {
        let full = full.clamp(2, MAX_LEN);
        Writer {
            acc: 0,
            nbits: 0,
            buf: [0; MAX_LEN + 4],
            len: 1,
            full,
            limit: full,
            counter: 0,
            crc: ScanCrc::start(),
            bytes: 0,
        }
    }

    /// Stream bytes written so far (the segments' bytes and CRCs, without the framing
    /// bytes and padding; bits still gathering not counted).
    pub fn stream_bytes(&self) -> u32 {
        self.bytes.wrapping_add(self.len.saturating_sub(1) as u32)
    }

    /// Start a segment in a fresh frame: its header fields.
    pub fn begin_segment<S: FrameSink + ?Sized>(
        &mut self,
        seq_low: u8,
        segment: u8,
        out: &mut Out<'_, S>,
    ) {
        if self.len > 1 || self.nbits > 0 {
            // A segment always ends its frame; this only happens after misuse.
            self.end_segment(out);
        }
        if let Some(b) = self.buf.first_mut() {
            *b = SEGMENT_START | (self.counter & COUNTER_MASK);
        }
        // Classic frames wait to be cut a batch at a time (the frame is empty here).
        self.limit = if self.full == CLASSIC_LEN && !out.fd {
            CLASSIC_BATCH_LEN
        } else {
            self.full
        };
        self.crc = ScanCrc::start();
        let fields = u32::from(seq_low & 0xF) | u32::from(segment & 0x1F) << 4;
        self.put(fields, SEGMENT_HEADER_BITS, out);
    }

    /// Put the `bits` low bits of `value` (at most 31; higher bits of `value` must be 0).
    #[inline(always)]
    pub fn put<S: FrameSink + ?Sized>(&mut self, value: u32, bits: u32, out: &mut Out<'_, S>) {
        let total = self.nbits.wrapping_add(bits);
        self.acc |= value.wrapping_shl(self.nbits);
        if total >= 32 {
            let word = self.acc;
            // Here `nbits` >= 1 (a field has at most 31 bits): the bits that did not fit.
            self.acc = value.wrapping_shr(32u32.wrapping_sub(self.nbits));
            self.nbits = total.wrapping_sub(32); // total >= 32 here
            self.word(word, out);
        } else {
            self.nbits = total;
        }
    }

    /// Moves 32 gathered bits into the frame (once per 4 bytes: not inlined); a word
    /// that reaches the frame's end fills it, sends it, and begins the next frame.
    #[inline(never)]
    fn word<S: FrameSink + ?Sized>(&mut self, word: u32, out: &mut Out<'_, S>) {
        self.word_inline(word, out);
    }

    /// [`Writer::word`], inlined where its call would cost most: the Rice code loop.
    #[inline(always)]
    fn word_inline<S: FrameSink + ?Sized>(&mut self, word: u32, out: &mut Out<'_, S>) {
        // `len < limit <= MAX_LEN` between calls, and the buffer has 4 bytes of room
        // past `MAX_LEN`: the word always fits (bytes past `limit` are cut with it).
        let at = self.len;
        let end = at.wrapping_add(4);
        if let Some(dst) = self.buf.get_mut(at..end) {
            dst.copy_from_slice(&word.to_le_bytes());
        }
        // The segment's CRC takes the word's bytes from the register, two at a time
        // (low first, as they go into the frame): words only follow stream bytes
        // already in it, and a cut frame's bytes stay in it.
        self.crc.code(word as u16);
        self.crc.code((word >> 16) as u16);
        self.len = end;
        if end >= self.limit {
            self.cut(out);
        }
    }

    /// Sends the full frames gathered, if any: on classic CAN they wait for this (or
    /// for the segment's end, or for eight frames' bytes, `CLASSIC_BATCH_LEN`), so that
    /// they go into slots taken a batch at a time. Call it where a frame the sink had no slot
    /// for should be known ([`Out::lost`]): the stream calls it at the end of each run.
    #[inline(always)]
    pub fn flush<S: FrameSink + ?Sized>(&mut self, out: &mut Out<'_, S>) {
        if self.len >= self.full {
            self.cut(out);
        }
    }

    /// Sends the full frames gathered (the bytes past the last, fewer than a frame's
    /// stream bytes, begin the next one). Every byte up to `len` is in the segment's
    /// CRC already (`word`, `end_segment`).
    #[inline(never)]
    fn cut<S: FrameSink + ?Sized>(&mut self, out: &mut Out<'_, S>) {
        if self.limit != self.full {
            self.cut_classic(out);
            return;
        }
        // Longer frames are cut as they fill (`limit == full`): one frame, and at most
        // 3 bytes past it, which begin the next one.
        let full = self.full;
        let rest = self.len.wrapping_sub(full);
        let mut next = [0u8; 4];
        if let Some(src) = self.buf.get(full..full.wrapping_add(4)) {
            next.copy_from_slice(src);
        }
        self.len = full;
        self.emit(out);
        if let Some(dst) = self.buf.get_mut(1..5) {
            dst.copy_from_slice(&next);
        }
        self.len = rest.wrapping_add(1);
    }

    /// [`Writer::cut`] on classic CAN: each full frame written into its slot as two
    /// words (none of `emit`'s length cases), into slots the sink hands out a batch at
    /// a time. Frame `j`'s stream bytes are `buf[1 + 7j..8 + 7j]`, its framing byte
    /// `buf[0]` for the first (a segment's start, perhaps), the counter for the others.
    fn cut_classic<S: FrameSink + ?Sized>(&mut self, out: &mut Out<'_, S>) {
        // `len <= CLASSIC_BATCH_LEN + 3`: at most 8 frames, no wrap anywhere below.
        let whole = self.len.wrapping_sub(1) / CLASSIC_STREAM_BYTES;
        let shape = Frame::classic_shape(CLASSIC_LEN);
        let mut framing = self.buf.first().copied().unwrap_or(0);
        let mut at = 0usize; // the frame's first byte: its framing byte's place
        let mut left = whole;
        while left > 0 {
            let slots = out.sink.data_slots(left);
            if slots.is_empty() {
                // No room: the frames are lost, and the scan goes on as if they had
                // been sent.
                out.lost = out.lost.wrapping_add(left as u32);
                self.counter = self.counter.wrapping_add(left as u8);
                break;
            }
            let given = slots.len().min(left);
            // One exit test per frame, the counter in a register.
            let mut counter = self.counter;
            for frame in slots.get_mut(..given).unwrap_or_default() {
                let end = at.wrapping_add(CLASSIC_LEN);
                if let Some(head) = self.buf.get(at..end).and_then(|b| b.first_chunk()) {
                    let mut head: [u8; CLASSIC_LEN] = *head;
                    head[0] = framing;
                    frame.set_classic_as(out.id, head, shape);
                }
                counter = counter.wrapping_add(1);
                framing = counter & COUNTER_MASK;
                at = at.wrapping_add(CLASSIC_STREAM_BYTES);
            }
            self.counter = counter;
            out.frames = out.frames.wrapping_add(given as u32);
            left = left.wrapping_sub(given);
        }
        let cut = whole.wrapping_mul(CLASSIC_STREAM_BYTES);
        self.bytes = self.bytes.wrapping_add(cut as u32);
        // The bytes past the frames (fewer than a frame's) after the framing byte, moved
        // as two words: `cut + 9 <= 65`, within the buffer.
        let next = self
            .buf
            .get(cut.wrapping_add(1)..)
            .and_then(|b| b.first_chunk::<8>())
            .copied();
        if let (Some(next), Some(dst)) = (next, self.buf.get_mut(1..9)) {
            dst.copy_from_slice(&next);
        }
        self.len = self.len.wrapping_sub(cut);
        if let Some(b) = self.buf.first_mut() {
            *b = self.counter & COUNTER_MASK;
        }
    }

    /// Put one value's Rice code with parameter `k` (at most 15): the quotient `u >> k`
    /// in unary (that many ones and a zero) and the `k` low bits, or, for a quotient of
    /// at least [`ESCAPE_ONES`], that many ones and `value` itself in `value_bits` bits.
    #[inline(never)]
    pub fn put_rice<S: FrameSink + ?Sized>(
        &mut self,
        u: u32,
        k: u32,
        value: u32,
        value_bits: u32,
        out: &mut Out<'_, S>,
    ) {
        let q = u >> k;
        if q < ESCAPE_ONES {
            // q < 16 and k <= 15: every shift and the width (q + 1 + k) stay below 32.
            let ones = (1u32 << q).wrapping_sub(1);
            let low = u & (1u32 << k).wrapping_sub(1);
            let q1 = q.wrapping_add(1);
            self.put(ones | low << q1, q1.wrapping_add(k), out);
        } else {
            self.put((1u32 << ESCAPE_ONES) - 1, ESCAPE_ONES, out);
            self.put(value, value_bits, out);
        }
    }

    /// Put the field `head` (its value, then its width: at most 31 bits; a block's
    /// header), then the Rice codes of `u` with parameter `k` (at most 15), none of
    /// whose quotients `x >> k` may reach [`ESCAPE_ONES`] (the caller checked): like
    /// [`Writer::put`] and [`Writer::put_rice`] for each, with the gathering word kept
    /// in registers. Two codes per turn: when they have at most 31 bits together (the
    /// common case), the second is set above the first and the pair goes into the word
    /// as one field, the same bits in the same order as one after the other.
    #[inline(always)]
    pub fn put_rices<S: FrameSink + ?Sized>(
        &mut self,
        head: (u32, u32),
        u: &[u32],
        k: u32,
        out: &mut Out<'_, S>,
    ) {
        let k = k.min(ESCAPE_ONES - 1);
        let mask = (1u32 << k).wrapping_sub(1);
        let k1 = k.wrapping_add(1);
        // One code and its width: q < 16 (checked by the caller) and k <= 15, so the
        // code has q + 1 + k <= 31 bits; `(2·low + 1) << q` less 1 is the low bits
        // after q ones and a zero.
        let rice = |x: u32| {
            let q = x >> k;
            let low = x & mask;
            let code = (low.wrapping_mul(2) | 1).wrapping_shl(q).wrapping_sub(1);
            (code, q.wrapping_add(k1))
        };
        let (mut acc, mut nbits) = (self.acc, self.nbits);
        self.gather(&mut acc, &mut nbits, head.0, head.1, out);
        let mut pairs = u.chunks_exact(2);
        for pair in &mut pairs {
            let &[x0, x1] = pair else {
                continue;
            };
            let (c0, b0) = rice(x0);
            let (c1, b1) = rice(x1);
            // Each width at most 31: no wrap.
            let bits = b0.wrapping_add(b1);
            if bits <= 31 {
                // `c1` has `b1` bits: shifted by `b0 <= 31` it stays below 2^31.
                let code = c0 | c1.wrapping_shl(b0);
                acc |= code.wrapping_shl(nbits);
                let total = nbits.wrapping_add(bits);
                if total >= 32 {
                    self.word_inline(acc, out);
                    // Here `nbits` >= 1 (the pair has at most 31 bits): the bits that
                    // did not fit.
                    acc = code.wrapping_shr(32u32.wrapping_sub(nbits));
                    nbits = total.wrapping_sub(32);
                } else {
                    nbits = total;
                }
            } else {
                // Too long for one field: one code after the other.
                self.gather(&mut acc, &mut nbits, c0, b0, out);
                self.gather(&mut acc, &mut nbits, c1, b1, out);
            }
        }
        if let &[x] = pairs.remainder() {
            let (c, b) = rice(x);
            self.gather(&mut acc, &mut nbits, c, b, out);
        }
        self.acc = acc;
        self.nbits = nbits;
    }

    /// Put the field `head` (its value, then its width: at most 31 bits; a block's
    /// header), then the Rice codes of `u` with parameter `k` (at most 15), escapes
    /// included: like [`Writer::put`] and [`Writer::put_rice`] of each `u` with the
    /// value of `values` beside it (in `value_bits` bits, at most 31), with the
    /// gathering word kept in registers (a block with an escape is not rare in real
    /// scans: a jump to or from an error code).
    #[inline(always)]
    pub fn put_rices_escaped<S: FrameSink + ?Sized>(
        &mut self,
        head: (u32, u32),
        u: &[u32],
        values: &[u32],
        k: u32,
        value_bits: u32,
        out: &mut Out<'_, S>,
    ) {
        let k = k.min(ESCAPE_ONES - 1);
        let mask = (1u32 << k).wrapping_sub(1);
        let value_bits = value_bits.min(31);
        let value_mask = (1u32 << value_bits).wrapping_sub(1);
        let (mut acc, mut nbits) = (self.acc, self.nbits);
        self.gather(&mut acc, &mut nbits, head.0, head.1, out);
        for (&x, &v) in u.iter().zip(values) {
            let q = x >> k;
            if q < ESCAPE_ONES {
                // q < 16 and k <= 15: the code has q + 1 + k <= 31 bits.
                let low = x & mask;
                let code = (low.wrapping_mul(2) | 1).wrapping_shl(q).wrapping_sub(1);
                self.gather(
                    &mut acc,
                    &mut nbits,
                    code,
                    q.wrapping_add(1).wrapping_add(k),
                    out,
                );
            } else {
                self.gather(
                    &mut acc,
                    &mut nbits,
                    (1 << ESCAPE_ONES) - 1,
                    ESCAPE_ONES,
                    out,
                );
                self.gather(&mut acc, &mut nbits, v & value_mask, value_bits, out);
            }
        }
        self.acc = acc;
        self.nbits = nbits;
    }

    /// [`Writer::put`] with the gathering word and its bit count in `acc` and `nbits`
    /// (the caller's registers) instead of the writer's.
    #[inline(always)]
    fn gather<S: FrameSink + ?Sized>(
        &mut self,
        acc: &mut u32,
        nbits: &mut u32,
        code: u32,
        bits: u32,
        out: &mut Out<'_, S>,
    ) {
        *acc |= code.wrapping_shl(*nbits);
        let total = nbits.wrapping_add(bits);
        if total >= 32 {
            self.word(*acc, out);
            // Here `nbits` >= 1 (a field has at most 31 bits): the bits that did not fit.
            *acc = code.wrapping_shr(32u32.wrapping_sub(*nbits));
            *nbits = total.wrapping_sub(32);
        } else {
            *nbits = total;
        }
    }

    /// End the segment: zero bits to a byte boundary, the segment's CRC (2 bytes, little
    /// endian), and its last frame sent at the shortest length that holds it. Returns
    /// the segment's CRC.
    pub fn end_segment<S: FrameSink + ?Sized>(&mut self, out: &mut Out<'_, S>) -> u16 {
        // The last bits with zeros to whole bytes (at most 4), then the CRC (2 bytes):
        // each as a word into the frame, which has room for one past `limit`.
        let whole = self.nbits.div_ceil(8) as usize;
        let last = self.acc;
        self.acc = 0;
        self.nbits = 0;
        // The segment's CRC covers the last bytes, not its own.
        let bytes = last.to_le_bytes();
        self.crc.bytes(bytes.get(..whole).unwrap_or(&bytes));
        self.tail(last, whole, out);
        let crc = self.crc.value();
        self.tail(u32::from(crc), 2, out);
        self.flush(out);
        if self.len > 1 {
            self.emit(out);
        }
        crc
    }

    /// The first `n` bytes (at most 4) of `word`, little endian, into the frame; the
    /// frames they fill are cut (the word's bytes past `n` land past the frame's length,
    /// where no frame takes them). Twice per segment: not inlined.
    #[inline(never)]
    fn tail<S: FrameSink + ?Sized>(&mut self, word: u32, n: usize, out: &mut Out<'_, S>) {
        // `len < limit <= MAX_LEN` here: the word fits in the buffer's room.
        let at = self.len;
        if let Some(dst) = self.buf.get_mut(at..at.wrapping_add(4)) {
            dst.copy_from_slice(&word.to_le_bytes());
        }
        self.len = at.wrapping_add(n.min(4));
        if self.len >= self.limit {
            self.cut(out);
        }
    }

    /// Send the frame being filled and begin the next one (not a segment start).
    #[cold]
    fn emit<S: FrameSink + ?Sized>(&mut self, out: &mut Out<'_, S>) {
        let len = if out.fd {
            padded_len(self.len).unwrap_or(MAX_LEN)
        } else {
            self.len
        };
        if len > self.len {
            if let Some(pad) = self.buf.get_mut(self.len..len) {
                pad.fill(0);
            }
        }
        match out.sink.data_slot() {
            Some(frame) => {
                let data = self.buf.get(..len).unwrap_or(&[]);
                // Lengths are valid by construction; a failure leaves an empty frame.
                if frame.set(out.id, data, out.fd).is_err() {
                    *frame = Frame::default();
                }
                out.frames = out.frames.wrapping_add(1);
            }
            None => out.lost = out.lost.wrapping_add(1),
        }
        self.bytes = self.bytes.wrapping_add(self.len.saturating_sub(1) as u32);
        self.counter = self.counter.wrapping_add(1);
        self.len = 1;
        if let Some(b) = self.buf.first_mut() {
            *b = self.counter & COUNTER_MASK;
        }
    }
}

/// Reads a segment's stream; reading past its end is "need more bytes" (`None`).
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    buf: &'a [u8],
    bit: usize,
}

impl<'a> Reader<'a> {
    /// A reader at the start of `buf`.
    pub fn new(buf: &'a [u8]) -> Reader<'a> {
        Reader { buf, bit: 0 }
    }

    /// Bits read so far.
    pub fn position(&self) -> usize {
        self.bit
    }

    fn available(&self) -> usize {
        self.buf.len().saturating_mul(8).saturating_sub(self.bit)
    }

    /// The next 57 or more bits (zero past the end), not consumed.
    fn peek(&self) -> u64 {
        let first = self.bit / 8;
        let mut word = [0u8; 8];
        if let Some(src) = self.buf.get(first..) {
            for (d, s) in word.iter_mut().zip(src) {
                *d = *s;
            }
        }
        u64::from_le_bytes(word) >> (self.bit % 8)
    }

    /// Read `bits` bits (at most 32).
    pub fn read(&mut self, bits: u32) -> Option<u32> {
        let bits = bits.min(32);
        if self.available() < bits as usize {
            return None;
        }
        // At most 32 bits; `bit` stays within the buffer (checked just above).
        let v = self.peek() & (1u64 << bits).wrapping_sub(1);
        self.bit = self.bit.wrapping_add(bits as usize);
        Some(v as u32)
    }

    /// Read a Rice code with parameter `k` (the inverse of [`Writer::put_rice`]):
    /// `Ok(u)`, or `Err(value)` for an escaped value.
    pub fn read_rice(&mut self, k: u32, value_bits: u32) -> Option<Result<u32, u32>> {
        let ones = (!self.peek()).trailing_zeros().min(ESCAPE_ONES);
        if ones >= ESCAPE_ONES {
            if self.available() < ESCAPE_ONES.saturating_add(value_bits) as usize {
                return None;
            }
            // Within the buffer: checked just above.
            self.bit = self.bit.wrapping_add(ESCAPE_ONES as usize);
            return self.read(value_bits).map(Err);
        }
        // ones < 16; `k` is a 4-bit parameter.
        if self.available() < ones.saturating_add(1).saturating_add(k) as usize {
            return None;
        }
        // Within the buffer: checked just above.
        self.bit = self.bit.wrapping_add(ones as usize).wrapping_add(1);
        let low = self.read(k)?;
        Some(Ok(ones << k | low))
    }

    /// Skip to the next byte boundary.
    pub fn align(&mut self) {
        // `bit` is at most the buffer's bit count, so rounding up cannot wrap.
        self.bit = self.bit.div_ceil(8).wrapping_mul(8);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::id::{IdWindow, Kind};

    type Frames = std::vec::Vec<Frame>;

    fn id() -> Id {
        IdWindow::DEFAULT.node(0).unwrap().id(Kind::Data)
    }

    /// Golden bytes written by hand from SPEC 4.2: segment 2 of a scan with sequence
    /// 0x25, then the fields 0b101 (3 bits) and 0x3FF (10 bits), on classic CAN.
    #[test]
    fn a_segment_on_classic_can() {
        let mut sink = Frames::new();
        let mut out = Out::new(&mut sink, id(), false);
        let mut w = Writer::new(8);
        w.begin_segment(0x25, 2, &mut out);
        w.put(0b101, 3, &mut out);
        w.put(0x3FF, 10, &mut out);
        w.end_segment(&mut out);
        // Stream bits: seq_low 5 = 0101, segment 2 = 00010, 101, 1111111111, then 3 zero
        // bits: 0b0010_0101 = 0x25, then bit 0 = 0 (segment's high bit), bits 1-3 = 101,
        // bits 4-7 = 1111: 0xFA; then 111111 and two zero bits: 0x3F.
        let crc = {
            let mut c = ScanCrc::start();
            c.bytes(&[0x25, 0xFA, 0x3F]);
            c.value().to_le_bytes()
        };
        assert_eq!(sink.len(), 1);
        assert_eq!(sink[0].data(), &[0x80, 0x25, 0xFA, 0x3F, crc[0], crc[1]]);
    }

    #[test]
    fn frames_are_cut_and_counted() {
        let mut sink = Frames::new();
        let mut out = Out::new(&mut sink, id(), true);
        let mut w = Writer::new(12);
        w.begin_segment(1, 0, &mut out);
        for i in 0..20u32 {
            w.put(i, 8, &mut out);
        }
        w.end_segment(&mut out);
        w.begin_segment(1, 1, &mut out);
        w.end_segment(&mut out);
        let f = &sink;
        // 9 + 160 bits + 7 padding = 22 bytes + 2 CRC = 24 stream bytes: 11 + 11 + 2.
        assert_eq!(f.len(), 4);
        assert_eq!(f[0].data()[0], 0x80);
        assert_eq!(f[1].data()[0], 0x01);
        assert_eq!(f[2].data()[0], 0x02);
        assert_eq!(f[2].len(), 3);
        assert_eq!(f[3].data()[0], 0x83);
        assert_eq!(f[3].len(), 5, "header bits, padding and CRC");
        let mut stream = vec![];
        for fr in &f[..3] {
            stream.extend_from_slice(&fr.data()[1..]);
        }
        let mut r = Reader::new(&stream);
        assert_eq!(r.read(4), Some(1));
        assert_eq!(r.read(5), Some(0));
        for i in 0..20 {
            assert_eq!(r.read(8), Some(i));
        }
    }

    /// A run of codes with escapes between them, long enough to fill several words
    /// and frames, read back by the receiver's reader (SPEC 4.2.3).
    #[test]
    fn a_run_of_codes_with_escapes_reads_back() {
        for k in [0u32, 3, 15] {
            let mut sink = Frames::new();
            let mut out = Out::new(&mut sink, id(), false);
            let mut w = Writer::new(8);
            w.begin_segment(0, 0, &mut out);
            let u: std::vec::Vec<u32> = (0..40u32).map(|i| (i * 7919) % (20 << k)).collect();
            let values: std::vec::Vec<u32> = (0..40u32).map(|i| 0xF_0000 | i).collect();
            w.put_rices_escaped((1 | k << 2, 6), &u, &values, k, 20, &mut out);
            w.end_segment(&mut out);
            let mut stream = vec![];
            for f in &sink {
                stream.extend_from_slice(&f.data()[1..]);
            }
            let mut r = Reader::new(&stream);
            r.read(9);
            assert_eq!(r.read(6), Some(1 | k << 2), "the header field first");
            for (&x, &v) in u.iter().zip(&values) {
                let expect = if (x >> k) < ESCAPE_ONES {
                    Ok(x)
                } else {
                    Err(v)
                };
                assert_eq!(r.read_rice(k, 20), Some(expect), "u {x} k {k}");
            }
        }
    }

    /// The frames of one segment: `lead` bits of ones after its header, then what
    /// `write` puts, on classic CAN (frames cut a batch at a time).
    fn segment_frames(lead: u32, write: impl FnOnce(&mut Writer, &mut Out<'_, Frames>)) -> Frames {
        let mut sink = Frames::new();
        let mut out = Out::new(&mut sink, id(), false);
        let mut w = Writer::new(8);
        w.begin_segment(3, 1, &mut out);
        if lead > 0 {
            w.put((1u32 << lead) - 1, lead, &mut out);
        }
        write(&mut w, &mut out);
        w.end_segment(&mut out);
        sink
    }

    /// Two Rice codes in one field, written by hand: k = 2, u = 5 (q 1, low 1: a one,
    /// the zero, then low's 2 bits LSB first: 1,0,1,0) then u = 2 (q 0, low 2: the
    /// zero, then 0,1), after the 9 header bits of segment 0 of sequence 0: stream bits
    /// 9..=15 are 1,0,1,0, 0,0,1.
    #[test]
    fn a_pair_of_rice_codes_by_hand() {
        let mut sink = Frames::new();
        let mut out = Out::new(&mut sink, id(), true);
        let mut w = Writer::new(64);
        w.begin_segment(0, 0, &mut out);
        w.put_rices((0, 0), &[5, 2], 2, &mut out);
        w.end_segment(&mut out);
        // Byte 0: the header's 8 low bits (0). Byte 1: header bit 8 (0), then 1,0,1,0,
        // 0,0,1 in bits 1..=7: 0x02 + 0x08 + 0x80 = 0x8A. Nothing past it.
        let crc = {
            let mut c = ScanCrc::start();
            c.bytes(&[0x00, 0x8A]);
            c.value().to_le_bytes()
        };
        assert_eq!(sink[0].data(), &[0x80, 0x00, 0x8A, crc[0], crc[1]]);
    }

    /// `put_rices` (the header field, then two codes per field where they fit) writes
    /// the same frames as `put` and `put_rice` value by value, the general rule: every
    /// k, quotients from 0 to 15 (pairs from 2 to 62 bits, so pairs too long for one
    /// field as well), odd and even counts, each offset of the gathering word, and runs
    /// long enough to cut frames.
    #[test]
    fn rice_codes_in_pairs_equal_codes_one_by_one() {
        for k in 0..=15u32 {
            for len in [0usize, 1, 2, 3, 16, 41] {
                for lead in [0u32, 1, 7, 22, 31] {
                    let u: std::vec::Vec<u32> = (0..len as u32)
                        .map(|i| {
                            let q = (i.wrapping_mul(2_654_435_761) >> 7) % 16;
                            let q = if i % 5 == 0 {
                                15
                            } else if i % 7 == 0 {
                                0
                            } else {
                                q
                            };
                            let low = i.wrapping_mul(40_503) & ((1u32 << k) - 1);
                            (q << k) | low
                        })
                        .collect();
                    // A block's header first (mode 2, k), as `put_block` writes it.
                    let head = 2 | k << 2;
                    let pairs = segment_frames(lead, |w, out| w.put_rices((head, 6), &u, k, out));
                    let one_by_one = segment_frames(lead, |w, out| {
                        w.put(head, 6, out);
                        for &x in &u {
                            w.put_rice(x, k, 0, 20, out);
                        }
                    });
                    assert_eq!(pairs, one_by_one, "k {k} len {len} lead {lead}");
                }
            }
        }
    }

    #[test]
    fn rice_codes_read_back() {
        let mut sink = Frames::new();
        let mut out = Out::new(&mut sink, id(), true);
        let mut w = Writer::new(64);
        w.begin_segment(0, 0, &mut out);
        let cases = [
            (0u32, 0u32),
            (5, 0),
            (5, 2),
            (15, 0),
            (16, 0),
            (1000, 3),
            (7, 15),
        ];
        for &(u, k) in &cases {
            w.put_rice(u, k, u + 7, 20, &mut out);
        }
        w.end_segment(&mut out);
        let data = sink[0].data()[1..].to_vec();
        let mut r = Reader::new(&data);
        r.read(9);
        for &(u, k) in &cases {
            let expect = if (u >> k) < ESCAPE_ONES {
                Ok(u)
            } else {
                Err(u + 7)
            };
            assert_eq!(r.read_rice(k, 20), Some(expect), "u {u} k {k}");
        }
        // Past the end: need more.
        let mut r = Reader::new(&[0xFF]);
        assert_eq!(r.read_rice(0, 20), None);
        assert_eq!(r.read(9), None);
    }
}
