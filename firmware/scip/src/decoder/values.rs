//! Values: a data line's checks, and its chars decoded into readings, a whole step at
//! a time on the fast path or char by char.

use super::*;

impl Decoder {
    pub(super) fn data_line(&mut self, len: usize) -> Option<Event<'_>> {
        if len < 2 {
            return self.fail(ErrorKind::BadDataLineLength);
        }
        // Data chars, sum char excluded (`len >= 2`).
        let n = len.wrapping_sub(1);
        // One pass for the sum and the value-char check of the fast path.
        let Some((expected, found, all_valid)) = self.line_sum_and_check(len) else {
            return self.fail(ErrorKind::BadDataLineLength);
        };
        if expected != found {
            return self.fail(ErrorKind::BadSum { expected, found });
        }
        if n > DATA_CHARS || self.short_line_seen {
            return self.fail(ErrorKind::BadDataLineLength);
        }
        if n < DATA_CHARS {
            self.short_line_seen = true;
        }
        self.n_readings = 0;
        if let Err(kind) = self.decode_values(n, all_valid) {
            return self.fail(kind);
        }
        Some(Event::Data(DataLine {
            readings: self.readings.get(..self.n_readings).unwrap_or(&[]),
            data: self.shape.data,
            limits: self.limits,
            line: self.line_no,
        }))
    }

    /// Decodes the first `n` bytes of the buffer as value chars, carrying partial values;
    /// `all_valid` tells that all of them are value chars (see [`sum_and_check`]).
    pub(super) fn decode_values(&mut self, n: usize, all_valid: bool) -> Result<(), ErrorKind> {
        // Fast path: a line of valid value chars only (no `&`, nothing to report by
        // column) is decoded a whole step at a time. Anything else goes char by char.
        #[cfg(any(test, fuzzing))]
        let all_valid = all_valid && !self.char_by_char;
        if !self.shape.multi_echo && all_valid {
            match (self.shape.dist_width, self.shape.aux_width) {
                (3, 0) => return self.decode_steps::<3, 0>(n),
                (2, 0) => return self.decode_steps::<2, 0>(n),
                (3, 3) => return self.decode_steps::<3, 3>(n),
                (3, 2) => return self.decode_steps::<3, 2>(n),
                (3, 4) => return self.decode_steps::<3, 4>(n),
                _ => {}
            }
        }
        self.decode_chars_copied(n)
    }

    /// Decodes the first `n` bytes of the buffer (all valid value chars, see
    /// [`sum_and_check`]) of a data set
    /// with `D`-char distances and `A`-char second values, a whole step at a time: the
    /// step begun on the previous line is completed from the carried value, the whole
    /// steps go straight into readings, the partial step at the end is carried. Same
    /// readings, state and errors as [`Self::decode_chars`] on the same chars.
    pub(super) fn decode_steps<const D: usize, const A: usize>(
        &mut self,
        n: usize,
    ) -> Result<(), ErrorKind> {
        // 2..=7 chars: the `D + A` of the data sets dispatched in `decode_values`.
        let width = D.wrapping_add(A);
        let chars = self.buf.get(..n).unwrap_or(&[]);
        let carried = usize::from(self.carry_n);
        // The step begun on the previous line, completed.
        let mut head = None;
        let mut rest = chars;
        if carried != 0 || self.in_aux {
            let (distance, aux, used) = if self.in_aux {
                let need = A.saturating_sub(carried);
                let Some(a) = chars.get(..need) else {
                    return self.decode_chars_copied(n);
                };
                (self.pending_distance, continue_valid(self.carry, a), need)
            } else {
                let need = D.saturating_sub(carried);
                // At most `D + A`: no wrap.
                let used = need.wrapping_add(A);
                let (Some(d), Some(a)) = (chars.get(..need), chars.get(need..used)) else {
                    return self.decode_chars_copied(n);
                };
                (continue_valid(self.carry, d), continue_valid(0, a), used)
            };
            head = Some((distance, aux));
            rest = chars.get(used..).unwrap_or(&[]);
        }
        // `width` is a nonzero constant here: the division folds, the `0` is never taken.
        let whole = rest.len().checked_div(width).unwrap_or(0);
        // Lengths and counts within one line (at most LINE_CAP): none of these wraps.
        let (mid, tail) = rest.split_at(whole.wrapping_mul(width));
        let total = whole.wrapping_add(usize::from(head.is_some()));
        let too_many = ErrorKind::TooManyValues {
            expected: self.shape.expected,
        };
        if usize::from(self.values).wrapping_add(total) > usize::from(self.shape.expected) {
            return Err(too_many);
        }
        if A == 0 && !self.readings_plain {
            // Once per change of data set: clear what readings with echoes or second
            // values left, so that distance-only lines write less.
            self.readings = [Reading::default(); MAX_READINGS];
            self.readings_plain = true;
        } else if A > 0 {
            self.readings_plain = false;
        }
        let first = self.n_readings;
        let end = first.wrapping_add(total);
        let slots = self.readings.get_mut(first..end).ok_or(too_many)?;
        let mut index = self.values;
        let mut slots = slots.iter_mut();
        if let Some((distance, aux)) = head {
            if let Some(slot) = slots.next() {
                *slot = Reading {
                    index,
                    echo: 0,
                    distance,
                    aux,
                };
                index = index.wrapping_add(1);
            }
        }
        if A == 0 && self.readings_plain {
            // Every slot already has echo 0 and aux 0: the distance and index will do.
            for (slot, step) in slots.zip(mid.chunks_exact(width)) {
                if let Some(d) = step.first_chunk::<D>() {
                    slot.distance = decode_valid(d);
                    slot.index = index;
                }
                index = index.wrapping_add(1);
            }
        } else {
            for (slot, step) in slots.zip(mid.chunks_exact(width)) {
                let Some((d, a)) = step.split_first_chunk::<D>() else {
                    continue;
                };
                let Some(a) = a.first_chunk::<A>() else {
                    continue;
                };
                *slot = Reading {
                    index,
                    echo: 0,
                    distance: decode_valid(d),
                    aux: decode_valid(a),
                };
                index = index.wrapping_add(1);
            }
        }
        if total > 0 {
            self.echo_no = 0;
        }
        self.values = index;
        self.n_readings = end;
        // The partial step at the end: a distance and part of its second value, or part
        // of a distance.
        match tail.split_at_checked(D) {
            Some((d, a)) if A > 0 => {
                self.pending_distance = continue_valid(0, d);
                self.in_aux = true;
                self.carry = continue_valid(0, a);
                self.carry_n = a.len() as u8;
                self.want = A as u8;
            }
            _ => {
                self.in_aux = false;
                self.carry = continue_valid(0, tail);
                self.carry_n = tail.len() as u8;
                self.want = D as u8;
            }
        }
        Ok(())
    }

    /// [`Self::decode_chars`] on the first `n` bytes of the buffer.
    pub(super) fn decode_chars_copied(&mut self, n: usize) -> Result<(), ErrorKind> {
        let buf = self.buf;
        self.decode_chars(buf.get(..n).unwrap_or(&[]), 0)
    }

    /// Decodes `chars` one by one, carrying partial values; `col0` is the column of the
    /// first of them in its line.
    pub(super) fn decode_chars(&mut self, chars: &[u8], col0: usize) -> Result<(), ErrorKind> {
        let mut carry = self.carry;
        let mut carry_n = self.carry_n;
        let mut want = self.want;
        for (i, &c) in chars.iter().enumerate() {
            // A column within one line: no wrap.
            let col = col0.wrapping_add(i);
            let v = c.wrapping_sub(CHAR_MIN);
            if v >= 0x40 {
                if c == b'&' {
                    self.ampersand(carry_n, col)?;
                    continue;
                }
                return Err(ErrorKind::BadChar { column: col as u8 });
            }
            carry = (carry << 6) | u32::from(v);
            // Below `want` (at most 4) before this char: no wrap.
            carry_n = carry_n.wrapping_add(1);
            if carry_n == want {
                want = self.value_done(carry)?;
                carry = 0;
                carry_n = 0;
            }
        }
        self.carry = carry;
        self.carry_n = carry_n;
        self.want = want;
        Ok(())
    }

    pub(super) fn ampersand(&mut self, carry_n: u8, col: usize) -> Result<(), ErrorKind> {
        if !self.shape.multi_echo {
            return Err(ErrorKind::BadChar { column: col as u8 });
        }
        if carry_n != 0 || self.in_aux || self.values == 0 || self.next_is_echo {
            return Err(ErrorKind::MisplacedEcho);
        }
        // Below MAX_ECHOES before: the check below fails the response at MAX_ECHOES.
        self.echo_no = self.echo_no.wrapping_add(1);
        if self.echo_no >= MAX_ECHOES {
            return Err(ErrorKind::TooManyEchoes);
        }
        self.next_is_echo = true;
        Ok(())
    }

    /// A value of `want` chars is complete; returns the width of the next one.
    #[inline]
    pub(super) fn value_done(&mut self, value: u32) -> Result<u8, ErrorKind> {
        if !self.in_aux && self.shape.aux_width != 0 {
            self.pending_distance = value;
            self.in_aux = true;
            return Ok(self.shape.aux_width);
        }
        let (distance, aux) = if self.in_aux {
            (self.pending_distance, value)
        } else {
            (value, 0)
        };
        self.in_aux = false;
        let (index, echo) = if self.next_is_echo {
            self.next_is_echo = false;
            self.extra_echoes = self.extra_echoes.saturating_add(1);
            (self.values.saturating_sub(1), self.echo_no)
        } else {
            if self.values >= self.shape.expected {
                return Err(ErrorKind::TooManyValues {
                    expected: self.shape.expected,
                });
            }
            self.echo_no = 0;
            // Below `expected` (checked above), so `+ 1` fits.
            let index = self.values;
            self.values = index.wrapping_add(1);
            (index, 0)
        };
        let slot = self
            .readings
            .get_mut(self.n_readings)
            .ok_or(ErrorKind::TooManyValues {
                expected: self.shape.expected,
            })?;
        self.readings_plain &= echo == 0 && aux == 0;
        *slot = Reading {
            index,
            echo,
            distance,
            aux,
        };
        // The slot at `n_readings` exists (above): below MAX_READINGS, no wrap.
        self.n_readings = self.n_readings.wrapping_add(1);
        Ok(self.shape.dist_width)
    }
}

/// The value of `N` valid value chars (see [`sum_and_check`]), most significant first.
///
/// Sums the raw bytes in base 64, then takes the `0x30` of every char off at once:
/// `Σ (c - 0x30)·64^k = Σ c·64^k - 0x30·Σ 64^k`, exact in `u32` for up to 4 chars.
#[inline(always)]
pub(super) fn decode_valid<const N: usize>(chars: &[u8; N]) -> u32 {
    let raw = chars
        .iter()
        .fold(0u32, |acc, &c| (acc << 6).wrapping_add(u32::from(c)));
    let offset = chars
        .iter()
        .fold(0u32, |acc, _| (acc << 6).wrapping_add(u32::from(CHAR_MIN)));
    raw.wrapping_sub(offset)
}

/// `carry` continued by valid value chars (see [`sum_and_check`]).
#[inline]
pub(super) fn continue_valid(carry: u32, chars: &[u8]) -> u32 {
    chars.iter().fold(carry, |acc, &c| {
        (acc << 6) | u32::from(c.wrapping_sub(CHAR_MIN) & 0x3F)
    })
}
