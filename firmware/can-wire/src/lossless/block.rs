//! One block of values of one channel: the sender chooses one of the four modes (the
//! constant block, or the better predictor's Rice code unless its verbatim form costs no
//! more) and writes it; the receiver reads it back.
//!
//! Every block is preceded by the history of its channel in the segment: the previous
//! value `h1` and the one before it `h2` (both the anchor at the segment's start).
//! Order 1 predicts `h1`, order 2 predicts `2·h1 − h2`; a residual `e` is zig-zagged to
//! `u` and Rice-coded with the block's parameter `k`.

use super::bits::{Out, Reader, Writer};
use super::{
    unzigzag, zigzag, Mode, BLOCK_POINTS, ESCAPE_ONES, K_BITS, MAX_VALUE, MODE_BITS, VALUE_BITS,
    WIDTH_BITS,
};
use crate::encoder::FrameSink;

/// The previous two values of a channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct History {
    /// The last value.
    pub h1: u32,
    /// The value before it.
    pub h2: u32,
}

impl History {
    /// The history at a segment's start: the anchor twice.
    pub const fn anchor(v: u32) -> History {
        History { h1: v, h2: v }
    }

    #[inline(always)]
    fn push(&mut self, v: u32) {
        self.h2 = self.h1;
        self.h1 = v;
    }
}

/// A block being gathered: its values, and room for their residuals under both
/// predictors, kept by the sender between blocks (a fresh array per block would be
/// cleared each time). The three arrays side by side: the residual pass reaches all
/// three from one pointer.
#[derive(Debug, Clone, Default)]
pub struct Block {
    /// The values (the block's first `n`).
    pub v: [u32; BLOCK_POINTS],
    u1: [u32; BLOCK_POINTS],
    u2: [u32; BLOCK_POINTS],
}

/// Width of a value: bits up to its highest one bit (0 for 0).
#[inline(always)]
pub const fn width(v: u32) -> u32 {
    // leading_zeros() is at most 32.
    32u32.wrapping_sub(v.leading_zeros())
}

/// The Rice parameter for `n` residuals summing to `sum`: one less than the width of
/// their mean (the integer part of its base-2 logarithm, as lossless audio coders
/// choose it), at most 15.
#[inline(always)]
fn rice_k(sum: u32, n: u32) -> u32 {
    let mean = sum.checked_div(n).unwrap_or(sum); // no residual: their sum
                                                  // One less than the width: the width of `mean | 1` is at least 1.
    width(mean | 1)
        .wrapping_sub(1)
        .min((1u32 << K_BITS).wrapping_sub(1))
}

/// Bits of the residuals `u` Rice-coded with parameter `k`, escapes counted.
#[cold]
#[inline(never)]
fn rice_bits_exact(u: &[u32], k: u32) -> u32 {
    // At most BLOCK_POINTS (16) codes of at most 36 bits: no wrap.
    let mut bits = 0u32;
    for &x in u {
        let q = x >> k;
        bits = bits.wrapping_add(if q < ESCAPE_ONES {
            q.wrapping_add(1).wrapping_add(k)
        } else {
            ESCAPE_ONES + VALUE_BITS
        });
    }
    bits
}

/// The OR of `values` (its width is a verbatim block's width).
#[cold]
#[inline(never)]
fn or_all(values: &[u32]) -> u32 {
    values.iter().fold(0, |a, &v| a | v)
}

