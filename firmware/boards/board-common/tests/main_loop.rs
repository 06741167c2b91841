//! The main loop (`sensor::run`) on a simulated board, on virtual time (embassy-time's
//! mock driver, moved forward by [`run_virtual`] whenever the main loop waits, so that
//! every time below is exact on any host): what it writes to the sensor and at which
//! bit rate, the frames a sensor stream produces, the watchdog, and bus-off recovery
//! with its rate limit.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::convert::Infallible;
use std::rc::Rc;

use board_common::config::{self, CanBus};
use board_common::sensor::{self, Board, Uart as Link};
use board_common::Shared;
use can_wire::{BusState, Kind};
use embassy_futures::select::{select, Either};
use embassy_time::{Duration, Instant, MockDriver, Timer};

/// The one virtual clock of this test binary, for one test at a time.
static CLOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The virtual clock for one test: held (the tests run one at a time), at 0.
fn virtual_clock() -> std::sync::MutexGuard<'static, ()> {
    let guard = CLOCK
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    MockDriver::get().reset();
    guard
}

/// The virtual clock's step: whenever `fut` waits, the clock moves by this much (the
/// main loop's times are whole milliseconds, so every deadline is met on time).
const STEP: Duration = Duration::from_micros(250);

/// Runs `fut` to completion on the virtual clock: polled, and whenever it waits, the
/// clock moved forward by [`STEP`] (waking the timers that are due) and polled again.
/// `limit_ms` of virtual time at most (a main loop that never ends fails the test).
fn run_virtual<F: std::future::Future>(fut: F, limit_ms: u64) -> F::Output {
    let waker = std::task::Waker::noop();
    let mut cx = std::task::Context::from_waker(waker);
    let mut fut = std::pin::pin!(fut);
    let end = Instant::now() + Duration::from_millis(limit_ms);
    loop {
        if let std::task::Poll::Ready(out) = fut.as_mut().poll(&mut cx) {
            return out;
        }
        assert!(Instant::now() < end, "still running after {limit_ms} ms");
        MockDriver::get().advance(STEP);
    }
}

/// What happened on the simulated sensor UART, in order.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Uart {
    Rate(u32),
    Write(Vec<u8>),
}

struct Rx {
    chunks: VecDeque<Vec<u8>>,
}

impl embedded_io_async::ErrorType for Rx {
    type Error = Infallible;
}

impl embedded_io_async::Read for Rx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        match self.chunks.pop_front() {
            Some(chunk) => {
                let n = chunk.len().min(buf.len());
                buf[..n].copy_from_slice(&chunk[..n]);
                if n < chunk.len() {
                    self.chunks.push_front(chunk[n..].to_vec());
                }
                Ok(n)
            }
            // The sensor has nothing more to say.
            None => core::future::pending().await,
        }
    }
}

struct Tx {
    log: Rc<RefCell<Vec<Uart>>>,
}

impl embedded_io_async::ErrorType for Tx {
    type Error = Infallible;
}

impl embedded_io_async::Write for Tx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.log.borrow_mut().push(Uart::Write(buf.to_vec()));
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

struct SimBoard {
    sensor: Link<Rx, Tx>,
    log: Rc<RefCell<Vec<Uart>>>,
    start: Instant,
    /// The controller is bus-off from this many ms after the start on.
    bus_off_from_ms: Option<u64>,
    recoveries_ms: Vec<u64>,
    feeds: u32,
    errors_to_report: u32,
}

impl SimBoard {
    fn new(stream: &[u8], bus_off_from_ms: Option<u64>) -> Self {
        let log = Rc::new(RefCell::new(Vec::new()));
        Self {
            sensor: Link {
                rx: Rx {
                    chunks: stream.chunks(100).map(<[u8]>::to_vec).collect(),
                },
                tx: Tx { log: log.clone() },
            },
            log,
            start: Instant::now(),
            bus_off_from_ms,
            recoveries_ms: Vec::new(),
            feeds: 0,
            errors_to_report: 3,
        }
    }

    fn elapsed_ms(&self) -> u64 {
        self.start.elapsed().as_millis()
    }
}

