//! The session state machine itself.

use scip::{
    Command, Event, KnownModel, ParamError, Request, ScanRequest, SensorParams, Status, StatusKind,
    Summary, TimeMode,
};

use super::config::{SessionConfig, SessionError};

/// Frame periods of silence a stream may have before it counts as lost (see
/// [`Session::silence_limit_ms`]).
pub const STALL_FRAMES: u32 = 8;

/// Silence a stream may have on top of [`STALL_FRAMES`] frame periods, ms.
pub const STALL_MARGIN_MS: u32 = 500;
/// `TM1` readings per time sync: answers at different phases of the sensor's
/// millisecond place its ticks to a fraction of one.
pub const TM_READS: u8 = 24;

/// Where the session is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum State {
    /// Not started, or stopped.
    Off,
    /// `QT` sent: stops any stream and tells SCIP 1.1 from 2.x.
    Probe,
    /// `SCIP2.0` sent to a SCIP 1.1 sensor.
    Switch,
    /// `VV` sent.
    Version,
    /// `PP` sent.
    Parameters,
    /// `II` sent.
    Info,
    /// `SS` sent.
    BitRate,
    /// The stream request sent, its ack awaited.
    Start,
    /// Scans arriving.
    Streaming,
    /// `QT` sent on the way to time sync.
    SyncStop,
    /// `TM0` sent.
    SyncEnter,
    /// `TM1` sent.
    SyncRead,
    /// `TM2` sent.
    SyncLeave,
    /// `QT` sent on the way to `Off`.
    Stopping,
    /// `QT`, then `RS`, sent after a failure.
    Resetting,
    /// Waiting out the back-off before probing again.
    Backoff,
    /// The sensor link (a TCP connection) is down: nothing is sent and nothing times
    /// out until [`Session::link_up`] starts the session again.
    LinkDown,
}

/// What the caller must do for the session.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Action {
    /// Write this command to the sensor (encode it with [`Request::encode`]).
    Send(Request),
    /// Switch the UART to this bit rate (after the sensor's `SS` answer, or back to the
    /// power-up rate after a reset).
    SetBitRate(u32),
}

/// Why the session is recovering the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecoverReason {
    /// No answer to a command, even after retries.
    Timeout,
    /// The stream went silent.
    Silence,
    /// A hardware-fault status (50–97) or a measurement stop (21–49).
    SensorFault(Status),
    /// A SCIP 1.1 status while in SCIP 2 mode: the sensor rebooted.
    Reboot,
    /// The sensor refused to start the stream for a reason other than its parameters.
    StartFailed(Status),
    /// The PP answer was doubted every time it was asked for ([`Geometry::Doubted`]).
    Parameters(ParamError),
}

/// What the session knows of the sensor's geometry (PP), which every published scan's
/// angles depend on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Geometry {
    /// No PP answer seen yet (e.g. a replay of a capture without one).
    Unknown,
    /// The last PP answer passed every check ([`SensorParams::check`]): [`Session::params`].
    Established,
    /// The last PP answer was damaged (a line failed its sum or framing): no scan may be
    /// published with a geometry until a sound answer comes.
    Damaged,
    /// The last PP answer arrived intact but failed a check (a flip the line sum cannot
    /// see, an implausible value): no scan may be published until a sound answer comes.
    Doubted(ParamError),
}

impl Geometry {
    /// True when scans may be published: established, or not known at all (no PP was
    /// ever seen, so none was doubted).
    pub fn allows_scans(self) -> bool {
        matches!(self, Self::Established | Self::Unknown)
    }
}

/// Something worth telling the rest of the bridge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Notice {
    /// The sensor answered in SCIP 1.1 and is being switched.
    Scip11Detected,
    /// PP decoded: the sensor's geometry is known ([`Session::params`]).
    Identified,
    /// The stream's ack arrived: scans follow.
    Streaming,
    /// The sensor refused the stream request's parameters; the session is off.
    StreamRefused(Status),
    /// The session is recovering the sensor.
    Recovering(RecoverReason),
    /// TM1 answered: the sensor's clock read `sensor_ms` at about `now_ms` (the midpoint
    /// of request and answer).
    TimeSync {
        /// Sensor time, 24-bit ms.
        sensor_ms: u32,
        /// Caller's time, ms.
        now_ms: u64,
    },
    /// `stop()` completed.
    Stopped,
    /// The sensor link went down: the session is held ([`State::LinkDown`]).
    LinkDown,
}

/// Counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SessionStats {
    /// Commands sent (retries included).
    pub commands: u32,
    /// Commands sent again after a timeout or a damaged answer.
    pub retries: u32,
    /// Recoveries started.
    pub recoveries: u32,
    /// Reboots detected (SCIP 1.1 status after SCIP 2 was reached).
    pub reboots: u32,
    /// Stream frames whose status was not 99/00/0M (21–97 and others).
    pub error_statuses: u32,
    /// Stream frames received intact.
    pub frames: u32,
    /// Stream frames received damaged.
    pub damaged_frames: u32,
    /// Answers nobody was waiting for.
    pub unexpected: u32,
    /// PP answers that arrived intact but failed a check ([`Geometry::Doubted`]).
    pub pp_doubted: u32,
}

/// The sensor session. See the [module docs](super).
#[derive(Debug, Clone)]
pub struct Session {
    config: SessionConfig,
    state: State,
    /// The command whose answer is awaited.
    pending: Option<Request>,
    sent_at: u64,
    retries: u8,
    /// Actions to hand out, oldest first (at most two are ever queued).
    outbox: [Option<Action>; 2],
    /// A notice raised by `poll` (timeouts), for [`Session::take_notice`].
    notice: Option<Notice>,
    /// The response being decoded answers `pending`.
    current_is_pending: bool,
    /// The response being decoded is a frame of our stream.
    current_is_frame: bool,
    /// The response being decoded is a PP answer (ours or not): its fields are
    /// collected and kept when it ends intact, so that a listening session (a replay)
    /// learns the geometry too.
    current_is_pp: bool,
    pp: SensorParams,
    /// The response being decoded is a VV answer: its `PROD` names the model.
    current_is_vv: bool,
    /// The echo of the response being decoded did not parse.
    current_echo_damaged: bool,
    /// The last response that ended was a stream frame.
    after_frame: bool,
    vv_model: Option<KnownModel>,
    /// The model the last intact VV answer named, if a known one.
    vv_known: Option<KnownModel>,
    /// The last PP answer doubted only for differing from its model's table: the same
    /// answer again is accepted (a unit that differs from the table, answering the same).
    last_doubted: Option<SensorParams>,
    geometry: Geometry,
    /// Doubt about the PP answer just ended, for `on_response`.
    pp_doubt: Option<ParamError>,
    current_status: Option<Status>,
    last_rx: u64,
    backoff_ms: u32,
    backoff_until: u64,
    reached_scip2: bool,
    sync_wanted: bool,
    /// `TM1` answers still to read in this time sync.
    sync_reads: u8,
    /// The UART bit rate the session last asked for (the power-up rate at first).
    link_rate: u32,
    params: SensorParams,
    stats: SessionStats,
}

impl Session {
    /// A session that is off until [`Session::start`].
    pub fn new(config: SessionConfig) -> Result<Self, SessionError> {
        config.validate()?;
        Ok(Self {
            config,
            state: State::Off,
            pending: None,
            sent_at: 0,
            retries: 0,
            outbox: [None, None],
            notice: None,
            current_is_pending: false,
            current_is_frame: false,
            current_is_pp: false,
            pp: SensorParams::default(),
            current_is_vv: false,
            current_echo_damaged: false,
            after_frame: false,
            vv_model: None,
            vv_known: None,
            last_doubted: None,
            geometry: Geometry::Unknown,
            pp_doubt: None,
            current_status: None,
            last_rx: 0,
            backoff_ms: config.backoff_min_ms,
            backoff_until: 0,
            reached_scip2: false,
            sync_wanted: false,
            sync_reads: 0,
            link_rate: config.initial_bit_rate,
            params: SensorParams::default(),
            stats: SessionStats::default(),
        })
    }

    /// The state.
    pub fn state(&self) -> State {
        self.state
    }

    /// The configuration.
    pub fn config(&self) -> &SessionConfig {
        &self.config
    }

