//! The session state machine against a scripted sensor: the bytes of each answer are
//! written with the codec's `ResponseWriter` and decoded with its `Decoder`, as on the MCU.

use bridge::session::{Action, Geometry, Notice, RecoverReason, Session, SessionConfig, State};
use scip::{
    Command, Decoder, ParamError, ParamName, Request, ResponseWriter, ScanMode, ScanRequest,
    TimeMode,
};

/// A scripted sensor: SCIP 1.1 until switched, UTM-30LX parameters.
struct Sensor {
    scip11: bool,
    mute: bool,
    baud: u32,
    /// PP answers still to damage: bit 6 of ARES's last digit flipped, which the line
    /// sum cannot see (`ARES:1440` reads `ARES:144p`).
    pp_flips: u32,
    /// The AFRT this unit reports (540, as the UTM-30LX table says).
    afrt: &'static [u8],
}

impl Sensor {
    fn answer(&mut self, req: &Request) -> Vec<u8> {
        let mut out = Vec::new();
        if self.mute {
            return out;
        }
        let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
        w.echo(req);
        if self.scip11 {
            if req.command == Command::Scip20 {
                self.scip11 = false;
                w.status_scip11(b'0');
            } else {
                w.status_scip11(b'E');
            }
            w.end();
            let _ = w.into_inner();
            return out;
        }
        match req.command {
            Command::Version => {
                w.status(*b"00");
                w.field(b"VEND", b"Hokuyo Automatic Co.,Ltd.");
                w.field(b"PROD", b"SOKUIKI Sensor TOP-URG UTM-30LX");
            }
            Command::Parameters => {
                w.status(*b"00");
                for (n, v) in [
                    (&b"MODL"[..], &b"UTM-30LX(Hokuyo Automatic Co.,Ltd.)"[..]),
                    (b"DMIN", b"23"),
                    (b"DMAX", b"60000"),
                    (b"ARES", b"1440"),
                    (b"AMIN", b"0"),
                    (b"AMAX", b"1080"),
                    (b"AFRT", self.afrt),
                    (b"SCAN", b"2400"),
                ] {
                    w.field(n, v);
                }
            }
            Command::Info => {
                w.status(*b"00");
                w.field(b"LASR", b"OFF");
            }
            Command::BitRate(rate) => {
                w.status(if rate == self.baud { *b"03" } else { *b"00" });
                self.baud = rate;
            }
            Command::Scan(s) if s.end > 1080 => w.status(*b"04"),
            Command::Time(TimeMode::Read) => {
                w.status(*b"00");
                w.timestamp(123_456);
            }
            _ => w.status(*b"00"),
        }
        w.end();
        let _ = w.into_inner();
        if req.command == Command::Parameters && self.pp_flips > 0 {
            self.pp_flips -= 1;
            let at = out.windows(9).position(|w| w == b"ARES:1440").unwrap() + 8;
            out[at] ^= 0x40;
        }
        out
    }
}

fn frame(scan: &ScanRequest, status: [u8; 2]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    w.echo(&Request::new(Command::Scan(*scan)));
    w.status(status);
    if status == *b"99" || status == *b"0M" {
        // Each frame a scan (25 ms) later than the one before: the decoder rejects a
        // stream frame whose timestamp does not move on.
        static CLOCK: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(1000);
        w.timestamp(CLOCK.fetch_add(25, std::sync::atomic::Ordering::Relaxed));
        for _ in 0..scan.value_count() {
            w.step(1000, 0);
        }
    }
    w.end();
    let _ = w.into_inner();
    out
}

/// Runs the session against the sensor until it has nothing to do; returns the commands
/// it sent, the bit-rate changes and the notices.
struct Rig {
    session: Session,
    decoder: Decoder,
    sensor: Sensor,
    sent: Vec<Request>,
    rates: Vec<u32>,
    notices: Vec<Notice>,
}

impl Rig {
    fn new(config: SessionConfig, scip11: bool) -> Self {
        Self {
            session: Session::new(config).expect("valid config"),
            decoder: Decoder::new(),
            sensor: Sensor {
                scip11,
                mute: false,
                baud: 115_200,
                pp_flips: 0,
                afrt: b"540",
            },
            sent: Vec::new(),
            rates: Vec::new(),
            notices: Vec::new(),
        }
    }

