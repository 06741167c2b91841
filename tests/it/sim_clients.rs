//! The clients against the simulator over real transports: TCP on 127.0.0.1 and a real
//! pseudo-terminal, in real time (sensor time sped up).

use std::net::TcpListener;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use scip::{Command, Request, Status};
use scip2can_host::sensor::client::{Client, Response};
use scip2can_host::sensor::link::{SerialLink, TcpLink};
use scip2can_host::sensor::scan::{self, Format, ScanArgs};
use scip2can_host::sensor::spec::SensorSpec;
use scip2can_host::sensor::{record, record_file};
use scip2can_host::sim::transport::{serve_pty, serve_tcp, Clock};
use scip2can_host::sim::SimOptions;

/// How long a client waits for an answer: a safety net against hangs, not a measure. A
/// debug-build simulator streaming at 10x speed on a 2-core machine busy with other
/// builds took more than 3 s to get a QT answer through the scans ahead of it.
const TIMEOUT: Duration = Duration::from_secs(10);

struct Server {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    /// `host:port` or the pty path.
    at: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn tcp_sim(spec: &str) -> Server {
    let opts = SimOptions::from_spec(spec).unwrap();
    let mut sensor = opts.build().unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let at = listener.local_addr().unwrap().to_string();
    let stop = Arc::new(AtomicBool::new(false));
    let s = Arc::clone(&stop);
    let thread = std::thread::spawn(move || {
        let clock = Clock::new(opts.speed);
        serve_tcp(listener, &mut sensor, &clock, &s, &mut |_| {}).unwrap();
    });
    Server {
        stop,
        thread: Some(thread),
        at,
    }
}

fn pty_sim(spec: &str) -> Server {
    let opts = SimOptions::from_spec(spec).unwrap();
    let mut sensor = opts.build().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let s = Arc::clone(&stop);
    let (tx, rx) = mpsc::channel();
    let thread = std::thread::spawn(move || {
        let clock = Clock::new(opts.speed);
        let mut ready = |p: &str| tx.send(p.to_owned()).unwrap();
        serve_pty(&mut sensor, &clock, &s, true, &mut ready, &mut |_| {}).unwrap();
    });
    let at = rx.recv_timeout(TIMEOUT).unwrap();
    Server {
        stop,
        thread: Some(thread),
        at,
    }
}

fn tcp_client(server: &Server) -> Client {
    let link = TcpLink::connect(&server.at, TIMEOUT).unwrap();
    let mut c = Client::new(Box::new(link), TIMEOUT);
    c.connect().unwrap();
    c
}

/// Sends a raw command line and returns its answer.
fn ask(c: &mut Client, line: &str) -> Response {
    c.send_raw(format!("{line}\n").as_bytes()).unwrap();
    let deadline = Instant::now() + TIMEOUT;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let r = c
            .next_response(left)
            .unwrap()
            .unwrap_or_else(|| panic!("no answer to {line}"));
        if r.echo == line.as_bytes() {
            return r;
        }
    }
}

/// Every command of scip-reference §4 and the status of every bad parameter and wrong
/// state, as (command line, status).
fn check_statuses(c: &mut Client, table: &[(&str, &str)]) {
    for (line, want) in table {
        let r = ask(c, line);
        assert!(r.is_intact(), "{line}: {:?}", r.errors);
        assert_eq!(r.status_str(), *want, "status of {line}");
    }
}

const UTM_TABLE: &[(&str, &str)] = &[
    ("GD0000108001", "10"),
    ("XX", "0E"),
    ("VV;12345678901234567", "0G"),
    ("VV;a\u{7f}", "0H"),
    ("VV", "00"),
    ("PP", "00"),
    ("II", "00"),
    ("VV1", "0D"),
    ("GD00000010", "0C"),
    ("MDx000001001000", "01"),
    ("MD0000x01001000", "02"),
    ("MD00000010x0000", "03"),
    ("MD0000200001000", "04"),
    ("MD0100000001000", "05"),
    ("MD0000001001x00", "06"),
    ("MD00000010010x0", "07"),
    ("HS0044072501", "0D"),
    ("CR05", "04"),
    ("CR00", "04"),
    ("SS115200", "00"),
    ("SS115200", "03"),
    ("SS009600", "04"),
    ("TM1", "04"),
    ("TM2", "03"),
    ("TM0", "00"),
    ("TM0", "02"),
    ("TM1", "00"),
    ("TM3", "01"),
    ("TM2", "00"),
    ("HS1", "00"),
    ("HS0", "00"),
    ("BM", "00"),
    ("BM", "02"),
    ("GD0000108001", "00"),
    ("GS0000108003", "00"),
    ("GE0000108001", "00"),
    ("GR0000108001", "00"),
    ("GI0000108001", "00"),
    ("HD0000108001", "00"),
    ("HE0000108001", "00"),
    ("QT", "00"),
    ("%ST", "0E"),
    ("%SL", "0E"),
    ("SCIP2.0", "0E"),
    ("RT", "00"),
    ("RS", "00"),
];

