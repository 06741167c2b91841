//! Splitting a byte stream into SLCAN lines, sans-IO, in a fixed buffer.
//!
//! Lines end at CR. LF is ignored anywhere (some terminals send CR LF). A BEL is reported
//! by itself, at once (an adapter's error answer has no CR). A line longer than
//! [`LINE_MAX`] is dropped up to its CR and reported as [`Error::LineTooLong`]. Any
//! chunking of the same bytes gives the same lines.

use crate::{Error, BEL, CR, LINE_MAX};

/// Longest line text, without its CR.
const TEXT_MAX: usize = LINE_MAX - 1;

/// What [`LineBuffer::feed`] found.
#[derive(Debug, PartialEq, Eq)]
pub enum Line<'a> {
    /// A complete line, without its CR.
    Text(&'a [u8]),
    /// A BEL.
    Bell,
    /// A line that was too long (dropped).
    Error(Error),
}

/// Collects the bytes of one line.
#[derive(Debug, Clone)]
pub struct LineBuffer {
    buf: [u8; LINE_MAX],
    len: usize,
    overflow: bool,
    /// Set after a line was handed out: the next feed starts a new line.
    done: bool,
}

impl Default for LineBuffer {
    fn default() -> Self {
        Self::new()
    }
}

impl LineBuffer {
    /// An empty buffer.
    pub const fn new() -> Self {
        Self {
            buf: [0; LINE_MAX],
            len: 0,
            overflow: false,
            done: false,
        }
    }

    /// Takes bytes until a line ends; returns how many were used and the line, if one
    /// ended. Call again with the rest. Work is linear in the bytes used.
    pub fn feed(&mut self, bytes: &[u8]) -> (usize, Option<Line<'_>>) {
        if self.done {
            self.len = 0;
            self.overflow = false;
            self.done = false;
        }
        // `used` counts the bytes taken so far, this one included.
        for (used, &b) in (1usize..).zip(bytes) {
            match b {
                CR => {
                    self.done = true;
                    if self.overflow {
                        return (used, Some(Line::Error(Error::LineTooLong)));
                    }
                    let line = self.buf.get(..self.len).unwrap_or(&[]);
                    return (used, Some(Line::Text(line)));
                }
                BEL => return (used, Some(Line::Bell)),
                b'\n' => {}
                _ => match self.buf.get_mut(self.len) {
                    // One byte stays free for the CR, so a line is at most LINE_MAX - 1.
                    Some(slot) if self.len < TEXT_MAX => {
                        *slot = b;
                        // `len < TEXT_MAX`, so this never saturates.
                        self.len = self.len.saturating_add(1);
                    }
                    _ => self.overflow = true,
                },
            }
        }
        (bytes.len(), None)
    }

    /// Bytes of the unfinished line so far.
    pub fn pending(&self) -> usize {
        if self.done {
            0
        } else {
            self.len
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(chunks: &[&[u8]]) -> Vec<Result<Vec<u8>, Option<Error>>> {
        let mut lb = LineBuffer::new();
        let mut out = Vec::new();
        for chunk in chunks {
            let mut rest = *chunk;
            while !rest.is_empty() {
                let (used, line) = lb.feed(rest);
                match line {
                    Some(Line::Text(t)) => out.push(Ok(t.to_vec())),
                    Some(Line::Bell) => out.push(Err(None)),
                    Some(Line::Error(e)) => out.push(Err(Some(e))),
                    None => {}
                }
                rest = &rest[used..];
            }
        }
        out
    }

    #[test]
    fn splits_lines_whatever_the_chunks() {
        let stream: &[u8] = b"S8\rO\r\nt1230\r\x07z\r\r";
        let want = vec![
            Ok(b"S8".to_vec()),
            Ok(b"O".to_vec()),
            Ok(b"t1230".to_vec()),
            Err(None),
            Ok(b"z".to_vec()),
            Ok(b"".to_vec()),
        ];
        assert_eq!(lines(&[stream]), want);
        let bytes: Vec<&[u8]> = stream.chunks(1).collect();
        assert_eq!(lines(&bytes), want);
        assert_eq!(lines(&[&stream[..3], &stream[3..9], &stream[9..]]), want);
    }

    #[test]
    fn long_lines_are_dropped_and_reported() {
        let mut long = vec![b't'; LINE_MAX];
        long.push(b'\r');
        long.extend_from_slice(b"O\r");
        let got = lines(&[&long]);
        assert_eq!(got, vec![Err(Some(Error::LineTooLong)), Ok(b"O".to_vec())]);
        // LINE_MAX - 1 chars + CR is the longest accepted line.
        let mut ok = vec![b'B'; LINE_MAX - 1];
        ok.push(b'\r');
        assert_eq!(lines(&[&ok]), vec![Ok(vec![b'B'; LINE_MAX - 1])]);
    }

    #[test]
    fn pending_counts_the_open_line() {
        let mut lb = LineBuffer::new();
        assert_eq!(lb.feed(b"t12"), (3, None));
        assert_eq!(lb.pending(), 3);
        assert!(matches!(lb.feed(b"3\r"), (2, Some(Line::Text(b"t123")))));
        assert_eq!(lb.pending(), 0);
    }
}