    /// Counters.
    pub fn stats(&self) -> &SessionStats {
        &self.stats
    }

    /// The PP parameters of the sensor from the last PP answer that passed every check
    /// (empty before one did).
    pub fn params(&self) -> &SensorParams {
        &self.params
    }

    /// What is known of the sensor's geometry: whether scans may be published.
    pub fn geometry(&self) -> Geometry {
        self.geometry
    }

    /// The stream request in force.
    pub fn scan_request(&self) -> ScanRequest {
        self.config.scan
    }

    /// Starts (or restarts) bringing the sensor up.
    pub fn start(&mut self, now: u64) {
        self.probe(now);
    }

    /// Stops the stream (`QT`) and turns the session off (at once when the link is
    /// down: there is no sensor to tell).
    pub fn stop(&mut self, now: u64) {
        if self.state == State::LinkDown {
            self.state = State::Off;
            self.notice = Some(Notice::Stopped);
            return;
        }
        self.send(State::Stopping, Request::new(Command::LaserOff), now);
    }

    /// Starts the session held for its link: nothing is sent until [`Session::link_up`].
    pub fn start_link_down(&mut self) {
        self.hold();
    }

    /// The sensor link went down: whatever was asked or being answered is forgotten, and
    /// the session is held ([`State::LinkDown`]) until [`Session::link_up`]. A session
    /// that is off stays off. Returns [`Notice::LinkDown`] when it was running.
    pub fn link_down(&mut self) -> Option<Notice> {
        if matches!(self.state, State::Off | State::LinkDown) {
            return None;
        }
        self.hold();
        Some(Notice::LinkDown)
    }

    /// The sensor link is up (again): a held session starts from the probe, as the
    /// sensor may have rebooted (`QT`, `VV`, `PP`, `II`, then the stream; no `SS` is
    /// re-sent unless configured). Any other state is left as it is.
    pub fn link_up(&mut self, now: u64) {
        if self.state == State::LinkDown {
            self.backoff_ms = self.config.backoff_min_ms;
            self.probe(now);
        }
    }

    /// Holds the session for its link: nothing pending, nothing queued, no response
    /// being decoded.
    fn hold(&mut self) {
        self.state = State::LinkDown;
        self.pending = None;
        self.retries = 0;
        self.outbox = [None, None];
        self.current_is_pending = false;
        self.current_is_frame = false;
        self.current_is_pp = false;
        self.current_is_vv = false;
        self.current_echo_damaged = false;
        self.current_status = None;
        self.after_frame = false;
        // The sensor on the other end may be another one, or rebooted in SCIP 1.1.
        self.reached_scip2 = false;
    }

    /// Asks for a time sync (TM0/TM1/TM2); while streaming, the stream stops for it and
    /// starts again after.
    pub fn request_time_sync(&mut self, now: u64) {
        self.sync_wanted = true;
        if self.state == State::Streaming {
            self.send(State::SyncStop, Request::new(Command::LaserOff), now);
        }
    }

    /// Changes the stream request; a running stream restarts with it.
    pub fn set_scan(&mut self, scan: ScanRequest, now: u64) -> Result<(), SessionError> {
        let config = SessionConfig {
            scan,
            ..self.config
        };
        config.validate()?;
        self.config = config;
        if matches!(self.state, State::Streaming | State::Start) {
            // QT then the new request: Probe does exactly that on a SCIP 2 sensor.
            self.probe(now);
        }
        Ok(())
    }

    /// A notice raised by a timeout in [`Session::poll`], once.
    pub fn take_notice(&mut self) -> Option<Notice> {
        self.notice.take()
    }

    /// The next thing to do, if any; also runs timeouts (whose notice
    /// [`Session::take_notice`] then gives). Call it after every event and periodically
    /// (every few ms).
    pub fn poll(&mut self, now: u64) -> Option<Action> {
        if let Some(a) = self.take_action() {
            return Some(a);
        }
        match self.state {
            State::Off | State::LinkDown => {}
            State::Backoff => {
                if now >= self.backoff_until {
                    self.probe(now);
                }
            }
            State::Streaming => {
                if now.saturating_sub(self.last_rx) > u64::from(self.silence_limit_ms()) {
                    self.notice = self.recover(RecoverReason::Silence, now);
                }
            }
            _ => {
                if self.pending.is_some()
                    && now.saturating_sub(self.sent_at) > u64::from(self.config.response_timeout_ms)
                {
                    self.notice = self.retry_or_recover(RecoverReason::Timeout, now);
                }
            }
        }
        self.take_action()
    }