#[test]
fn tcp_every_command_and_status() {
    let server = tcp_sim("model=utm30lx,speed=10");
    let mut c = tcp_client(&server);
    check_statuses(&mut c, UTM_TABLE);
    // TM1 carries the clock; GD carries 1081 values.
    ask(&mut c, "TM0");
    let tm = ask(&mut c, "TM1");
    assert!(tm.timestamp.is_some());
    ask(&mut c, "TM2");
    ask(&mut c, "BM");
    let gd = ask(&mut c, "GD0000108001");
    assert_eq!(gd.readings.len(), 1081);
    let gd3 = ask(&mut c, "GD0000108003");
    assert_eq!(gd3.readings.len(), 361);
}

#[test]
fn tcp_multiscan_skip_count_and_qt_mid_stream() {
    let server = tcp_sim("model=utm30lx,speed=10,scene=wall:2000,noise=0");
    let mut c = tcp_client(&server);
    // 4 scans, skipping 2 between each: counts 03..00, timestamps 3 scans (75 ms) apart.
    let ack = ask(&mut c, "MD0500058002204;x");
    assert_eq!(ack.status_str(), "00");
    let mut frames = Vec::new();
    while frames.len() < 4 {
        let r = c.next_response(TIMEOUT).unwrap().expect("frame");
        frames.push(r);
    }
    let echoes: Vec<_> = frames.iter().map(|f| f.echo_str()).collect();
    assert_eq!(
        echoes,
        [
            "MD0500058002203;x",
            "MD0500058002202;x",
            "MD0500058002201;x",
            "MD0500058002200;x"
        ]
    );
    for w in frames.windows(2) {
        assert_eq!(w[1].timestamp.unwrap() - w[0].timestamp.unwrap(), 75);
    }
    assert!(frames
        .iter()
        .all(|f| f.status == Some(Status::STREAM) && f.readings.len() == 41));
    // The laser is off after the last scan of a counted request.
    assert_eq!(ask(&mut c, "GD0540054001").status_str(), "10");

    // An endless stream keeps running while VV is answered, and stops at QT.
    assert_eq!(ask(&mut c, "MS0540054001000").status_str(), "00");
    let mut seen = 0;
    while seen < 3 {
        let r = c.next_response(TIMEOUT).unwrap().expect("frame");
        assert_eq!(r.echo_str(), "MS0540054001000");
        seen += 1;
    }
    c.send_raw(b"VV\n").unwrap();
    let mut after_vv = 0;
    let mut got_vv = false;
    while after_vv < 3 {
        let r = c.next_response(TIMEOUT).unwrap().expect("response");
        if r.echo == b"VV" {
            got_vv = true;
        } else if got_vv {
            after_vv += 1;
        }
    }
    c.send_raw(b"QT\n").unwrap();
    let mut qt = false;
    while !qt {
        let r = c.next_response(TIMEOUT).unwrap().expect("QT answer");
        qt = r.echo == b"QT";
    }
    // Nothing after the QT answer: 20 scan periods of silence.
    assert_eq!(c.next_response(Duration::from_millis(50)).unwrap(), None);
}

#[test]
fn tcp_clients_one_after_another_and_busy() {
    let server = tcp_sim("model=ust10lx,speed=10");
    {
        let mut first = tcp_client(&server);
        // While the first is connected, a second one is turned away.
        let link = TcpLink::connect(&server.at, TIMEOUT).unwrap();
        let mut second = Client::new(Box::new(link), TIMEOUT);
        let err = second.connect().unwrap_err().to_string();
        assert!(err.contains("busy"), "{err}");
        // The first leaves a stream running.
        assert_eq!(ask(&mut first, "MD0000108001000").status_str(), "00");
        first.next_response(TIMEOUT).unwrap().expect("frame");
    }
    std::thread::sleep(Duration::from_millis(100));
    let mut again = tcp_client(&server);
    assert_eq!(ask(&mut again, "%ST").payload, vec![b"000".to_vec()]);
    // Refused and unreachable addresses are clear errors, not hangs.
    let closed = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let err = TcpLink::connect(&closed.to_string(), TIMEOUT)
        .unwrap_err()
        .to_string();
    assert!(err.contains("refused"), "{err}");
}

