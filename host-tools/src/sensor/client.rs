//! A SCIP client: requests out, whole decoded responses in, over any [`Link`].
//!
//! Responses are decoded with the `scip` streaming decoder; a damaged response comes
//! back with its errors (never as data). Every wait has a deadline, so nothing hangs.

use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use scip::{Command, Decoder, Event, IndexedReading, Request, SensorParams, Status, REQUEST_MAX};

use super::link::{self, Link};
use super::spec::SensorSpec;

/// One response as received.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Response {
    /// The echo line.
    pub echo: Vec<u8>,
    /// The echo parsed, `None` when it is not a known command.
    pub request: Option<Request>,
    /// The status, `None` when the response broke before it.
    pub status: Option<Status>,
    /// VV/PP/II fields in order.
    pub fields: Vec<(String, String)>,
    /// Scan timestamp or TM1 time, ms.
    pub timestamp: Option<u32>,
    /// Every reading (all echoes) of a measurement.
    pub readings: Vec<IndexedReading>,
    /// Other payload lines (`%ST`).
    pub payload: Vec<Vec<u8>>,
    /// Decode errors; non-empty means damaged.
    pub errors: Vec<scip::Error>,
}

impl Response {
    /// True when every line of the response checked out.
    pub fn is_intact(&self) -> bool {
        self.errors.is_empty() && self.status.is_some()
    }

    /// The status as text (`"00"`, `"E"`), `"--"` when missing.
    pub fn status_str(&self) -> &str {
        self.status.as_ref().map_or("--", |s| s.as_str())
    }

    /// The echo as text.
    pub fn echo_str(&self) -> String {
        String::from_utf8_lossy(&self.echo).into_owned()
    }

    /// The value of field `name`.
    pub fn field(&self, name: &str) -> Option<&str> {
        self.fields
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }
}

/// A client on a link.
pub struct Client {
    link: Box<dyn Link>,
    dec: Decoder,
    buf: Vec<u8>,
    pos: usize,
    current: Option<Response>,
    bytes_seen: u64,
    /// How long to wait for an answer.
    pub timeout: Duration,
    /// What the client noticed and did on its own (SCIP 1.1 switched, a stream stopped).
    pub notes: Vec<String>,
}

impl core::fmt::Debug for Client {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Client({})", self.link.describe())
    }
}

fn line_of(req: &Request) -> anyhow::Result<Vec<u8>> {
    let mut buf = [0u8; REQUEST_MAX];
    let n = req
        .encode(&mut buf)
        .map_err(|e| anyhow!("cannot send {req:?}: {e}"))?;
    Ok(buf.get(..n).unwrap_or(&[]).to_vec())
}

impl Client {
    /// A client on `link`.
    pub fn new(link: Box<dyn Link>, timeout: Duration) -> Self {
        Self {
            link,
            dec: Decoder::new(),
            buf: Vec::new(),
            pos: 0,
            current: None,
            bytes_seen: 0,
            timeout,
            notes: Vec::new(),
        }
    }

    /// Opens the sensor a spec names and brings it to a known state ([`Self::connect`]).
    pub fn open(spec: &SensorSpec, timeout: Duration) -> anyhow::Result<Self> {
        let link = link::open(spec, timeout)?;
        let mut c = Self::new(link, timeout);
        c.connect()?;
        Ok(c)
    }

    /// The link.
    pub fn link(&self) -> &dyn Link {
        self.link.as_ref()
    }

    /// The link, mutable.
    pub fn link_mut(&mut self) -> &mut dyn Link {
        self.link.as_mut()
    }

    /// What the decoder learned from PP.
    pub fn params(&self) -> &SensorParams {
        self.dec.params()
    }

    /// The decoder's counters.
    pub fn stats(&self) -> &scip::DecoderStats {
        self.dec.stats()
    }

    /// Sends a request.
    pub fn send(&mut self, req: &Request) -> anyhow::Result<()> {
        let line = line_of(req)?;
        self.send_raw(&line)
    }

    /// Sends raw bytes (a command line with its LF, or anything for tests).
    pub fn send_raw(&mut self, bytes: &[u8]) -> anyhow::Result<()> {
        self.link
            .send(bytes)
            .with_context(|| format!("writing to {}", self.link.describe()))
    }

    /// The next whole response within `timeout`, `None` when none completed in time.
    pub fn next_response(&mut self, timeout: Duration) -> anyhow::Result<Option<Response>> {
        let deadline = Instant::now() + timeout;
        let mut chunk = [0u8; 4096];
        loop {
            while self.pos < self.buf.len() {
                if let Some(r) = self.feed_one() {
                    return Ok(Some(r));
                }
            }
            self.buf.clear();
            self.pos = 0;
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            let n = self
                .link
                .recv(&mut chunk, deadline - now)
                .with_context(|| format!("reading from {}", self.link.describe()))?;
            self.bytes_seen += n as u64;
            self.buf.extend_from_slice(chunk.get(..n).unwrap_or(&[]));
        }
    }

