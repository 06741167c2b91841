//! The one-pass path of data lines (32-bit targets): a full data line's chars are
//! checked, summed and decoded into readings as they arrive, chunk by chunk, instead of
//! being copied into the line buffer first and decoded from there at the LF.
//!
//! A full data line is 64 value chars, the sum char and the LF. The path decodes the
//! chars at columns 0..64 as they come (they are data in a full line) and stores them
//! in the line buffer on the way (one word store per word loaded); the readings of the
//! line are published only at its LF, when the sum char matched and the line was full.
//! A step begun at a chunk's end is carried in the decoder's state, like the step begun
//! at a line's end. Anything else (a byte that is not a value char, an LF before column
//! 65 (a short line), no LF after the sum char, a bad sum) hands the line over to the
//! general path where it stands: the line buffer holds every byte so far with their sum,
//! and the decoding state of the line's start is untouched, so the general path decodes
//! the line from the buffer at its LF, with the events and errors it always gives.

use super::*;

/// Chars the one-pass path takes at once: three words, a whole number of steps of 3
/// chars (4 steps) or 6 chars (2 steps).
const GROUP: usize = 12;

/// Where a call of [`Decoder::run_fast`] stopped.
pub(super) enum Progress {
    /// All of the input taken; the line goes on.
    More,
    /// The line ended intact at this many bytes of the input (LF included).
    Line(usize),
    /// The line goes to the general path after this many bytes of the input.
    Bail(usize),
}

impl Decoder {
    /// True when the one-pass path may take data lines: on 32-bit targets (and in tests
    /// and fuzzing, for a decoder made by [`Decoder::one_pass`]).
    #[inline(always)]
    pub(super) fn one_pass_enabled(&self) -> bool {
        #[cfg(any(test, fuzzing))]
        if self.char_by_char {
            return false;
        }
        #[cfg(any(test, fuzzing))]
        if self.one_pass {
            return true;
        }
        cfg!(target_pointer_width = "32")
    }

    /// Takes `input` into the data line the one-pass path is decoding (or begins one,
    /// when the line buffer is empty). [`Progress::Bail`] with the bytes taken when the
    /// general path must go on with the line (or take it from its start).
    ///
    /// Kept out of line: inlined into a caller optimised for size, its loops would not
    /// be unrolled nor its iterators flattened.
    #[inline(never)]
    pub(super) fn feed_fast(&mut self, input: &[u8]) -> Progress {
        if !self.fast && !self.fast_begin() {
            return Progress::Bail(0);
        }
        let progress = match (self.shape.dist_width, self.shape.aux_width) {
            (3, 0) => self.run_fast::<3, 0, 3, 4>(input),
            _ => Progress::Bail(0),
        };
        if let Progress::Bail(_) = progress {
            // The general path decodes the line from the buffer at its LF, from the
            // state of the line's start (untouched here).
            self.fast = false;
            self.n_readings = 0;
        }
        progress
    }

    /// Begins a data line on the one-pass path when it can take it: a single-echo data
    /// set it knows, a line that can be full (none was short), and room in the scan for
    /// every step a full line completes (else the general path reports the error).
    #[inline]
    fn fast_begin(&mut self) -> bool {
        let s = self.shape;
        let width = match (s.dist_width, s.aux_width) {
            (3, 0) => 3,
            _ => return false,
        };
        if s.multi_echo || self.short_line_seen || self.next_is_echo {
            return false;
        }
        let n = if self.in_aux {
            s.dist_width.wrapping_add(self.carry_n)
        } else {
            self.carry_n
        };
        // At most 7 + 64 chars over at least 3 a step: no wrap, at most 23 steps.
        let steps = (usize::from(n).wrapping_add(DATA_CHARS) / width) as u16;
        if self.values.saturating_add(steps) > s.expected {
            return false;
        }
        if !self.readings_plain {
            // Distance-only lines write the distance and index of a reading only.
            self.readings = [Reading::default(); MAX_READINGS];
            self.readings_plain = true;
        }
        self.fast = true;
        self.fast_n = n;
        self.fast_carry = self.carry;
        self.fast_dist = self.pending_distance;
        self.n_readings = 0;
        self.sum = 0;
        self.bad = 0;
        true
    }