    fn feed(&mut self, bytes: &[u8], now: u64) {
        let mut rest = bytes;
        while !rest.is_empty() {
            let (used, ev) = self.decoder.feed(rest);
            rest = &rest[used..];
            if let Some(ev) = ev {
                if let Some(n) = self.session.on_event(&ev, now) {
                    self.notices.push(n);
                }
            }
        }
    }

    fn run(&mut self, now: u64) {
        for _ in 0..100 {
            let action = self.session.poll(now);
            if let Some(n) = self.session.take_notice() {
                self.notices.push(n);
            }
            match action {
                Some(Action::Send(req)) => {
                    self.sent.push(req);
                    // A sensor at another bit rate hears nothing the host says.
                    let link = self.rates.last().copied().unwrap_or(115_200);
                    if link == self.sensor.baud {
                        let answer = self.sensor.answer(&req);
                        self.feed(&answer, now);
                    }
                }
                Some(Action::SetBitRate(r)) => self.rates.push(r),
                None => return,
            }
        }
        panic!("session never settles");
    }

    fn codes(&self) -> Vec<String> {
        self.sent
            .iter()
            .map(|r| {
                let mut b = [0u8; scip::REQUEST_MAX];
                let n = r.encode(&mut b).unwrap();
                String::from_utf8_lossy(&b[..n - 1]).into_owned()
            })
            .collect()
    }
}

fn config() -> SessionConfig {
    SessionConfig {
        scan: ScanRequest::distance(ScanMode::Continuous, 0, 1080),
        full_range: false,
        ..SessionConfig::default()
    }
}

#[test]
fn scip11_sensor_is_switched_identified_and_streams() {
    let mut rig = Rig::new(config(), true);
    rig.session.start(0);
    rig.run(0);
    assert_eq!(
        rig.codes(),
        ["QT", "SCIP2.0", "QT", "VV", "PP", "II", "MD0000108001000"]
    );
    assert_eq!(
        rig.notices,
        [
            Notice::Scip11Detected,
            Notice::Identified,
            Notice::Streaming
        ]
    );
    assert_eq!(rig.session.state(), State::Streaming);
    assert_eq!(rig.session.params().scan_rpm, Some(2400));
    assert_eq!(rig.session.params().dmin, Some(23));

    // Frames keep it streaming; their count is kept.
    let scan = rig.session.scan_request();
    for t in 1..=5 {
        rig.feed(&frame(&scan, *b"99"), t * 25);
        rig.run(t * 25);
    }
    assert_eq!(rig.session.state(), State::Streaming);
    assert_eq!(rig.session.stats().frames, 5);
}

#[test]
fn silence_is_recovered_with_growing_back_off() {
    let mut rig = Rig::new(config(), false);
    rig.session.start(0);
    rig.run(0);
    assert_eq!(rig.session.state(), State::Streaming);
    // 2400 rpm = 25 ms per scan: silence limit 8 * 25 + 500 = 700 ms.
    rig.run(700);
    assert_eq!(rig.session.state(), State::Streaming);
    rig.sent.clear();
    rig.run(701);
    assert_eq!(
        rig.notices.last(),
        Some(&Notice::Recovering(RecoverReason::Silence))
    );
    assert_eq!(rig.codes(), ["QT", "RS"]);
    assert_eq!(rig.session.state(), State::Backoff);
    // 100 ms back-off, then the whole bring-up again.
    rig.run(800);
    assert_eq!(rig.session.state(), State::Backoff);
    rig.sent.clear();
    rig.run(801);
    assert_eq!(rig.codes(), ["QT", "VV", "PP", "II", "MD0000108001000"]);
    assert_eq!(rig.session.state(), State::Streaming);
    // Streaming resets the back-off; a second silence waits 100 ms again.
    rig.run(1502);
    assert_eq!(rig.session.state(), State::Backoff);
    rig.sent.clear();
    rig.run(1602);
    assert_eq!(rig.session.state(), State::Streaming);
    assert_eq!(rig.session.stats().recoveries, 2);
}