impl Board for SimBoard {
    type Sensor = Link<Rx, Tx>;

    fn sensor(&mut self) -> &mut Link<Rx, Tx> {
        &mut self.sensor
    }

    fn set_sensor_bit_rate(&mut self, bit_rate: u32) -> bool {
        self.log.borrow_mut().push(Uart::Rate(bit_rate));
        true
    }

    fn bus_state(&mut self) -> BusState {
        match self.bus_off_from_ms {
            Some(t) if self.elapsed_ms() >= t => BusState::BusOff,
            _ => BusState::ErrorActive,
        }
    }

    fn take_bus_errors(&mut self) -> u32 {
        std::mem::take(&mut self.errors_to_report)
    }

    fn recover_bus(&mut self) {
        let t = self.elapsed_ms();
        self.recoveries_ms.push(t);
    }

    fn feed_watchdog(&mut self) {
        self.feeds += 1;
    }
}

/// Runs the main loop on `board` for `ms` milliseconds of virtual time.
fn run_for(shared: &Shared, board: &mut SimBoard, ms: u64) {
    let outcome = run_virtual(
        select(
            sensor::run(shared, board),
            Timer::after(Duration::from_millis(ms)),
        ),
        ms + 1,
    );
    assert!(matches!(outcome, Either::Second(())));
}

/// One stream response (`MD`, status 99) of `n` steps at 1000 + i mm.
fn scan_response(n: u16) -> Vec<u8> {
    use scip::{Command, Request, ResponseWriter, ScanMode, ScanRequest};
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    let mut s = ScanRequest::distance(ScanMode::Continuous, 0, n - 1);
    s.count = 0;
    w.echo(&Request::new(Command::Scan(s)));
    w.status(*b"99");
    w.timestamp(42);
    for i in 0..u32::from(n) {
        w.step(1000 + i, 0);
    }
    w.end();
    let _ = w.into_inner();
    out
}

fn drain(shared: &Shared) -> Vec<can_wire::Frame> {
    std::iter::from_fn(|| shared.with(|b| b.pop_frame())).collect()
}

#[test]
fn boot_resets_the_sensor_rate_then_the_session_probes_at_the_power_up_rate() {
    let _clock = virtual_clock();
    let shared = Shared::new(config::bridge(CanBus::CLASSIC_1M).expect("bridge"));
    let mut board = SimBoard::new(&[], None);
    run_for(&shared, &mut board, 150);
    let log = board.log.borrow().clone();
    // QT and RS at the streaming rate, back to the power-up rate, then the session's
    // first command (it probes with QT) at the power-up rate.
    assert_eq!(
        log.get(..4),
        Some(
            &[
                Uart::Rate(250_000),
                Uart::Write(b"QT\nRS\n".to_vec()),
                Uart::Rate(19_200),
                Uart::Write(b"QT\n".to_vec()),
            ][..]
        ),
        "{log:?}"
    );
    // Fed on every 5 ms tick once the 100 ms of the rate reset are over: the ticker
    // starts at 100 ms, so 105, 110, ..., 150 (the main loop is polled before the end).
    assert_eq!(board.feeds, 10);
}

#[test]
fn a_sensor_scan_becomes_frames_in_order_behind_the_status_pages() {
    let _clock = virtual_clock();
    let shared = Shared::new(config::bridge(CanBus::CLASSIC_1M).expect("bridge"));
    let mut board = SimBoard::new(&scan_response(40), None);
    run_for(&shared, &mut board, 200);
    let ids = config::node_ids().expect("ids");
    let kinds: Vec<Kind> = drain(&shared)
        .iter()
        .map(|f| ids.window().classify(f.id()).expect("ours").1)
        .collect();
    // Heartbeat, sensor and bus counters first (the first poll), then the scan: 40
    // points 1000..=1039 mm in the lossless coding, 13 stream bytes (worked out by hand
    // in `shared.rs`'s test of the same scan): two classic data frames.
    let mut expected = vec![Kind::Status; 3];
    expected.extend([Kind::HeaderA, Kind::HeaderB]);
    expected.extend(std::iter::repeat_n(Kind::Data, 2));
    expected.push(Kind::Trailer);
    assert_eq!(kinds, expected);
    assert_eq!(shared.with(|b| b.stats().scans_sent), 1);
    // The board's error count reached the bridge.
    assert_eq!(shared.with(|b| b.health().bus_errors), 3);
}