#[test]
fn pty_urg_scip11_bit_rate_and_scans() {
    let server = pty_sim("model=urg04lx,speed=20,scene=wall:1500,noise=0");
    let link = SerialLink::open(&server.at, 19_200).unwrap();
    let mut c = Client::new(Box::new(link), TIMEOUT);
    c.connect().unwrap();
    assert!(
        c.notes.iter().any(|n| n.contains("SCIP 1.1")),
        "{:?}",
        c.notes
    );
    check_statuses(
        &mut c,
        &[
            ("GD0044072501", "10"),
            ("CR00", "03"),
            ("CR11", "04"),
            ("CR05", "00"),
            ("CR05", "03"),
            ("CR99", "00"),
            ("GE0044072501", "0E"),
            ("HD0044072501", "0E"),
            ("MD0044080001000", "04"),
            ("SS019200", "03"),
            ("SS001200", "04"),
        ],
    );
    let r = c.set_bit_rate(115_200).unwrap();
    assert_eq!(r.status_str(), "00");
    let ii = c.command(&Request::new(Command::Info)).unwrap();
    assert_eq!(ii.field("SBPS"), Some("115200[bps]"));
    // A counted stream with skip over the pty.
    assert_eq!(ask(&mut c, "MD0384038401102").status_str(), "00");
    let f1 = c.next_response(TIMEOUT).unwrap().expect("frame 1");
    let f2 = c.next_response(TIMEOUT).unwrap().expect("frame 2");
    assert_eq!(
        (f1.echo_str(), f2.echo_str()),
        ("MD0384038401101".into(), "MD0384038401100".into())
    );
    assert_eq!(f2.timestamp.unwrap() - f1.timestamp.unwrap(), 200);
    assert_eq!(f1.readings[0].distance, 1500);
    // QT in the middle of an endless stream.
    assert_eq!(ask(&mut c, "MD0044072501000").status_str(), "00");
    c.next_response(TIMEOUT).unwrap().expect("frame");
    let qt = c.command(&Request::new(Command::LaserOff)).unwrap();
    assert_eq!(qt.status_str(), "00");
    assert_eq!(c.next_response(Duration::from_millis(150)).unwrap(), None);
    let gd = ask(&mut c, "BM");
    assert_eq!(gd.status_str(), "00");
    assert_eq!(ask(&mut c, "GD0044072501").readings.len(), 682);
}

fn temp_path(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("scip2can-{}-{name}", std::process::id()))
}

#[test]
fn scan_record_parse_and_replay() {
    let server = tcp_sim("model=utm30lx,speed=10,scene=room,seed=4");
    let spec = SensorSpec::parse(&format!("tcp://{}", server.at), 0).unwrap();
    // scan: N scans with intensity.
    let mut c = Client::open(&spec, TIMEOUT).unwrap();
    let args = ScanArgs {
        count: 5,
        intensity: true,
        start: Some(100),
        end: Some(200),
        cluster: 2,
        format: Format::Json,
    };
    let mut scans = Vec::new();
    let report = scan::stream(&mut c, &args, false, &|| false, &mut |s| {
        scans.push(s.clone());
        Ok(())
    })
    .unwrap();
    assert_eq!(report.scans, 5);
    assert!(scans
        .iter()
        .all(|s| s.distances.len() == 51 && s.intensities.len() == 51));
    let mut csv = Vec::new();
    scan::write_scan(&mut csv, &scans[0], Format::Csv).unwrap();
    assert_eq!(String::from_utf8(csv).unwrap().lines().count(), 52);
    drop(c);
    std::thread::sleep(Duration::from_millis(150));

    // record: 4 scans, then the file parses and replays.
    let path = temp_path("rec.scipr");
    let (rep, _) =
        record::record(&spec, "test", &path, Some(4), false, TIMEOUT, &|| false).unwrap();
    assert_eq!(rep.scans, 4);
    let bytes = std::fs::read(&path).unwrap();
    assert!(bytes.starts_with(record_file::MAGIC));
    let parsed = scip2can_host::parse::parse_bytes(&record_file::sensor_bytes(&bytes).unwrap());
    let frames: Vec<_> = parsed
        .iter()
        .filter(|r| r.status.as_deref() == Some("99"))
        .collect();
    // The 4 scans, and any frame that left before the sensor read QT (at 10x speed in a
    // debug build, a few).
    assert!(frames.len() >= 4, "{}", frames.len());
    assert!(parsed.iter().all(|r| !r.damaged));
    assert_eq!(parsed.last().unwrap().command.as_deref(), Some("QT"));

    let replay = SimOptions::from_spec(&format!("replay={},speed=10", path.display())).unwrap();
    let mut c = Client::open(&SensorSpec::Sim(replay), TIMEOUT).unwrap();
    ask(&mut c, "BM");
    let gd = ask(&mut c, "GD0000108001");
    let replayed: Vec<u32> = gd.readings.iter().map(|r| r.distance).collect();
    let recorded = &frames
        .iter()
        .map(|f| f.distances.clone())
        .collect::<Vec<_>>();
    assert!(
        recorded.contains(&replayed),
        "a GD of the replay is one of the recorded scans"
    );
    std::fs::remove_file(&path).unwrap();
}