#[test]
fn a_back_off_at_the_end_of_the_clock_saturates() {
    // A caller's clock 750 ms before its end: the 100 ms back-off after the silence
    // (700 ms) would end past it, so it ends at the clock's last ms instead.
    let t0 = u64::MAX - 750;
    let mut rig = Rig::new(config(), false);
    rig.session.start(t0);
    rig.run(t0);
    assert_eq!(rig.session.state(), State::Streaming);
    rig.sent.clear();
    rig.run(t0 + 701);
    assert_eq!(rig.codes(), ["QT", "RS"]);
    assert_eq!(rig.session.state(), State::Backoff);
    rig.run(u64::MAX - 1);
    assert_eq!(rig.session.state(), State::Backoff);
    rig.sent.clear();
    rig.run(u64::MAX);
    assert_eq!(rig.codes(), ["QT", "VV", "PP", "II", "MD0000108001000"]);
    assert_eq!(rig.session.state(), State::Streaming);
}

#[test]
fn a_reboot_into_scip11_mid_stream_is_recovered() {
    let mut rig = Rig::new(config(), false);
    rig.session.start(0);
    rig.run(0);
    let scan = rig.session.scan_request();
    rig.feed(&frame(&scan, *b"99"), 10);
    // The sensor reboots: it answers in SCIP 1.1 now (e.g. to a stray command).
    rig.sensor.scip11 = true;
    rig.feed(b"QT\nE\n\n", 20);
    assert_eq!(
        rig.notices.last(),
        Some(&Notice::Recovering(RecoverReason::Reboot))
    );
    assert_eq!(rig.session.stats().reboots, 1);
    rig.sent.clear();
    rig.run(20);
    // QT and RS are answered in 1.1; then back-off and the SCIP 1.1 bring-up.
    rig.run(200);
    assert_eq!(
        rig.codes(),
        [
            "QT",
            "RS",
            "QT",
            "SCIP2.0",
            "QT",
            "VV",
            "PP",
            "II",
            "MD0000108001000"
        ]
    );
    assert_eq!(rig.session.state(), State::Streaming);
}

#[test]
fn hardware_fault_status_recovers_and_other_statuses_are_counted() {
    let mut rig = Rig::new(config(), false);
    rig.session.start(0);
    rig.run(0);
    let scan = rig.session.scan_request();
    rig.feed(&frame(&scan, *b"0M"), 5);
    assert_eq!(rig.session.state(), State::Streaming);
    rig.feed(&frame(&scan, *b"98"), 6);
    assert_eq!(rig.session.state(), State::Streaming);
    assert_eq!(rig.session.stats().error_statuses, 1);
    rig.feed(&frame(&scan, *b"55"), 7);
    assert_eq!(
        rig.notices.last(),
        Some(&Notice::Recovering(RecoverReason::SensorFault(
            scip::Status::Scip2(*b"55")
        )))
    );
}

#[test]
fn timeouts_retry_then_recover() {
    let mut rig = Rig::new(config(), false);
    rig.sensor.mute = true;
    rig.session.start(0);
    rig.run(0);
    rig.run(1001); // retry 1
    rig.run(2002); // retry 2
    assert_eq!(rig.codes(), ["QT", "QT", "QT"]);
    rig.run(3003); // give up: recover
    assert_eq!(rig.notices, [Notice::Recovering(RecoverReason::Timeout)]);
    assert_eq!(rig.session.stats().retries, 2);
    // QT and RS go unanswered too: back-off, then probing again.
    rig.run(4004);
    assert_eq!(rig.session.state(), State::Backoff);
    rig.sensor.mute = false;
    rig.run(4105);
    assert_eq!(rig.session.state(), State::Streaming);
}

#[test]
fn bit_rate_change_and_time_sync() {
    let mut rig = Rig::new(
        SessionConfig {
            bit_rate: Some(500_000),
            ..config()
        },
        false,
    );
    rig.session.start(0);
    rig.run(0);
    assert_eq!(rig.rates, [500_000]);
    assert!(rig.codes().contains(&"SS500000".to_string()));
    rig.sent.clear();
    rig.session.request_time_sync(50);
    rig.run(50);
    // Twenty-four TM1 readings (their phases against the sensor's millisecond differ).
    let mut want = vec!["QT", "TM0"];
    want.extend(["TM1"; 24]);
    want.extend(["TM2", "MD0000108001000"]);
    assert_eq!(rig.codes(), want);
    assert!(rig.notices.contains(&Notice::TimeSync {
        sensor_ms: 123_456,
        now_ms: 50
    }));
    assert_eq!(rig.session.state(), State::Streaming);
}

