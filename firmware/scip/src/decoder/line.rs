//! Line framing: the LF search, the copy of a line into the line buffer, and the
//! line's sum and value-char check (taken while copying on 32-bit targets).

use super::*;

impl Decoder {
    /// Copies `bytes` up to the first LF into the line buffer and returns the LF's
    /// index, or copies them all and returns `None`: the LF found eight bytes at a
    /// time, the bytes copied. The accumulators of the sum and char check are flagged
    /// as unusable, so that [`Self::line_sum_and_check`] takes them from the line
    /// itself ([`sum_and_check`], vectorised on 64-bit hosts); the data lines of
    /// [`Self::feed`]'s fast paths take them on the way instead. Past the buffer's
    /// capacity the line is marked overflowed and its bytes are not kept.
    #[inline]
    pub(super) fn take_line_bytes(&mut self, bytes: &[u8]) -> Option<usize> {
        self.bad = 0xC0;
        let lf = find_lf(bytes);
        let line = bytes.get(..lf.unwrap_or(bytes.len())).unwrap_or(&[]);
        if !self.overflow {
            let words = self.on_m4_paths();
            // `self.len <= LINE_CAP` and a slice's length is at most `isize::MAX`: no wrap.
            let end = self.len.wrapping_add(line.len());
            match self.buf.get_mut(self.len..end) {
                Some(dst) => {
                    if words {
                        copy_line_words(line, dst);
                    } else {
                        dst.copy_from_slice(line);
                    }
                    self.len = end;
                }
                None => self.overflow = true,
            }
        }
        lf
    }

    /// The fast path of [`Self::feed`] in a data line (no overflow) on 32-bit targets
    /// (and for [`Decoder::m4_paths`]): the bytes of `input` up to where a full data
    /// line's LF must be (64 data chars and the sum char after the bytes buffered),
    /// when that byte is an LF, or all of `input` when it ends before. They must all be
    /// value chars (so none is an LF: the LF found is the line's first); they are copied
    /// into the line buffer a word at a time, summed and checked on the way (see
    /// [`copy_check_words`]), the stream offset and byte counter advanced. Returns the
    /// bytes taken and whether they end the line (its LF taken too, the line complete
    /// in the buffer for [`Self::line_event`]); `None`, having taken nothing, for
    /// anything else (another length, a char that is not a value char), which the
    /// general path then handles.
    ///
    /// Kept out of line: [`Decoder::feed`] is inlined into its callers, and in a caller
    /// optimised for size (as the boards' main code is) the word loop inlined with it
    /// is compiled for size too.
    #[inline(never)]
    pub(super) fn take_data_words(&mut self, input: &[u8]) -> Option<(usize, bool)> {
        let buffered = self.len;
        let rest = (DATA_CHARS + 1).checked_sub(buffered)?;
        let (n, ends) = match input.get(rest) {
            Some(&b'\n') => (rest, true),
            Some(_) => return None,
            None => (input.len(), false),
        };
        let src = input.get(..n)?;
        // Both at most a full line: no wrap.
        let end = buffered.wrapping_add(n);
        let (add, valid) = copy_check_words(src, self.buf.get_mut(buffered..end)?);
        if !valid {
            return None;
        }
        if buffered == 0 {
            (self.sum, self.bad) = (add, 0);
        } else {
            self.sum = self.sum.wrapping_add(add);
        }
        self.len = end;
        let used = n.wrapping_add(usize::from(ends));
        // The byte counter, also the stream offset, wraps (after 2^64 bytes).
        self.stats.bytes = self.stats.bytes.wrapping_add(used as u64);
        Some((used, ends))
    }

    /// The other fast path of [`Self::feed`] on 64-bit hosts:
    /// `input` continues a data line of `start` bytes so far (no overflow) and ends
    /// before a full data line's LF could come, and all of it is value chars (so none is
    /// an LF). It is copied into the line buffer eight bytes at a time and checked on
    /// the way, without an LF search. False, having taken nothing, for anything else,
    /// which the general path then handles.
    #[cfg(not(target_pointer_width = "32"))]
    #[inline(always)]
    pub(super) fn take_data_chars(&mut self, input: &[u8], start: usize) -> bool {
        // `start` is at most LINE_CAP: no wrap.
        let end = start.wrapping_add(input.len());
        let Some(dst) = self.buf.get_mut(start..end) else {
            return false;
        };
        if !copy_value_chars(input, dst) {
            return false;
        }
        self.len = end;
        // The byte counter, also the stream offset, wraps (after 2^64 bytes).
        self.stats.bytes = self.stats.bytes.wrapping_add(input.len() as u64);
        true
    }

