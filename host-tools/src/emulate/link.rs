//! The host end of the board's SLCAN port (UART1) over TCP: commands out; replies,
//! frames and the board's diagnostics line in.

use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use slcan::{Command, Reply};

/// One line from the SLCAN port, with the time it arrived.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Incoming {
    /// An SLCAN reply or frame.
    Reply(Reply),
    /// BEL: the last command failed.
    Bell,
    /// The board's `?` diagnostics line (without the `?`).
    Diagnostics(String),
    /// A line that is not SLCAN.
    Garbage(Vec<u8>),
}

/// The host end of an SLCAN port over TCP: commands out, replies and frames in.
#[derive(Debug)]
pub struct SlcanLink {
    stream: TcpStream,
    line: Vec<u8>,
    buf: Vec<u8>,
    pos: usize,
    queue: VecDeque<Incoming>,
}

impl SlcanLink {
    /// Wraps a connected stream.
    pub fn new(stream: TcpStream) -> io::Result<Self> {
        stream.set_nodelay(true)?;
        Ok(Self {
            stream,
            line: Vec::new(),
            buf: Vec::new(),
            pos: 0,
            queue: VecDeque::new(),
        })
    }

    /// Sends one command.
    pub fn send(&mut self, cmd: &Command) -> anyhow::Result<()> {
        let mut line = [0u8; slcan::LINE_MAX];
        let n = cmd.emit(&mut line).map_err(|e| anyhow!("{e}"))?;
        self.send_raw(line.get(..n).unwrap_or_default())
    }

    /// Sends bytes as they are (e.g. the board's `?\r`).
    pub fn send_raw(&mut self, bytes: &[u8]) -> anyhow::Result<()> {
        self.stream
            .write_all(bytes)
            .context("writing to the SLCAN port")
    }

    /// The next line, waiting at most `timeout`; `Ok(None)` on time-out. An error when
    /// the port closed.
    pub fn recv(&mut self, timeout: Duration) -> anyhow::Result<Option<Incoming>> {
        let until = Instant::now() + timeout;
        loop {
            if let Some(i) = self.queue.pop_front() {
                return Ok(Some(i));
            }
            // Lines from what was read before. (Not `slcan::LineBuffer`: the board's
            // diagnostics line is longer than an SLCAN line may be.)
            while let Some(rest) = self.buf.get(self.pos..) {
                let Some(end) = rest.iter().position(|&b| b == slcan::CR || b == slcan::BEL) else {
                    self.line.extend(rest.iter().filter(|&&b| b != b'\n'));
                    self.pos = self.buf.len();
                    break;
                };
                self.line
                    .extend(rest.iter().take(end).filter(|&&b| b != b'\n'));
                let bell = rest.get(end) == Some(&slcan::BEL);
                self.pos += end + 1;
                let text = std::mem::take(&mut self.line);
                if bell {
                    // An error answer has no CR; any text before it is a broken line.
                    if !text.is_empty() {
                        self.queue.push_back(Incoming::Garbage(text));
                    }
                    self.queue.push_back(Incoming::Bell);
                    continue;
                }
                self.queue.push_back(match text.split_first() {
                    Some((b'?', diag)) => {
                        Incoming::Diagnostics(String::from_utf8_lossy(diag).into_owned())
                    }
                    _ => match Reply::parse(&text) {
                        Ok(r) => Incoming::Reply(r),
                        Err(_) => Incoming::Garbage(text),
                    },
                });
            }
            if let Some(i) = self.queue.pop_front() {
                return Ok(Some(i));
            }
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.stream
                .set_read_timeout(Some(left.max(Duration::from_millis(1))))?;
            self.buf.resize(1 << 16, 0);
            match self.stream.read(&mut self.buf) {
                Ok(0) => bail!("the SLCAN port closed (QEMU stopped)"),
                Ok(n) => {
                    self.buf.truncate(n);
                    self.pos = 0;
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                    ) =>
                {
                    self.buf.truncate(0);
                    self.pos = 0;
                }
                Err(e) => return Err(e).context("reading the SLCAN port"),
            }
        }
    }

    /// Sends `?` and waits for the board's diagnostics; other lines that arrive
    /// meanwhile are handed to `other`.
    pub fn diagnostics(
        &mut self,
        timeout: Duration,
        other: &mut dyn FnMut(Incoming),
    ) -> anyhow::Result<Diagnostics> {
        self.send_raw(b"?\r")?;
        let until = Instant::now() + timeout;
        while let Some(left) = until.checked_duration_since(Instant::now()) {
            match self.recv(left)? {
                Some(Incoming::Diagnostics(text)) => return Ok(Diagnostics::parse(&text)),
                Some(i) => other(i),
                None => break,
            }
        }
        bail!("no diagnostics from the board")
    }
}

/// The board's `?` line: `key=value` pairs (see the firmware's `main.rs`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Diagnostics(pub Vec<(String, String)>);

impl Diagnostics {
    /// Parses `key=value key=value ...`.
    pub fn parse(text: &str) -> Self {
        Diagnostics(
            text.split_whitespace()
                .filter_map(|kv| kv.split_once('='))
                .map(|(k, v)| (k.to_owned(), v.to_owned()))
                .collect(),
        )
    }

    /// A numeric value.
    pub fn get(&self, key: &str) -> Option<u64> {
        self.0
            .iter()
            .find(|(k, _)| k == key)
            .and_then(|(_, v)| v.parse().ok())
    }
}
