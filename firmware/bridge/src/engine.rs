//! The bridge engine: UART bytes in, CAN frames out, with the session, the pipeline, the
//! governor and the CAN scan encoder wired together.
//!
//! ```text
//! UART bytes ─▶ scip::Decoder ─▶ events ─┬─▶ Session ─▶ commands for the sensor (poll)
//!                                        └─▶ scan path: admit (governor) ─▶ Pipeline
//!                                              ─▶ can_wire::ScanEncoder ─▶ frame queue ─▶ CAN
//! ```
//! A scan is processed line by line as it arrives; its header frames are queued when its
//! timestamp line is decoded, each data frame as soon as it is full, and its trailer when
//! the response ends intact. A damaged response (any decode error) ends the scan with an
//! abort frame instead, so a receiver never takes a damaged scan for an intact one.
//!
//! Every measurement response is a scan: a single scan (G*/H*, status 00) or a stream
//! frame (M*/N*, status 99 or 0M). Only the first echo of multi-echo steps is published.
//! Intensities are scaled to 16 bits before the wire encoding (`4 × raw`, saturating:
//! SPEC 4).
//!
//! The frame queue (capacity `Q`) always keeps one slot for a scan's trailer or abort:
//! a data frame that finds fewer than two free slots is not queued, and the scan ends with
//! an abort frame (`QueueOverflow`), counted. The governor admits a scan only when the
//! queue and the bus can take all of it, so this happens only when the bus is busier than
//! the bridge's share assumed.

use can_wire::{
    AbortReason, Distance, Encoding, Frame, FrameSink, Grouping, NodeIds, RunStop, ScanEncoder,
    ScanHeader, TrailerFlags,
};
use scip::{Command, DataLine, Decoder, Event, ScanMode, ScanRequest, Status};

use crate::governor::{Budget, Governor};
use crate::link::LinkKind;
use crate::pipeline::{
    Decimation, DecimationMode, DirectRun, Pipeline, PipelineConfig, Point, RawPoint, ScanInfo,
    ScanStart, TemporalDecimation,
};
use crate::queue::FrameQueue;
use crate::session::{Action, Notice, RecoverReason, Session, SessionConfig, SessionError};

/// Everything the bridge is configured with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BridgeConfig {
    /// The sensor session.
    pub session: SessionConfig,
    /// The scan pipeline.
    pub pipeline: PipelineConfig,
    /// Point encoding on the wire.
    pub encoding: Encoding,
    /// The bus and the bridge's share of it (frame format included).
    pub budget: Budget,
    /// The bridge's CAN identifiers.
    pub ids: NodeIds,
    /// The UART bit rate (to know how long a scan takes to arrive).
    pub uart_bit_rate: u32,
    /// Period of the heartbeat and counter status frames, ms; 0 sends none.
    pub status_period_ms: u32,
    /// The CAN controller can send CAN FD frames (a control frame may switch to FD).
    pub fd_capable: bool,
    /// The link to the sensor: a UART (at `uart_bit_rate`) or a TCP stream
    /// ([`crate::link`]).
    pub link: LinkKind,
}

/// Why a bridge configuration is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BridgeError {
    /// The session settings.
    Session(SessionError),
    /// The pipeline settings.
    Pipeline(crate::pipeline::ConfigError),
    /// The wire encoding or frame format.
    Wire(can_wire::Error),
    /// A UART bit rate of 0.
    UartBitRate,
    /// An `SS` bit rate asked for on a link without one (TCP).
    LinkHasNoBitRate,
}

impl core::fmt::Display for BridgeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Session(e) => write!(f, "session: {e}"),
            Self::Pipeline(e) => write!(f, "pipeline: {e}"),
            Self::Wire(e) => write!(f, "wire: {e:?}"),
            Self::UartBitRate => f.write_str("UART bit rate must be non-zero"),
            Self::LinkHasNoBitRate => f.write_str("a TCP link has no bit rate to set with SS"),
        }
    }
}

/// Counters of the scan path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BridgeStats {
    /// Measurement responses that began (timestamp decoded).
    pub scans_in: u32,
    /// Scans sent whole, with their trailer.
    pub scans_sent: u32,
    /// Scans ended with an abort frame.
    pub scans_aborted: u32,
    /// Scans left out by temporal decimation.
    pub scans_skipped: u32,
    /// Scans the governor dropped whole.
    pub scans_dropped: u32,
    /// Data frames that found the queue full (their scan was aborted).
    pub queue_overflows: u32,
    /// Frames queued.
    pub frames: u32,
    /// Scans the sensor sent that the bridge never started: a stream frame whose echo,
    /// status or timestamp line was damaged, or a scan withheld because the sensor's
    /// geometry is in doubt ([`crate::session::Geometry`]). Each one advances the scan
    /// sequence (a receiver sees the gap) and counts in `dropped_scans`.
    pub scans_lost: u32,
}

/// Where the scan path is within the current response.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Not in a measurement response.
    None,
    /// A measurement echo; the status decides.
    Echo(ScanRequest),
    /// A status that carries a scan; the timestamp starts it.
    Framed(ScanRequest),
    /// A scan being published.
    Active(ScanRequest),
    /// A scan not published (skipped, dropped, or aborted): its lines are ignored.
    Ignored,
}

/// The parts of the bridge other than the decoder (so that the decoder's events, which
/// borrow it, can be handled with mutable access to everything else).
#[derive(Debug)]
struct Core<const Q: usize> {
    config: BridgeConfig,
    session: Session,
    pipeline: Pipeline,
    encoder: ScanEncoder,
    governor: Governor,
    queue: FrameQueue<Q>,
    phase: Phase,
    seq: u16,
    /// The last response that ended was a stream frame: a next response whose echo is
    /// damaged is most likely one too.
    in_stream: bool,
    /// The echo of the response being decoded did not parse.
    echo_damaged: bool,
    /// The status of a response whose echo was damaged.
    echo_status: Option<Status>,
    overflow: bool,
    filtered: bool,
    stats: BridgeStats,
    notice: Option<Notice>,
    /// A frame format asked for by a control frame, applied when the next scan begins.
    pending_format: Option<can_wire::FrameFormat>,
    /// Status, bus and load bookkeeping.
    health: crate::status::Health,
    /// Let the governor choose decimation when the stream starts.
    auto_decimation: bool,
    /// The governor's last plan.
    plan: Option<crate::governor::Plan>,
    /// The cost the scan being published was admitted with.
    admitted: Option<can_wire::bandwidth::ScanCost>,
    /// A data line's points out of [`Pipeline::filter_run`], as readings.
    decimated: [scip::Reading; scip::MAX_READINGS + crate::pipeline::LINE_HEADROOM],
    /// The sensor's 24-bit ms clock, extended (SPEC 3.1); reset when the sensor restarts.
    clock: scip::TimestampUnwrapper,
    /// Bridge ms minus extended sensor ms at the last TM sync, while it holds.
    sync_offset: Option<i64>,
    /// The caller asked for the TM sync ([`Bridge::request_time_sync`]): it maps header
    /// timestamps (without it, TM answers only calibrate the clock model).
    sync_asked: bool,
    /// The sensor clock model: scan times in the caller's clock, µs.
    scan_clock: crate::clock::ScanClock,
    /// Put the model's estimate in headers once valid, and take a TM at session start
    /// ([`Bridge::set_time_estimation`]).
    estimate_time: bool,
    /// When the last byte of the current UART chunk arrived, caller's µs, and how many
    /// bytes of it follow the current event ([`Core::event_us`]).
    chunk_end_us: u64,
    bytes_after: usize,
    /// When the last command sent left the UART, caller's µs (estimated).
    sent_us: u64,
    /// `(ARES, AFRT)` assumed where no PP answer gave them ([`Bridge::assume_sensor`]).
    assumed: (Option<u32>, Option<u32>),
    /// The model the sensor's `MODL` or `PROD` text named (status page 4).
    model: Option<can_wire::SensorModel>,
    /// Following a time master over CAN (SPEC 9), on identifier `time_id`.
    time_sync: crate::timesync::TimeSync,
    time_id: Option<embedded_can::Id>,
    /// The sensor link is up (always for a UART; see [`crate::link`]).
    link_up: bool,
}