    /// Feeds the decoder up to one event; returns a response when one is complete.
    fn feed_one(&mut self) -> Option<Response> {
        let input = self.buf.get(self.pos..).unwrap_or(&[]);
        let (used, ev) = self.dec.feed(input);
        self.pos += used;
        let mut done = false;
        if let Some(ev) = ev {
            let cur = self.current.get_or_insert_with(Response::default);
            match ev {
                Event::Start { echo, request } => {
                    *cur = Response {
                        echo: echo.to_vec(),
                        request,
                        ..Response::default()
                    };
                }
                Event::Status(s) => cur.status = Some(s),
                Event::Field(f) => cur.fields.push((
                    String::from_utf8_lossy(f.name).into_owned(),
                    String::from_utf8_lossy(f.value).into_owned(),
                )),
                Event::Timestamp(t) => cur.timestamp = Some(t),
                Event::Data(line) => cur.readings.extend(line.indexed()),
                Event::Payload(p) => cur.payload.push(p.to_vec()),
                Event::End(_) => done = true,
                Event::Error(e) => cur.errors.push(e),
            }
        }
        let damaged_over = self.dec.between_responses()
            && self.current.as_ref().is_some_and(|c| !c.errors.is_empty());
        if done || damaged_over {
            self.current.take()
        } else {
            None
        }
    }

    /// Sends `req` and waits for its answer (responses to anything else, such as the
    /// frames of a stream, are passed over). `extra` lengthens the wait (e.g. a scan).
    pub fn command_within(&mut self, req: &Request, extra: Duration) -> anyhow::Result<Response> {
        let line = line_of(req)?;
        self.send_raw(&line)?;
        let echo = line.get(..line.len().saturating_sub(1)).unwrap_or(&[]);
        let deadline = Instant::now() + self.timeout + extra;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.next_response(left)? {
                Some(r) if r.echo == echo => return Ok(r),
                Some(_) => {}
                None => bail!(
                    "no answer to {} from {} within {:?}",
                    String::from_utf8_lossy(echo),
                    self.link.describe(),
                    self.timeout + extra
                ),
            }
        }
    }

    /// Sends `req` and waits for its answer.
    pub fn command(&mut self, req: &Request) -> anyhow::Result<Response> {
        self.command_within(req, Duration::ZERO)
    }

    /// Brings the sensor to a known state: flushes the line, stops a stream a previous
    /// session left running (QT), and switches a SCIP 1.1 sensor to SCIP 2.0. Errors say
    /// what was seen: nothing (sensor off, wrong port), garbage (wrong bit rate), a
    /// closed connection (busy with another client).
    pub fn connect(&mut self) -> anyhow::Result<()> {
        let desc = self.link.describe();
        let busy = |e: anyhow::Error| -> anyhow::Error {
            let eof = e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>().is_some_and(|io| {
                    use std::io::ErrorKind as K;
                    matches!(
                        io.kind(),
                        K::UnexpectedEof
                            | K::BrokenPipe
                            | K::ConnectionReset
                            | K::ConnectionAborted
                    )
                })
            });
            if eof {
                anyhow!("{desc} closed the connection at once: sensor busy with another client?")
            } else {
                e
            }
        };
        self.send_raw(b"\nQT\n").map_err(busy)?;
        let deadline = Instant::now() + self.timeout;
        let mut frames = 0;
        let qt = loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.next_response(left).map_err(busy)? {
                Some(r) if r.echo == b"QT" => break r,
                Some(r) if r.status.is_some_and(|s| s == Status::STREAM) => frames += 1,
                Some(_) => {}
                None if self.bytes_seen == 0 => {
                    let hint = match self.link.bit_rate() {
                        Some(rate) => format!(
                            " (at {rate} bit/s: sensor off, wrong device, or wrong bit rate?)"
                        ),
                        None => String::new(),
                    };
                    bail!("no answer from {desc} within {:?}{hint}", self.timeout);
                }
                None => bail!(
                    "{desc} sent {} bytes but no SCIP response within {:?}: wrong bit rate, or not a SCIP sensor?",
                    self.bytes_seen,
                    self.timeout
                ),
            }
        };
        if frames > 0 {
            self.notes.push(format!(
                "sensor was busy streaming ({frames} frames seen); stopped it with QT"
            ));
        }
        if matches!(qt.status, Some(Status::Scip11(_))) {
            let r = self.command(&Request::new(Command::Scip20))?;
            match r.status {
                Some(Status::Scip11(b'0')) => self
                    .notes
                    .push("SCIP 1.1 found; switched the sensor to SCIP 2.0".into()),
                other => bail!("SCIP 1.1 sensor refused SCIP2.0 (status {other:?})"),
            }
        }
        Ok(())
    }

    /// Sets the bit rate with SS, then the host side's (serial links).
    pub fn set_bit_rate(&mut self, rate: u32) -> anyhow::Result<Response> {
        let r = self.command(&Request::new(Command::BitRate(rate)))?;
        if r.status == Some(Status::OK) {
            std::thread::sleep(Duration::from_millis(20));
            self.link.set_bit_rate(rate)?;
        }
        Ok(r)
    }
}
