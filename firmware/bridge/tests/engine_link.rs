//! The sensor link (issue 14): a TCP link has no `SS` step, starts down, and the board's
//! `link_down` / `link_up` abort the scan in progress, hold the session and bring the
//! sensor up again from the probe.
//!
//! The sensor is scripted with the codec's `ResponseWriter`; its PP values are the
//! UST-10LX's data sheet values (DMIN 20 mm, DMAX 30 m, 1440 steps per turn, steps
//! 0..=1080, front 540, 2400 rpm = 40 Hz); what is checked on the CAN side is decoded with
//! the can-wire reassembly, against what the script sent.

use bridge::engine::{Bridge, BridgeConfig, BridgeError};
use bridge::link::LinkKind;
use bridge::session::{Action, State};
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{Abort, AbortReason, Frame, FrameFormat, IdWindow, Kind};
use scip::{Command, Request, ResponseWriter};

const Q: usize = 256;

fn config(link: LinkKind) -> BridgeConfig {
    BridgeConfig {
        encoding: can_wire::Encoding::PLAIN_MM,
        status_period_ms: 0,
        link,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(3).unwrap(), FrameFormat::FD64)
    }
}

/// A scripted UST-10LX: answers every command, streams on `MD`.
#[derive(Default)]
struct Ust10 {
    /// The stream request acknowledged, if streaming.
    stream: Option<scip::ScanRequest>,
    clock: u32,
}

impl Ust10 {
    fn answer(&mut self, req: &Request) -> Vec<u8> {
        let mut out = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
        w.echo(req);
        match req.command {
            Command::Version => {
                w.status(*b"00");
                w.field(b"VEND", b"Hokuyo Automatic Co.,Ltd.");
                w.field(b"PROD", b"UST-10LX");
            }
            Command::Parameters => {
                w.status(*b"00");
                for (n, v) in [
                    (&b"MODL"[..], &b"UST-10LX"[..]),
                    (b"DMIN", b"20"),
                    (b"DMAX", b"30000"),
                    (b"ARES", b"1440"),
                    (b"AMIN", b"0"),
                    (b"AMAX", b"1080"),
                    (b"AFRT", b"540"),
                    (b"SCAN", b"2400"),
                ] {
                    w.field(n, v);
                }
            }
            Command::Info => {
                w.status(*b"00");
                w.field(b"LASR", b"OFF");
            }
            Command::Scan(s) => {
                w.status(*b"00");
                self.stream = Some(s);
            }
            Command::LaserOff => {
                w.status(*b"00");
                self.stream = None;
            }
            _ => w.status(*b"00"),
        }
        w.end();
        let _ = w.into_inner();
        out
    }

    /// The next stream frame: step `i` at `1000 + i` mm.
    fn frame(&mut self) -> Vec<u8> {
        let s = self.stream.expect("streaming");
        let mut out = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
        w.echo(&Request::new(Command::Scan(s)));
        w.status(*b"99");
        self.clock += 25;
        w.timestamp(self.clock);
        for i in 0..s.value_count() {
            w.step(1000 + u32::from(i), 0);
        }
        w.end();
        let _ = w.into_inner();
        out
    }
}

/// Bridge and sensor on one clock; every command the bridge sends is recorded.
struct Rig {
    bridge: Bridge<Q>,
    sensor: Ust10,
    now: u64,
    sent: Vec<Command>,
    frames: Vec<Frame>,
    connected: bool,
}

impl Rig {
    fn new(link: LinkKind) -> Self {
        let mut bridge = Bridge::new(config(link)).unwrap();
        bridge.start(0);
        Self {
            bridge,
            sensor: Ust10::default(),
            now: 0,
            sent: Vec::new(),
            frames: Vec::new(),
            connected: link == LinkKind::Uart,
        }
    }

    /// Lets `ms` pass a millisecond at a time, answering what the bridge asks.
    fn run(&mut self, ms: u64) {
        for _ in 0..ms {
            self.now += 1;
            while let Some(action) = self.bridge.poll(self.now) {
                match action {
                    Action::Send(req) => {
                        self.sent.push(req.command);
                        if self.connected {
                            let bytes = self.sensor.answer(&req);
                            self.bridge.on_uart(&bytes, self.now);
                        }
                    }
                    Action::SetBitRate(rate) => panic!(
                        "bit rate change to {rate} on {:?}",
                        self.bridge.config().link
                    ),
                }
            }
            self.frames
                .extend(std::iter::from_fn(|| self.bridge.pop_frame()));
        }
    }

    fn stream(&mut self, frames: usize) {
        for _ in 0..frames {
            let bytes = self.sensor.frame();
            self.bridge.on_uart(&bytes, self.now);
            self.run(25);
        }
    }