/// The bridge. `Q` is the capacity of the CAN transmit queue, in frames (at least 4).
#[derive(Debug)]
pub struct Bridge<const Q: usize> {
    decoder: Decoder,
    core: Core<Q>,
    /// When the last UART byte arrived, ms.
    last_uart_ms: u64,
}

impl<const Q: usize> Bridge<Q> {
    /// A bridge with every setting validated; the session is off until [`Bridge::start`].
    pub fn new(config: BridgeConfig) -> Result<Self, BridgeError> {
        if config.uart_bit_rate == 0 {
            return Err(BridgeError::UartBitRate);
        }
        if !config.link.has_bit_rate() && config.session.bit_rate.is_some() {
            return Err(BridgeError::LinkHasNoBitRate);
        }
        config.encoding.validate().map_err(BridgeError::Wire)?;
        let session = Session::new(config.session).map_err(BridgeError::Session)?;
        let pipeline = Pipeline::new(config.pipeline).map_err(BridgeError::Pipeline)?;
        let encoder =
            ScanEncoder::new(config.ids, config.budget.format).map_err(BridgeError::Wire)?;
        Ok(Self {
            decoder: Decoder::new(),
            last_uart_ms: 0,
            core: Core {
                link_up: config.link.up_at_start(),
                session,
                pipeline,
                encoder,
                governor: Governor::new(config.budget),
                queue: FrameQueue::new(),
                phase: Phase::None,
                seq: 0,
                in_stream: false,
                echo_damaged: false,
                echo_status: None,
                overflow: false,
                filtered: false,
                stats: BridgeStats::default(),
                notice: None,
                pending_format: None,
                health: crate::status::Health::new(),
                auto_decimation: true,
                plan: None,
                admitted: None,
                decimated: [scip::Reading::default();
                    scip::MAX_READINGS + crate::pipeline::LINE_HEADROOM],
                clock: scip::TimestampUnwrapper::new(),
                sync_offset: None,
                sync_asked: false,
                scan_clock: crate::clock::ScanClock::new(),
                estimate_time: false,
                chunk_end_us: 0,
                bytes_after: 0,
                sent_us: 0,
                assumed: (None, None),
                model: None,
                time_sync: crate::timesync::TimeSync::new(),
                time_id: can_wire::timesync::time_id(
                    can_wire::timesync::DEFAULT_TIME_ID.into(),
                    &config.ids.window(),
                )
                .ok(),
                config,
            },
        })
    }

    /// Starts the sensor session. The extended sensor clock and any time sync start
    /// over (the sensor may have restarted while the bridge was not streaming).
    pub fn start(&mut self, now_ms: u64) {
        self.decoder.forget_stream();
        self.core.start_session(now_ms);
    }

    /// The sensor link is up: a TCP connection to the sensor was made (or made again).
    /// A session held by [`Bridge::link_down`] (or started before the link was up)
    /// starts over from the probe, identification included (the sensor may have
    /// rebooted); the extended sensor clock and any time sync start over. Nothing
    /// happens on a link that was already up. See [`crate::link`].
    pub fn link_up(&mut self, now_ms: u64) {
        if self.core.link_up {
            return;
        }
        self.core.link_up = true;
        if self.core.session.state() == crate::session::State::LinkDown {
            self.decoder.reset();
            self.decoder.forget_stream();
            self.core.start_session(now_ms);
        }
    }

    /// The sensor link is down: the TCP connection closed or failed. The scan in
    /// progress ends with an abort ([`AbortReason::LinkLost`]), any partial response is
    /// dropped, and the session is held (no commands, no timeouts) until
    /// [`Bridge::link_up`]. A stopped session stays stopped. See [`crate::link`].
    pub fn link_down(&mut self, now_ms: u64) {
        let _ = now_ms;
        self.core.link_up = false;
        self.core.abort_scan(AbortReason::LinkLost);
        self.decoder.reset();
        if let Some(notice) = self.core.session.link_down() {
            self.core.notice(notice);
        }
    }

    /// Whether the sensor link is up (always, for a UART).
    pub fn link_is_up(&self) -> bool {
        self.core.link_up
    }

    /// Asks the session for a time sync (SCIP `TM`); a running stream stops for it and
    /// starts again after. Once it answered, header timestamps are in the caller's clock
    /// (the `now_ms` this bridge is given, truncated to 32 bits) and marked
    /// `time_synced`, until the sensor restarts or the session is started again.
    pub fn request_time_sync(&mut self, now_ms: u64) {
        self.core.sync_asked = true;
        self.core.session.request_time_sync(now_ms);
    }

    /// Estimates each scan's time in the caller's clock (the sensor clock model,
    /// [`crate::clock`]): a session starts with a `TM` exchange that calibrates it, and
    /// once the model is valid, headers carry the first point's time in µs
    /// (`time_estimated`, SPEC 3.1). Give arrival times in µs ([`Bridge::on_uart_at`],
    /// [`Bridge::poll_at`]) for sub-millisecond results. Takes effect at the next
    /// [`Bridge::start`].
    ///
    /// Needs the crate feature `time-estimate` (the host tools have it); without it
    /// the model is not built in (it does not fit the 96 KiB flash budget of the STM32
    /// boards yet) and this does nothing.
    pub fn set_time_estimation(&mut self, on: bool) {
        self.core.estimate_time = on;
    }

    /// The sensor clock model.
    pub fn scan_clock(&self) -> &crate::clock::ScanClock {
        &self.core.scan_clock
    }

    /// Sensor parameters to assume where the sensor's own PP answer gives none (it
    /// always wins): for a recorded stream without PP, from a known model. Sets the
    /// geometry of scan headers (without it, and without PP, they say "geometry
    /// unknown") and, when `params` gives `dmin` or `family`, the decoder's range limits
    /// (the decoder starts afresh then: call this before the first bytes).
    pub fn assume_sensor(&mut self, params: scip::SensorParams) {
        self.core.assumed = (params.ares, params.afrt);
        if params.dmin.is_some() || params.family.is_some() {
            let mut limits = self.decoder.limits();
            limits.dmin = params.dmin.unwrap_or(limits.dmin);
            limits.family = params.family.unwrap_or(limits.family);
            self.decoder = Decoder::with_limits(limits);
        }
    }

    /// Whether header timestamps are mapped to the caller's clock (a time sync held).
    pub fn time_synced(&self) -> bool {
        self.core.sync_offset.is_some()
    }