    /// The sum char of the buffered line's first `len - 1` bytes and whether all of them
    /// are value chars, as [`sum_and_check`] gives them: from what
    /// [`Self::take_line_bytes`] took when every byte of the line (sum char included) is
    /// a value char, else computed again.
    #[inline]
    pub(super) fn line_sum_and_check(&self, len: usize) -> Option<(u8, u8, bool)> {
        let [data @ .., s] = self.buf.get(..len)? else {
            return None;
        };
        // The accumulators cover exactly the line just completed (it did not overflow, or
        // it would not be decoded).
        if self.bad & 0xC0 == 0 {
            // 0x30..=0x6F: no wrap.
            let sum = ((self.sum.wrapping_sub(u32::from(*s)) & 0x3F) as u8).wrapping_add(0x30);
            return Some((sum, *s, true));
        }
        let (sum, valid) = sum_and_check(data);
        Some((sum, *s, valid))
    }

    /// True when the buffered line ends with the right sum char.
    pub(super) fn line_sum_ok(&self) -> bool {
        match self.buf.get(..self.len) {
            Some([body @ .., s]) => checksum(body) == *s,
            _ => false,
        }
    }
}

/// Copies `src` into `dst` (of the same length, at most [`LINE_CAP`] bytes; nothing
/// copied otherwise) four bytes at a time, the last four overlapping the ones before
/// (fewer than four: one at a time): on 32-bit targets the library's
/// copy takes several instructions a byte for a line's few dozen unaligned bytes. The
/// loop ends on the length found wanting, so it is not turned into a call of that
/// copy, nor unrolled (a loop of 24 rounds at most, with a constant bound, was: 364
/// bytes of flash). Out of line: [`Decoder::feed`], where it is used, is inlined into
/// callers built for size (inlined, it cost 156 B more and one instruction more per
/// UART byte of the URG-04LX capture, a third of it VV/PP/II answers).
#[inline(never)]
pub(super) fn copy_line_words(src: &[u8], dst: &mut [u8]) {
    if src.len() != dst.len() || src.len() > LINE_CAP {
        return;
    }
    let (Some(last), Some(last_dst)) = (src.last_chunk::<4>(), dst.last_chunk_mut::<4>()) else {
        // One to three bytes: the first, the middle and the last cover them (a byte
        // loop here would be turned into a call of the library's copy).
        for i in [0, src.len() / 2, src.len().wrapping_sub(1)] {
            if let (Some(d), Some(&c)) = (dst.get_mut(i), src.get(i)) {
                *d = c;
            }
        }
        return;
    };
    *last_dst = *last;
    let mut at: usize = 0;
    while let (Some(s), Some(d)) = (
        src.get(at..).and_then(|r| r.first_chunk::<4>()),
        dst.get_mut(at..).and_then(|r| r.first_chunk_mut::<4>()),
    ) {
        *d = *s;
        // Below LINE_CAP + 4: no wrap.
        at = at.wrapping_add(4);
    }
}