/// Write the block of the first `n` values of `b` (at most [`BLOCK_POINTS`], each at
/// most [`MAX_VALUE`]) of a channel whose history is `h`, in the cheaper of a Rice-coded prediction and its
/// verbatim form (or constant); returns the mode. Not inlined: one copy serves both
/// channels (flash is the boards' tight budget).
///
/// One pass computes both predictors' residuals and their sums; the predictor with the
/// smaller sum is taken, its Rice parameter follows from the mean residual, and its cost
/// is bounded in closed form (`n·(k + 1) + sum >> k`, never below the exact cost, so a
/// block never costs more than its verbatim form); only a block where a quotient could
/// reach an escape has its cost counted value by value.
#[inline(never)]
pub fn put_block<S: FrameSink + ?Sized>(
    b: &mut Block,
    n: usize,
    h: &mut History,
    w: &mut Writer,
    out: &mut Out<'_, S>,
) -> Mode {
    let n = n.min(BLOCK_POINTS);
    let Block { v: values, u1, u2 } = b;
    // `or` gathers both predictors' residuals: a quotient of either may escape.
    let (mut s1, mut s2, mut or) = (0u32, 0u32, 0u32);
    // The last value and the last order-1 residual (the order-2 prediction is `a + p`).
    // Values and residuals stay far inside i32 (values below 2^20; larger ones would only
    // make wrong codes, and the stream never gives any).
    let mut a = h.h1 as i32;
    let mut p = a.wrapping_sub(h.h2 as i32);
    // One value: its residuals under both predictors into `x1` and `x2`, their sums and
    // OR. At most 16 residuals below 2^22 are summed: no wrap.
    let mut step = |v: u32, x1: &mut u32, x2: &mut u32| {
        let e1 = (v as i32).wrapping_sub(a);
        let z1 = zigzag(e1);
        let z2 = zigzag(e1.wrapping_sub(p));
        *x1 = z1;
        *x2 = z2;
        s1 = s1.wrapping_add(z1);
        s2 = s2.wrapping_add(z2);
        or |= z1 | z2;
        p = e1;
        a = v as i32;
    };
    // Two values per turn (no register shuffling between turns), then an odd last one.
    let pairs = values
        .chunks_exact(2)
        .zip(u1.chunks_exact_mut(2))
        .zip(u2.chunks_exact_mut(2))
        .take(n / 2);
    for ((v, x1), x2) in pairs {
        if let ([v0, v1], [a0, a1], [b0, b1]) = (v, x1, x2) {
            step(*v0, a0, b0);
            step(*v1, a1, b1);
        }
    }
    if n % 2 == 1 {
        let last = n.wrapping_sub(1); // n is odd here
        if let (Some(&v), Some(x1), Some(x2)) =
            (values.get(last), u1.get_mut(last), u2.get_mut(last))
        {
            step(v, x1, x2);
        }
    }
    // The history after the block, whatever its mode.
    h.h1 = a as u32;
    h.h2 = a.wrapping_sub(p) as u32;
    let n32 = n as u32;
    if s1 == 0 {
        w.put(Mode::Constant as u32, MODE_BITS, out);
        return Mode::Constant;
    }
    let (mode, u, sum) = if s2 < s1 {
        (Mode::Order2, &*u2, s2)
    } else {
        (Mode::Order1, &*u1, s1)
    };
    let u = u.get(..n).unwrap_or(&[]);
    let values = values.get(..n).unwrap_or(&[]);
    let k = rice_k(sum, n32);
    // Whether a quotient of the chosen residuals may reach an escape (`or` bounds both
    // predictors' residuals: a few blocks take the exact path without need).
    let escapes = (or >> k) >= ESCAPE_ONES;
    // Sum of the quotients is at most sum >> k; at most 16 values below 2^22.
    let rice = if escapes {
        rice_bits_exact(u, k)
    } else {
        n32.wrapping_mul(k.wrapping_add(1)).wrapping_add(sum >> k)
    };
    let rice = K_BITS.wrapping_add(rice);
    // A verbatim block is at least as wide as its last value: only a Rice code that
    // may not be cheaper looks at every value's width.
    if rice >= WIDTH_BITS.wrapping_add(n32.wrapping_mul(width(a as u32))) {
        let wv = width(or_all(values));
        // At most 16 values of at most 32 bits.
        let verbatim = WIDTH_BITS.wrapping_add(n32.wrapping_mul(wv));
        if verbatim <= rice {
            w.put(
                Mode::Verbatim as u32 | wv << MODE_BITS,
                MODE_BITS + WIDTH_BITS,
                out,
            );
            for &v in values {
                w.put(v & MAX_VALUE, wv, out);
            }
            return Mode::Verbatim;
        }
    }
    // The header goes into the word the codes gather in.
    let head = (mode as u32 | k << MODE_BITS, MODE_BITS + K_BITS);
    if escapes {
        w.put_rices_escaped(head, u, values, k, VALUE_BITS, out);
    } else {
        w.put_rices(head, u, k, out);
    }
    mode
}

/// Why a block could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadError {
    /// The stream ends before the block does: more frames are needed.
    NeedMore,
    /// The block is malformed (a width above 20, a value out of range).
    Corrupt,
}