    /// Stops the stream (and aborts a scan in progress).
    pub fn stop(&mut self, now_ms: u64) {
        self.core.abort_scan(AbortReason::Stopped);
        self.core.session.stop(now_ms);
    }

    /// Takes bytes from the sensor's UART. Work is linear in `bytes.len()`.
    pub fn on_uart(&mut self, bytes: &[u8], now_ms: u64) {
        self.on_uart_at(bytes, now_ms.saturating_mul(1000));
    }

    /// [`Bridge::on_uart`] with the time, µs of the caller's monotonic clock, at which
    /// the chunk's last byte arrived; earlier bytes are placed back at the UART's bit
    /// rate (10 bits a byte). The time a scan's timestamp line ended arriving feeds the
    /// sensor clock model.
    pub fn on_uart_at(&mut self, bytes: &[u8], now_us: u64) {
        let now_ms = now_us / 1000;
        if !bytes.is_empty() {
            self.last_uart_ms = now_ms;
        }
        self.core.chunk_end_us = now_us;
        let mut rest = bytes;
        while !rest.is_empty() {
            let (used, event) = self.decoder.feed(rest);
            rest = rest.get(used..).unwrap_or(&[]);
            if let Some(event) = event {
                // The event's time is worked out only where it is used.
                self.core.bytes_after = rest.len();
                self.core.event(&event, now_ms);
            }
        }
    }

    /// [`Bridge::poll`] with the time in µs: a command it returns is taken as sent
    /// (its last byte leaving the UART) at `now_us` plus its UART time.
    pub fn poll_at(&mut self, now_us: u64) -> Option<Action> {
        let action = self.poll(now_us / 1000);
        if let Some(Action::Send(request)) = &action {
            let mut buf = [0u8; scip::REQUEST_MAX];
            let len = scip::Request::encode(request, &mut buf).unwrap_or(0);
            let bits = u64::try_from(len).unwrap_or(0).saturating_mul(10_000_000);
            let uart_us = bits
                .checked_div(u64::from(self.core.config.uart_bit_rate))
                .unwrap_or(0);
            self.core.sent_us = now_us.saturating_add(uart_us);
        }
        action
    }

    /// The next command for the sensor or UART change, if any. Call after `on_uart` and
    /// periodically.
    pub fn poll(&mut self, now_ms: u64) -> Option<Action> {
        self.core.periodic_status(now_ms, self.decoder.stats());
        // A response cut off (the sensor rebooted or the link dropped bytes) and silence
        // since: what is buffered is stale. Without this, the next answer would be glued
        // to the partial line and lost with it.
        let silent = now_ms.saturating_sub(self.last_uart_ms);
        if !self.decoder.is_idle() && silent > u64::from(self.core.session.stale_input_ms()) {
            if let Some(event) = self.decoder.finish() {
                // It happened when the bytes stopped.
                self.core.event(&event, self.last_uart_ms);
            }
        }
        let action = self.core.session.poll(now_ms);
        if let Some(notice) = self.core.session.take_notice() {
            self.core.notice(notice);
        }
        action
    }

    /// The next frame to transmit: control answers and status first, then the frames
    /// of scans in their order.
    pub fn pop_frame(&mut self) -> Option<Frame> {
        self.pop_frame_with(|frame| *frame)
    }

    /// [`Bridge::pop_frame`] that hands the frame to `send` where it lies in the queue,
    /// instead of returning a copy (a 76-byte move on a 32-bit MCU): for a board that
    /// copies it into its CAN controller anyway. `None` (and `send` not called) when no
    /// frame is waiting.
    #[inline]
    pub fn pop_frame_with<R>(&mut self, send: impl FnOnce(&Frame) -> R) -> Option<R> {
        let Core { queue, health, .. } = &mut self.core;
        queue.pop_front_with(|frame| {
            health.sent(frame);
            send(frame)
        })
    }

    /// Takes a frame received from the bus; control frames addressed to this bridge are
    /// applied and answered (the answer is queued). Returns true for such a frame.
    pub fn on_can_frame(&mut self, frame: &Frame, now_ms: u64) -> bool {
        if self.core.time_frame(frame, now_ms.saturating_mul(1000)) {
            return false;
        }
        let ids = self.core.config.ids;
        match ids.window().classify(frame.id()) {
            Some((node, can_wire::Kind::Control)) if node == ids.node() => {
                self.core.control(frame.data(), now_ms);
                true
            }
            _ => false,
        }
    }

    /// [`Bridge::on_can_frame`] with the reception time in µs of the bridge's clock (the
    /// CAN controller's RX timestamp where it has one): time frames (SPEC 9) are taken at
    /// this resolution instead of the millisecond.
    pub fn on_can_frame_at(&mut self, frame: &Frame, now_us: u64) -> bool {
        if self.core.time_frame(frame, now_us) {
            return false;
        }
        self.on_can_frame(frame, now_us / 1000)
    }

    /// The robot's (time master's) clock, µs, at bridge time `bridge_us` (the clock given
    /// to [`Bridge::on_can_frame_at`]), while a time sync holds (SPEC 9.3).
    pub fn to_master(&self, bridge_us: u64) -> Option<u64> {
        self.core.time_sync.to_master(bridge_us)
    }

    /// The time sync state (mapping quality, counters).
    pub fn time_sync(&self) -> &crate::timesync::TimeSync {
        &self.core.time_sync
    }

    /// Follows the time master on identifier `raw` (in the format of the bridge's window),
    /// or none (`None`). The default is 0x0FF ([`can_wire::timesync::DEFAULT_TIME_ID`]),
    /// none when the window contains it. Fails, changing nothing, for an identifier
    /// inside the window or beyond the format. The mapping starts over.
    pub fn set_time_id(&mut self, raw: Option<u32>) -> Result<(), can_wire::Error> {
        let window = self.core.config.ids.window();
        self.core.time_id = match raw {
            Some(raw) => Some(can_wire::timesync::time_id(raw, &window)?),
            None => None,
        };
        self.core.time_sync.reset();
        Ok(())
    }

    /// The identifier of the time master's frames this bridge follows (SPEC 9), if any:
    /// a board's CAN acceptance filter must let it through beside the control frames.
    pub fn time_id(&self) -> Option<embedded_can::Id> {
        self.core.time_id
    }

    /// The board saw a CAN bus error.
    pub fn on_bus_error(&mut self) {
        self.core.health.bus_errors = self.core.health.bus_errors.saturating_add(1);
    }

    /// The CAN controller's error state changed; entering bus-off is counted.
    pub fn set_bus_state(&mut self, state: can_wire::BusState) {
        let code = u8::from(state);
        if state == can_wire::BusState::BusOff && self.core.health.bus_state != code {
            self.core.health.bus_off_events = self.core.health.bus_off_events.saturating_add(1);
        }
        self.core.health.bus_state = code;
    }

    /// The board's measured CPU load, permille.
    pub fn set_cpu_load(&mut self, permille: u16) {
        self.core.health.cpu_permille = permille.min(1000);
    }

    /// Bus-side counters and loads.
    pub fn health(&self) -> &crate::status::Health {
        &self.core.health
    }