/// Copies `src` into `dst` (of the same length; false otherwise) and tells whether
/// every byte is a value char (`0x30..=0x6F`), with a sum of them that is their sum
/// mod 64 (meaningless when they are not all value chars). A word at a time: no
/// byte of `w - 0x30303030` has bit 6 or 7 set exactly when every byte is a value char
/// (a byte below 0x30 flags itself, whatever it borrows), the flags gathered by OR and
/// tested once at the end; the four values below 0x40 summed by one multiplication (no
/// partial sum carries). The last one to three bytes, taken first, are the last word's
/// top bytes, read overlapping the word before (those bytes shifted out), or, with
/// fewer than four bytes in all, one at a time.
#[inline(always)]
pub(super) fn copy_check_words(src: &[u8], dst: &mut [u8]) -> (u32, bool) {
    const FLAGS: u32 = 0xC0C0_C0C0;
    const CHARS: u32 = 0x3030_3030;
    if src.len() != dst.len() {
        return (0, false);
    }
    let (mut sum, mut flags) = (0u32, 0u32);
    let mut from = src.chunks_exact(4);
    // The last one to three bytes first: after the word loop, what they need (the
    // count, the destination) was kept on the stack on a Cortex-M4.
    let tail = from.remainder().len();
    if tail != 0 {
        match (src.last_chunk::<4>(), dst.last_chunk_mut::<4>()) {
            (Some(last), Some(out)) => {
                // The word's low `4 - tail` bytes are checked and summed by the word
                // loop (valid ones borrow nothing from the bytes above them). 1..=3: no
                // wrap.
                let v = u32::from_le_bytes(*last).wrapping_sub(CHARS)
                    >> (32usize.wrapping_sub(tail.wrapping_mul(8)));
                flags = v;
                // The `0x30` of each of the `tail` bytes back (a word's four make 0
                // mod 64).
                sum = (v.wrapping_mul(0x0101_0101) >> 24)
                    .wrapping_add((tail as u32).wrapping_mul(0x30));
                *out = *last;
            }
            // Fewer than four bytes: no word above, and no word loop below.
            _ => {
                for (d, &c) in dst.iter_mut().zip(src) {
                    *d = c;
                    flags |= u32::from(c.wrapping_sub(CHAR_MIN));
                    sum = sum.wrapping_add(u32::from(c));
                }
                return (sum, flags & FLAGS == 0);
            }
        }
    }
    let mut to = dst.chunks_exact_mut(4);
    for (s, d) in (&mut from).zip(&mut to) {
        let Ok(four) = <[u8; 4]>::try_from(s) else {
            break;
        };
        let v = u32::from_le_bytes(four).wrapping_sub(CHARS);
        flags |= v;
        d.copy_from_slice(&four);
        // The top byte of v·0x01010101 is the sum of v's four bytes.
        sum = sum.wrapping_add(v.wrapping_mul(0x0101_0101) >> 24);
    }
    (sum, flags & FLAGS == 0)
}

/// Copies `src` into `dst` (of the same length) and tells whether every byte is a
/// value char (`0x30..=0x6F`); false when one is not or the lengths differ (`dst` then
/// holds part or all of `src`, beyond what the caller counts as taken). Eight bytes at a
/// time (see [`copy_words`]) with no branch per word but the length's: the word test is
/// [`copy_check_words`]', its flags gathered by OR and tested once at the end.
#[cfg(not(target_pointer_width = "32"))]
#[inline(always)]
pub(super) fn copy_value_chars(src: &[u8], dst: &mut [u8]) -> bool {
    const CHARS: u64 = u64::from_le_bytes([CHAR_MIN; 8]);
    const FLAGS: u64 = u64::from_le_bytes([0xC0; 8]);
    let mut flags = 0u64;
    let copied = copy_words(src, dst, |w| {
        flags |= u64::from_le_bytes(w).wrapping_sub(CHARS);
    });
    copied && flags & FLAGS == 0 && {
        // Fewer than eight bytes: [`copy_words`] copied them one by one.
        src.len() >= 8 || src.iter().all(|c| c.wrapping_sub(CHAR_MIN) < 0x40)
    }
}

/// Copies `src` into `dst` (of the same length, at most [`LINE_CAP`] bytes; false and
/// nothing copied otherwise) eight bytes at a time, the last eight overlapping the ones
/// before, and hands every word copied to `each` (the last one too; none when `src` has
/// fewer than eight bytes, then copied one by one). The loop has a constant bound and
/// an exit on the length, so it unrolls into a few instructions per word and is not
/// turned into a call of the library's copy, which costs more for a line's bytes.
#[cfg(not(target_pointer_width = "32"))]
#[inline(always)]
pub(super) fn copy_words(src: &[u8], dst: &mut [u8], mut each: impl FnMut([u8; 8])) -> bool {
    if src.len() != dst.len() || src.len() > LINE_CAP {
        return false;
    }
    let (Some(last), Some(last_dst)) = (src.last_chunk::<8>(), dst.last_chunk_mut::<8>()) else {
        for (d, &c) in dst.iter_mut().zip(src) {
            *d = c;
        }
        return true;
    };
    each(*last);
    *last_dst = *last;
    for i in 0..LINE_CAP / 8 {
        // Below LINE_CAP + 8: no wrap.
        let at = i.wrapping_mul(8);
        let (Some(s), Some(d)) = (
            src.get(at..).and_then(|r| r.first_chunk::<8>()),
            dst.get_mut(at..).and_then(|r| r.first_chunk_mut::<8>()),
        ) else {
            break;
        };
        each(*s);
        *d = *s;
    }
    true
}

/// The sum char of `bytes` (as [`checksum`]) and whether every byte is a value char
/// (`0x30..=0x6F`), in one branch-free pass: bytewise where that vectorises, a 32-bit
/// word at a time on 32-bit targets (a Cortex-M4 has no vectors for it).
#[inline]
pub(super) fn sum_and_check(bytes: &[u8]) -> (u8, bool) {
    #[cfg(target_pointer_width = "32")]
    {
        sum_and_check_words(bytes)
    }
    #[cfg(not(target_pointer_width = "32"))]
    {
        sum_and_check_bytes(bytes)
    }
}

