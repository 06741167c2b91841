//! One text line per SCIP response, from the decoder's events.
//!
//! ```text
//! resp echo=ME0000108001100 status=99 lines=105 values=1081 ranges=1052 codes=29 ts=5240063 ok
//! error kind=bad_sum line=7 offset=1047
//! end bytes=7814 responses=11 errors=0 resyncs=0 overruns=0 uptime_ms=366
//! ```

use embedded_io::Write;
use scip::{Event, Range};

/// Longest echo kept for the summary line (longer echoes are cut).
const ECHO_CAP: usize = 32;

/// Collects what one response needs for its summary line.
pub struct Summariser {
    echo: [u8; ECHO_CAP],
    echo_len: usize,
    ranges: u32,
    codes: u32,
}

impl Summariser {
    /// An empty summariser.
    pub const fn new() -> Self {
        Self {
            echo: [0; ECHO_CAP],
            echo_len: 0,
            ranges: 0,
            codes: 0,
        }
    }

    /// Takes one event; writes a line to `out` when a response ends or an
    /// error is reported. Output errors are ignored: the summary is a
    /// diagnostic, and the board's UART cannot fail on write.
    pub fn event(&mut self, ev: &Event<'_>, out: &mut impl Write) {
        match ev {
            Event::Start { echo, .. } => {
                self.echo_len = 0;
                for (slot, &b) in self.echo.iter_mut().zip(echo.iter()) {
                    // Keep the line printable whatever the sensor sent.
                    *slot = if b.is_ascii_graphic() { b } else { b'?' };
                    self.echo_len += 1;
                }
                self.ranges = 0;
                self.codes = 0;
            }
            Event::Data(line) => {
                for r in line.indexed().filter(|r| r.echo == 0) {
                    match line.range(&r.reading()) {
                        Range::Mm(_) => self.ranges += 1,
                        Range::Error(_) => self.codes += 1,
                    }
                }
            }
            Event::End(s) => {
                let echo = self.echo.get(..self.echo_len).unwrap_or_default();
                let echo = core::str::from_utf8(echo).unwrap_or("?");
                let _ = write!(
                    out,
                    "resp echo={} status={} lines={} values={} ranges={} codes={} ts=",
                    echo,
                    s.status.as_str(),
                    s.lines,
                    s.values,
                    self.ranges,
                    self.codes
                );
                let _ = match s.timestamp {
                    Some(ts) => write!(out, "{ts} ok\r\n"),
                    None => write!(out, "- ok\r\n"),
                };
            }
            Event::Error(e) => {
                let _ = write!(
                    out,
                    "error kind={} line={} offset={}\r\n",
                    e.kind.name(),
                    e.line,
                    e.offset
                );
            }
            _ => {}
        }
    }
}
