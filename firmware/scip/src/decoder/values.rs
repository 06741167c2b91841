//! Values: a data line's checks, and its chars decoded into readings, a whole step at
//! a time on the fast path or char by char.

#[cfg(not(target_pointer_width = "32"))]
use super::line::{copy_words, sum_and_check};
use super::*;

/// Bytes of a full data line (64 data chars and the sum char), LF excluded.
#[cfg(not(target_pointer_width = "32"))]
const FULL_LINE: usize = DATA_CHARS + 1;

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
        if let Err(kind) = self.decode_values(None, n, all_valid) {
            return self.fail(kind);
        }
        Some(self.data_event())
    }

    /// The event of the full data line [`Self::feed`]'s 32-bit fast path just
    /// completed in the line buffer (64 value chars and the sum char, see
    /// [`Self::take_data_words`]): [`Self::line_event`]'s bookkeeping, then, for a line
    /// of 3-char distances whose readings are plain, its sum checked from the
    /// accumulators and its steps decoded with the line's lengths fixed, with the plain
    /// full lines after it at the start of `more` joined to it ([`Self::join_plain_lines`];
    /// `more` is empty but for [`Decoder::feed_runs`]); anything else (a bad sum, a
    /// line after a short one, another data set ...) goes to [`Self::data_line`] as the
    /// general path would. Same events, readings and state. Returns the bytes of `more`
    /// taken, and the event.
    #[cfg_attr(not(target_pointer_width = "32"), allow(dead_code))]
    #[inline(never)]
    pub(super) fn full_line_event(&mut self, more: &[u8]) -> (usize, Option<Event<'_>>) {
        let len = self.len;
        self.len = 0;
        self.current_line = self.line_start;
        self.line_start = self.stats.bytes;
        self.line_no = self.line_no.saturating_add(1);
        if len == DATA_CHARS + 1 && self.full_sum_ok() && self.bad & 0xC0 == 0 && self.plain_lines()
        {
            return match self.join_plain_lines(more, true) {
                (taken, Ok(())) => (taken, Some(self.data_event())),
                (taken, Err(kind)) => (taken, self.fail(kind)),
            };
        }
        (0, self.data_line(len))
    }

    /// True when the full line in the line buffer ends with the sum char of its 64 data
    /// chars, as summed by [`Self::take_data_words`].
    #[inline(always)]
    fn full_sum_ok(&self) -> bool {
        match self.buf.get(DATA_CHARS) {
            // 0x30..=0x6F: no wrap.
            Some(&s) => {
                ((self.sum.wrapping_sub(u32::from(s)) & 0x3F) as u8).wrapping_add(0x30) == s
            }
            None => false,
        }
    }

    /// True when a full line of valid value chars with a good sum is decoded by
    /// [`Self::plain_full_line`]: 3-char distances only, in a scan whose lines so far
    /// were full, with plain readings.
    #[inline(always)]
    fn plain_lines(&self) -> bool {
        #[cfg(any(test, fuzzing))]
        let plain = self.readings_plain && !self.char_by_char;
        #[cfg(not(any(test, fuzzing)))]
        let plain = self.readings_plain;
        plain
            && !self.short_line_seen
            && self.shape.data == DataSet::Distance
            && !self.shape.multi_echo
    }

    /// The full line of 3-char distances in the line buffer decoded into the readings
    /// when `buffered` (else it is decoded already), then, for [`Decoder::feed_runs`],
    /// the full data lines of 3-char distances at the start of `more` joined to it
    /// ([`Self::take_plain_line`]), each decoded after the readings before it by
    /// [`Self::plain_full_line`]. Returns the bytes of `more` taken, and the outcome
    /// (an error only for the buffered line: a joined line is checked before it is
    /// taken).
    #[inline(never)]
    pub(super) fn join_plain_lines(
        &mut self,
        more: &[u8],
        buffered: bool,
    ) -> (usize, Result<(), ErrorKind>) {
        let mut taken: usize = 0;
        let mut at = buffered.then_some(0);
        loop {
            if let Some(at) = at {
                if let Err(kind) = self.plain_full_line(at) {
                    return (taken, Err(kind));
                }
            }
            let Some(used) = self.take_plain_line(more.get(taken..).unwrap_or_default()) else {
                return (taken, Ok(()));
            };
            // At most `more`'s length: no wrap.
            taken = taken.wrapping_add(used);
            at = Some(self.n_readings);
        }
    }

    /// After a full data line just decoded into the readings (its event not yet
    /// given): the full data line of 3-char distances at the start of `more`, when all
    /// of it is there (its LF where a full line's is), copied and checked by
    /// [`Self::take_data_words`], with the bookkeeping of [`Self::full_line_event`], for
    /// [`Self::plain_full_line`] to decode after the readings, while
    /// [`MAX_RUN_READINGS`] hold it. A line that is not a plain full line, or has a bad
    /// char or sum, or would complete more values than the scan has, is left untaken
    /// (its bytes counted back): the next call takes it alone and reports it. Returns
    /// the bytes taken.
    #[inline(always)]
    fn take_plain_line(&mut self, more: &[u8]) -> Option<usize> {
        // Readings a full line of 3-char distances completes at most: 21 whole steps
        // and the one begun on the line before.
        const LINE_MOST: usize = DATA_CHARS / 3 + 1;
        if self.n_readings.saturating_add(LINE_MOST) > MAX_RUN_READINGS
            || !self.plain_lines()
            || more.get(DATA_CHARS + 1) != Some(&b'\n')
        {
            return None;
        }
        // The line before is complete (`len` is 0): the line's bytes from the start.
        let Some((used, true)) = self.take_data_words(more) else {
            return None;
        };
        // The steps the line completes: 21, or 22 when it ends one begun with two chars
        // on the line before (see `plain_full_line`).
        let total = usize::from(self.carry_n >= 2).wrapping_add(21);
        let fits = usize::from(self.values).wrapping_add(total) <= usize::from(self.shape.expected);
        if !self.full_sum_ok() || !fits {
            // Untaken: as before the copy (the next call copies it again).
            self.len = 0;
            self.stats.bytes = self.stats.bytes.wrapping_sub(used as u64);
            return None;
        }
        self.len = 0;
        self.current_line = self.line_start;
        self.line_start = self.stats.bytes;
        self.line_no = self.line_no.saturating_add(1);
        Some(used)
    }

    /// [`Self::decode_steps`] for 3-char distances on a full line of valid value chars
    /// in the line buffer, the readings plain (aux 0 in every slot), written from slot
    /// `at` on (0 for a line of its own, after the readings of the lines before for a
    /// run): the step begun on the previous line (0, 1 or 2 chars carried) completed,
    /// the 20 or 21 whole steps after it, the 0 to 2 chars left carried: every length
    /// follows from the chars carried. Same readings, state and errors.
    #[cfg_attr(not(target_pointer_width = "32"), allow(dead_code))]
    #[inline(always)]
    fn plain_full_line(&mut self, at: usize) -> Result<(), ErrorKind> {
        const D: usize = 3;
        let Some(chars) = self.buf.first_chunk::<DATA_CHARS>() else {
            return Ok(());
        };
        // A char's 6 bits (a value char: no wrap, nothing above them).
        let v = |c: u8| u32::from(c).wrapping_sub(u32::from(CHAR_MIN));
        let &[c0, c1, ..] = chars;
        let &[.., c62, c63] = chars;
        // By the chars carried (0, 1 or 2): the step begun on the previous line
        // completed by the line's first 0, 2 or 1 chars (`off`), the 21, 20 or 21 whole
        // steps after them, and the 1, 2 or 0 chars left, carried. Straight-line: the
        // 0 to 2 chars at either end of the line were taken by two char loops.
        let (head, off, whole, carry, carry_n): (_, usize, usize, u32, u8) = match self.carry_n {
            0 => (None, 0, 21, v(c63), 1),
            1 => (
                Some((self.carry << 12) | (v(c0) << 6) | v(c1)),
                2,
                20,
                (v(c62) << 6) | v(c63),
                2,
            ),
            _ => (Some((self.carry << 6) | v(c0)), 1, 21, 0, 0),
        };
        let total: usize = whole.wrapping_add(usize::from(head.is_some()));
        if usize::from(self.values).wrapping_add(total) > usize::from(self.shape.expected) {
            return Err(self.too_many());
        }
        // `at` is at most MAX_RUN_READINGS - 22 (see `take_plain_line`): no wrap.
        let Some(line) = self.readings.get_mut(at..at.wrapping_add(total)) else {
            return Err(self.too_many());
        };
        let Some((first, slots)) = line.split_at_mut_checked(usize::from(head.is_some())) else {
            return Err(self.too_many());
        };
        if let (Some(slot), Some(distance)) = (first.first_mut(), head) {
            slot.distance = distance;
        }
        // `off + 3 * 21` is at most 64: within the line.
        let mid = chars.get(off..).unwrap_or(&[]);
        // The chars' address hidden from the optimiser: known as the line buffer's, the
        // loop indexes chars and slots by one counter (15 instructions a step on a
        // Cortex-M4) instead of walking two pointers (11). Their count taken again
        // from `whole` (the same), so that the steps' count is `whole` without a
        // division by 3.
        let mid = core::hint::black_box(mid);
        let mid = mid.get(..whole.wrapping_mul(D)).unwrap_or(&[]);
        put_plain3(slots, mid);
        self.echo_no = 0;
        // At most `expected` (checked above): no wrap.
        self.values = self.values.wrapping_add(total as u16);
        // At most MAX_RUN_READINGS: no wrap.
        self.n_readings = at.wrapping_add(total);
        self.carry = carry;
        self.carry_n = carry_n;
        Ok(())
    }

    /// True where the paths of 32-bit targets are taken (a data line's bytes copied,
    /// checked and summed a word at a time, then decoded from the line buffer): always
    /// on 32-bit targets, and on a 64-bit host in tests and fuzzing for a decoder made
    /// by [`Decoder::m4_paths`].
    #[inline(always)]
    pub(super) fn on_m4_paths(&self) -> bool {
        #[cfg(target_pointer_width = "32")]
        return true;
        #[cfg(all(not(target_pointer_width = "32"), any(test, fuzzing)))]
        return self.m4;
        #[cfg(all(not(target_pointer_width = "32"), not(any(test, fuzzing))))]
        false
    }

    /// The readings of the data line just decoded, as an event.
    #[inline]
    pub(super) fn data_event(&self) -> Event<'_> {
        let n = self.n_readings;
        let readings = self.readings.get(..n).unwrap_or(&[]);
        let (first, echoes) = if self.shape.multi_echo {
            self.multi_echo_line()
        } else {
            // Every reading began a step, the last of them `values - 1`: at most
            // MAX_RUN_READINGS of at most `values`, no wrap.
            (self.values.wrapping_sub(n as u16), &[][..])
        };
        Event::Data(DataLine {
            readings,
            first,
            echoes,
            data: self.shape.data,
            limits: self.limits,
            line: self.line_no,
        })
    }

    /// The first step index and the echo table of the multi-echo line just decoded:
    /// `values` counts the steps begun so far, one for each first echo of the line; a
    /// line that begins with an extra echo begins in the step before its first first
    /// echo (the decoder accepts an extra echo only after a step, so `values` is then
    /// above the line's first echoes).
    #[cold]
    #[inline(never)]
    fn multi_echo_line(&self) -> (u16, &[u8]) {
        let echoes = self.echoes.get(..self.n_readings).unwrap_or(&[]);
        let begun = echoes.iter().filter(|&&e| e == 0).count() as u16;
        let before = u16::from(echoes.first().is_some_and(|&e| e != 0));
        let first = self.values.wrapping_sub(begun).wrapping_sub(before);
        (first, echoes)
    }

    /// The fast path of [`Self::feed`] on 64-bit hosts for a full data line (64 value
    /// chars, its sum char and the LF) that ends in `input`: its LF at `input[rest]`,
    /// after `buffered` bytes of the line in the line buffer. Either all of it is in
    /// `input` (decoded from there, not copied) or it began in the line buffer (its rest
    /// copied there). Returns the bytes of `input` the line took and the outcome of
    /// decoding it, as [`Self::data_line`] would give them; `None`, having consumed
    /// nothing, for anything else (a bad sum or char, a line after a short one,
    /// multi-echo data ...).
    ///
    /// No LF search: the LF is where a full line puts it, and the value-char check of
    /// the 64 data chars and the sum char (a value char, as the computed sum is) rule
    /// out an earlier LF.
    #[cfg(not(target_pointer_width = "32"))]
    #[inline(always)]
    pub(super) fn full_data_line(
        &mut self,
        input: &[u8],
        buffered: usize,
        rest: usize,
    ) -> Option<(usize, Result<(), ErrorKind>)> {
        if self.short_line_seen || self.shape.multi_echo {
            return None;
        }
        #[cfg(any(test, fuzzing))]
        if self.char_by_char {
            return None;
        }
        let line: &[u8; FULL_LINE] = if buffered == 0 {
            input.first_chunk()?
        } else {
            let tail = input.get(..rest)?;
            copy_words(tail, self.buf.get_mut(buffered..FULL_LINE)?, |_| {});
            self.buf.first_chunk()?
        };
        let (data, &[s]) = line.split_first_chunk::<DATA_CHARS>()? else {
            return None;
        };
        let (sum, valid) = sum_and_check(data);
        if !valid || sum != s {
            return None;
        }
        // The line is taken: the bookkeeping of `feed` and `line_event` for it. `rest`
        // is below `LINE`, so `used` cannot wrap.
        let used = rest.wrapping_add(1);
        self.stats.bytes = self.stats.bytes.wrapping_add(used as u64);
        self.current_line = self.line_start;
        self.line_start = self.stats.bytes;
        self.len = 0;
        self.line_no = self.line_no.saturating_add(1);
        self.n_readings = 0;
        let from_input = if buffered == 0 {
            input.get(..DATA_CHARS)
        } else {
            None
        };
        let decoded = match (self.shape.dist_width, self.shape.aux_width) {
            (3, 0) => self.decode_full::<3, 0, 3>(from_input),
            (2, 0) => self.decode_full::<2, 0, 2>(from_input),
            (3, 3) => self.decode_full::<3, 3, 6>(from_input),
            // The other data sets with second values (3 + 2, 3 + 4 chars) keep the
            // general whole-step loop (no stream of them is benchmarked).
            _ => self.decode_values(from_input, DATA_CHARS, true),
        };
        Some((used, decoded))
    }

    /// [`Self::decode_steps`] for a full line (`DATA_CHARS` valid value chars, from
    /// `input` or the line buffer), `W = D + A`: the step begun on the previous line is
    /// completed, then the rest goes to [`Self::decode_full_from`] for the offset of the
    /// first whole step, where every length is a constant. Same readings, state and
    /// errors.
    #[cfg(not(target_pointer_width = "32"))]
    #[inline]
    fn decode_full<const D: usize, const A: usize, const W: usize>(
        &mut self,
        input: Option<&[u8]>,
    ) -> Result<(), ErrorKind> {
        let chars = match input {
            Some(chars) => chars,
            None => self.buf.get(..DATA_CHARS).unwrap_or(&[]),
        };
        let carried = usize::from(self.carry_n);
        let (head, used) = if self.in_aux {
            let need = A.saturating_sub(carried);
            let a = chars.get(..need).unwrap_or(&[]);
            (
                Some((self.pending_distance, continue_valid(self.carry, a))),
                need,
            )
        } else if carried != 0 {
            let need = D.saturating_sub(carried);
            // At most `D + A`: no wrap.
            let used = need.wrapping_add(A);
            let (d, a) = (
                chars.get(..need).unwrap_or(&[]),
                chars.get(need..used).unwrap_or(&[]),
            );
            (
                Some((continue_valid(self.carry, d), continue_valid(0, a))),
                used,
            )
        } else {
            (None, 0)
        };
        // `used` is below `W`: the step begun before is part of one step.
        match used {
            0 => self.decode_full_from::<D, A, W, 0>(input, head),
            1 => self.decode_full_from::<D, A, W, 1>(input, head),
            2 => self.decode_full_from::<D, A, W, 2>(input, head),
            3 => self.decode_full_from::<D, A, W, 3>(input, head),
            4 => self.decode_full_from::<D, A, W, 4>(input, head),
            5 => self.decode_full_from::<D, A, W, 5>(input, head),
            6 => self.decode_full_from::<D, A, W, 6>(input, head),
            _ => self.decode_values(input, DATA_CHARS, true),
        }
    }

    /// The rest of [`Self::decode_full`]: the whole steps from char `OFF` on, after the
    /// completed step `head` (present exactly when `OFF > 0`), and the partial step at
    /// the end carried.
    #[cfg(not(target_pointer_width = "32"))]
    #[inline(always)]
    fn decode_full_from<const D: usize, const A: usize, const W: usize, const OFF: usize>(
        &mut self,
        input: Option<&[u8]>,
        head: Option<(u32, u32)>,
    ) -> Result<(), ErrorKind> {
        if OFF >= W || W != D.wrapping_add(A) || (OFF == 0) != head.is_none() {
            // Not a shape `decode_full` dispatches here.
            return self.decode_values(input, DATA_CHARS, true);
        }
        let chars = match input {
            Some(chars) => chars.first_chunk::<DATA_CHARS>(),
            None => self.buf.first_chunk::<DATA_CHARS>(),
        };
        let Some(chars) = chars else {
            return self.decode_values(input, DATA_CHARS, true);
        };
        // Constants per instantiation (`OFF < W <= 7`): none of these wraps.
        let whole = DATA_CHARS.wrapping_sub(OFF).checked_div(W).unwrap_or(0);
        let tail_at = OFF.wrapping_add(whole.wrapping_mul(W));
        let total = whole.wrapping_add(usize::from(OFF > 0));
        begin_steps::<A>(
            &mut self.readings,
            &mut self.readings_plain,
            self.values,
            self.shape.expected,
            total,
        )?;
        let plain = A == 0 && self.readings_plain;
        let too_many = self.too_many();
        let Some(slots) = self.readings.get_mut(..total) else {
            return Err(too_many);
        };
        let (head_slot, mid_slots) = slots.split_at_mut(usize::from(OFF > 0));
        if let (Some((distance, aux)), [slot]) = (head, head_slot) {
            *slot = Reading { distance, aux };
        }
        // `whole` steps from `OFF` on, `W` chars each, within the line, unrolled (see
        // `put_full_steps`): written out apart for the line in `input` (which has its
        // 64 chars, checked above) and in the line buffer, so that every load of the
        // unrolled steps is from one base, not a choice of two per load.
        let from_input = input.and_then(|c| c.first_chunk::<DATA_CHARS>());
        let from_buf = self.buf.first_chunk::<DATA_CHARS>();
        match (plain, from_input, from_buf) {
            (true, Some(c), _) => put_full_steps::<D, A, W, OFF, true>(mid_slots, c, whole),
            (true, None, Some(c)) => put_full_steps::<D, A, W, OFF, true>(mid_slots, c, whole),
            (false, Some(c), _) => put_full_steps::<D, A, W, OFF, false>(mid_slots, c, whole),
            (false, None, Some(c)) => put_full_steps::<D, A, W, OFF, false>(mid_slots, c, whole),
            _ => {}
        }
        if total > 0 {
            self.echo_no = 0;
        }
        // `total` is at most `expected - values` (checked above): no wrap.
        self.values = self.values.wrapping_add(total as u16);
        self.n_readings = total;
        let tail = chars.get(tail_at..).unwrap_or(&[]);
        self.set_carry(Carry::of::<D, A>(tail));
        Ok(())
    }

    /// The error of a line that completes more values than the scan has.
    #[inline(always)]
    fn too_many(&self) -> ErrorKind {
        ErrorKind::TooManyValues {
            expected: self.shape.expected,
        }
    }

    /// Carries the partial step at the end of a line's whole steps into the next line.
    #[inline(always)]
    fn set_carry(&mut self, c: Carry) {
        if let Some(d) = c.pending_distance {
            self.pending_distance = d;
        }
        self.in_aux = c.in_aux;
        self.carry = c.carry;
        self.carry_n = c.carry_n;
        self.want = c.want;
    }

    /// Decodes the first `n` bytes of the buffer (or `input`, when the line is there) as
    /// value chars, carrying partial values; `all_valid` tells that all of them are value
    /// chars (see [`sum_and_check`]).
    pub(super) fn decode_values(
        &mut self,
        input: Option<&[u8]>,
        n: usize,
        all_valid: bool,
    ) -> Result<(), ErrorKind> {
        // Fast path: a line of valid value chars only (no `&`, nothing to report by
        // column) is decoded a whole step at a time. Anything else goes char by char.
        #[cfg(any(test, fuzzing))]
        let all_valid = all_valid && !self.char_by_char;
        if !self.shape.multi_echo && all_valid {
            // The data set fixes the widths (see `begin_scan`): one dispatch on it.
            return match self.shape.data {
                DataSet::Distance => self.decode_steps::<3, 0>(input, n),
                DataSet::ShortDistance => self.decode_steps::<2, 0>(input, n),
                DataSet::DistanceIntensity => self.decode_steps::<3, 3>(input, n),
                DataSet::DistanceReflectance => self.decode_steps::<3, 2>(input, n),
                DataSet::DistanceAux => self.decode_steps::<3, 4>(input, n),
            };
        }
        self.decode_chars_from(input, n)
    }

    /// [`Self::decode_chars`] on `input`, or on the first `n` bytes of the buffer.
    fn decode_chars_from(&mut self, input: Option<&[u8]>, n: usize) -> Result<(), ErrorKind> {
        match input {
            Some(chars) => self.decode_chars(chars, 0),
            None => self.decode_chars_copied(n),
        }
    }

    /// Decodes `input`, or the first `n` bytes of the buffer when it is `None` (all valid
    /// value chars, see [`sum_and_check`]) of a data set
    /// with `D`-char distances and `A`-char second values, a whole step at a time: the
    /// step begun on the previous line is completed from the carried value, the whole
    /// steps go straight into readings, the partial step at the end is carried. Same
    /// readings, state and errors as [`Self::decode_chars`] on the same chars.
    pub(super) fn decode_steps<const D: usize, const A: usize>(
        &mut self,
        input: Option<&[u8]>,
        n: usize,
    ) -> Result<(), ErrorKind> {
        // 2..=7 chars: the `D + A` of the data sets dispatched in `decode_values`.
        let width = D.wrapping_add(A);
        let chars = match input {
            Some(chars) => chars,
            None => self.buf.get(..n).unwrap_or(&[]),
        };
        let carried = usize::from(self.carry_n);
        // The step begun on the previous line, completed.
        let mut head = None;
        let mut rest = chars;
        if carried != 0 || self.in_aux {
            let (distance, aux, used) = if self.in_aux {
                let need = A.saturating_sub(carried);
                let Some(a) = chars.get(..need) else {
                    return self.decode_chars_from(input, n);
                };
                (self.pending_distance, continue_valid(self.carry, a), need)
            } else {
                let need = D.saturating_sub(carried);
                // At most `D + A`: no wrap.
                let used = need.wrapping_add(A);
                let (Some(d), Some(a)) = (chars.get(..need), chars.get(need..used)) else {
                    return self.decode_chars_from(input, n);
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
        begin_steps::<A>(
            &mut self.readings,
            &mut self.readings_plain,
            self.values,
            self.shape.expected,
            total,
        )?;
        let first = self.n_readings;
        let end = first.wrapping_add(total);
        let too_many = self.too_many();
        let slots = self.readings.get_mut(first..end).ok_or(too_many)?;
        let mut slots = slots.iter_mut();
        if let Some((distance, aux)) = head {
            if let Some(slot) = slots.next() {
                *slot = Reading { distance, aux };
            }
        }
        let slots = slots.into_slice();
        if A == 0 && self.readings_plain {
            // Every slot already has aux 0: the distance will do.
            put_steps::<D, A, true>(slots, mid);
        } else {
            put_steps::<D, A, false>(slots, mid);
        }
        if total > 0 {
            self.echo_no = 0;
        }
        // `total` is at most `expected - values` (checked above): no wrap.
        self.values = self.values.wrapping_add(total as u16);
        self.n_readings = end;
        self.set_carry(Carry::of::<D, A>(tail));
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
        let echo = if self.next_is_echo {
            self.next_is_echo = false;
            self.extra_echoes = self.extra_echoes.saturating_add(1);
            self.echo_no
        } else {
            if self.values >= self.shape.expected {
                return Err(ErrorKind::TooManyValues {
                    expected: self.shape.expected,
                });
            }
            self.echo_no = 0;
            // Below `expected` (checked above), so `+ 1` fits.
            self.values = self.values.wrapping_add(1);
            0
        };
        let slot = self
            .readings
            .get_mut(self.n_readings)
            .ok_or(ErrorKind::TooManyValues {
                expected: self.shape.expected,
            })?;
        self.readings_plain &= aux == 0;
        *slot = Reading { distance, aux };
        if let Some(e) = self.echoes.get_mut(self.n_readings) {
            *e = echo;
        }
        // The slot at `n_readings` exists (above): below MAX_READINGS, no wrap.
        self.n_readings = self.n_readings.wrapping_add(1);
        Ok(self.shape.dist_width)
    }
}

/// What every whole-step decoder does before it writes a line's `total` steps of
/// `A`-char second values (after `values` of `expected`): fail when they would make more
/// values than the scan has, and keep `plain` (the decoder's `readings_plain`) true for
/// distance-only lines: once per change of data set, the readings that echoes or second
/// values left are cleared, so that distance-only lines write less.
#[inline(always)]
fn begin_steps<const A: usize>(
    readings: &mut [Reading; MAX_RUN_READINGS],
    plain: &mut bool,
    values: u16,
    expected: u16,
    total: usize,
) -> Result<(), ErrorKind> {
    if usize::from(values).wrapping_add(total) > usize::from(expected) {
        return Err(ErrorKind::TooManyValues { expected });
    }
    if A == 0 && !*plain {
        *readings = [Reading::default(); MAX_RUN_READINGS];
        *plain = true;
    } else if A > 0 {
        *plain = false;
    }
    Ok(())
}

/// Writes the `whole` steps of a full line from char `OFF` on (`W = D + A` chars each,
/// valid value chars) into `slots`, four per round: with
/// `whole` a constant the rounds unroll fully, so no loop instruction is left per step
/// and every offset is a constant. `PLAIN`: as in [`put_steps`].
#[cfg(not(target_pointer_width = "32"))]
#[inline(always)]
fn put_full_steps<
    const D: usize,
    const A: usize,
    const W: usize,
    const OFF: usize,
    const PLAIN: bool,
>(
    slots: &mut [Reading],
    chars: &[u8; DATA_CHARS],
    whole: usize,
) {
    let rounds = whole / 4;
    for r in 0..rounds {
        // Below `whole`: no wrap.
        let j = r.wrapping_mul(4);
        for k in 0..4 {
            put_step_at::<D, A, W, OFF, PLAIN>(slots, chars, j.wrapping_add(k));
        }
    }
    for j in rounds.wrapping_mul(4)..whole {
        put_step_at::<D, A, W, OFF, PLAIN>(slots, chars, j);
    }
}

/// Writes step `j` of a full line's whole steps from char `OFF` on (`W = D + A` chars
/// each, valid value chars) into `slots[j]`; nothing when either is out of range.
/// `PLAIN`: as in [`put_steps`].
#[cfg(not(target_pointer_width = "32"))]
#[inline(always)]
fn put_step_at<
    const D: usize,
    const A: usize,
    const W: usize,
    const OFF: usize,
    const PLAIN: bool,
>(
    slots: &mut [Reading],
    chars: &[u8; DATA_CHARS],
    j: usize,
) {
    // Within one line: none of these wraps.
    let at = OFF.wrapping_add(j.wrapping_mul(W));
    let (Some(slot), Some(step)) = (
        slots.get_mut(j),
        chars.get(at..).and_then(|r| r.first_chunk::<W>()),
    ) else {
        return;
    };
    let Some((d, a)) = step.split_first_chunk::<D>() else {
        return;
    };
    if PLAIN {
        slot.distance = decode_valid(d);
    } else if let Some(a) = a.first_chunk::<A>() {
        *slot = Reading {
            distance: decode_valid(d),
            aux: decode_valid(a),
        };
        // No instruction: it keeps the unrolled steps' stores apart, so that LLVM's SLP
        // vectorizer does not pack two steps' distances and second values (adjacent in
        // the 8-byte readings) into vector stores, whose byte shuffles cost more than
        // the scalar steps (callgrind, UTM-30LX ME stream: 7.71 -> 6.92 per byte).
        core::sync::atomic::compiler_fence(core::sync::atomic::Ordering::SeqCst);
    }
}

/// Writes the whole steps of `mid` (valid value chars, `D`-char distances and `A`-char
/// second values) into `slots`, as many as both have. `PLAIN`: every slot has aux 0
/// already (`A == 0`), so only the distance is written. On 64-bit hosts four steps at a
/// time, unrolled (fewer loop instructions per step); 32-bit targets keep the smaller
/// plain loop.
#[inline(always)]
fn put_steps<const D: usize, const A: usize, const PLAIN: bool>(slots: &mut [Reading], mid: &[u8]) {
    // 2..=7: the `D + A` of the data sets `decode_values` dispatches; no wrap.
    let width = D.wrapping_add(A);
    #[cfg(not(target_pointer_width = "32"))]
    {
        let mut slots4 = slots.chunks_exact_mut(4);
        let mut mid4 = mid.chunks_exact(width.wrapping_mul(4));
        for (s, m) in (&mut slots4).zip(&mut mid4) {
            put_step_run::<D, A, PLAIN>(s, m);
        }
        put_step_run::<D, A, PLAIN>(slots4.into_remainder(), mid4.remainder());
    }
    #[cfg(target_pointer_width = "32")]
    {
        let _ = width;
        put_step_run::<D, A, PLAIN>(slots, mid);
    }
}

/// [`put_steps`] one step at a time.
#[inline(always)]
fn put_step_run<const D: usize, const A: usize, const PLAIN: bool>(
    slots: &mut [Reading],
    mid: &[u8],
) {
    let width = D.wrapping_add(A);
    for (slot, step) in slots.iter_mut().zip(mid.chunks_exact(width)) {
        if PLAIN {
            if let Some(d) = step.first_chunk::<D>() {
                slot.distance = decode_valid(d);
            }
        } else {
            let Some((d, a)) = step.split_first_chunk::<D>() else {
                continue;
            };
            let Some(a) = a.first_chunk::<A>() else {
                continue;
            };
            *slot = Reading {
                distance: decode_valid(d),
                aux: decode_valid(a),
            };
        }
    }
}

/// [`put_step_run`] for plain readings of 3-char distances (`D = 3`, `A = 0`,
/// `PLAIN`): the same distances. The chars' `0x30` offsets are taken off
/// by starting each step's value from `-0x30·(64² + 64 + 1)`, held in a register (its
/// value hidden from the optimiser, which would otherwise add it last, after an extra
/// shift): three shifted adds a step instead of four instructions (9 a step on a
/// Cortex-M4: three loads, three adds, the store and the loop's two; 11 while each
/// reading had its index stored too). Two steps a round was slower, twice: LLVM
/// unrolled the pairs and spilled their registers (URG-04LX D16 28.5 -> 29.5 per UART
/// byte), and with the 8-byte readings it took the steps' count by a division by 3
/// (26.6 -> 27.6).
#[cfg_attr(not(target_pointer_width = "32"), allow(dead_code))]
#[inline(always)]
fn put_plain3(slots: &mut [Reading], mid: &[u8]) {
    const OFFSETS: u32 = CHAR_MIN as u32 * (64 * 64 + 64 + 1);
    let base = core::hint::black_box(0u32.wrapping_sub(OFFSETS));
    for (slot, step) in slots.iter_mut().zip(mid.chunks_exact(3)) {
        if let Some(&[a, b, c]) = step.first_chunk::<3>() {
            slot.distance = base
                .wrapping_add(u32::from(a) << 12)
                .wrapping_add(u32::from(b) << 6)
                .wrapping_add(u32::from(c));
        }
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

/// The partial step at the end of a line's whole steps, carried into the next line.
struct Carry {
    /// The step's distance, complete (with a second value begun), or none.
    pending_distance: Option<u32>,
    /// The carried chars belong to the second value.
    in_aux: bool,
    /// The carried chars' value so far, how many there are and how many the value has.
    carry: u32,
    carry_n: u8,
    want: u8,
}

impl Carry {
    /// The carry of `tail`, fewer chars than a step of `D` + `A` chars: a distance and
    /// part of its second value, or part of a distance.
    #[inline(always)]
    fn of<const D: usize, const A: usize>(tail: &[u8]) -> Self {
        match tail.split_at_checked(D) {
            Some((d, a)) if A > 0 => Carry {
                pending_distance: Some(continue_valid(0, d)),
                in_aux: true,
                carry: continue_valid(0, a),
                carry_n: a.len() as u8,
                want: A as u8,
            },
            _ => Carry {
                pending_distance: None,
                in_aux: false,
                carry: continue_valid(0, tail),
                carry_n: tail.len() as u8,
                want: D as u8,
            },
        }
    }
}

#[cfg(test)]
mod plain3_tests {
    use super::*;

    /// The value of three value chars, written plainly: each char's 6 bits, most
    /// significant first.
    fn reference(a: u8, b: u8, c: u8) -> u32 {
        let bits = |ch: u8| u32::from(ch - 0x30);
        bits(a) * 4096 + bits(b) * 64 + bits(c)
    }

    #[test]
    fn every_three_chars_decode_as_the_rule_says() {
        // Every value of three chars, 21 steps (a full line's) at a time, each slot
        // starting from garbage that must not survive in the distance, nor change the
        // aux (the plain path writes the distance only).
        let all: Vec<[u8; 3]> = (0x30..=0x6Fu8)
            .flat_map(|a| {
                (0x30..=0x6Fu8).flat_map(move |b| (0x30..=0x6Fu8).map(move |c| [a, b, c]))
            })
            .collect();
        assert_eq!(all.len(), 1 << 18);
        for group in all.chunks(21) {
            let mid: Vec<u8> = group.iter().flatten().copied().collect();
            let mut slots = [Reading {
                distance: 0xDEAD_BEEF,
                aux: 0,
            }; 21];
            put_plain3(&mut slots[..group.len()], &mid);
            for (slot, &[a, b, c]) in slots.iter().zip(group) {
                assert_eq!(slot.distance, reference(a, b, c), "{:?}", [a, b, c]);
                assert_eq!(slot.aux, 0);
            }
        }
        // The extremes by hand: "000" is 0, "ooo" is 2^18 - 1, "0o0" is 63 * 64.
        assert_eq!(reference(b'0', b'0', b'0'), 0);
        assert_eq!(reference(b'o', b'o', b'o'), 262_143);
        let mut slots = [Reading::default(); 3];
        put_plain3(&mut slots, b"000ooo0o0");
        assert_eq!(slots.map(|r| r.distance), [0, 262_143, 4032]);
    }

    #[test]
    fn the_shorter_of_slots_and_steps_is_written() {
        // Fewer slots than steps, fewer whole steps than slots (a partial step left),
        // and nothing at all: only what both have is written.
        let untouched = Reading {
            distance: 77,
            aux: 5,
        };
        let mut slots = [untouched; 4];
        put_plain3(&mut slots[..2], b"001002003");
        assert_eq!(slots.map(|r| r.distance), [1, 2, 77, 77]);
        let mut slots = [untouched; 4];
        put_plain3(&mut slots, b"0010020");
        assert_eq!(slots.map(|r| r.distance), [1, 2, 77, 77]);
        assert!(slots.iter().all(|r| r.aux == 5));
        put_plain3(&mut [], b"001");
        put_plain3(&mut slots, b"");
        assert_eq!(slots.map(|r| r.distance), [1, 2, 77, 77]);
    }
}
