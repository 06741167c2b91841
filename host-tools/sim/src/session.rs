//! The sensor itself, sans-IO: command bytes and the current time go in, response
//! bytes come out when they are due.
//!
//! [`Sensor::receive`] takes what the host sent, [`Sensor::poll`] produces stream frames
//! that are due, [`Sensor::take_output`] hands out the bytes whose time has come and
//! [`Sensor::next_wakeup`] tells when to call again. Time is µs of sensor time since
//! power-on, given by the caller: a virtual clock in tests, the real one in transports.
//!
//! Behaviour (scip-reference §2, §4):
//! - Commands end at `LF` or `CR` (`CR LF` too); empty lines are ignored.
//! - The motor turns all the time: scan `k` runs from `k × period` (the period comes
//!   from the `SCAN` rpm). A G* answer leaves when the scan being measured ends; an M*
//!   ack leaves at once and its frames leave as each later scan ends, every
//!   `skip + 1` scans, with the echo's count = scans still to come (`00` for endless).
//!   After the last frame of a counted request the laser goes off. QT, RS, RT and `%SL`
//!   stop a stream; other commands are answered in between.
//! - The timestamp of a scan is the 24-bit ms clock at the scan's start; the clock wraps
//!   and RS sets it to 0. TM0 enters adjust mode (02 if already), TM1 reads the clock
//!   0 to [`TM_LATENCY_US`] after the request and answers then (04 outside adjust
//!   mode), TM2 leaves (03 if already out).
//! - Statuses of bad commands: see [`Sensor::malformed_status`] and the checks in the
//!   command handlers below.
//! - SCIP 2.2 `RB`: `01` first; a second `RB` within a second is answered `00` and the
//!   sensor reboots (SCIP 2.0 models answer `0E`).
//! - Paced ([`Sensor::set_paced`], serial links): output leaves at the bit rate through
//!   a [`TX_CAP`]-byte transmit buffer; frames that do not fit are skipped, and QT drops
//!   the frames not yet begun. Unpaced, everything is due when made (USB, Ethernet).

use std::collections::VecDeque;

use scip::{
    Command, RawRequest, Request, ResponseWriter, ScanMode, ScanRequest, TimeMode, BIT_RATES,
};

use super::faults::{FaultConfig, FaultRecord, Faults};
use super::measure::{Source, Value};
use super::model::{LinkKind, Model};

/// Longest command line kept; longer lines are answered from their first bytes.
const LINE_MAX: usize = 64;
/// Time a reboot takes, µs.
const BOOT_US: u64 = 500_000;
/// The transmit buffer of a paced sensor, bytes: a stream frame that does not fit
/// behind what is still waiting is skipped (a frame larger than the whole buffer is
/// taken only when the buffer is empty).
pub const TX_CAP: usize = 4096;
/// Bytes a paced sensor hands to its UART at once (its FIFO).
const TX_FIFO: u64 = 32;
/// SCIP 2.2 `RB`: the second `RB` must follow the first within this time, µs.
const RB_WINDOW_US: u64 = 1_000_000;
/// A `TM1` is taken by the sensor's main loop up to this long after it arrived, µs
/// (uniform, drawn per request): the sensor reads its clock then and answers at once.
/// Without it the simulator answered in the instant of the request, so that on a link
/// without byte times (TCP, the in-process link) a calibration's 24 readings fell
/// within a few µs of each other, at one phase of the sensor's millisecond.
pub const TM_LATENCY_US: u64 = 500;

/// The sensor's oscillator against the caller's clock.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClockModel {
    /// Drift, parts per billion (positive: the sensor's clock runs fast).
    pub drift_ppb: i64,
    /// Sub-millisecond phase of the oscillator at time 0, µs (where its ms ticks fall).
    pub phase_us: u64,
    /// Each stream frame leaves up to this many µs late (uniform, drawn per frame):
    /// the output jitter of the sensor's data path.
    pub jitter_us: u64,
    /// Seed of the jitter draws.
    pub seed: u64,
}

/// What the sensor meant to send for one scan, before any fault: the ground truth a
/// receiver's output is judged against.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScanTruth {
    /// Scan number of the sensor's scan clock.
    pub scan: u64,
    /// The request as echoed (for a stream frame: the count = scans remaining).
    pub request: ScanRequest,
    /// The status sent (`99` for stream frames, `00` for G* answers).
    pub status: [u8; 2],
    /// The scan's timestamp, 24-bit ms.
    pub timestamp: u32,
    /// When the scan's first requested step was measured, µs of the caller's clock
    /// (the simulation's true time; the timestamp is the sensor's clock at step 0).
    pub first_step_us: u64,
    /// Per value (step or cluster), its first echo: (distance or error code, second
    /// value; 0 without one).
    pub values: Vec<Value>,
    /// Extra echoes of multi-echo scans: (value index, echo number 1.., value).
    pub extra: Vec<(u16, u8, Value)>,
}

/// An M*/N* stream in progress.
#[derive(Debug, Clone, Copy)]
struct Stream {
    request: Request,
    scan: ScanRequest,
    /// Frames still to send; `None` = until stopped.
    remaining: Option<u8>,
    /// Scan number of the next frame.
    next_scan: u64,
}

/// Something to do once a response has left.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum After {
    /// The bit rate changes (SS, RS).
    BitRate(u32),
}

#[derive(Debug)]
struct Pending {
    at: u64,
    bytes: Vec<u8>,
    /// Bytes of it already on the wire.
    sent: usize,
    /// A stream frame (dropped on QT while none of it has left).
    frame: bool,
    after: Option<After>,
}

/// A simulated sensor.
pub struct Sensor {
    model: Model,
    source: Box<dyn Source>,
    faults: Faults,
    clock_start_ms: u32,
    boots_scip11: bool,
    // State.
    scip2: bool,
    laser: bool,
    sleeping: bool,
    adjust: bool,
    high_sensitivity: bool,
    bit_rate: Option<u32>,
    speed_step: u8,
    rpm: u32,
    timer_offset_ms: i64,
    clock_model: ClockModel,
    /// State of the jitter draws.
    jitter_rng: u64,
    /// State of the `TM1` latency draws.
    tm_rng: u64,
    epoch_us: u64,
    epoch_scan: u64,
    stream: Option<Stream>,
    booting_until: u64,
    /// When the first `RB` of a pair was answered (SCIP 2.2).
    reboot_armed_at: Option<u64>,
    /// Reboots on request since the last [`Sensor::take_rebooted`].
    rebooted: bool,
    line: Vec<u8>,
    queue: VecDeque<Pending>,
    /// Output leaves at the bit rate through a bounded buffer ([`Sensor::set_paced`]).
    paced: bool,
    /// When the wire is done with the bytes handed out so far, ns.
    wire_free_ns: u64,
    /// Stream frames skipped for want of room in the transmit buffer.
    skipped_frames: u64,
    responses: u64,
    frames: u64,
    values: Vec<Value>,
    faults_seen: usize,
    /// Ground truth of the scans written, when asked for ([`Sensor::record_truth`]).
    truth: Option<Vec<ScanTruth>>,
}