    /// Takes a data line's event (what [`Session::on_event`] does with it, for a caller
    /// that has told the data lines apart).
    #[inline]
    pub(crate) fn on_data(&mut self, now: u64) {
        self.last_rx = now;
    }

    /// Takes one decoder event; returns what the rest of the bridge should know.
    pub fn on_event(&mut self, event: &Event<'_>, now: u64) -> Option<Notice> {
        match event {
            Event::Start { request, .. } => {
                self.last_rx = now;
                self.current_status = None;
                self.current_is_pending = match (request, self.pending) {
                    (Some(r), Some(p)) => same_command(&r.command, &p.command),
                    _ => false,
                };
                self.current_is_frame = matches!(
                    request.map(|r| r.command),
                    Some(Command::Scan(s)) if same_scan(&s, &self.config.scan)
                );
                self.current_is_pp =
                    matches!(request.map(|r| r.command), Some(Command::Parameters));
                self.current_is_vv = matches!(request.map(|r| r.command), Some(Command::Version));
                self.current_echo_damaged = request.is_none();
                self.pp = SensorParams::default();
                self.vv_model = None;
                None
            }
            Event::Status(status) => {
                self.current_status = Some(*status);
                None
            }
            Event::Field(field) => {
                if self.current_is_pp {
                    self.pp.apply(field.name, field.value);
                }
                if self.current_is_vv && field.name == b"PROD" {
                    self.vv_model = KnownModel::from_model(field.value);
                }
                None
            }
            Event::Timestamp(t) => {
                if self.current_is_pending && self.state == State::SyncRead {
                    // The midpoint of request and answer is the best estimate of when
                    // the sensor read its clock.
                    let mid = self
                        .sent_at
                        .saturating_add(now.saturating_sub(self.sent_at) / 2);
                    return Some(Notice::TimeSync {
                        sensor_ms: *t,
                        now_ms: mid,
                    });
                }
                None
            }
            Event::Data(_) => {
                self.on_data(now);
                None
            }
            Event::Payload(_) => {
                self.last_rx = now;
                None
            }
            Event::End(summary) => {
                self.last_rx = now;
                self.after_frame = self.current_is_frame || is_frame_status(summary.status);
                if core::mem::take(&mut self.current_is_vv) && summary.status == Status::OK {
                    self.vv_known = self.vv_model;
                }
                self.pp_doubt = None;
                if core::mem::take(&mut self.current_is_pp) {
                    self.judge_pp();
                }
                self.on_response(summary, now)
            }
            Event::Error(_) => {
                self.last_rx = now;
                self.current_is_vv = false;
                let frame_status = self.current_status.is_some_and(is_frame_status);
                let maybe_pp = self.current_echo_damaged
                    && self.geometry == Geometry::Unknown
                    && !frame_status
                    && (self.current_status.is_some() || !self.after_frame);
                if core::mem::take(&mut self.current_is_pp) || maybe_pp {
                    // A damaged PP answer, or a damaged answer to an unknown command
                    // (not a stream frame) before any PP: it may have been the PP answer.
                    self.geometry = Geometry::Damaged;
                }
                self.after_frame = self.current_is_frame || frame_status;
                if self.current_is_frame && !self.current_is_pending {
                    self.stats.damaged_frames = self.stats.damaged_frames.wrapping_add(1);
                } else if self.current_is_pending && self.pending.is_some() {
                    // A damaged answer: ask again.
                    return self.retry_or_recover(RecoverReason::Timeout, now);
                }
                self.current_is_pending = false;
                self.current_is_frame = false;
                None
            }
        }
    }