    /// Whether the governor chooses the angular and temporal decimation when the stream
    /// starts (on by default). Its plan keeps the average bus load within the share; it
    /// replaces the pipeline's decimation settings and keeps every other stage. Turn it
    /// off to keep configured decimation as it is; a control frame that sets decimation
    /// turns it off too.
    pub fn set_auto_decimation(&mut self, on: bool) {
        self.core.auto_decimation = on;
    }

    /// The governor's plan for the running stream, once made.
    pub fn plan(&self) -> Option<&crate::governor::Plan> {
        self.core.plan.as_ref()
    }

    /// Frames waiting to be transmitted.
    pub fn queued(&self) -> usize {
        self.core.queue.len()
    }

    /// The last notice of the session (taken once).
    pub fn take_notice(&mut self) -> Option<Notice> {
        self.core.notice.take()
    }

    /// Counters of the scan path.
    pub fn stats(&self) -> &BridgeStats {
        &self.core.stats
    }

    /// The decoder (its counters, its learned limits).
    pub fn decoder(&self) -> &Decoder {
        &self.decoder
    }

    /// The session.
    pub fn session(&self) -> &Session {
        &self.core.session
    }

    /// The pipeline.
    pub fn pipeline(&self) -> &Pipeline {
        &self.core.pipeline
    }

    /// The governor.
    pub fn governor(&self) -> &Governor {
        &self.core.governor
    }

    /// The configuration.
    pub fn config(&self) -> &BridgeConfig {
        &self.core.config
    }
}

impl<const Q: usize> Core<Q> {
    fn event(&mut self, event: &Event<'_>, now: u64) {
        if let Some(n) = self.session.on_event(event, now) {
            self.notice(n);
        }
        if let Event::Field(f) = event {
            if f.name == b"MODL" || f.name == b"PROD" {
                if let Some(model) = crate::status::model_from_text(f.value) {
                    self.model = Some(model);
                }
            }
        }
        match (event, self.phase) {
            (Event::Start { request, .. }, phase) => {
                if matches!(phase, Phase::Active(_)) {
                    // A response began before the scan's end: cannot happen with a sound
                    // decoder, but never leave a scan open.
                    self.abort_scan(AbortReason::BadData);
                }
                self.echo_damaged = request.is_none();
                self.echo_status = None;
                self.phase = match request.map(|r| r.command) {
                    Some(Command::Scan(s)) => Phase::Echo(s),
                    _ => Phase::None,
                };
            }
            (Event::Status(status), Phase::Echo(s)) => {
                self.phase = if carries_scan(&s, *status) {
                    Phase::Framed(s)
                } else {
                    Phase::None
                };
            }
            (Event::Timestamp(t), Phase::Framed(s)) => {
                self.in_stream = s.mode == ScanMode::Continuous;
                self.begin_scan(s, *t, now);
            }
            (Event::Data(line), Phase::Active(s)) => self.data_line(line, &s),
            (Event::End(_), Phase::Active(_)) => {
                self.finish_scan();
                if self.estimating() && self.scan_clock.wants_tm() {
                    // The scans just crossed a tick of the sensor's clock: a TM now pins
                    // the latency. Asked once the scan is complete (the stream stops for
                    // it, a few scans; the one under way is not cut).
                    self.scan_clock.tm_requested();
                    self.session.request_time_sync(now);
                }
            }
            (Event::Error(e), Phase::Active(_)) => {
                let reason = match e.kind {
                    scip::ErrorKind::BadSum { .. } => AbortReason::Checksum,
                    scip::ErrorKind::Truncated => AbortReason::Timeout,
                    _ => AbortReason::BadData,
                };
                self.abort_scan(reason);
            }
            (Event::Error(_), Phase::Echo(_) | Phase::Framed(_)) => {
                // A measurement response damaged before its scan began.
                self.lose_scan();
                self.phase = Phase::None;
            }
            (Event::Status(status), Phase::None) if self.echo_damaged => {
                self.echo_status = Some(*status);
            }
            (Event::Error(_), Phase::None)
                if self.echo_damaged
                    && match self.echo_status {
                        Some(status) => carries_frame(status),
                        None => self.in_stream,
                    } =>
            {
                // A stream frame whose echo was damaged (its status says so or, when
                // that was damaged too, it came in a stream).
                self.lose_scan();
            }
            (Event::End(_) | Event::Error(_), _) => {
                if matches!(event, Event::End(_))
                    && matches!(self.phase, Phase::None)
                    && !self.echo_damaged
                {
                    // An answer to another command: the stream is not what came last.
                    self.in_stream = false;
                }
                self.phase = Phase::None;
            }
            _ => {}
        }
    }

    /// A scan the sensor sent and the bridge never started: counted, and its sequence
    /// number skipped so that a receiver sees the gap.
    fn lose_scan(&mut self) {
        self.stats.scans_lost = self.stats.scans_lost.wrapping_add(1);
        self.seq = self.seq.wrapping_add(1);
    }

    /// The pipeline, the decimated-line buffer and the parts output points go through,
    /// borrowed apart.
    fn split(
        &mut self,
    ) -> (
        &mut Pipeline,
        &mut [scip::Reading; scip::MAX_READINGS + crate::pipeline::LINE_HEADROOM],
        Output<'_, Q>,
    ) {
        let Self {
            pipeline,
            decimated,
            encoder,
            queue,
            stats,
            overflow,
            filtered,
            ..
        } = self;
        let out = Output {
            encoder,
            queue,
            stats,
            overflow,
            filtered,
        };
        (pipeline, decimated, out)
    }

    /// One data line of the scan being published. With every pipeline stage off, the
    /// line's readings go straight to the encoder in one run (the pipeline only counts
    /// them); otherwise they go through every stage in one loop
    /// ([`Pipeline::filter_run`]) and the line's output points into the encoder in one
    /// run. Only multi-echo lines and lines out of sequence go point by point.
    fn data_line(&mut self, line: &DataLine<'_>, s: &ScanRequest) {
        let cluster = u32::from(s.cluster.max(1));
        let start = u32::from(s.start);
        let has_aux = line.data.aux_width() > 0;
        let width = line.data.distance_width();
        let step = |index: u16| {
            // u16 + u16 × u8: below 2^25, no overflow.
            let step = start.wrapping_add(u32::from(index).wrapping_mul(cluster));
            u16::try_from(step).unwrap_or(u16::MAX)
        };
        // Without multi-echo every reading is a first echo, the next step of the scan.
        let first = line.readings.first().map(|r| step(r.index));
        let test = line.limits.range_test(width);
        let raw = |r: &scip::Reading| RawPoint {
            step: step(r.index),
            distance: r.distance,
            intensity: has_aux.then_some(r.aux),
            valid: test.is_range(r.distance),
        };
        if let Some(first) = first.filter(|_| !s.multi_echo) {
            if let Some(run) = self.pipeline.pass_run(first, line.readings.len(), has_aux) {
                self.publish_run(line, width, run);
                return;
            }
            // Any other stages: the line's readings, a range or none each, through the
            // stages in place, then the output points into the encoder in one run, as
            // readings so that the encoder runs the same code as for a line's readings.
            // A point without a range: 0 for the fixed-width encodings (invalid to the
            // rule "at least 1"), a value no sensor sends for the lossless coding (coded
            // invalid, not as the sensor's error code 0).
            let lossless = self.encoder.lossless_progress().is_some();
            let (none, rule) = if lossless {
                let no_value = can_wire::lossless::code::NO_SENSOR_VALUE;
                let rule = can_wire::RangeRule {
                    band: Some(no_value),
                    ..can_wire::RangeRule::at_least(1)
                };
                (no_value, rule)
            } else {
                (0, can_wire::RangeRule::at_least(1))
            };
            let sensor = can_wire::RangeRule {
                min: test.min(),
                except: [test.exception(), u32::MAX],
                band: test.band(),
                window: [0, u32::MAX],
            };
            let (pipeline, cells, mut out) = self.split();
            let k = pipeline.filter_line(first, line.readings, cells, sensor, has_aux, none);
            if let Some(k) = k {
                if !*out.overflow {
                    let points = cells.get(..k).unwrap_or_default();
                    out.encode_run(points, rule);
                }
                return;
            }
        }
        let points = line.readings.iter().filter(|r| r.echo == 0).map(raw);
        let (pipeline, _, mut out) = self.split();
        pipeline.push_iter(points, &mut |p: Point| out.emit(p));
    }