/// Reads from `link` until `done(bytes so far)` or `secs` pass.
fn read_until(
    link: &mut SerialLink,
    got: &mut Vec<u8>,
    secs: u64,
    done: impl Fn(&[u8]) -> bool,
) -> bool {
    use scip2can_host::sensor::link::Link;
    let deadline = Instant::now() + Duration::from_secs(secs);
    let mut buf = [0u8; 4096];
    while !done(got) {
        if Instant::now() > deadline {
            return false;
        }
        let n = link.recv(&mut buf, Duration::from_millis(50)).unwrap();
        got.extend_from_slice(&buf[..n]);
    }
    true
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

#[test]
fn pty_urg_at_19200_skips_scans_it_cannot_send_and_answers_qt_after_the_frame_on_the_wire() {
    use scip2can_host::sensor::link::Link;
    // 19 200 bit/s carry 1 920 bytes a second: a URG-04LX frame of MD0044072501000 (the
    // 2 134 bytes of the recorded GD0044072501 answer, its echo 3 chars longer) takes
    // 1.1 s, eleven 100 ms scans. Sensor time runs 4 times faster than real time.
    let server = pty_sim("model=urg04lx,scip11=0,speed=4,scene=wall:1500,noise=0");
    let mut link = SerialLink::open(&server.at, 19_200).unwrap();
    link.send(b"MD0044072501000\n").unwrap();
    let mut got = Vec::new();
    // The ack and five frames.
    let frames_in = |b: &[u8]| b.windows(2).filter(|w| w == b"\n\n").count();
    assert!(
        read_until(&mut link, &mut got, 20, |b| frames_in(b) >= 6),
        "{} bytes",
        got.len()
    );
    // Each frame whole (2 137 bytes), the scans between them skipped: the buffer (4 KiB)
    // takes the first two frames at once, then one more each time one has gone, so the
    // timestamps of the frames after the first two are at least 10 scans apart.
    let mut stamps = Vec::new();
    let mut rest = &got[..];
    while let Some(i) = find(rest, b"\n\n") {
        let resp = &rest[..i + 2];
        rest = &rest[i + 2..];
        if resp.starts_with(b"MD0044072501000\n99b\n") {
            assert_eq!(resp.len(), 2137);
            stamps.push(scip::value::decode(&resp[20..24]).unwrap());
        }
    }
    assert!(stamps.len() >= 4, "{stamps:?}");
    for w in stamps.windows(2).skip(1) {
        assert!(w[1] - w[0] >= 1000, "scans not skipped: {stamps:?}");
    }
    // QT mid-stream: its answer follows at most the rest of the frame on the wire, and
    // nothing follows it.
    let mark = got.len();
    link.send(b"QT\n").unwrap();
    assert!(
        read_until(&mut link, &mut got, 10, |b| find(
            &b[mark..],
            b"QT\n00P\n\n"
        )
        .is_some()),
        "no QT answer"
    );
    let at = mark + find(&got[mark..], b"QT\n00P\n\n").unwrap();
    assert!(
        at - mark <= 2137,
        "{} bytes before the QT answer",
        at - mark
    );
    let end = at + b"QT\n00P\n\n".len();
    read_until(&mut link, &mut got, 1, |_| false);
    assert_eq!(got.len(), end, "{:?}", String::from_utf8_lossy(&got[end..]));
}

#[test]
fn tcp_ust_reboots_on_a_confirmed_rb_and_drops_the_connection() {
    let server = tcp_sim("model=ust10lx,speed=10");
    let mut c = tcp_client(&server);
    // SCIP 2.2: 01 asks for confirmation, a second RB within a second gets 00.
    assert_eq!(ask(&mut c, "RB").status_str(), "01");
    let md = ask(&mut c, "MD0000108001000");
    assert_eq!(md.status_str(), "00", "{md:?}");
    let rb = ask(&mut c, "RB");
    assert_eq!(rb.status_str(), "00", "{rb:?}");
    // Then the sensor reboots: the connection ends.
    let deadline = Instant::now() + TIMEOUT;
    let closed = loop {
        match c.next_response(Duration::from_millis(100)) {
            Err(_) => break true,
            Ok(_) if Instant::now() > deadline => break false,
            Ok(_) => {}
        }
    };
    assert!(closed, "the connection stayed up");
    // Back after the boot: idle, laser off, and a lone RB starts a new pair.
    std::thread::sleep(Duration::from_millis(100));
    let mut c = tcp_client(&server);
    check_statuses(
        &mut c,
        &[("%ST", "00"), ("GD0000108001", "10"), ("RB", "01")],
    );
}