    fn on_response(&mut self, summary: &Summary, now: u64) -> Option<Notice> {
        let status = summary.status;
        let is_pending = core::mem::take(&mut self.current_is_pending);
        let is_frame = core::mem::take(&mut self.current_is_frame);
        if let Status::Scip11(_) = status {
            if self.reached_scip2 && self.state != State::Switch {
                // A SCIP 2 sensor answering in 1.1: it rebooted (URG-04LX boots in 1.1).
                self.stats.reboots = self.stats.reboots.wrapping_add(1);
                self.reached_scip2 = false;
                return self.recover(RecoverReason::Reboot, now);
            }
        } else {
            self.reached_scip2 = true;
        }
        if is_frame && !is_pending {
            return self.on_frame(status, now);
        }
        if !is_pending {
            self.stats.unexpected = self.stats.unexpected.wrapping_add(1);
            return None;
        }
        if let (State::Parameters, Some(doubt)) = (self.state, self.pp_doubt) {
            // Ask again (bounded), then recover.
            return self.retry_or_recover(RecoverReason::Parameters(doubt), now);
        }
        self.pending = None;
        self.retries = 0;
        let kind = status.kind(&command_code(&summary.request));
        match self.state {
            State::Probe => {
                if let Status::Scip11(_) = status {
                    self.send(State::Switch, Request::new(Command::Scip20), now);
                    return Some(Notice::Scip11Detected);
                }
                self.send(State::Version, Request::new(Command::Version), now);
            }
            State::Switch => {
                // Whatever the answer, probe again: a SCIP 2 status proves the switch.
                self.probe(now);
            }
            State::Version => self.send(State::Parameters, Request::new(Command::Parameters), now),
            State::Parameters => {
                if self.config.full_range {
                    if let (Some(amin), Some(amax)) = (self.params.amin, self.params.amax) {
                        let (Ok(start), Ok(end)) = (u16::try_from(amin), u16::try_from(amax))
                        else {
                            return self.recover(RecoverReason::StartFailed(status), now);
                        };
                        let scan = ScanRequest {
                            start,
                            end,
                            ..self.config.scan
                        };
                        // Keep the old range if the sensor's makes an invalid request.
                        if (SessionConfig {
                            scan,
                            ..self.config
                        })
                        .validate()
                        .is_ok()
                        {
                            self.config.scan = scan;
                        }
                    }
                }
                self.send(State::Info, Request::new(Command::Info), now);
                return Some(Notice::Identified);
            }
            State::Info => match self.config.bit_rate {
                Some(rate) => self.send(State::BitRate, Request::new(Command::BitRate(rate)), now),
                None => self.start_stream(now),
            },
            State::BitRate => {
                if kind == StatusKind::Ok {
                    if let Some(rate) = self.config.bit_rate {
                        self.set_link_rate(rate);
                    }
                }
                self.start_stream(now);
            }
            State::Start => match kind {
                StatusKind::Ok => {
                    self.state = State::Streaming;
                    self.backoff_ms = self.config.backoff_min_ms;
                    return Some(Notice::Streaming);
                }
                StatusKind::Refused => {
                    self.state = State::Off;
                    return Some(Notice::StreamRefused(status));
                }
                _ => return self.recover(RecoverReason::StartFailed(status), now),
            },
            State::SyncStop => self.send(
                State::SyncEnter,
                Request::new(Command::Time(TimeMode::Enter)),
                now,
            ),
            State::SyncEnter => {
                self.sync_reads = TM_READS.saturating_sub(1);
                self.send(
                    State::SyncRead,
                    Request::new(Command::Time(TimeMode::Read)),
                    now,
                )
            }
            State::SyncRead if self.sync_reads > 0 => {
                // Another reading: answers at other phases of the sensor's millisecond
                // narrow down where its ticks fall (crate::clock).
                self.sync_reads = self.sync_reads.saturating_sub(1);
                self.send(
                    State::SyncRead,
                    Request::new(Command::Time(TimeMode::Read)),
                    now,
                )
            }
            State::SyncRead => self.send(
                State::SyncLeave,
                Request::new(Command::Time(TimeMode::Leave)),
                now,
            ),
            State::SyncLeave => {
                self.sync_wanted = false;
                self.start_stream(now);
            }
            State::Stopping => {
                self.state = State::Off;
                return Some(Notice::Stopped);
            }
            State::Resetting => {
                if matches!(summary.request.map(|r| r.command), Some(Command::LaserOff)) {
                    self.send(State::Resetting, Request::new(Command::Reset), now);
                } else {
                    // RS puts the sensor's bit rate back to its power-up value.
                    if self.config.bit_rate.is_some() {
                        self.set_link_rate(self.config.initial_bit_rate);
                    }
                    self.back_off(now);
                }
            }
            State::Off | State::Streaming | State::Backoff | State::LinkDown => {}
        }
        None
    }