#[test]
fn bus_off_is_recovered_after_100_ms_and_at_most_every_100_ms() {
    let _clock = virtual_clock();
    let shared = Shared::new(config::bridge(CanBus::FD_1M_5M).expect("bridge"));
    // The rate reset takes the first 100 ms; the bus goes off at 150 ms.
    let mut board = SimBoard::new(&[], Some(150));
    run_for(&shared, &mut board, 520);
    // The bus is seen off at the tick at 150 ms (the ticker runs from 100 ms, every 5
    // ms); a recovery 100 ms after that, and then every 100 ms while it stays off.
    assert_eq!(board.recoveries_ms, [250, 350, 450]);
    let health = shared.with(|b| *b.health());
    assert_eq!(health.bus_state, u8::from(BusState::BusOff));
    assert_eq!(health.bus_off_events, 1);
}

/// What happened on a simulated TCP sensor link, with the time in ms since the start.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Net {
    /// The main loop opened the link (a connect attempt).
    Open(u64),
    /// The main loop closed it (an abort).
    Close(u64),
    /// The bridge was told the link is up (true) or down.
    Changed(bool, u64),
    /// Bytes to the sensor.
    Write(Vec<u8>, u64),
}

/// A TCP link: refuses the first `refuse` attempts, connects the others on the next
/// tick, and is reset by the sensor `reset_after_ms` after its first connection.
struct TcpSensor {
    start: Instant,
    state: Rc<RefCell<sensor::LinkState>>,
    log: Rc<RefCell<Vec<Net>>>,
    reset_at: Option<Instant>,
}

impl embedded_io_async::ErrorType for TcpSensor {
    type Error = embedded_io_async::ErrorKind;
}

impl embedded_io_async::Read for TcpSensor {
    async fn read(&mut self, _buf: &mut [u8]) -> Result<usize, Self::Error> {
        match self.reset_at {
            Some(at) => {
                Timer::at(at).await;
                self.reset_at = None;
                *self.state.borrow_mut() = sensor::LinkState::Down;
                Err(embedded_io_async::ErrorKind::ConnectionReset)
            }
            None => core::future::pending().await,
        }
    }
}

impl embedded_io_async::Write for TcpSensor {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let t = self.start.elapsed().as_millis();
        self.log.borrow_mut().push(Net::Write(buf.to_vec(), t));
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

struct TcpBoard {
    sensor: TcpSensor,
    state: Rc<RefCell<sensor::LinkState>>,
    log: Rc<RefCell<Vec<Net>>>,
    refuse: u32,
    reset_after_ms: Option<u64>,
    rates: Vec<u32>,
}

impl TcpBoard {
    fn new(refuse: u32, reset_after_ms: Option<u64>) -> Self {
        let state = Rc::new(RefCell::new(sensor::LinkState::Down));
        let log = Rc::new(RefCell::new(Vec::new()));
        Self {
            sensor: TcpSensor {
                start: Instant::now(),
                state: state.clone(),
                log: log.clone(),
                reset_at: None,
            },
            state,
            log,
            refuse,
            reset_after_ms,
            rates: Vec::new(),
        }
    }

    fn now(&self) -> u64 {
        self.sensor.start.elapsed().as_millis()
    }
}

impl Board for TcpBoard {
    type Sensor = TcpSensor;

    const LINK_CAN_FAIL: bool = true;

    fn sensor(&mut self) -> &mut TcpSensor {
        &mut self.sensor
    }

    fn set_sensor_bit_rate(&mut self, bit_rate: u32) -> bool {
        self.rates.push(bit_rate);
        false
    }

    fn bus_state(&mut self) -> BusState {
        BusState::ErrorActive
    }

    fn take_bus_errors(&mut self) -> u32 {
        0
    }

    fn recover_bus(&mut self) {}

    fn feed_watchdog(&mut self) {}