#[test]
fn full_range_takes_the_sensors_amin_amax() {
    let mut rig = Rig::new(
        SessionConfig {
            scan: ScanRequest::distance(ScanMode::Continuous, 100, 200),
            full_range: true,
            ..SessionConfig::default()
        },
        false,
    );
    rig.session.start(0);
    rig.run(0);
    // The scripted sensor is a UTM-30LX: AMIN 0, AMAX 1080.
    assert_eq!(
        rig.codes().last().map(String::as_str),
        Some("MD0000108001000")
    );
    assert_eq!(rig.session.state(), State::Streaming);
}

#[test]
fn refused_parameters_turn_the_session_off() {
    let mut scan = ScanRequest::distance(ScanMode::Continuous, 0, 1440);
    scan.cluster = 1;
    let mut rig = Rig::new(SessionConfig { scan, ..config() }, false);
    rig.session.start(0);
    rig.run(0);
    assert_eq!(
        rig.notices.last(),
        Some(&Notice::StreamRefused(scip::Status::Scip2(*b"04")))
    );
    assert_eq!(rig.session.state(), State::Off);
    rig.session.stop(10);
    rig.run(10);
    assert_eq!(rig.notices.last(), Some(&Notice::Stopped));
}

#[test]
fn a_sensor_left_at_the_raised_rate_is_found_there() {
    // The MCU reset; the sensor still runs at the 500 000 bit/s an earlier session set.
    let mut rig = Rig::new(
        SessionConfig {
            bit_rate: Some(500_000),
            ..config()
        },
        false,
    );
    rig.sensor.baud = 500_000;
    rig.session.start(0);
    rig.run(0);
    rig.run(1001);
    rig.run(2002);
    assert!(rig.rates.is_empty());
    // Silent three times at 115 200: the session tries the raised rate.
    rig.run(3003);
    assert_eq!(rig.rates, [500_000]);
    assert_eq!(rig.session.state(), State::Streaming);
    // SS to the rate it already runs at is answered 03: no second switch.
    assert_eq!(rig.rates, [500_000]);
    assert_eq!(rig.codes()[..4], ["QT", "QT", "QT", "QT"]);
    assert!(rig
        .notices
        .iter()
        .all(|n| !matches!(n, Notice::Recovering(_))));
}

#[test]
fn a_silent_sensor_at_both_rates_is_recovered_at_the_power_up_rate() {
    let mut rig = Rig::new(
        SessionConfig {
            bit_rate: Some(500_000),
            ..config()
        },
        false,
    );
    rig.sensor.mute = true;
    rig.session.start(0);
    for t in [0, 1001, 2002, 3003, 4004, 5005, 6006] {
        rig.run(t);
    }
    // Three tries at each rate, then back to the power-up rate to recover.
    assert_eq!(rig.rates, [500_000, 115_200]);
    assert_eq!(
        rig.notices.first(),
        Some(&Notice::Recovering(RecoverReason::Timeout))
    );
}

#[test]
fn a_pp_answer_damaged_past_its_sums_is_asked_again() {
    let mut rig = Rig::new(config(), false);
    rig.sensor.pp_flips = 1;
    rig.session.start(0);
    rig.run(0);
    assert_eq!(
        rig.codes(),
        ["QT", "VV", "PP", "PP", "II", "MD0000108001000"]
    );
    assert_eq!(rig.session.state(), State::Streaming);
    assert_eq!(rig.session.geometry(), Geometry::Established);
    // The values of the sound answer, as the script writes them.
    let p = rig.session.params();
    assert_eq!(
        (p.ares, p.afrt, p.amin, p.amax),
        (Some(1440), Some(540), Some(0), Some(1080))
    );
    assert_eq!(rig.session.stats().pp_doubted, 1);
    assert_eq!(rig.notices, [Notice::Identified, Notice::Streaming]);
}