    /// A line's readings, accepted by [`Pipeline::pass_run`], straight into the encoder:
    /// what [`Output::emit`] does for each of the run's points, in one loop; the
    /// region of interest is a slice, the range window part of the encoder's range
    /// rule (no work per point).
    fn publish_run(&mut self, line: &DataLine<'_>, width: u8, run: DirectRun) {
        let test = line.limits.range_test(width);
        let rule = can_wire::RangeRule {
            min: test.min(),
            except: [test.exception(), u32::MAX],
            band: test.band(),
            window: run.window,
        };
        let readings = line.readings.get(run.lo..run.hi).unwrap_or_default();
        if self.overflow {
            let (invalid, rejected) = count_no_range(&rule, readings);
            self.pipeline.count_direct(invalid, rejected);
            return;
        }
        let lossless = self.encoder.lossless_progress().is_some();
        let (taken, mut invalid, mut rejected) = self.split().2.encode_run(readings, rule);
        if lossless && run.window != [0, u32::MAX] {
            // The lossless coding does not count the window's rejections.
            rejected = count_no_range(&rule, readings.get(..taken).unwrap_or_default()).1;
        }
        // Points the encoder did not take (it stopped early) are counted too, as the
        // pipeline emitted them.
        let rest = readings.get(taken..).unwrap_or(&[]);
        if !rest.is_empty() {
            let (i, r) = count_no_range(&rule, rest);
            // All at most the line's reading count.
            invalid = invalid.wrapping_add(i);
            rejected = rejected.wrapping_add(r);
        }
        self.pipeline.count_direct(invalid, rejected);
    }

    /// A frame that goes ahead of queued scan frames (control answers, status). It never
    /// takes the last free slot while a scan is open (that one is the trailer's).
    fn push_priority(&mut self, frame: Frame) {
        let reserve = if matches!(self.phase, Phase::Active(_)) {
            2
        } else {
            1
        };
        if self.queue.free() >= reserve && self.queue.push_front(frame).is_ok() {
            self.stats.frames = self.stats.frames.wrapping_add(1);
        } else {
            self.health.tx_overflows = self.health.tx_overflows.saturating_add(1);
        }
    }

    /// A frame on the time identifier (SPEC 9): taken by the time sync, and page 7 sent
    /// after a FOLLOW-UP. Returns whether it was one (malformed ones are counted).
    #[inline(never)]
    fn time_frame(&mut self, frame: &Frame, now_us: u64) -> bool {
        if self.time_id != Some(frame.id()) {
            return false;
        }
        match can_wire::TimeFrame::parse(frame.data()) {
            Ok(can_wire::TimeFrame::Sync { seq }) => self.time_sync.on_sync(seq, now_us),
            Ok(can_wire::TimeFrame::FollowUp { seq, master_us }) => {
                self.time_sync.on_follow_up(seq, master_us);
                let master = self.time_sync.to_master(now_us);
                self.push_status(can_wire::Status::TimeSync {
                    synced: master.is_some(),
                    error_us: u16::try_from(self.time_sync.mean_error_us()).unwrap_or(u16::MAX),
                    // Modulo 2^32 (SPEC 5, page 7).
                    master_time: master.map_or(0, |m| m as u32),
                });
            }
            Err(_) => self.time_sync.on_malformed(),
        }
        true
    }

    fn push_status(&mut self, status: can_wire::Status) {
        let id = self.config.ids.id(can_wire::Kind::Status);
        let fd = self.encoder.format().is_fd();
        if let Ok(bytes) = status.emit() {
            if let Ok(frame) = Frame::new(id, &bytes, fd) {
                self.push_priority(frame);
            }
        }
    }

    fn periodic_status(&mut self, now: u64, dec: &scip::DecoderStats) {
        let boot = *self.health.boot_ms.get_or_insert(now);
        let period = u64::from(self.config.status_period_ms);
        if period == 0 {
            return;
        }
        let last = self.health.last_status_ms.unwrap_or(boot);
        if self.health.last_status_ms.is_some() && now.saturating_sub(last) < period {
            return;
        }
        if self.health.last_status_ms.is_some() {
            let budget = self.config.budget;
            self.health
                .close_period(now.saturating_sub(last), budget.rates, budget.extended);
        }
        self.health.last_status_ms = Some(now);
        let sum_errors = dec
            .by_kind
            .get(
                scip::ErrorKind::BadSum {
                    expected: 0,
                    found: 0,
                }
                .index(),
            )
            .copied()
            .unwrap_or(0);
        let g = self.governor.stats();
        let dropped = self
            .stats
            .scans_aborted
            .saturating_add(self.stats.scans_lost)
            .saturating_add(g.dropped_budget)
            .saturating_add(g.dropped_queue);
        let pages = crate::status::periodic_pages(
            &self.health,
            crate::status::bridge_state(self.session.state()),
            now,
            sum_errors,
            dec.resyncs,
            dropped,
            self.session.stats().recoveries,
        );
        // Pushed to the front in reverse, so they leave as heartbeat, sensor, bus.
        for page in pages.into_iter().rev() {
            self.push_status(page);
        }
    }

    fn control(&mut self, data: &[u8], now: u64) {
        let answer = match can_wire::Control::parse(data) {
            Err(e) => can_wire::Answer::reject(data, &e),
            Ok(control) => {
                match crate::control::plan(&control, &self.config.pipeline, self.config.fd_capable)
                {
                    Err((outcome, detail)) => crate::control::rejection(&control, outcome, detail),
                    Ok(apply) => {
                        self.apply(apply, now);
                        can_wire::Answer::accept(&control)
                    }
                }
            }
        };
        let id = self.config.ids.id(can_wire::Kind::ControlAnswer);
        if let Ok(frame) = Frame::new(id, &answer.emit(), self.encoder.format().is_fd()) {
            self.push_priority(frame);
        }
    }