    /// Judges the PP answer that just ended intact: its parameters become the session's
    /// when they pass every check; otherwise the geometry is doubted (`pp_doubt`).
    fn judge_pp(&mut self) {
        let pp = self.pp;
        let mut verdict = pp.check();
        if verdict.is_ok() {
            if let (Some(vv), Some(modl)) = (self.vv_known, pp.model) {
                if vv != modl {
                    verdict = Err(ParamError::ModelConflict);
                }
            }
        }
        if let Err(ParamError::NotTheModels(_)) = verdict {
            if self.last_doubted == Some(pp) {
                // The same answer twice: the unit differs from its model's table.
                verdict = Ok(());
            }
        }
        match verdict {
            Ok(()) => {
                self.params = pp;
                self.geometry = Geometry::Established;
                self.last_doubted = None;
            }
            Err(e) => {
                self.stats.pp_doubted = self.stats.pp_doubted.wrapping_add(1);
                self.geometry = Geometry::Doubted(e);
                self.last_doubted = Some(pp);
                self.pp_doubt = Some(e);
            }
        }
    }

    fn on_frame(&mut self, status: Status, now: u64) -> Option<Notice> {
        match status.kind(b"MD") {
            StatusKind::StreamFrame | StatusKind::Unstable | StatusKind::Ok => {
                self.stats.frames = self.stats.frames.wrapping_add(1);
                None
            }
            StatusKind::HardwareFault | StatusKind::Stopped => {
                self.stats.error_statuses = self.stats.error_statuses.wrapping_add(1);
                self.recover(RecoverReason::SensorFault(status), now)
            }
            _ => {
                self.stats.error_statuses = self.stats.error_statuses.wrapping_add(1);
                None
            }
        }
    }

    /// How long a partial response may wait for its next byte before it is stale (the
    /// sensor stopped in the middle of it): the stream's silence limit, or the answer
    /// timeout if shorter.
    pub fn stale_input_ms(&self) -> u32 {
        self.silence_limit_ms().min(self.config.response_timeout_ms)
    }

    /// The stream's silence limit, ms: [`SessionConfig::silence_timeout_ms`], or when
    /// that is 0, [`STALL_FRAMES`] frame periods (scan period × (skip + 1), from PP's
    /// SCAN; 100 ms before PP) plus [`STALL_MARGIN_MS`]. A UTM-30LX (25 ms) recovers
    /// after 700 ms of silence, a URG-04LX (100 ms) after 1300 ms: a sensor that stalls
    /// for 300 ms and resumes keeps its stream, and one that rebooted (which takes about
    /// half a second) is answering by the time it is probed.
    pub fn silence_limit_ms(&self) -> u32 {
        if self.config.silence_timeout_ms != 0 {
            return self.config.silence_timeout_ms;
        }
        let period_ms = self
            .params
            .scan_period_us()
            .map_or(100, |us| us.div_ceil(1000));
        let skip = u32::from(self.config.scan.skip) + 1;
        period_ms
            .saturating_mul(STALL_FRAMES)
            .saturating_mul(skip)
            .saturating_add(STALL_MARGIN_MS)
    }

    fn probe(&mut self, now: u64) {
        self.send(State::Probe, Request::new(Command::LaserOff), now);
    }

    fn start_stream(&mut self, now: u64) {
        if self.sync_wanted {
            self.send(
                State::SyncEnter,
                Request::new(Command::Time(TimeMode::Enter)),
                now,
            );
            return;
        }
        self.send(
            State::Start,
            Request::new(Command::Scan(self.config.scan)),
            now,
        );
    }