    /// Scans the CAN side received intact, and the aborts, in order.
    fn received(&self) -> (Vec<u16>, Vec<Abort>) {
        let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
        let abort_id = config(LinkKind::Tcp).ids.id(Kind::Abort);
        let mut scans = Vec::new();
        let mut aborts = Vec::new();
        for f in &self.frames {
            if f.id() == abort_id {
                aborts.push(Abort::parse(f.data()).unwrap());
            }
            if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(f) {
                if !scan.is_intact() {
                    // The aborted scan, reported by the receiver (its abort is above).
                    continue;
                }
                let points: Vec<_> = scan.points().collect();
                assert_eq!(points.len(), 1081);
                for (i, p) in points.iter().enumerate() {
                    let want = can_wire::Distance::Mm(1000 + i as u32);
                    assert_eq!(p.map(|p| p.distance), Some(want));
                }
                scans.push(scan.header().seq);
            }
        }
        (scans, aborts)
    }
}

const BRING_UP: [&str; 5] = ["QT", "VV", "PP", "II", "MD"];

fn names(commands: &[Command]) -> Vec<&'static str> {
    commands
        .iter()
        .map(|c| match c {
            Command::LaserOff => "QT",
            Command::Version => "VV",
            Command::Parameters => "PP",
            Command::Info => "II",
            Command::Scan(_) => "MD",
            Command::BitRate(_) => "SS",
            Command::Reset => "RS",
            _ => "other",
        })
        .collect()
}

#[test]
fn a_tcp_link_refuses_an_ss_bit_rate() {
    let mut c = config(LinkKind::Tcp);
    c.session.bit_rate = Some(500_000);
    assert_eq!(
        Bridge::<Q>::new(c).err(),
        Some(BridgeError::LinkHasNoBitRate)
    );
    // The same on a UART is a bit-rate step.
    let mut c = config(LinkKind::Uart);
    c.session.bit_rate = Some(500_000);
    assert!(Bridge::<Q>::new(c).is_ok());
}

#[test]
fn a_tcp_session_waits_for_its_link() {
    let mut rig = Rig::new(LinkKind::Tcp);
    // Not connected: nothing sent, nothing timed out, however long.
    rig.run(10_000);
    assert!(rig.sent.is_empty(), "{:?}", rig.sent);
    assert_eq!(rig.bridge.session().state(), State::LinkDown);
    assert!(!rig.bridge.link_is_up());
    rig.connected = true;
    rig.bridge.link_up(rig.now);
    rig.run(5);
    assert_eq!(names(&rig.sent), BRING_UP);
    assert_eq!(rig.bridge.session().state(), State::Streaming);
    rig.stream(3);
    assert_eq!(rig.received().0, [0, 1, 2]);
}

#[test]
fn link_down_aborts_the_scan_holds_and_link_up_brings_the_sensor_up_again() {
    let mut rig = Rig::new(LinkKind::Tcp);
    rig.connected = true;
    rig.bridge.link_up(rig.now);
    rig.run(5);
    rig.stream(2);
    // Half of the third scan, then the connection drops.
    let third = rig.sensor.frame();
    rig.bridge.on_uart(&third[..third.len() / 2], rig.now);
    rig.run(1);
    rig.connected = false;
    rig.bridge.link_down(rig.now);
    rig.run(1);
    let (scans, aborts) = rig.received();
    assert_eq!(scans, [0, 1]);
    assert_eq!(aborts.len(), 1);
    assert_eq!(aborts[0].seq, 2);
    assert_eq!(aborts[0].reason, AbortReason::LinkLost);
    assert_eq!(rig.bridge.session().state(), State::LinkDown);

    // Down for 10 s: no command, no recovery.
    let before = rig.sent.len();
    rig.run(10_000);
    assert_eq!(rig.sent.len(), before);
    assert_eq!(rig.bridge.session().stats().recoveries, 0);

    // The sensor rebooted meanwhile (its clock restarted; the rest of the third scan is
    // never sent): the link comes up, the sensor is probed and identified again.
    rig.sensor = Ust10::default();
    rig.connected = true;
    rig.bridge.link_up(rig.now);
    rig.run(5);
    assert_eq!(names(&rig.sent[before..]), BRING_UP);
    assert_eq!(rig.bridge.session().state(), State::Streaming);
    rig.stream(2);
    let (scans, aborts) = rig.received();
    assert_eq!(scans, [0, 1, 3, 4]);
    assert_eq!(aborts.len(), 1);
}

#[test]
fn a_stopped_session_stays_stopped_across_the_link() {
    let mut rig = Rig::new(LinkKind::Tcp);
    rig.connected = true;
    rig.bridge.link_up(rig.now);
    rig.run(5);
    rig.bridge.link_down(rig.now);
    rig.bridge.stop(rig.now);
    rig.run(5);
    assert_eq!(rig.bridge.session().state(), State::Off);
    let before = rig.sent.len();
    rig.bridge.link_up(rig.now);
    rig.run(100);
    assert_eq!(rig.sent.len(), before);
    assert_eq!(rig.bridge.session().state(), State::Off);
}

#[test]
fn a_uart_link_is_always_up() {
    let mut rig = Rig::new(LinkKind::Uart);
    assert!(rig.bridge.link_is_up());
    rig.run(5);
    assert_eq!(names(&rig.sent), BRING_UP);
    // A board that reports a UART up changes nothing.
    rig.bridge.link_up(rig.now);
    rig.run(5);
    assert_eq!(names(&rig.sent), BRING_UP);
}