    fn apply(&mut self, apply: crate::control::Apply, now: u64) {
        use crate::control::Apply;
        match apply {
            Apply::Start => self.start_session(now),
            Apply::Stop => {
                self.abort_scan(AbortReason::Stopped);
                self.session.stop(now);
            }
            Apply::SensorInfo => {
                let pages = crate::status::info_pages(self.session.params(), self.model);
                for page in pages.into_iter().rev() {
                    self.push_status(page);
                }
            }
            Apply::ResetCounters => {
                self.stats = BridgeStats::default();
                let boot = self.health.boot_ms;
                let state = self.health.bus_state;
                self.health = crate::status::Health::new();
                self.health.boot_ms = boot;
                self.health.bus_state = state;
            }
            Apply::Pipeline(cfg) => {
                if cfg.decimation != self.config.pipeline.decimation
                    || cfg.temporal != self.config.pipeline.temporal
                {
                    // The user takes the decimation over from the governor.
                    self.auto_decimation = false;
                }
                // Validated by `plan`; takes effect when the next scan begins.
                let _ = self.pipeline.set_config(cfg);
                self.config.pipeline = cfg;
            }
            Apply::Encoding(e) => self.config.encoding = e,
            Apply::Format(f) => {
                self.pending_format = Some(f);
                self.config.budget.format = f;
                self.governor = Governor::new(self.config.budget);
            }
        }
    }

    /// Lets the governor choose decimation for the stream the session runs.
    fn apply_plan(&mut self) {
        let scan = self.session.scan_request();
        let Some(rpm) = self.session.params().scan_rpm.filter(|&r| r > 0) else {
            return;
        };
        let info = ScanInfo {
            seq: 0,
            timestamp_ms: 0,
            first_step: scan.start,
            last_step: scan.end,
            cluster: u16::from(scan.cluster),
        };
        let mut cfg = self.config.pipeline;
        cfg.decimation = None;
        cfg.temporal = TemporalDecimation::All;
        let points = u16::try_from(crate::pipeline::output_len(&cfg, &info)).unwrap_or(u16::MAX);
        // Scans per second × 1000: rpm / 60 per second, one in (skip + 1) sent.
        // The rpm comes from the sensor: saturating. `skip + 1` is 1..=256.
        let rate_milli = (rpm.saturating_mul(1000) / 60)
            .checked_div(u32::from(scan.skip).wrapping_add(1))
            .unwrap_or(0);
        let plan = self
            .governor
            .plan(points, &self.wire_encoding(&scan), rate_milli);
        cfg.decimation = (plan.factor > 1).then_some(Decimation {
            factor: u16::from(plan.factor),
            mode: DecimationMode::Min,
        });
        if plan.every_nth > 1 {
            cfg.temporal = TemporalDecimation::EveryNth(u16::from(plan.every_nth));
        }
        if self.pipeline.set_config(cfg).is_ok() {
            self.config.pipeline = cfg;
            self.plan = Some(plan);
        }
    }

    /// When the byte that ended the current event arrived, caller's µs: the chunk's
    /// end less the bytes after it at the UART's bit rate.
    fn event_us(&self) -> u64 {
        let byte_ns = 10_000_000_000u64
            .checked_div(u64::from(self.config.uart_bit_rate))
            .unwrap_or(0);
        let after = u64::try_from(self.bytes_after).unwrap_or(u64::MAX);
        self.chunk_end_us
            .saturating_sub(after.saturating_mul(byte_ns) / 1000)
    }

    fn start_session(&mut self, now: u64) {
        self.model = None;
        self.clock.reset();
        self.sync_offset = None;
        self.sync_asked = false;
        self.scan_clock.reset();
        if self.link_up {
            self.session.start(now);
            if self.estimating() {
                self.session.request_time_sync(now);
            }
        } else {
            // Nothing to send to yet: held until the link is up.
            self.session.start_link_down();
        }
    }

    fn notice(&mut self, notice: Notice) {
        if notice == Notice::Streaming && self.auto_decimation {
            self.apply_plan();
        }
        if let Notice::TimeSync { sensor_ms, now_ms } = notice {
            // The TM reading is one more reading of the sensor's clock, in order with the
            // scans' timestamps: extended the same way.
            let sensor = self.clock.unwrap(sensor_ms);
            // The sensor read its clock before sending the answer: echo `TM1`, status
            // and the timestamp line are 14 bytes ahead of the time this line ended.
            let byte_ns = 10_000_000_000u64
                .checked_div(u64::from(self.config.uart_bit_rate))
                .unwrap_or(0);
            let read_by = self
                .event_us()
                .saturating_sub(byte_ns.saturating_mul(14) / 1000);
            self.scan_clock
                .on_tm(sensor, self.sent_us.min(read_by), read_by);
            if self.sync_asked {
                self.sync_offset = i64::try_from(now_ms)
                    .ok()
                    .zip(i64::try_from(sensor).ok())
                    .map(|(now, sensor)| now.wrapping_sub(sensor));
            }
        }
        if matches!(notice, Notice::Recovering(_)) {
            // The sensor rebooted, or the recovery's `RS` resets its clock to 0: the
            // extension and the sync are void.
            self.clock.reset();
            self.sync_offset = None;
            self.scan_clock.sensor_restarted();
        }
        if let Notice::Recovering(reason) = notice {
            self.abort_scan(match reason {
                RecoverReason::Reboot => AbortReason::SensorRestart,
                RecoverReason::Silence | RecoverReason::Timeout => AbortReason::Timeout,
                _ => AbortReason::SensorError,
            });
        }
        self.notice = Some(notice);
    }

    /// Whether the sensor clock model runs: asked for, and built in (a constant false
    /// without the `time-estimate` feature, so that none of its code is linked).
    fn estimating(&self) -> bool {
        cfg!(feature = "time-estimate") && self.estimate_time
    }