impl core::fmt::Debug for Sensor {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Sensor")
            .field("model", &self.model.kind)
            .field("scip2", &self.scip2)
            .field("laser", &self.laser)
            .field("responses", &self.responses)
            .finish_non_exhaustive()
    }
}

impl Sensor {
    /// A sensor powered on at time 0 with its clock at `clock_start_ms`, speaking SCIP
    /// 1.1 first when `boots_scip11` (the URG-04LX factory setting).
    pub fn new(
        model: Model,
        source: Box<dyn Source>,
        faults: FaultConfig,
        clock_start_ms: u32,
        boots_scip11: bool,
    ) -> Self {
        let rpm = model.scan_rpm;
        let mut s = Self {
            bit_rate: model.default_bit_rate(),
            model,
            source,
            faults: Faults::new(faults),
            clock_start_ms,
            boots_scip11,
            scip2: !boots_scip11,
            laser: false,
            sleeping: false,
            adjust: false,
            high_sensitivity: false,
            speed_step: 0,
            rpm,
            timer_offset_ms: i64::from(clock_start_ms),
            clock_model: ClockModel::default(),
            jitter_rng: 0,
            tm_rng: 0x5DEE_CE66_D1CE_5EED,
            epoch_us: 0,
            epoch_scan: 0,
            stream: None,
            booting_until: 0,
            reboot_armed_at: None,
            rebooted: false,
            line: Vec::new(),
            queue: VecDeque::new(),
            paced: false,
            wire_free_ns: 0,
            skipped_frames: 0,
            responses: 0,
            frames: 0,
            values: Vec::new(),
            faults_seen: 0,
            truth: None,
        };
        s.power_on(0, false);
        s.timer_offset_ms = i64::from(clock_start_ms);
        s
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Every fault injected so far.
    pub fn fault_log(&self) -> &[FaultRecord] {
        self.faults.log()
    }

    /// The faults injected since the last call (for a live log).
    pub fn new_faults(&mut self) -> &[FaultRecord] {
        let log = self.faults.log();
        let new = log.get(self.faults_seen..).unwrap_or(&[]);
        self.faults_seen = log.len();
        new
    }

    /// Makes output leave as it does on a serial line (models with a bit rate): no
    /// faster than the bit rate (10 bits a byte, handed out 32 bytes at a time), through
    /// a transmit buffer of [`TX_CAP`] bytes. A stream frame that does not fit is skipped
    /// (its scan is not sent; the remaining count of a counted stream does not drop), and
    /// QT, RS, RT and `%SL` drop the frames not yet begun, so that their answer follows
    /// at most the frame on the wire. Off (the default), output is due as soon as it is
    /// made, as on USB and Ethernet.
    pub fn set_paced(&mut self, on: bool) {
        self.paced = on;
    }

    /// Bytes made but not yet on the wire.
    pub fn tx_backlog(&self) -> usize {
        self.queue
            .iter()
            .map(|p| p.bytes.len().saturating_sub(p.sent))
            .sum()
    }

    /// Stream frames skipped for want of room in the transmit buffer.
    pub fn skipped_frames(&self) -> u64 {
        self.skipped_frames
    }

    /// ns a byte takes on the wire, when output is paced.
    fn byte_ns(&self) -> Option<u64> {
        let rate = self.bit_rate.filter(|_| self.paced)?;
        Some(10_000_000_000 / u64::from(rate.max(1)))
    }

    /// Drops the stream frames none of whose bytes has left (paced output only).
    fn drop_unsent_frames(&mut self) {
        if self.byte_ns().is_some() {
            self.queue.retain(|p| !p.frame || p.sent > 0);
        }
    }

    /// Starts (or stops) keeping the ground truth of every scan written, for
    /// [`Sensor::take_truth`].
    pub fn record_truth(&mut self, on: bool) {
        self.truth = on.then(Vec::new);
    }

    /// The ground truth of the scans written since the last call, oldest first.
    pub fn take_truth(&mut self) -> Vec<ScanTruth> {
        self.truth.as_mut().map(core::mem::take).unwrap_or_default()
    }

    /// Replaces the line noise from now on (e.g. after a clean start-up exchange).
    pub fn set_line_noise(&mut self, noise: super::faults::LineNoise) {
        self.faults.set_line_noise(noise);
    }

    /// What line noise did so far.
    pub fn line_noise_stats(&self) -> super::faults::LineNoiseStats {
        *self.faults.line_stats()
    }

    /// The current bit rate (serial and USB models), changed by SS after its answer.
    pub fn bit_rate(&self) -> Option<u32> {
        self.bit_rate
    }

    /// True while the sensor speaks SCIP 2.x.
    pub fn is_scip2(&self) -> bool {
        self.scip2
    }

    /// True while a stream is running.
    pub fn is_streaming(&self) -> bool {
        self.stream.is_some()
    }

    /// The scan period in µs at the current motor speed.
    pub fn scan_period_us(&self) -> u64 {
        Model::scan_period_us(self.rpm)
    }

    /// Sets the sensor's oscillator ([`ClockModel`]); the clock keeps its reading
    /// at time 0.
    pub fn set_clock_model(&mut self, model: ClockModel) {
        self.clock_model = model;
        self.jitter_rng = model.seed;
        self.tm_rng = model.seed ^ 0x5DEE_CE66_D1CE_5EED;
    }

    /// The sensor's free-running oscillator at `now` µs of the caller's clock, µs:
    /// `now × (1 + drift) + phase`.
    pub fn oscillator_us(&self, now: u64) -> i64 {
        let now = i128::from(now);
        let drift = now * i128::from(self.clock_model.drift_ppb) / 1_000_000_000;
        i64::try_from(now + drift + i128::from(self.clock_model.phase_us)).unwrap_or(i64::MAX)
    }

    /// The 24-bit ms clock at `now` µs.
    pub fn clock_ms(&self, now: u64) -> u32 {
        let ms = self.oscillator_us(now).div_euclid(1000);
        ms.wrapping_add(self.timer_offset_ms).rem_euclid(1 << 24) as u32
    }

    /// The clock's offset for it to read 0 at `now` (a reboot, `RS`).
    fn zero_offset(&self, now: u64) -> i64 {
        -self.oscillator_us(now).div_euclid(1000)
    }

    /// A draw of the output jitter, µs.
    fn jitter(&mut self) -> u64 {
        if self.clock_model.jitter_us == 0 {
            return 0;
        }
        self.jitter_rng = self
            .jitter_rng
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.jitter_rng >> 33) % (self.clock_model.jitter_us + 1)
    }