    /// The one-pass path for a data set of `D`-char distances and `A`-char second values
    /// (`W = D + A` chars a step, `S = 12 / W` steps in a group of [`GROUP`] chars).
    #[inline(always)]
    fn run_fast<const D: usize, const A: usize, const W: usize, const S: usize>(
        &mut self,
        input: &[u8],
    ) -> Progress {
        let mut pos = self.len;
        let mut at: usize = 0;
        let mut n = usize::from(self.fast_n);
        let mut carry = self.fast_carry;
        let mut dist = self.fast_dist;
        let mut sum = self.sum;
        let mut k = self.n_readings;
        let base = self.values;
        // The chars of `input` that are data in a full line.
        let data_end = input.len().min(DATA_CHARS.saturating_sub(pos));
        let mut ok = true;
        // The step begun before, char by char.
        while n != 0 && at < data_end {
            let c = input.get(at).copied().unwrap_or(0);
            ok = self.one_char::<D, A, W>(c, pos, &mut n, &mut carry, &mut dist, &mut k, base);
            if !ok {
                break;
            }
            sum = sum.wrapping_add(u32::from(c));
            // Within the line and the input: no wrap.
            at = at.wrapping_add(1);
            pos = pos.wrapping_add(1);
        }
        if ok && n == 0 {
            // Whole groups, then (3-char steps) whole steps, each read as a word (its
            // fourth byte in the input).
            while data_end.saturating_sub(at) >= GROUP {
                if !self.put_group_at::<D, A, S>(input, at, pos, k, base, &mut sum) {
                    break;
                }
                // Within the line, the input and the readings: no wrap.
                at = at.wrapping_add(GROUP);
                pos = pos.wrapping_add(GROUP);
                k = k.wrapping_add(S);
            }
            while W == 3 && data_end.saturating_sub(at) >= 3 {
                if !self.put_step3_at(input, at, pos, k, base, &mut sum) {
                    break;
                }
                at = at.wrapping_add(3);
                pos = pos.wrapping_add(3);
                k = k.wrapping_add(1);
            }
        }
        // The rest of the data chars (a step begun, or what the groups left), one by one.
        while ok && at < data_end {
            let c = input.get(at).copied().unwrap_or(0);
            ok = self.one_char::<D, A, W>(c, pos, &mut n, &mut carry, &mut dist, &mut k, base);
            if !ok {
                break;
            }
            sum = sum.wrapping_add(u32::from(c));
            at = at.wrapping_add(1);
            pos = pos.wrapping_add(1);
        }
        let progress = if at < data_end {
            // A char that is not a value char (or no room, which cannot happen).
            Progress::Bail(at)
        } else if pos < DATA_CHARS {
            Progress::More
        } else {
            // The sum char and the LF of a full line.
            let mut progress = Progress::More;
            if pos == DATA_CHARS {
                match input.get(at) {
                    Some(&s) if s.wrapping_sub(CHAR_MIN) < 0x40 => {
                        if let Some(slot) = self.buf.get_mut(DATA_CHARS) {
                            *slot = s;
                        }
                        sum = sum.wrapping_add(u32::from(s));
                        pos = pos.wrapping_add(1);
                        at = at.wrapping_add(1);
                    }
                    Some(_) => progress = Progress::Bail(at),
                    None => {}
                }
            }
            if pos > DATA_CHARS {
                let s = self.buf.get(DATA_CHARS).copied().unwrap_or(0);
                let expected = ((sum.wrapping_sub(u32::from(s)) & 0x3F) as u8).wrapping_add(0x30);
                match input.get(at) {
                    Some(&b'\n') if expected == s => progress = Progress::Line(at.wrapping_add(1)),
                    Some(_) => progress = Progress::Bail(at),
                    None => {}
                }
            }
            progress
        };
        let used = match progress {
            Progress::More => input.len(),
            Progress::Line(used) | Progress::Bail(used) => used,
        };
        // The stream offset and the byte counter wrap (after 2^64 bytes).
        self.offset = self.offset.wrapping_add(used as u64);
        self.stats.bytes = self.stats.bytes.wrapping_add(used as u64);
        self.sum = sum;
        self.bad = 0;
        self.n_readings = k;
        if let Progress::Line(_) = progress {
            self.len = 0;
            self.fast = false;
            self.current_line = self.line_start;
            self.line_start = self.offset;
            self.line_no = self.line_no.saturating_add(1);
            // At most 23 steps a line: fits.
            self.values = base.wrapping_add(k as u16);
            if k > 0 {
                self.echo_no = 0;
            }
            // The step begun at the line's end, carried as the general path does.
            if A > 0 && n >= D {
                self.pending_distance = dist;
                self.in_aux = true;
                self.carry_n = n.wrapping_sub(D) as u8;
                self.want = A as u8;
            } else {
                self.in_aux = false;
                self.carry_n = n as u8;
                self.want = D as u8;
            }
            self.carry = carry;
        } else {
            self.len = pos;
            // Below W: fits.
            self.fast_n = n as u8;
            self.fast_carry = carry;
            self.fast_dist = dist;
        }
        progress
    }