    fn begin_scan(&mut self, s: ScanRequest, raw_timestamp: u32, now: u64) {
        self.stats.scans_in = self.stats.scans_in.wrapping_add(1);
        self.phase = Phase::Ignored;
        // SPEC 3.1: the sensor's 24-bit clock extended (modulo 2^32), or with a time
        // sync the caller's clock.
        let sensor_ms = self.clock.unwrap(raw_timestamp);
        let estimate = if self.estimating() {
            self.scan_clock.on_scan(sensor_ms, self.event_us())
        } else {
            crate::clock::Estimate {
                time_us: 0,
                valid: false,
            }
        };
        let (mut timestamp, time_synced) = match self.sync_offset {
            Some(offset) => ((sensor_ms as i64).wrapping_add(offset) as u32, true),
            None => (sensor_ms as u32, false),
        };
        let time_estimated = self.estimating() && estimate.valid;
        let mut time_master = false;
        if time_estimated {
            // SPEC 3.1: the first point's time, µs modulo 2^32, in the time master's
            // clock while a time sync holds (SPEC 9), else in the bridge's.
            let first_us = estimate
                .time_us
                .wrapping_add(self.first_point_offset_us(&s));
            let master = self.time_sync.to_master(first_us);
            time_master = master.is_some();
            timestamp = master.unwrap_or(first_us) as u32;
        }
        let time_synced = time_synced || time_estimated;
        if !self.session.geometry().allows_scans() {
            // The last PP answer was damaged or doubted: no angles to publish it with.
            self.lose_scan();
            return;
        }
        let info = ScanInfo {
            seq: u32::from(self.seq),
            timestamp_ms: sensor_ms as u32,
            first_step: s.start,
            last_step: s.end,
            cluster: u16::from(s.cluster),
        };
        let points = match self.pipeline.begin_scan(info) {
            ScanStart::Publish { points } => points,
            ScanStart::Skip => {
                self.stats.scans_skipped = self.stats.scans_skipped.wrapping_add(1);
                return;
            }
            ScanStart::BadGeometry => return,
        };
        let Ok(point_count) = u16::try_from(points) else {
            self.pipeline_discard();
            return;
        };
        let encoding = self.wire_encoding(&s);
        let cost = self.governor.cost(point_count, &encoding);
        // 10 bits per UART byte; a step is `width` chars, lines add 2 bytes per 64 chars.
        // Widths are at most 3 + 4 chars and `value_count` a u16: `bytes` is below 2^23,
        // `bytes × 10^7` below 2^47, no overflow.
        let width = u64::from(s.data.distance_width().wrapping_add(s.data.aux_width()));
        let chars = u64::from(s.value_count()).wrapping_mul(width);
        let bytes = chars
            .wrapping_add(chars.div_ceil(64).wrapping_mul(2))
            .wrapping_add(40);
        let uart_us = match self.config.link {
            // A TCP stream brings a scan at once: no frame leaves while it arrives.
            LinkKind::Tcp => 0,
            LinkKind::Uart => bytes,
        }
        .wrapping_mul(10 * 1_000_000)
        .checked_div(u64::from(self.config.uart_bit_rate.max(1)))
        .unwrap_or(0);
        let free = Q.saturating_sub(self.queue.len());
        if !self.governor.admit(now, &cost, uart_us, free) {
            self.stats.scans_dropped = self.stats.scans_dropped.wrapping_add(1);
            self.pipeline_discard();
            return;
        }
        self.admitted = Some(cost);
        let header = ScanHeader {
            seq: self.seq,
            timestamp_ms: timestamp,
            point_count,
            encoding,
            time_synced,
            time_estimated,
            time_master,
            grouping: self.grouping(&s),
            step_increment: u8::try_from(self.step_increment(&s)).unwrap_or(u8::MAX),
            first_step: self.first_output_step(&s),
            ares: self.geometry().map_or(0, |(ares, _)| ares),
        };
        if let Some(format) = self.pending_format.take() {
            // Between scans: cannot fail for a validated format.
            let _ = self.encoder.set_format(format);
        }
        match self.encoder.begin(&header) {
            Ok(frames) => {
                for f in frames {
                    push(&mut self.queue, f, &mut self.stats);
                }
                self.seq = self.seq.wrapping_add(1);
                self.overflow = false;
                self.filtered = false;
                self.phase = Phase::Active(s);
            }
            Err(_) => self.pipeline_discard(),
        }
    }

    /// The configured encoding, without an intensity channel when the scan has none.
    fn wire_encoding(&self, s: &ScanRequest) -> Encoding {
        let mut e = self.config.encoding;
        if s.data.aux_width() == 0 {
            e.intensity = can_wire::IntensityEncoding::None;
        }
        e
    }

    fn step_increment(&self, s: &ScanRequest) -> u32 {
        let factor = self
            .pipeline
            .config()
            .decimation
            .map_or(1, |d| u32::from(d.factor));
        // u8 × u16: no overflow.
        u32::from(s.cluster.max(1)).wrapping_mul(factor)
    }

    fn grouping(&self, s: &ScanRequest) -> Grouping {
        match self.pipeline.config().decimation.map(|d| d.mode) {
            Some(DecimationMode::Mean) => Grouping::Mean,
            Some(DecimationMode::Min) => Grouping::Min,
            _ if s.cluster > 1 => Grouping::Min,
            _ => Grouping::Single,
        }
    }

    /// The sensor's geometry, `(ARES, AFRT)`, when a PP answer (or
    /// [`Bridge::assume_sensor`]) gave both; `None`: unknown (SPEC 3.2, `ares` = 0).
    fn geometry(&self) -> Option<(u16, u32)> {
        let params = self.session.params();
        let ares = params.ares.or(self.assumed.0);
        let afrt = params.afrt.or(self.assumed.1);
        let ares = ares
            .and_then(|a| u16::try_from(a).ok())
            .filter(|&a| a > 0)?;
        Some((ares, afrt?))
    }

    /// How long after the sensor's stamp (step 0 of its revolution) the first output
    /// point was measured, µs: its step × the scan period / ARES (0 without geometry
    /// or scan speed).
    fn first_point_offset_us(&self, s: &ScanRequest) -> u64 {
        let Some((ares, afrt)) = self.geometry() else {
            return 0;
        };
        let Some(rpm) = self.session.params().scan_rpm.filter(|&r| r > 0) else {
            return 0;
        };
        // The first point's sensor step: its step relative to AFRT, plus AFRT.
        let step = i64::from(self.first_output_step(s)).saturating_add(i64::from(afrt));
        let step = u64::try_from(step).unwrap_or(0);
        // step < 2^16, 60·10^6 < 2^26: the product fits easily.
        step.saturating_mul(60_000_000)
            .checked_div(u64::from(rpm).saturating_mul(u64::from(ares)))
            .unwrap_or(0)
    }

    /// Step of the first output point, relative to the sensor's front step (AFRT); with
    /// the geometry unknown, the sensor step itself (SPEC 3.2).
    fn first_output_step(&self, s: &ScanRequest) -> i16 {
        let cluster = u32::from(s.cluster.max(1));
        let mut first = u32::from(s.start);
        if let Some(roi) = self.pipeline.config().roi {
            let lo = u32::from(roi.first);
            if lo > first {
                // `lo > first`, both u16, cluster a u8: no overflow.
                first = first.wrapping_add(
                    lo.wrapping_sub(first)
                        .div_ceil(cluster)
                        .wrapping_mul(cluster),
                );
            }
        }
        let afrt = self.geometry().map_or(0, |(_, afrt)| afrt);
        // Two u32 values: the difference fits an i64.
        let rel = i64::from(first).wrapping_sub(i64::from(afrt));
        i16::try_from(rel).unwrap_or(i16::MIN)
    }

    fn finish_scan(&mut self) {
        let (pipeline, _, mut out) = self.split();
        let _ = pipeline.end_scan(true, &mut |p: Point| out.emit(p));
        self.phase = Phase::None;
        if self.overflow {
            self.abort_scan_now(AbortReason::QueueOverflow);
            return;
        }
        let flags = TrailerFlags {
            truncated: false,
            sensor_error: false,
            filtered: self.filtered || self.pipeline.filtered(),
        };
        self.settle_lossless();
        match self.encoder.finish(flags) {
            Ok(frames) => {
                for f in frames {
                    push(&mut self.queue, f, &mut self.stats);
                }
                self.stats.scans_sent = self.stats.scans_sent.wrapping_add(1);
            }
            Err(_) => self.abort_scan_now(AbortReason::BadData),
        }
    }

    /// A lossless scan about to be finished: the governor learns what it really cost,
    /// is charged what it took beyond its admission, and re-plans when its estimate
    /// moved.
    fn settle_lossless(&mut self) {
        let (Some((points, bytes)), Some(admitted)) =
            (self.encoder.lossless_progress(), self.admitted.take())
        else {
            return;
        };
        let budget = *self.governor.budget();
        let encoding = self.config.encoding;
        // A u32 × 128 fits 64 bits.
        let bits_x16 = u32::try_from(
            u64::from(bytes)
                .wrapping_mul(128)
                .checked_div(u64::from(points.max(1)))
                .unwrap_or(0),
        )
        .unwrap_or(u32::MAX);
        let actual = can_wire::bandwidth::lossless_cost(
            points,
            &encoding,
            Some(bits_x16),
            budget.format,
            budget.extended,
            budget.rates,
        );
        self.governor.observe(points, bytes);
        self.governor.settle(&admitted, &actual);
        if self.auto_decimation && self.governor.replan_due(&encoding) {
            self.apply_plan();
        }
    }