    /// A draw of the `TM1` latency, µs (0..=[`TM_LATENCY_US`]).
    fn tm_latency(&mut self) -> u64 {
        self.tm_rng = self
            .tm_rng
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.tm_rng >> 33) % (TM_LATENCY_US + 1)
    }

    /// The host closed the connection: a stream stops (laser stays as it is).
    pub fn disconnect(&mut self) {
        self.stream = None;
        self.line.clear();
    }

    fn power_on(&mut self, now: u64, reboot: bool) {
        self.scip2 = !self.boots_scip11;
        self.laser = false;
        self.sleeping = false;
        self.adjust = false;
        self.high_sensitivity = false;
        self.stream = None;
        self.line.clear();
        self.reboot_armed_at = None;
        self.speed_step = 0;
        self.set_rpm(now, self.model.scan_rpm);
        self.bit_rate = self.model.default_bit_rate();
        if reboot {
            self.timer_offset_ms = self.zero_offset(now);
            self.booting_until = now + BOOT_US;
        } else {
            self.timer_offset_ms = i64::from(self.clock_start_ms);
        }
    }

    fn set_rpm(&mut self, now: u64, rpm: u32) {
        // The new speed holds from the next scan boundary on.
        let next = self.scan_at(now) + 1;
        let boundary = self.scan_start(next);
        self.epoch_scan = next;
        self.epoch_us = boundary;
        self.rpm = rpm;
    }

    /// The scan being measured at `t`.
    fn scan_at(&self, t: u64) -> u64 {
        if t < self.epoch_us {
            return self.epoch_scan.saturating_sub(1);
        }
        self.epoch_scan + (t - self.epoch_us) / self.scan_period_us()
    }

    /// When scan `k` starts.
    fn scan_start(&self, k: u64) -> u64 {
        let p = self.scan_period_us();
        if k >= self.epoch_scan {
            self.epoch_us + (k - self.epoch_scan) * p
        } else {
            self.epoch_us.saturating_sub((self.epoch_scan - k) * p)
        }
    }

    /// Takes bytes from the host at time `now`.
    pub fn receive(&mut self, now: u64, bytes: &[u8]) {
        self.poll(now);
        if now < self.booting_until {
            return;
        }
        for &b in bytes {
            if b == b'\n' || b == b'\r' {
                if !self.line.is_empty() {
                    let line = core::mem::take(&mut self.line);
                    self.command(now, &line);
                }
            } else if self.line.len() < LINE_MAX {
                self.line.push(b);
            }
        }
    }

    /// Produces the stream frames due by `now`.
    pub fn poll(&mut self, now: u64) {
        while let Some(s) = self.stream {
            let due = self.scan_start(s.next_scan) + self.scan_period_us();
            if due > now {
                break;
            }
            self.stream_frame(due, s);
        }
    }

    /// When the sensor next has something to do (a frame or a held response), µs.
    pub fn next_wakeup(&self) -> Option<u64> {
        let frame = self
            .stream
            .map(|s| self.scan_start(s.next_scan) + self.scan_period_us());
        let out = self.queue.front().map(|p| match self.byte_ns() {
            Some(_) => p.at.max(self.wire_free_ns.div_ceil(1000)),
            None => p.at,
        });
        match (frame, out) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The bytes due by `now`, in order; a held response holds back those after it.
    pub fn take_output(&mut self, now: u64) -> Vec<u8> {
        self.poll(now);
        let mut out = Vec::new();
        while self.queue.front().is_some_and(|p| p.at <= now) {
            let byte_ns = self.byte_ns();
            let Some(p) = self.queue.front_mut() else {
                break;
            };
            let left = p.bytes.len().saturating_sub(p.sent);
            let n = match byte_ns {
                None => left,
                Some(byte_ns) => {
                    // The wire takes the next bytes once it is free: those that start by
                    // now, and at least a FIFO's worth.
                    let start = self.wire_free_ns.max(p.at * 1000);
                    let now_ns = now * 1000;
                    if start > now_ns {
                        break;
                    }
                    let fit = ((now_ns - start) / byte_ns + 1).max(TX_FIFO);
                    let n = usize::try_from(fit).unwrap_or(usize::MAX).min(left);
                    self.wire_free_ns = start + n as u64 * byte_ns;
                    n
                }
            };
            out.extend_from_slice(p.bytes.get(p.sent..p.sent + n).unwrap_or(&[]));
            p.sent += n;
            if p.sent < p.bytes.len() {
                break;
            }
            if let Some(After::BitRate(r)) = p.after {
                self.bit_rate = Some(r);
            }
            self.queue.pop_front();
        }
        out
    }

    fn push(&mut self, at: u64, bytes: Vec<u8>, after: Option<After>) {
        // Responses leave in order: none before the one ahead of it.
        let at = self.queue.back().map_or(at, |p| p.at.max(at));
        let bytes = self.faults.line(bytes);
        self.queue.push_back(Pending {
            at,
            bytes,
            sent: 0,
            frame: false,
            after,
        });
        self.responses += 1;
    }

    /// A response without payload: echo, status, empty line.
    fn simple(&mut self, now: u64, echo: &[u8], status: [u8; 2]) {
        let mut buf = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| buf.extend_from_slice(b));
        w.echo_raw(echo);
        w.status(status);
        w.end();
        let _ = w.into_inner();
        self.push(now, buf, None);
    }

    fn command(&mut self, now: u64, line: &[u8]) {
        if !self.scip2 {
            // SCIP 1.1: only the switch is understood here; the rest gets a lone `E`.
            let switch = line == b"SCIP2.0";
            let mut buf = Vec::new();
            let mut w = ResponseWriter::new(|b: &[u8]| buf.extend_from_slice(b));
            w.echo_raw(line);
            w.status_scip11(if switch { b'0' } else { b'E' });
            w.end();
            let _ = w.into_inner();
            self.push(now, buf, None);
            self.scip2 = switch;
            return;
        }
        let raw = RawRequest::split(line);
        if self.model.scip22
            && raw.code == b"RB"
            && raw.params.is_empty()
            && raw.check_tag().is_ok()
        {
            return self.reboot_cmd(now, line);
        }
        if let Err(e) = raw.check_tag() {
            let status = if e == scip::EncodeError::TagTooLong {
                *b"0G"
            } else {
                *b"0H"
            };
            return self.simple(now, line, status);
        }
        match Request::parse(line) {
            Ok(req) => self.execute(now, line, req),
            Err(_) => {
                let status = self.malformed_status(&raw);
                self.simple(now, line, status);
            }
        }
    }

    /// The status for a command line that does not parse as a request.
    ///
    /// Unknown code → `0E`. Parameters too short → `0C` (`0H` on SCIP 2.2), too long →
    /// `0D`. G*/M*: start, end, cluster, skip, count not decimal → `01`, `02`, `03`,
    /// `06`, `07`. SS/CR/TM/HS with a bad value → `01`.
    pub fn malformed_status(&self, raw: &RawRequest<'_>) -> [u8; 2] {
        let short = if self.model.scip22 { *b"0H" } else { *b"0C" };
        let length = |want: usize| -> Option<[u8; 2]> {
            match raw.params.len().cmp(&want) {
                core::cmp::Ordering::Less => Some(short),
                core::cmp::Ordering::Greater => Some(*b"0D"),
                core::cmp::Ordering::Equal => None,
            }
        };
        match raw.code {
            b"VV" | b"PP" | b"II" | b"BM" | b"QT" | b"RS" | b"RT" | b"%ST" | b"%SL" => {
                length(0).unwrap_or(*b"0E")
            }
            b"SS" => length(6).unwrap_or(*b"01"),
            b"CR" => length(2).unwrap_or(*b"01"),
            b"TM" | b"HS" => length(1).unwrap_or(*b"01"),
            [first @ (b'G' | b'M' | b'H' | b'N'), letter] => {
                let multi = matches!(first, b'H' | b'N');
                let known = match letter {
                    b'D' | b'E' => true,
                    b'S' | b'R' | b'I' => !multi,
                    _ => false,
                };
                if !known {
                    return *b"0E";
                }
                let continuous = matches!(first, b'M' | b'N');
                if let Some(s) = length(if continuous { 13 } else { 10 }) {
                    return s;
                }
                let fields: &[(core::ops::Range<usize>, [u8; 2])] = &[
                    (0..4, *b"01"),
                    (4..8, *b"02"),
                    (8..10, *b"03"),
                    (10..11, *b"06"),
                    (11..13, *b"07"),
                ];
                fields
                    .iter()
                    .filter(|(r, _)| continuous || r.end <= 10)
                    .find(|(r, _)| raw.decimal_field(r.clone()).is_none())
                    .map_or(*b"0E", |(_, s)| *s)
            }
            _ => *b"0E",
        }
    }

    fn unsupported(&self) -> [u8; 2] {
        if self.model.scip22 {
            *b"0F"
        } else {
            *b"04"
        }
    }

    fn execute(&mut self, now: u64, line: &[u8], req: Request) {
        match req.command {
            Command::Scip20 => self.simple(now, line, *b"0E"),
            Command::Version => {
                let fields = self.model.version.clone();
                self.fields(now, line, &fields);
            }
            Command::Parameters => {
                let fields = self.model.parameters(self.rpm);
                self.fields(now, line, &fields);
            }
            Command::Info => {
                let fields = self.info_fields(now);
                self.fields(now, line, &fields);
            }
            Command::LaserOn => {
                let status = if self.sleeping || !self.laser {
                    *b"00"
                } else {
                    *b"02"
                };
                self.sleeping = false;
                self.laser = true;
                self.simple(now, line, status);
            }
            Command::LaserOff => {
                self.drop_unsent_frames();
                self.stream = None;
                self.laser = false;
                self.simple(now, line, *b"00");
            }
            Command::Reset | Command::PartialReset => {
                let keep = req.command == Command::PartialReset;
                let (rate, step, rpm) = (self.bit_rate, self.speed_step, self.rpm);
                self.drop_unsent_frames();
                self.simple(now, line, *b"00");
                self.stream = None;
                self.laser = false;
                self.sleeping = false;
                self.adjust = false;
                self.high_sensitivity = false;
                self.timer_offset_ms = self.zero_offset(now);
                if keep {
                    self.speed_step = step;
                    self.set_rpm(now, rpm);
                } else {
                    self.speed_step = 0;
                    self.set_rpm(now, self.model.scan_rpm);
                    if let (Some(def), Some(cur)) = (self.model.default_bit_rate(), rate) {
                        if def != cur {
                            if let Some(p) = self.queue.back_mut() {
                                p.after = Some(After::BitRate(def));
                            }
                        }
                    }
                }
            }
            Command::BitRate(rate) => self.bit_rate_cmd(now, line, rate),
            Command::MotorSpeed(step) => self.motor_cmd(now, line, step),
            Command::Time(mode) => self.time_cmd(now, line, mode),
            Command::Sensitivity(on) => {
                self.high_sensitivity = on;
                self.simple(now, line, *b"00");
            }
            Command::Scan(scan) => self.scan_cmd(now, line, req, scan),
            Command::State if self.model.scip22 => {
                let state: &[u8] = if self.sleeping {
                    b"005"
                } else if self.adjust {
                    b"002"
                } else if self.stream.is_some() {
                    b"004"
                } else {
                    b"000"
                };
                let mut buf = Vec::new();
                let mut w = ResponseWriter::new(|b: &[u8]| buf.extend_from_slice(b));
                w.echo_raw(line);
                w.status(*b"00");
                w.line(state);
                w.end();
                let _ = w.into_inner();
                self.push(now, buf, None);
            }
            Command::Sleep if self.model.scip22 => {
                self.drop_unsent_frames();
                self.stream = None;
                self.laser = false;
                self.sleeping = true;
                self.simple(now, line, *b"00");
            }
            Command::State | Command::Sleep => self.simple(now, line, *b"0E"),
        }
    }

    fn fields(&mut self, now: u64, line: &[u8], fields: &[(String, String)]) {
        let mut buf = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| buf.extend_from_slice(b));
        w.echo_raw(line);
        w.status(*b"00");
        for (name, value) in fields {
            w.field(name.as_bytes(), value.as_bytes());
        }
        w.end();
        let _ = w.into_inner();
        self.push(now, buf, None);
    }

    fn info_fields(&self, now: u64) -> Vec<(String, String)> {
        let rpm = self.rpm;
        let scsp = if self.speed_step == 0 {
            format!("Initial({rpm}[rpm])<-Default setting by user")
        } else {
            format!("Level {}({rpm}[rpm])", self.speed_step)
        };
        let sbps = match (self.model.link, self.bit_rate) {
            (LinkKind::Serial(def), Some(r)) if r == def => {
                format!("{r}[bps]<-Default setting by user")
            }
            (LinkKind::Serial(_), Some(r)) => format!("{r}[bps]"),
            (LinkKind::Serial(def), None) => format!("{def}[bps]"),
            (LinkKind::Usb, _) => "USB Full Speed".into(),
            (LinkKind::Ethernet, _) => "Ethernet 100[Mbps]".into(),
        };
        let clock = self.clock_ms(now);
        let time = if self.model.time_encoded {
            let mut t = [0u8; 4];
            let _ = scip::value::encode(clock, &mut t);
            String::from_utf8_lossy(&t).into_owned()
        } else {
            format!("{clock:06X}")
        };
        let mesm = match (self.laser, self.high_sensitivity) {
            (false, _) => "IDLE",
            (true, false) => "CLASSIC",
            (true, true) => "HIGH SENSITIVITY",
        };
        vec![
            ("MODL".into(), self.model.modl.clone()),
            ("LASR".into(), if self.laser { "ON" } else { "OFF" }.into()),
            ("SCSP".into(), scsp),
            ("MESM".into(), mesm.into()),
            ("SBPS".into(), sbps),
            ("TIME".into(), time),
            ("STAT".into(), "Sensor works well.".into()),
        ]
    }

    /// RB (SCIP 2.2): the first `RB` is answered `01` (send it again to confirm); a
    /// second one within a second is answered `00` and the sensor reboots once the
    /// answer has left. An `RB` more than a second after the first starts over.
    fn reboot_cmd(&mut self, now: u64, line: &[u8]) {
        let confirmed = self
            .reboot_armed_at
            .is_some_and(|at| now.saturating_sub(at) <= RB_WINDOW_US);
        if !confirmed {
            self.reboot_armed_at = Some(now);
            return self.simple(now, line, *b"01");
        }
        self.simple(now, line, *b"00");
        let at = self.queue.back().map_or(now, |p| p.at);
        self.power_on(at, true);
        self.rebooted = true;
    }

    /// True once after the sensor rebooted on request (`RB` twice), or an Ethernet
    /// sensor by a reboot fault: an Ethernet sensor's connection ends there.
    pub fn take_rebooted(&mut self) -> bool {
        core::mem::take(&mut self.rebooted)
    }

    /// SS: Ethernet → `0F` (SCIP 2.2) / `04`; a rate not in the list → `04`; the rate in
    /// force → `03`; else `00` and the rate changes once the answer has left.
    fn bit_rate_cmd(&mut self, now: u64, line: &[u8], rate: u32) {
        if self.model.link == LinkKind::Ethernet {
            let status = if self.model.scip22 { *b"0F" } else { *b"04" };
            return self.simple(now, line, status);
        }
        if !BIT_RATES.contains(&rate) {
            return self.simple(now, line, *b"04");
        }
        if self.bit_rate == Some(rate) {
            return self.simple(now, line, *b"03");
        }
        self.simple(now, line, *b"00");
        if let Some(p) = self.queue.back_mut() {
            p.after = Some(After::BitRate(rate));
        }
    }

    /// CR: models without speed control → `04` (`0F` on SCIP 2.2); a step not 0..=10 or
    /// 99 → `04`; the speed in force → `03`. Each step lowers the speed by 2 %.
    fn motor_cmd(&mut self, now: u64, line: &[u8], step: u8) {
        if !self.model.motor_speed {
            let status = self.unsupported();
            return self.simple(now, line, status);
        }
        if step > 10 && step != 99 {
            return self.simple(now, line, *b"04");
        }
        let step = if step == 99 { 0 } else { step };
        if step == self.speed_step {
            return self.simple(now, line, *b"03");
        }
        self.simple(now, line, *b"00");
        self.speed_step = step;
        let rpm = self.model.scan_rpm * (100 - 2 * u32::from(step)) / 100;
        self.set_rpm(now, rpm);
    }

    fn time_cmd(&mut self, now: u64, line: &[u8], mode: TimeMode) {
        match mode {
            TimeMode::Enter => {
                let status = if self.adjust { *b"02" } else { *b"00" };
                self.adjust = true;
                self.simple(now, line, status);
            }
            TimeMode::Leave => {
                let status = if self.adjust { *b"00" } else { *b"03" };
                self.adjust = false;
                self.simple(now, line, status);
            }
            TimeMode::Read if !self.adjust => self.simple(now, line, *b"04"),
            TimeMode::Read => {
                let now = now + self.tm_latency();
                let clock = self.clock_ms(now);
                let mut buf = Vec::new();
                let mut w = ResponseWriter::new(|b: &[u8]| buf.extend_from_slice(b));
                w.echo_raw(line);
                w.status(*b"00");
                w.timestamp(clock);
                w.end();
                let _ = w.into_inner();
                self.push(now, buf, None);
            }
        }
    }

    /// G*/M*: a data set the model lacks → `0E`; end (or start) above AMAX → `04`; end
    /// before start → `05`; G* with the laser off → `10`.
    fn scan_cmd(&mut self, now: u64, line: &[u8], req: Request, scan: ScanRequest) {
        let needs_intensity = scan.data.aux_width() > 0;
        if (needs_intensity && !self.model.intensity) || (scan.multi_echo && !self.model.multi_echo)
        {
            return self.simple(now, line, *b"0E");
        }
        let amax = u16::try_from(self.model.amax).unwrap_or(u16::MAX);
        if scan.end > amax || scan.start > amax {
            return self.simple(now, line, *b"04");
        }
        if scan.end < scan.start {
            return self.simple(now, line, *b"05");
        }
        match scan.mode {
            ScanMode::Single => {
                if !self.laser || self.sleeping {
                    return self.simple(now, line, *b"10");
                }
                // The scan under way is sent when it ends.
                let k = self.scan_at(now);
                let at = self.scan_start(k) + self.scan_period_us();
                let mut buf = Vec::new();
                self.write_scan(&mut buf, &req, &scan, *b"00", k);
                let response = self.responses;
                self.faults.damage(&mut buf, at, response, k);
                let stall = self.faults.stall(at, response, k);
                self.push(at + stall, buf, None);
            }
            ScanMode::Continuous => {
                self.laser = true;
                self.sleeping = false;
                self.simple(now, line, *b"00");
                let next_scan = self.scan_at(now) + 1;
                self.stream = Some(Stream {
                    request: req,
                    scan,
                    remaining: (scan.count > 0).then_some(scan.count),
                    next_scan,
                });
            }
        }
    }

    fn stream_frame(&mut self, due: u64, mut s: Stream) {
        let k = s.next_scan;
        let remaining = s.remaining.map(|r| r.saturating_sub(1));
        let mut echo = s.scan;
        echo.count = remaining.unwrap_or(0);
        let request = Request {
            command: Command::Scan(echo),
            tag: s.request.tag,
        };
        let response = self.responses;
        let mut buf = Vec::new();
        let stream_status = *b"99";
        if let Some(status) = self.faults.hardware_fault(due, response, k) {
            let mut w = ResponseWriter::new(|b: &[u8]| buf.extend_from_slice(b));
            w.echo(&request);
            w.status(status);
            w.end();
        } else {
            self.write_scan(&mut buf, &request, &echo, stream_status, k);
            self.faults.damage(&mut buf, due, response, k);
        }
        let backlog = self.tx_backlog();
        if self.byte_ns().is_some() && backlog > 0 && backlog + buf.len() > TX_CAP {
            // No room: this scan is not sent (and was not sent, as far as its truth goes).
            self.skipped_frames += 1;
            if let Some(t) = self.truth.as_mut() {
                t.retain(|t| t.scan != k);
            }
            s.next_scan = k + 1 + u64::from(s.scan.skip);
            self.stream = Some(s);
            return;
        }
        let frame = self.frames;
        self.frames += 1;
        let stall = self.faults.stall(due, response, k) + self.jitter();
        if let Some(sent) = self.faults.reboot(frame, buf.len(), due, response, k) {
            buf.truncate(sent);
            self.push(due + stall, buf, None);
            self.power_on(due, true);
            // An Ethernet sensor's connection ends with it (`take_rebooted`).
            self.rebooted = self.model.link == LinkKind::Ethernet;
            return;
        }
        self.push(due + stall, buf, None);
        if let Some(p) = self.queue.back_mut() {
            p.frame = true;
        }
        s.remaining = remaining;
        s.next_scan = k + 1 + u64::from(s.scan.skip);
        if remaining == Some(0) {
            self.stream = None;
            self.laser = false;
        } else {
            self.stream = Some(s);
        }
    }

    /// Writes a measurement response for scan `k` into `buf`.
    fn write_scan(
        &mut self,
        buf: &mut Vec<u8>,
        req: &Request,
        scan: &ScanRequest,
        status: [u8; 2],
        k: u64,
    ) {
        let start_us = self.scan_start(k);
        let period = self.scan_period_us();
        let clock = self.clock_ms(start_us);
        let cluster = u32::from(scan.cluster.max(1));
        let (first, last) = (u32::from(scan.start), u32::from(scan.end));
        let ares = u64::from(self.model.ares.max(1));
        let mut values = core::mem::take(&mut self.values);
        let mut best: Vec<Value> = Vec::new();
        let mut truth = self.truth.is_some().then(|| ScanTruth {
            scan: k,
            request: *scan,
            status,
            timestamp: clock,
            first_step_us: start_us + period * u64::from(first) / ares,
            values: Vec::new(),
            extra: Vec::new(),
        });
        let mut w = ResponseWriter::new(|b: &[u8]| buf.extend_from_slice(b));
        w.echo(req);
        w.status(status);
        w.timestamp(clock);
        let mut step = first;
        while step <= last {
            // Cluster: the nearest real range of the group, with its intensity and echoes
            // (paper §3.2); all error codes → the first step's code.
            best.clear();
            let mut best_d = u32::MAX;
            for s in step..(step + cluster).min(last + 1) {
                let t_us = start_us + period * u64::from(s) / ares;
                let t_s = t_us as f64 / 1e6;
                self.source
                    .step(&self.model, k, t_s, s, scan.data, &mut values);
                let d = values.first().map_or(0, |v| v.0);
                let valid = d >= self.model.dmin && d != self.model.no_echo_code();
                if best.is_empty() || (valid && d < best_d) {
                    best.clear();
                    best.extend_from_slice(&values);
                    best_d = if valid { d } else { u32::MAX };
                }
            }
            let mut echoes = best.iter();
            if let Some(&(d, aux)) = echoes.next() {
                w.step(d, aux);
                if let Some(t) = truth.as_mut() {
                    t.values.push((d, aux));
                }
            }
            if scan.multi_echo {
                for (e, &(d, aux)) in echoes.take(2).enumerate() {
                    w.extra_echo(d, aux);
                    if let Some(t) = truth.as_mut() {
                        let index = u16::try_from(t.values.len().saturating_sub(1));
                        t.extra
                            .push((index.unwrap_or(u16::MAX), e as u8 + 1, (d, aux)));
                    }
                }
            }
            step += cluster;
        }
        w.end();
        let _ = w.into_inner();
        self.values = values;
        if let (Some(log), Some(t)) = (self.truth.as_mut(), truth) {
            log.push(t);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::SceneSource;
    use crate::model::{ModelKind, Noise};
    use crate::scene::Scene;

    fn sensor(kind: ModelKind, scip11: bool) -> Sensor {
        let src = SceneSource::new(Scene::wall(1000.0, 0.8), 1, Noise::EXACT);
        Sensor::new(
            Model::new(kind),
            Box::new(src),
            FaultConfig::default(),
            0,
            scip11,
        )
    }

    /// Sends `cmd` at `now` and collects everything due within 150 ms.
    fn ask(s: &mut Sensor, now: u64, cmd: &[u8]) -> Vec<u8> {
        s.receive(now, cmd);
        s.take_output(now + 150_000)
    }

    #[test]
    fn urg_boots_in_scip11_and_switches() {
        let mut s = sensor(ModelKind::Urg04lx, true);
        assert_eq!(ask(&mut s, 0, b"VV\n"), b"VV\nE\n\n");
        assert_eq!(ask(&mut s, 0, b"SCIP2.0\n"), b"SCIP2.0\n0\n\n");
        assert!(s.is_scip2());
        assert_eq!(ask(&mut s, 0, b"SCIP2.0\n"), b"SCIP2.0\n0Ee\n\n");
        // The real unit's bytes (hokuyoaist_example_urg_04lx).
        assert_eq!(
            ask(&mut s, 0, b"VV\n"),
            &b"VV\n00P\nVEND:Hokuyo Automatic Co.,Ltd.;[\nPROD:SOKUIKI Sensor URG-04LX;[\n\
FIRM:3.1.04(02/Aug./2007);a\nPROT:SCIP 2.0;N\nSERI:H0706400;F\n\n"[..]
        );
        assert_eq!(
            ask(&mut s, 0, b"PP\n"),
            &b"PP\n00P\nMODL:URG-04LX(Hokuyo Automatic Co.,Ltd.);N\nDMIN:20;4\nDMAX:5600;_\n\
ARES:1024;\\\nAMIN:44;7\nAMAX:725;o\nAFRT:384;6\nSCAN:600;e\n\n"[..]
        );
        assert_eq!(ask(&mut s, 0, b"BM\n"), b"BM\n00P\n\n");
        assert_eq!(ask(&mut s, 0, b"BM\r\n"), b"BM\n02R\n\n");
        assert_eq!(ask(&mut s, 0, b"CR00\n"), b"CR00\n03S\n\n");
    }

    #[test]
    fn statuses_of_bad_commands() {
        let mut s = sensor(ModelKind::Utm30lx, false);
        let status = |s: &mut Sensor, cmd: &[u8]| {
            let out = ask(s, 0, cmd);
            let line = out.split(|&b| b == b'\n').nth(1).unwrap_or(&[]).to_vec();
            String::from_utf8(line).unwrap()
        };
        assert_eq!(status(&mut s, b"GD0000108001\n"), "10Q"); // laser off
        assert_eq!(status(&mut s, b"XX\n"), "0Ee");
        assert_eq!(status(&mut s, b"VV;12345678901234567\n"), "0Gg");
        assert_eq!(status(&mut s, b"VV;a\x01\n"), "0Hh");
        assert_eq!(status(&mut s, b"GD00000010\n"), "0Cc");
        assert_eq!(status(&mut s, b"GD000000100100\n"), "0Dd");
        assert_eq!(status(&mut s, b"MDx000001001000\n"), "01Q");
        assert_eq!(status(&mut s, b"MD0000x00100100\n"), "02R");
        assert_eq!(status(&mut s, b"MD000000100x0100\n"), "0Dd");
        assert_eq!(status(&mut s, b"MD00000010x0000\n"), "03S");
        assert_eq!(status(&mut s, b"MD0000001001x00\n"), "06V");
        assert_eq!(status(&mut s, b"MD00000010010x0\n"), "07W");
        assert_eq!(status(&mut s, b"MD0000200001000\n"), "04T");
        assert_eq!(status(&mut s, b"MD0100000001000\n"), "05U");
        assert_eq!(status(&mut s, b"CR05\n"), "04T"); // UTM: no speed control
        assert_eq!(status(&mut s, b"SS115200\n"), "00P");
        assert_eq!(status(&mut s, b"SS115200\n"), "03S");
        assert_eq!(status(&mut s, b"SS009600\n"), "04T");
        assert_eq!(status(&mut s, b"TM1\n"), "04T");
        assert_eq!(status(&mut s, b"TM2\n"), "03S");
        assert_eq!(status(&mut s, b"TM0\n"), "00P");
        assert_eq!(status(&mut s, b"TM0\n"), "02R");
        assert_eq!(status(&mut s, b"TM3\n"), "01Q");
        assert_eq!(status(&mut s, b"%ST\n"), "0Ee"); // not SCIP 2.2
        assert_eq!(ask(&mut s, 0, b"\n\n"), b""); // empty commands are ignored
    }

    #[test]
    fn clock_wraps_and_tm_reads_it() {
        let src = SceneSource::new(Scene::empty(), 1, Noise::EXACT);
        let mut s = Sensor::new(
            Model::new(ModelKind::Utm30lx),
            Box::new(src),
            FaultConfig::default(),
            0xFF_FFF0,
            false,
        );
        ask(&mut s, 0, b"TM0\n");
        // 10 ms after power-on: 0xFFFFFA.
        let out = ask(&mut s, 10_000, b"TM1\n");
        let mut t = [0u8; 4];
        scip::value::encode(0xFF_FFFA, &mut t).unwrap();
        assert_eq!(&out[..8], b"TM1\n00P\n");
        assert_eq!(&out[8..12], &t);
        // 20 ms later it has wrapped to 14.
        let out = ask(&mut s, 30_000, b"TM1\n");
        scip::value::encode(14, &mut t).unwrap();
        assert_eq!(&out[8..12], &t);
        // RS sets it to 0.
        ask(&mut s, 40_000, b"RS\n");
        ask(&mut s, 40_000, b"TM0\n");
        let out = ask(&mut s, 45_000, b"TM1\n");
        scip::value::encode(5, &mut t).unwrap();
        assert_eq!(&out[8..12], &t);
    }

    /// A TM1 is answered when the sensor reads its clock, 0 to 500 µs after the
    /// request: a calibration's readings fall at different phases of its millisecond
    /// even on a link that carries the request in no time.
    #[test]
    fn tm1_is_read_and_answered_up_to_half_a_millisecond_later() {
        let mut s = sensor(ModelKind::Utm30lx, false);
        // The sensor's ticks fall 700 µs into each millisecond of the caller's clock.
        s.set_clock_model(ClockModel {
            phase_us: 300,
            ..ClockModel::default()
        });
        ask(&mut s, 0, b"TM0\n");
        let (mut latencies, mut readings) = (Vec::new(), Vec::new());
        for k in 0..24u64 {
            // 500 µs past a caller's millisecond: 200 µs before a tick.
            let t = 1_000_500 + k * 10_000;
            s.receive(t, b"TM1\n");
            let (d, out) = (0..=TM_LATENCY_US + 1)
                .map(|d| (d, s.take_output(t + d)))
                .find(|(_, out)| !out.is_empty())
                .expect("answered");
            assert!(d <= TM_LATENCY_US, "answered {d} µs after the request");
            // The clock as it read when the answer left.
            let mut want = [0u8; 4];
            scip::value::encode(1_000 + k as u32 * 10 + u32::from(d >= 200), &mut want).unwrap();
            assert_eq!(&out[8..12], &want, "request at {t} µs, answer {d} µs later");
            latencies.push(d);
            readings.push(d >= 200);
        }
        let (lo, hi) = (latencies.iter().min(), latencies.iter().max());
        assert!(
            hi.zip(lo).is_some_and(|(h, l)| h - l >= TM_LATENCY_US / 2),
            "{latencies:?}"
        );
        // Some readings before the tick, some after it: they pin where it falls.
        assert!(readings.contains(&true) && readings.contains(&false));
    }

    #[test]
    fn a_drifting_clock_and_jittered_frames() {
        let mut s = sensor(ModelKind::Utm30lx, false);
        s.set_clock_model(ClockModel {
            drift_ppb: 100_000,
            phase_us: 600,
            jitter_us: 2000,
            seed: 7,
        });
        // +100 ppm: 1 ms gained in 10 s; the phase puts the ticks 400 µs early.
        assert_eq!(s.clock_ms(0), 0);
        assert_eq!(s.clock_ms(399), 0);
        assert_eq!(s.clock_ms(400), 1);
        assert_eq!(s.clock_ms(10_000_000), 10_001);
        // -100 ppm after 10 s: 9 999 ms (and 400 µs).
        s.set_clock_model(ClockModel {
            drift_ppb: -100_000,
            ..ClockModel::default()
        });
        assert_eq!(s.clock_ms(10_000_000), 9_999);
        // Jitter: frames leave between their due time and 2 ms later, not all on time.
        s.set_clock_model(ClockModel {
            jitter_us: 2000,
            seed: 3,
            ..ClockModel::default()
        });
        s.record_truth(true);
        ask(&mut s, 0, b"MD0000108000000\n");
        let mut lates = Vec::new();
        for now in (100_000..1_100_000u64).step_by(50) {
            if !s.take_output(now).is_empty() {
                lates.push((now - 100_000) % 25_000);
            }
        }
        assert!(lates.len() >= 38, "{} frames", lates.len());
        assert!(lates.iter().all(|&l| l <= 2050), "{lates:?}");
        assert!(lates.iter().any(|&l| l >= 1000), "{lates:?}");
    }

    #[test]
    fn stream_counts_down_with_skip_and_stops() {
        let mut s = sensor(ModelKind::Utm30lx, false);
        // 3 scans, skip 1: frames leave every 2 scans (50 ms) after the next one.
        s.receive(1_000, b"MD0540054001103;t\n");
        let ack = s.take_output(1_000);
        assert_eq!(ack, b"MD0540054001103;t\n00P\n\n");
        let mut frames = Vec::new();
        let mut t = 1_000;
        while t < 400_000 {
            t += 1_000;
            let out = s.take_output(t);
            if !out.is_empty() {
                frames.push((t, out));
            }
        }
        let echoes: Vec<_> = frames
            .iter()
            .map(|(t, f)| {
                (
                    *t,
                    String::from_utf8_lossy(&f[..f.iter().position(|&b| b == b'\n').unwrap()])
                        .into_owned(),
                )
            })
            .collect();
        assert_eq!(
            echoes,
            vec![
                (50_000, "MD0540054001102;t".to_string()),
                (100_000, "MD0540054001101;t".to_string()),
                (150_000, "MD0540054001100;t".to_string()),
            ]
        );
        // One value: the wall at 1000 mm straight ahead = "0?X" (1000 = 15*64 + 40).
        let f = &frames[0].1;
        let lines: Vec<&[u8]> = f.split(|&b| b == b'\n').collect();
        assert_eq!(lines[1], b"99b");
        assert_eq!(lines[3], b"0?X7");
        assert!(!s.is_streaming());
        assert_eq!(
            ask(&mut s, 400_000, b"GD0540054001\n")[..16],
            *b"GD0540054001\n10Q"
        );
    }

    #[test]
    fn scip22_rb_asks_for_confirmation_then_reboots() {
        let mut s = sensor(ModelKind::Ust10lx, false);
        // SCIP 2.2: the first RB is answered 01, a second within 1 s 00 (then reboot).
        assert_eq!(ask(&mut s, 0, b"RB\n"), b"RB\n01Q\n\n");
        // More than a second later: the first of a new pair again.
        assert_eq!(ask(&mut s, 1_200_000, b"RB\n"), b"RB\n01Q\n\n");
        ask(&mut s, 1_300_000, b"MD0000108001000\n");
        assert!(s.is_streaming());
        let t = 1_900_000;
        s.receive(t, b"RB;x\n");
        let out = s.take_output(t);
        assert!(
            out.ends_with(b"RB;x\n00P\n\n"),
            "{}",
            String::from_utf8_lossy(&out)
        );
        assert!(s.take_rebooted());
        assert!(!s.take_rebooted());
        // Booting: the stream is gone and commands go unanswered for a while.
        assert!(!s.is_streaming());
        assert_eq!(ask(&mut s, t + 100_000, b"%ST\n"), b"");
        assert_eq!(ask(&mut s, t + 600_000, b"%ST\n"), b"%ST\n00P\n000@\n\n");
        // The pair does not carry over the reboot.
        assert_eq!(ask(&mut s, t + 700_000, b"RB\n"), b"RB\n01Q\n\n");
        // SCIP 2.0 sensors do not know RB.
        let mut utm = sensor(ModelKind::Utm30lx, false);
        assert_eq!(ask(&mut utm, 0, b"RB\n"), b"RB\n0Ee\n\n");
        assert_eq!(ask(&mut utm, 0, b"RB\n"), b"RB\n0Ee\n\n");
    }

    #[test]
    fn paced_output_keeps_to_the_bit_rate_and_a_bounded_buffer() {
        let mut s = sensor(ModelKind::Urg04lx, false);
        s.set_paced(true);
        assert_eq!(s.bit_rate(), Some(19_200));
        s.receive(0, b"MD0044072501000\n");
        let mut out = Vec::new();
        let mut max_backlog = 0;
        // 30 s of sensor time in 1 ms ticks, QT at 20 s.
        let mut qt_at = None;
        for ms in 1..=30_000u64 {
            let now = ms * 1000;
            if ms == 20_000 {
                s.receive(now, b"QT\n");
                qt_at = Some(out.len());
            }
            out.extend(s.take_output(now));
            max_backlog = max_backlog.max(s.tx_backlog());
            // 19 200 bit/s = 1 920 bytes a second (10 bits a byte), plus one FIFO.
            assert!(
                out.len() as u64 <= ms * 1920 / 1000 + 32,
                "{ms} ms: {}",
                out.len()
            );
        }
        assert!(max_backlog <= TX_CAP, "{max_backlog}");
        // A frame is 2 137 bytes: about 18 of the 200 scans of 20 s fit, the rest are
        // skipped.
        let frames = out
            .windows(20)
            .filter(|w| w == b"MD0044072501000\n99b\n")
            .count() as u64;
        assert!((16..=19).contains(&frames), "{frames}");
        assert!(s.skipped_frames() >= 180, "{}", s.skipped_frames());
        // The QT answer follows at most the rest of the frame on the wire, and ends it.
        let qt_at = qt_at.unwrap();
        let tail = &out[qt_at..];
        assert!(tail.ends_with(b"QT\n00P\n\n"));
        assert!(tail.len() <= 2137 + 8, "{}", tail.len());
        assert!(!s.is_streaming());
    }
}