/// Read a block of `out.len()` values of a channel whose history is `h`.
pub fn read_block(r: &mut Reader<'_>, h: &mut History, out: &mut [u32]) -> Result<Mode, ReadError> {
    let mode = Mode::from_bits(r.read(MODE_BITS).ok_or(ReadError::NeedMore)?);
    match mode {
        Mode::Constant => {
            for v in out.iter_mut() {
                *v = h.h1;
            }
            if !out.is_empty() {
                h.push(h.h1);
            }
        }
        Mode::Verbatim => {
            let wv = r.read(WIDTH_BITS).ok_or(ReadError::NeedMore)?;
            if wv > VALUE_BITS {
                return Err(ReadError::Corrupt);
            }
            for v in out.iter_mut() {
                *v = r.read(wv).ok_or(ReadError::NeedMore)?;
                h.push(*v);
            }
        }
        Mode::Order1 | Mode::Order2 => {
            let k = r.read(K_BITS).ok_or(ReadError::NeedMore)?;
            for v in out.iter_mut() {
                let value = match r.read_rice(k, VALUE_BITS).ok_or(ReadError::NeedMore)? {
                    Err(escaped) => escaped,
                    Ok(u) => {
                        let (a, b) = (i64::from(h.h1), i64::from(h.h2));
                        // u32 history and an i32 residual: far inside i64.
                        let p = if mode == Mode::Order1 {
                            a
                        } else {
                            a.wrapping_mul(2).wrapping_sub(b)
                        };
                        let x = p.wrapping_add(i64::from(unzigzag(u)));
                        if !(0..=i64::from(MAX_VALUE)).contains(&x) {
                            return Err(ReadError::Corrupt);
                        }
                        x as u32
                    }
                };
                *v = value;
                h.push(value);
            }
        }
    }
    Ok(mode)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;
    use crate::id::{IdWindow, Kind};

    type Frames = std::vec::Vec<Frame>;

    /// Writes the blocks into one long frame's stream and reads them back.
    fn round_trip(blocks: &[std::vec::Vec<u32>], anchor: u32) -> std::vec::Vec<Mode> {
        let mut sink = Frames::new();
        let id = IdWindow::DEFAULT.node(0).unwrap().id(Kind::Data);
        let mut out = Out::new(&mut sink, id, true);
        let mut w = Writer::new(64);
        w.begin_segment(0, 0, &mut out);
        let mut h = History::anchor(anchor);
        let mut modes = vec![];
        let mut block = Block::default();
        for b in blocks {
            block.v[..b.len()].copy_from_slice(b);
            modes.push(put_block(&mut block, b.len(), &mut h, &mut w, &mut out));
        }
        w.end_segment(&mut out);
        let mut stream = vec![];
        for f in &sink {
            stream.extend_from_slice(&f.data()[1..]);
        }
        let mut r = Reader::new(&stream);
        r.read(9);
        let mut h = History::anchor(anchor);
        for (b, m) in blocks.iter().zip(&modes) {
            let mut got = vec![0; b.len()];
            assert_eq!(read_block(&mut r, &mut h, &mut got), Ok(*m));
            assert_eq!(&got, b);
        }
        modes
    }

    #[test]
    fn each_mode_is_chosen_where_it_is_cheapest() {
        let flat = vec![1000; 16];
        let ramp: std::vec::Vec<u32> = (0..16).map(|i| 1000 + 7 * i).collect();
        let noisy: std::vec::Vec<u32> = (0..16).map(|i| 1000 + (i * 37 % 11)).collect();
        let wild: std::vec::Vec<u32> = (0..16).map(|i| (i * 0x9E37 + 11) % 60000).collect();
        let modes = round_trip(&[flat, ramp, noisy, wild], 1000);
        assert_eq!(
            modes,
            [Mode::Constant, Mode::Order2, Mode::Order1, Mode::Verbatim]
        );
    }

    #[test]
    fn extremes_and_short_blocks() {
        round_trip(
            &[
                vec![MAX_VALUE, 0, MAX_VALUE, 0],
                vec![0],
                vec![],
                vec![5, 5],
            ],
            0,
        );
        round_trip(&[vec![0; 16], vec![MAX_VALUE; 16]], MAX_VALUE);
    }

    proptest::proptest! {
        #[test]
        fn any_blocks_round_trip(
            anchor in 0..=MAX_VALUE,
            blocks in proptest::collection::vec(
                proptest::collection::vec(proptest::prop_oneof![0..=MAX_VALUE, 900u32..1100, proptest::strategy::Just(0u32)], 0..=16), 0..6)
        ) {
            round_trip(&blocks, anchor);
        }
    }
}