#[test]
fn a_pp_answer_doubted_every_time_is_recovered_and_never_streams() {
    let mut rig = Rig::new(config(), false);
    rig.sensor.pp_flips = u32::MAX;
    rig.session.start(0);
    rig.run(0);
    let doubt = ParamError::BadValue(ParamName::Ares);
    assert_eq!(
        rig.notices,
        [Notice::Recovering(RecoverReason::Parameters(doubt))]
    );
    // Asked three times (two retries), then QT, RS.
    assert_eq!(rig.codes(), ["QT", "VV", "PP", "PP", "PP", "QT", "RS"]);
    assert_eq!(rig.session.geometry(), Geometry::Doubted(doubt));
    assert_eq!(rig.session.params().ares, None);
    // Once the sensor answers soundly, the session streams.
    rig.sensor.pp_flips = 0;
    rig.run(101);
    assert_eq!(rig.session.state(), State::Streaming);
    assert_eq!(rig.session.params().ares, Some(1440));
}

#[test]
fn a_unit_that_differs_from_its_models_table_is_taken_when_it_answers_the_same_twice() {
    let mut rig = Rig::new(config(), false);
    rig.sensor.afrt = b"541";
    rig.session.start(0);
    rig.run(0);
    assert_eq!(
        rig.codes(),
        ["QT", "VV", "PP", "PP", "II", "MD0000108001000"]
    );
    assert_eq!(rig.session.state(), State::Streaming);
    assert_eq!(rig.session.params().afrt, Some(541));
}

/// Feeds `frames` stream frames, one every `period` ms from `from`, polling every ms in
/// between; returns the time after the last one.
fn stream_for(rig: &mut Rig, from: u64, frames: u64, period: u64) -> u64 {
    let scan = rig.session.scan_request();
    let mut t = from;
    for _ in 0..frames {
        for _ in 0..period {
            t += 1;
            rig.run(t);
        }
        rig.feed(&frame(&scan, *b"99"), t);
    }
    t
}

#[test]
fn a_300_ms_stall_keeps_the_stream_and_its_late_scans() {
    let mut rig = Rig::new(config(), false);
    rig.session.start(0);
    rig.run(0);
    let t = stream_for(&mut rig, 0, 10, 25);
    // The sensor holds its output back for 300 ms, then sends the 12 scans it measured
    // meanwhile in a burst, and streams on.
    let mut t2 = t;
    for _ in 0..325 {
        t2 += 1;
        rig.run(t2);
    }
    let scan = rig.session.scan_request();
    for _ in 0..12 {
        rig.feed(&frame(&scan, *b"99"), t2);
    }
    rig.run(t2);
    let end = stream_for(&mut rig, t2, 20, 25);
    rig.run(end);
    assert_eq!(rig.session.state(), State::Streaming);
    assert!(
        rig.notices
            .iter()
            .all(|n| !matches!(n, Notice::Recovering(_))),
        "{:?}",
        rig.notices
    );
    assert_eq!(rig.session.stats().frames, 10 + 12 + 20);
    assert_eq!(rig.session.stats().recoveries, 0);
    assert_eq!(rig.codes(), ["QT", "VV", "PP", "II", "MD0000108001000"]);
}

#[test]
fn the_silence_limit_scales_with_the_frame_period() {
    // UTM-30LX, 25 ms per scan: 8 frames + 500 ms = 700 ms; every second scan: 900 ms.
    for (skip, limit) in [(0u8, 700u64), (1, 900)] {
        let mut scan = ScanRequest::distance(ScanMode::Continuous, 0, 1080);
        scan.skip = skip;
        let mut rig = Rig::new(SessionConfig { scan, ..config() }, false);
        rig.session.start(0);
        rig.run(0);
        let t = stream_for(&mut rig, 0, 4, 25 * (u64::from(skip) + 1));
        assert_eq!(rig.session.silence_limit_ms(), limit as u32);
        rig.run(t + limit);
        assert_eq!(rig.session.state(), State::Streaming, "skip {skip}");
        rig.run(t + limit + 1);
        assert_eq!(
            rig.notices.last(),
            Some(&Notice::Recovering(RecoverReason::Silence)),
            "skip {skip}"
        );
    }
}