    /// Takes data char `c` at `pos` of the line into the line buffer and the step begun
    /// (`n` chars so far, their value `carry`, the step's distance `dist` once its
    /// second value has begun), writing the step's reading at `k` when it completes.
    /// False, having taken nothing, when `c` is not a value char.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn one_char<const D: usize, const A: usize, const W: usize>(
        &mut self,
        c: u8,
        pos: usize,
        n: &mut usize,
        carry: &mut u32,
        dist: &mut u32,
        k: &mut usize,
        base: u16,
    ) -> bool {
        let v = c.wrapping_sub(CHAR_MIN);
        let Some(slot) = self.buf.get_mut(pos).filter(|_| v < 0x40) else {
            return false;
        };
        *slot = c;
        *carry = (*carry << 6) | u32::from(v);
        // Below W (at most 7): no wrap.
        *n = n.wrapping_add(1);
        if A > 0 && *n == D {
            *dist = *carry;
            *carry = 0;
        } else if *n == W {
            let Some(slot) = self.readings.get_mut(*k) else {
                return false;
            };
            // Below MAX_READINGS: fits.
            let index = base.wrapping_add(*k as u16);
            if A == 0 {
                slot.distance = *carry;
                slot.index = index;
            } else {
                *slot = Reading {
                    index,
                    echo: 0,
                    distance: *dist,
                    aux: *carry,
                };
            }
            *k = k.wrapping_add(1);
            *n = 0;
            *carry = 0;
        }
        true
    }

    /// Decodes the group of [`GROUP`] chars at `input[at..]` into the line buffer at
    /// `pos` and the readings at `k` (indices from `base + k`), adding its chars to
    /// `sum`. False, having taken nothing, when one is not a value char (or the group
    /// does not fit, which cannot happen).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn put_group_at<const D: usize, const A: usize, const S: usize>(
        &mut self,
        input: &[u8],
        at: usize,
        pos: usize,
        k: usize,
        base: u16,
        sum: &mut u32,
    ) -> bool {
        const CHARS: u32 = 0x3030_3030;
        const FLAGS: u32 = 0xC0C0_C0C0;
        let (Some(src), Some(dst), Some(slots)) = (
            input.get(at..).and_then(|r| r.first_chunk::<GROUP>()),
            self.buf
                .get_mut(pos..)
                .and_then(|r| r.first_chunk_mut::<GROUP>()),
            self.readings
                .get_mut(k..)
                .and_then(|r| r.first_chunk_mut::<S>()),
        ) else {
            return false;
        };
        let [a0, a1, a2, a3, b0, b1, b2, b3, c0, c1, c2, c3] = *src;
        let w0 = u32::from_le_bytes([a0, a1, a2, a3]);
        let w1 = u32::from_le_bytes([b0, b1, b2, b3]);
        let w2 = u32::from_le_bytes([c0, c1, c2, c3]);
        let (v0, v1, v2) = (
            w0.wrapping_sub(CHARS),
            w1.wrapping_sub(CHARS),
            w2.wrapping_sub(CHARS),
        );
        if (v0 | v1 | v2) & FLAGS != 0 {
            return false;
        }
        *dst = *src;
        // Bytes below 0x40, so their sum mod 64 per byte lane, and the lanes' sum in the
        // top byte of the product (no lane carries). The 0x30 of each of 12 chars is 0
        // mod 64.
        let lanes = v0.wrapping_add(v1).wrapping_add(v2) & 0x3F3F_3F3F;
        *sum = sum.wrapping_add(lanes.wrapping_mul(0x0101_0101) >> 24);
        // Below MAX_READINGS: fits.
        put_group::<D, A, S>(slots, [v0, v1, v2], base.wrapping_add(k as u16));
        true
    }

    /// Decodes the 3-char distance at `input[at..]` (read as a word: the input has a
    /// byte more) into the line buffer at `pos` and the reading at `k` (index
    /// `base + k`), adding its chars to `sum`. False, having taken nothing, when one is
    /// not a value char or the input has no byte after it.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn put_step3_at(
        &mut self,
        input: &[u8],
        at: usize,
        pos: usize,
        k: usize,
        base: u16,
        sum: &mut u32,
    ) -> bool {
        let (Some(&word), Some(dst), Some(slot)) = (
            input.get(at..).and_then(|r| r.first_chunk::<4>()),
            self.buf
                .get_mut(pos..)
                .and_then(|r| r.first_chunk_mut::<4>()),
            self.readings.get_mut(k),
        ) else {
            return false;
        };
        let v = u32::from_le_bytes(word).wrapping_sub(0x3030_3030);
        if v & 0x00C0_C0C0 != 0 {
            return false;
        }
        // The fourth byte lands past the step, where the next byte will be written.
        *dst = word;
        // Three bytes below 0x40: their sum in the top byte, with the three 0x30 (0x90)
        // put back.
        *sum = sum
            .wrapping_add((v & 0x003F_3F3F).wrapping_mul(0x0101_0101) >> 24)
            .wrapping_add(0x90);
        let c = |i: u32| (v >> (8 * i)) & 0xFF;
        slot.distance = (c(0) << 12) | (c(1) << 6) | c(2);
        // Below MAX_READINGS: fits.
        slot.index = base.wrapping_add(k as u16);
        true
    }
}

