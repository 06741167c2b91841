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
//!
//! This module holds the [`Bridge`] API, its configuration, errors and counters, and the
//! state it works on; the work is split by concern:
//! - `route`: each decoder event to the session and along the scan path;
//! - `scan`: a scan's lifecycle (begin, finish, abort) and its geometry;
//! - `line`: data lines into the pipeline and the encoder;
//! - `output`: points and frames into the encoder and the queue;
//! - `control`: control and time frames received from the bus;
//! - `status`: status frames;
//! - `notice`: the session's start and its notices.

use can_wire::{AbortReason, Encoding, Frame, NodeIds, ScanEncoder};
use scip::{Decoder, ScanRequest, Status};

use crate::governor::{Budget, Governor};
use crate::link::LinkKind;
use crate::pipeline::{Pipeline, PipelineConfig};
use crate::queue::FrameQueue;
use crate::session::{Action, Notice, Session, SessionConfig, SessionError};

/// Cells of the filtered lines' output buffer: the output points of the data events
/// before waiting for the encoder as one run, and a data event's cells (a line, or a
/// run of lines: [`scip::Decoder::feed_runs`]) with the windows' headroom after them.
/// Two lines' readings: a run's, or two lines of 2-char values.
const BATCH_CELLS: usize = 2 * scip::MAX_READINGS + crate::pipeline::LINE_HEADROOM;
const _: () = assert!(scip::MAX_RUN_READINGS <= 2 * scip::MAX_READINGS);

mod control;
mod line;
mod notice;
mod output;
mod route;
mod scan;
mod status;

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

impl BridgeConfig {
    /// The configuration of the bridge with identifiers `ids` sending `format` frames,
    /// with the defaults of the project's boards:
    /// - the default session ([`SessionConfig::default`]: a full-range distance stream,
    ///   the UART at 115 200 bit/s, no `SS`) and pipeline (every stage off);
    /// - the lossless coding with 16-bit intensities (SPEC 4.2);
    /// - the whole of a 1 Mbit/s bus: classic CAN, or for a CAN FD `format` a 5 Mbit/s
    ///   data phase and a controller that can send FD frames; extended identifiers when
    ///   `ids` is in an extended window;
    /// - a UART link at 115 200 bit/s, status pages every second.
    ///
    /// Change the rest with struct update syntax:
    /// ```
    /// # use bridge::engine::{Bridge, BridgeConfig};
    /// # use can_wire::{Encoding, FrameFormat, IdWindow};
    /// let config = BridgeConfig {
    ///     encoding: Encoding::PLAIN_MM,
    ///     status_period_ms: 0,
    ///     ..BridgeConfig::new(IdWindow::DEFAULT.node(0).unwrap(), FrameFormat::FD64)
    /// };
    /// assert!(Bridge::<64>::new(config).is_ok());
    /// ```
    pub fn new(ids: NodeIds, format: can_wire::FrameFormat) -> BridgeConfig {
        let session = SessionConfig::default();
        let fd = format.is_fd();
        BridgeConfig {
            session,
            pipeline: PipelineConfig::default(),
            encoding: Encoding {
                distance: can_wire::DistanceEncoding::Lossless,
                intensity: can_wire::IntensityEncoding::I16,
                unit_exp: 0,
            },
            budget: Budget {
                rates: if fd {
                    can_wire::bandwidth::BitRates::FD_1M_5M
                } else {
                    can_wire::bandwidth::BitRates::CLASSIC_1M
                },
                format,
                extended: ids.window().is_extended(),
                share_permille: 1000,
            },
            ids,
            uart_bit_rate: session.initial_bit_rate,
            status_period_ms: 1000,
            fd_capable: fd,
            link: LinkKind::Uart,
        }
    }

    /// This configuration for a sensor on a network link (an Ethernet sensor's TCP
    /// connection, or a simulator that hands over whole responses as one does): a TCP
    /// stream ([`LinkKind::Tcp`]: the session waits for [`Bridge::link_up`] and holds on
    /// [`Bridge::link_down`]), no SCIP bit-rate steps (`SS` is for serial links), and
    /// the bytes of a chunk [`crate::link::NETWORK_BIT_RATE`] apart.
    pub fn on_network(mut self) -> Self {
        self.link = LinkKind::Tcp;
        self.uart_bit_rate = crate::link::NETWORK_BIT_RATE;
        self.session.bit_rate = None;
        self
    }
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
    /// The filtered data lines' output points, as readings: the batch not yet encoded
    /// at the front ([`Core::batch`]), the next line's cells after it.
    decimated: [scip::Reading; BATCH_CELLS],
    /// The output points at the front of `decimated` waiting for the encoder, and how
    /// many of them have no range: the filtered lines of one `on_uart` chunk go into
    /// the encoder as one run ([`Core::flush_batch`]).
    batch: (usize, usize),
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
                decimated: [scip::Reading::default(); BATCH_CELLS],
                batch: (0, 0),
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
            // The full data lines of the chunk in runs: the pipeline's and the encoder's
            // set-up once a run, not once a line.
            let (used, event) = self.decoder.feed_runs(rest);
            rest = rest.get(used..).unwrap_or(&[]);
            if let Some(event) = event {
                // The event's time is worked out only where it is used.
                self.core.bytes_after = rest.len();
                self.core.event(&event, now_ms);
            }
        }
        // The chunk's filtered lines leave before it returns.
        self.core.flush_batch();
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