    fn link_state(&mut self) -> sensor::LinkState {
        let mut state = self.state.borrow_mut();
        let now = *state;
        if now == sensor::LinkState::Opening {
            // The handshake completes by the next look.
            *state = sensor::LinkState::Up;
        }
        now
    }

    fn open_link(&mut self) {
        let t = self.now();
        self.log.borrow_mut().push(Net::Open(t));
        if self.refuse > 0 {
            self.refuse -= 1;
            *self.state.borrow_mut() = sensor::LinkState::Down;
        } else {
            *self.state.borrow_mut() = sensor::LinkState::Opening;
            if let Some(after) = self.reset_after_ms.take() {
                self.sensor.reset_at = Some(Instant::now() + Duration::from_millis(after));
            }
        }
    }

    fn close_link(&mut self) {
        let t = self.now();
        self.log.borrow_mut().push(Net::Close(t));
        *self.state.borrow_mut() = sensor::LinkState::Down;
    }

    fn link_changed(&mut self, bridge: &mut config::Bridge, up: bool, now_ms: u64) {
        let t = self.now();
        self.log.borrow_mut().push(Net::Changed(up, t));
        // As the H723 board does.
        if up {
            bridge.link_up(now_ms);
        } else {
            bridge.link_down(now_ms);
        }
    }
}

#[test]
fn a_tcp_sensor_is_connected_with_back_off_and_reconnected_after_a_reset() {
    let _clock = virtual_clock();
    let shared = Shared::new(config::ethernet_bridge(CanBus::FD_1M_5M).expect("bridge"));
    // Two refused attempts, then a connection that the sensor resets 300 ms later.
    let mut board = TcpBoard::new(2, Some(300));
    let outcome = run_virtual(
        select(
            sensor::run(&shared, &mut board),
            Timer::after(Duration::from_millis(2600)),
        ),
        2601,
    );
    assert!(matches!(outcome, Either::Second(())));
    let log = board.log.borrow().clone();
    let opens: Vec<u64> = log
        .iter()
        .filter_map(|e| match e {
            Net::Open(t) => Some(*t),
            _ => None,
        })
        .collect();
    let changes: Vec<(bool, u64)> = log
        .iter()
        .filter_map(|e| match e {
            Net::Changed(up, t) => Some((*up, *t)),
            _ => None,
        })
        .collect();
    // The schedule (link.rs), with the 5 ms ticker from 0: the first attempt at once;
    // the refusal seen at the tick at 5 ms, the next attempt 250 ms later (255);
    // refused again, seen at 260, and 500 ms later (760); connected, the handshake seen
    // at the next tick and the link up at the one after (770). The sensor resets it 300
    // ms after the attempt (1060): closed, and the wait back to 250 ms (1310), up at
    // 1320.
    assert_eq!(opens, [0, 255, 760, 1310], "{log:?}");
    assert_eq!(
        changes,
        [(true, 770), (false, 1060), (true, 1320)],
        "{log:?}"
    );
    let (up1, down, up2) = (770, 1060, 1320);
    assert!(
        log.contains(&Net::Close(down)),
        "the reset link is closed: {log:?}"
    );
    // The session ran on each connection (it probes with QT first), wrote nothing while
    // the link was down, and never asked for a bit rate.
    let writes: Vec<(Vec<u8>, u64)> = log
        .iter()
        .filter_map(|e| match e {
            Net::Write(b, t) => Some((b.clone(), *t)),
            _ => None,
        })
        .collect();
    assert!(
        writes
            .iter()
            .any(|(b, t)| b == b"QT\n" && (up1..down).contains(t)),
        "{log:?}"
    );
    assert!(
        writes.iter().any(|(b, t)| b == b"QT\n" && *t >= up2),
        "{log:?}"
    );
    assert!(
        writes
            .iter()
            .all(|(_, t)| (up1..=down).contains(t) || *t >= up2),
        "{log:?}"
    );
    assert!(board.rates.is_empty(), "{:?}", board.rates);
    // Status frames went out all along (heartbeats while the link was down).
    assert!(!drain(&shared).is_empty());
}