    // Per command, not per byte: one copy instead of one inlined at each of its callers
    // (about 0.9 KB of Cortex-M4 flash).
    #[inline(never)]
    fn send(&mut self, state: State, request: Request, now: u64) {
        self.state = state;
        self.pending = Some(request);
        self.sent_at = now;
        self.stats.commands = self.stats.commands.wrapping_add(1);
        self.push_action(Action::Send(request));
    }

    fn retry_or_recover(&mut self, reason: RecoverReason, now: u64) -> Option<Notice> {
        let request = self.pending?;
        if self.retries < self.config.max_retries && self.state != State::Resetting {
            // Below `max_retries` here.
            self.retries = self.retries.wrapping_add(1);
            self.stats.retries = self.stats.retries.wrapping_add(1);
            self.send(self.state, request, now);
            return None;
        }
        if self.state == State::Probe {
            if let Some(raised) = self.config.bit_rate {
                if self.link_rate != raised {
                    // Silent at the power-up rate: the sensor may still run at the rate an
                    // earlier session raised it to (the MCU reset, the sensor did not).
                    self.set_link_rate(raised);
                    self.retries = 0;
                    self.stats.retries = self.stats.retries.wrapping_add(1);
                    self.send(State::Probe, request, now);
                    return None;
                }
                self.set_link_rate(self.config.initial_bit_rate);
            }
        }
        if self.state == State::Resetting {
            // The sensor does not even answer QT/RS: wait, then probe from scratch.
            self.pending = None;
            self.retries = 0;
            self.back_off(now);
            return None;
        }
        self.recover(reason, now)
    }

    /// Waits the current back-off before probing again; the next one is twice as long
    /// (up to the maximum).
    fn back_off(&mut self, now: u64) {
        self.state = State::Backoff;
        self.backoff_until = now.saturating_add(u64::from(self.backoff_ms));
        self.backoff_ms = self
            .backoff_ms
            .saturating_mul(2)
            .min(self.config.backoff_max_ms);
    }

    fn recover(&mut self, reason: RecoverReason, now: u64) -> Option<Notice> {
        self.stats.recoveries = self.stats.recoveries.wrapping_add(1);
        self.retries = 0;
        self.send(State::Resetting, Request::new(Command::LaserOff), now);
        Some(Notice::Recovering(reason))
    }

    /// Asks the caller to switch the UART to `rate`, and remembers it.
    fn set_link_rate(&mut self, rate: u32) {
        self.link_rate = rate;
        self.push_action(Action::SetBitRate(rate));
    }

    fn push_action(&mut self, action: Action) {
        match self.outbox {
            [None, _] => self.outbox[0] = Some(action),
            [Some(_), None] => self.outbox[1] = Some(action),
            // Full: the newest command replaces the queued one (only the latest matters).
            [Some(_), Some(_)] => self.outbox[1] = Some(action),
        }
    }

    fn take_action(&mut self) -> Option<Action> {
        let first = self.outbox[0].take();
        self.outbox[0] = self.outbox[1].take();
        first
    }
}

/// The two command letters (or `SC`/`%S`), for status meanings.
fn command_code(request: &Option<Request>) -> [u8; 2] {
    match request.map(|r| r.command) {
        Some(Command::Scan(s)) => s.code(),
        Some(Command::LaserOn) => *b"BM",
        Some(Command::BitRate(_)) => *b"SS",
        Some(Command::MotorSpeed(_)) => *b"CR",
        Some(Command::Time(_)) => *b"TM",
        _ => *b"??",
    }
}

/// An answer's echo stands for the pending command (a scan ack echoes it exactly).
fn same_command(echo: &Command, sent: &Command) -> bool {
    match (echo, sent) {
        (Command::Scan(a), Command::Scan(b)) => a == b,
        (a, b) => core::mem::discriminant(a) == core::mem::discriminant(b),
    }
}

/// The status of a stream frame (`99`, or `0M` on SCIP 2.2).
fn is_frame_status(status: Status) -> bool {
    matches!(status, Status::Scip2([b'9', b'9'] | [b'0', b'M']))
}

/// A stream frame of `sent`: the same request but for the remaining count.
fn same_scan(echo: &ScanRequest, sent: &ScanRequest) -> bool {
    ScanRequest {
        count: sent.count,
        ..*echo
    } == *sent
}