    /// Ends the scan in progress, if any, with an abort frame.
    fn abort_scan(&mut self, reason: AbortReason) {
        if matches!(self.phase, Phase::Active(_)) {
            self.pipeline_discard();
            self.abort_scan_now(reason);
        }
        self.phase = Phase::None;
    }

    fn abort_scan_now(&mut self, reason: AbortReason) {
        if let Ok(f) = self.encoder.abort(reason, 0) {
            push(&mut self.queue, f, &mut self.stats);
            self.stats.scans_aborted = self.stats.scans_aborted.wrapping_add(1);
        }
        self.phase = Phase::None;
    }

    /// Ends the pipeline's scan without publishing what its windows still hold.
    fn pipeline_discard(&mut self) {
        let _ = self.pipeline.end_scan(false, &mut |_p: Point| {});
    }
}

/// A reading as the encoder takes it: its distance (range or error code, the run's rule
/// tells) and its second value as the intensity (0 for data sets without one, as the
/// decoder gives them), scaled to 16 bits (SPEC 4). A plain function, so that every run
/// of readings shares one compiled encoder loop per encoding.
fn reading_point(r: &scip::Reading) -> (u32, u16) {
    (r.distance, can_wire::IntensityEncoding::from_sensor(r.aux))
}

/// The parts of the engine a run of output points goes through.
struct Output<'a, const Q: usize> {
    encoder: &'a mut ScanEncoder,
    queue: &'a mut FrameQueue<Q>,
    stats: &'a mut BridgeStats,
    overflow: &'a mut bool,
    filtered: &'a mut bool,
}

impl<const Q: usize> Output<'_, Q> {
    /// One output point into the encoder; a full data frame into the queue, if two slots
    /// are free (one stays for the trailer or abort).
    fn emit(&mut self, p: Point) {
        if *self.overflow {
            return;
        }
        let distance = match p.range_mm {
            Some(mm) => Distance::Mm(mm),
            None => Distance::Invalid,
        };
        let intensity = p
            .intensity
            .map_or(0, can_wire::IntensityEncoding::from_sensor);
        // A due data frame is built in a new back slot of the queue, not moved into it.
        let mut slots = DataSlots(self.queue);
        match push_point(self.encoder, distance, intensity, &mut slots) {
            Ok(run) => {
                self.stats.frames = self.stats.frames.wrapping_add(run.frames);
                if run.stop == Some(RunStop::NoSlot) {
                    *self.overflow = true;
                    self.stats.queue_overflows = self.stats.queue_overflows.wrapping_add(1);
                }
            }
            Err(_) => *self.filtered = true,
        }
    }

    /// Points the pipeline emitted, into the encoder in one run (what [`Output::emit`]
    /// does for each of them); returns how many it took, how many of those were no
    /// range and how many of those were ranges outside the rule's window.
    fn encode_run(
        &mut self,
        points: &[scip::Reading],
        rule: can_wire::RangeRule,
    ) -> (usize, usize, usize) {
        let mut slots = DataSlots(self.queue);
        match push_readings(self.encoder, points, rule, &mut slots) {
            Ok(run) => {
                self.stats.frames = self.stats.frames.wrapping_add(run.frames);
                match run.stop {
                    Some(RunStop::NoSlot) => {
                        *self.overflow = true;
                        self.stats.queue_overflows = self.stats.queue_overflows.wrapping_add(1);
                    }
                    Some(RunStop::TooManyPoints) => *self.filtered = true,
                    None => {}
                }
                let n = |x: u32| usize::try_from(x).unwrap_or(usize::MAX);
                (n(run.points), n(run.invalid), n(run.rejected))
            }
            Err(_) => {
                *self.filtered = true;
                (0, 0, 0)
            }
        }
    }
}

/// A run of readings into the encoder ([`ScanEncoder::push_run`]), its frames into
/// `sink`. Not generic (the queue is a `dyn` sink, one call per frame) and never
/// inlined: the encoder's loops are compiled here, in this crate, at its optimisation
/// level (the boards build their own crates for size; a copy instantiated there for the
/// board's queue ran the DL loops about 40 % slower on the Cortex-M4).
#[inline(never)]
fn push_readings(
    encoder: &mut ScanEncoder,
    points: &[scip::Reading],
    rule: can_wire::RangeRule,
    sink: &mut dyn FrameSink,
) -> Result<can_wire::Run, can_wire::Error> {
    encoder.push_run(points, rule, reading_point, sink)
}

/// One point into the encoder ([`ScanEncoder::push_point_to`]): like [`push_readings`],
/// compiled here once for every queue.
#[inline(never)]
fn push_point(
    encoder: &mut ScanEncoder,
    distance: Distance,
    intensity: u16,
    sink: &mut dyn FrameSink,
) -> Result<can_wire::Run, can_wire::Error> {
    encoder.push_point_to(distance, intensity, sink)
}

/// The readings that `rule` finds no range, and those of them that are ranges its
/// window rejects (the points a run did not code).
#[cold]
#[inline(never)]
fn count_no_range(rule: &can_wire::RangeRule, readings: &[scip::Reading]) -> (usize, usize) {
    let (mut invalid, mut rejected) = (0usize, 0usize);
    for r in readings {
        let d = r.distance;
        // At most the readings' count.
        invalid = invalid.wrapping_add(usize::from(!rule.is_range(d)));
        rejected = rejected.wrapping_add(usize::from(rule.is_sensor_range(d) && !rule.is_range(d)));
    }
    (invalid, rejected)
}

/// A measurement response whose status carries a scan.
fn carries_scan(s: &ScanRequest, status: Status) -> bool {
    match s.mode {
        ScanMode::Single => status == Status::OK,
        ScanMode::Continuous => carries_frame(status),
    }
}

/// The status of a stream frame (`99`, or `0M` on SCIP 2.2).
fn carries_frame(status: Status) -> bool {
    matches!(status, Status::Scip2([b'9', b'9'] | [b'0', b'M']))
}

/// The queue as the encoder's [`FrameSink`]: a data frame gets a slot when two are free
/// (one stays for the scan's trailer or abort).
struct DataSlots<'a, const Q: usize>(&'a mut FrameQueue<Q>);

impl<const Q: usize> FrameSink for DataSlots<'_, Q> {
    #[inline]
    fn data_slot(&mut self) -> Option<&mut Frame> {
        data_slot(self.0)
    }
}

/// A back slot for a data frame, if two are free.
#[inline]
fn data_slot<const Q: usize>(queue: &mut FrameQueue<Q>) -> Option<&mut Frame> {
    if queue.free() >= 2 {
        queue.push_back_slot()
    } else {
        None
    }
}

fn push<const Q: usize>(queue: &mut FrameQueue<Q>, f: Frame, stats: &mut BridgeStats) {
    if queue.push_back(f).is_ok() {
        stats.frames = stats.frames.wrapping_add(1);
    }
}