/// Writes the `S` steps of a group of [`GROUP`] value chars, less `0x30` each, in the
/// bytes of `v` (first char lowest), into `slots` with indices from `index`: four
/// 3-char distances, or two steps of a 3-char distance and a 3-char second value.
/// Written out step by step: every char is a constant field of one of the words.
#[inline(always)]
fn put_group<const D: usize, const A: usize, const S: usize>(
    slots: &mut [Reading; S],
    v: [u32; 3],
    index: u16,
) {
    let [v0, v1, v2] = v;
    // Char `k` (0..4) of word `w`.
    let c = |w: u32, k: u32| (w >> (8 * k)) & 0xFF;
    let three = |x: u32, y: u32, z: u32| (x << 12) | (y << 6) | z;
    if let Ok([s0, s1, s2, s3]) = <&mut [Reading; 4]>::try_from(slots.as_mut_slice()) {
        if D == 3 && A == 0 {
            s0.distance = three(c(v0, 0), c(v0, 1), c(v0, 2));
            s1.distance = three(c(v0, 3), c(v1, 0), c(v1, 1));
            s2.distance = three(c(v1, 2), c(v1, 3), c(v2, 0));
            s3.distance = three(c(v2, 1), c(v2, 2), c(v2, 3));
            // Indices of one line's steps: no wrap beyond the scan's u16 indices.
            s0.index = index;
            s1.index = index.wrapping_add(1);
            s2.index = index.wrapping_add(2);
            s3.index = index.wrapping_add(3);
        }
    } else if let Ok([s0, s1]) = <&mut [Reading; 2]>::try_from(slots.as_mut_slice()) {
        if D == 3 && A == 3 {
            *s0 = Reading {
                index,
                echo: 0,
                distance: three(c(v0, 0), c(v0, 1), c(v0, 2)),
                aux: three(c(v0, 3), c(v1, 0), c(v1, 1)),
            };
            *s1 = Reading {
                index: index.wrapping_add(1),
                echo: 0,
                distance: three(c(v1, 2), c(v1, 3), c(v2, 0)),
                aux: three(c(v2, 1), c(v2, 2), c(v2, 3)),
            };
        }
    }
}