/// [`sum_and_check`] a byte at a time.
#[cfg_attr(target_pointer_width = "32", allow(dead_code))]
#[inline]
pub(super) fn sum_and_check_bytes(bytes: &[u8]) -> (u8, bool) {
    let (sum, chars) = fold_chars(bytes);
    // 0x30..=0x6F: no wrap.
    ((sum & 0x3F).wrapping_add(0x30), chars < 0x40)
}

/// The byte sum and the OR of every `c - 0x30` (below `0x40` iff all are value chars).
#[inline(always)]
pub(super) fn fold_chars(bytes: &[u8]) -> (u8, u8) {
    bytes.iter().fold((0u8, 0u8), |(sum, chars), &c| {
        (sum.wrapping_add(c), chars | c.wrapping_sub(CHAR_MIN))
    })
}

/// [`sum_and_check`] four bytes at a time. The sum goes into two 16-bit lanes (bytes 0
/// and 2, bytes 1 and 3), kept below `2^12` so no lane carries into the next (only the
/// sum mod 64 counts). The check tests every byte's top bit after arithmetic that never
/// carries or borrows across bytes: a value char has its top bit clear, `c + 0x10`
/// below `0x80` (`c <= 0x6F`) and `(c | 0x80) - 0x30` at least `0x80` (`c >= 0x30`).
#[cfg_attr(not(target_pointer_width = "32"), allow(dead_code))]
#[inline]
pub(super) fn sum_and_check_words(bytes: &[u8]) -> (u8, bool) {
    const HIGHS: u32 = 0x8080_8080;
    const LOWS: u32 = 0x7F7F_7F7F;
    const EVEN: u32 = 0x00FF_00FF;
    let mut words = bytes.chunks_exact(4);
    let (mut lanes, mut bad) = (0u32, 0u32);
    for word in &mut words {
        let w = u32::from_le_bytes(word.try_into().unwrap_or([0; 4]));
        lanes = (lanes & 0x0FFF_0FFF)
            .wrapping_add(w & EVEN)
            .wrapping_add((w >> 8) & EVEN);
        let low = w & LOWS;
        bad |= w | low.wrapping_add(0x1010_1010) | !(low | HIGHS).wrapping_sub(0x3030_3030);
    }
    let (rest_sum, rest_chars) = fold_chars(words.remainder());
    let sum = (lanes & 0xFFFF)
        .wrapping_add(lanes >> 16)
        .wrapping_add(u32::from(rest_sum));
    (
        // 0x30..=0x6F: no wrap.
        ((sum & 0x3F) as u8).wrapping_add(0x30),
        bad & HIGHS == 0 && rest_chars < 0x40,
    )
}

/// Index of the first LF in `bytes`, eight bytes at a time: a zero-byte test on the
/// bytes XOR LF, whose lowest flagged byte is exact (borrows only run upwards).
#[inline]
pub(super) fn find_lf(bytes: &[u8]) -> Option<usize> {
    const ONES: u64 = u64::from_le_bytes([0x01; 8]);
    const HIGHS: u64 = u64::from_le_bytes([0x80; 8]);
    const LFS: u64 = u64::from_le_bytes([b'\n'; 8]);
    let lf_in = |word: [u8; 8]| {
        let x = u64::from_le_bytes(word) ^ LFS;
        let hit = x.wrapping_sub(ONES) & !x & HIGHS;
        (hit != 0).then_some((hit.trailing_zeros() / 8) as usize)
    };
    let mut words = bytes.chunks_exact(8);
    let mut at: usize = 0;
    for word in &mut words {
        // Indices within `bytes`: no wrap.
        if let Some(i) = lf_in(word.try_into().unwrap_or([0; 8])) {
            return Some(at.wrapping_add(i));
        }
        at = at.wrapping_add(8);
    }
    if words.remainder().is_empty() {
        return None;
    }
    // The last eight bytes, overlapping bytes already found free of LF.
    match bytes.last_chunk::<8>() {
        // `bytes` has at least the eight bytes of `last`: no wrap.
        Some(last) => lf_in(*last).map(|i| bytes.len().wrapping_sub(8).wrapping_add(i)),
        None => bytes.iter().position(|&b| b == b'\n'),
    }
}
