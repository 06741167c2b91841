//! The Foxglove WebSocket server of `bridge --foxglove` and `decode --foxglove`
//! (the `foxglove` crate's server; it speaks the subprotocol `foxglove.sdk.v1`, the
//! successor of `foxglove.websocket.v1`, which the Foxglove app offers).
//!
//! Topics:
//! - `/scip2can/node<N>/scan`: every scan of bridge `N` as it completes,
//!   `foxglove.LaserScan` (protobuf; converted as `decode --mcap` converts it, see
//!   [`crate::view`]: REP 117 ranges, scans without geometry or damaged left out), frame
//!   `scip2can_node<N>`, stamped with the scan's time.
//! - `/scip2can/node<N>/status`: the bridge's status frames (SPEC 5) as JSON, the fields
//!   `decode` prints.
//! - `/scip2can/bridge` or `/scip2can/decode`: once a second, the process's own state and
//!   counters as JSON: session state, the governor's plan, scans sent/aborted/dropped,
//!   frames per second, the measured bus load, decoder errors, and this server's own
//!   drops.
//!
//! Nothing here can block the caller. [`LiveView::item`] and [`LiveView::status`] hand
//! their message to a publishing thread through a bounded queue ([`QUEUE`] messages);
//! when it is full the message is dropped and counted ([`LiveView::dropped`]). The
//! server gives each client its own bounded queue ([`CLIENT_BACKLOG`] messages) and
//! drops a slow client's oldest messages; a client that goes away is forgotten. The
//! bridge or decoder goes on in every case.

use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

use anyhow::{anyhow, Context as _};
use foxglove::schemas::LaserScan;
use foxglove::{Channel, ChannelBuilder, Context, RawChannel, Schema, WebSocketServer};
use serde_json::Value;

use crate::decode::{json, Item};

/// Messages waiting for the publishing thread.
pub const QUEUE: usize = 64;
/// Messages the server holds for one client before it drops the oldest.
pub const CLIENT_BACKLOG: usize = 256;

/// The JSON schema of the status topics: any object (their fields are documented above).
const OBJECT_SCHEMA: &[u8] = br#"{"type":"object"}"#;

enum Msg {
    Item(Box<Item>),
    Status(Value),
}

/// A running Foxglove WebSocket server fed with scans and status.
pub struct LiveView {
    tx: Option<SyncSender<Msg>>,
    dropped: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
    server: Option<foxglove::WebSocketServerHandle>,
    addr: SocketAddr,
}

impl std::fmt::Debug for LiveView {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveView")
            .field("addr", &self.addr)
            .field("dropped", &self.dropped())
            .finish_non_exhaustive()
    }
}

impl LiveView {
    /// Starts a server on `addr` (`HOST:PORT`; port 0 picks a free one). `process`
    /// names the status topic (`/scip2can/<process>`).
    pub fn start(addr: &str, process: &str) -> anyhow::Result<Self> {
        let sock = addr
            .to_socket_addrs()
            .with_context(|| format!("--foxglove {addr}: expected HOST:PORT"))?
            .next()
            .ok_or_else(|| anyhow!("--foxglove {addr}: no address"))?;
        let ctx = Context::new();
        let server = WebSocketServer::new()
            .name("scip2can")
            .context(&ctx)
            .bind(sock.ip().to_string(), sock.port())
            .message_backlog_size(CLIENT_BACKLOG)
            .start_blocking()
            .map_err(|e| anyhow!("starting the Foxglove WebSocket server on {addr}: {e}"))?;
        let addr = SocketAddr::new(sock.ip(), server.port());
        let status_topic = format!("/scip2can/{process}");
        let (tx, rx) = sync_channel(QUEUE);
        let thread = std::thread::Builder::new()
            .name("foxglove".into())
            .spawn(move || publish(&ctx, &status_topic, &rx))
            .context("starting the Foxglove publishing thread")?;
        Ok(Self {
            tx: Some(tx),
            dropped: Arc::new(AtomicU64::new(0)),
            thread: Some(thread),
            server: Some(server),
            addr,
        })
    }

    /// The address the server listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.server.as_ref().map_or(0, |s| s.client_count())
    }

    /// Messages dropped because the publishing thread was behind.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    fn offer(&self, msg: Msg) {
        let Some(tx) = &self.tx else { return };
        match tx.try_send(msg) {
            Ok(()) => {}
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Publishes a decoded item: scans and status frames (control traffic is not shown).
    pub fn item(&self, item: &Item) {
        if matches!(item, Item::Scan(_) | Item::Status { .. }) {
            self.offer(Msg::Item(Box::new(item.clone())));
        }
    }

    /// Publishes the process's status object.
    pub fn status(&self, status: Value) {
        self.offer(Msg::Status(status));
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        // The thread ends when its queue closes, then the server stops.
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        if let Some(s) = self.server.take() {
            s.stop().detach_all();
        }
    }
}

/// Topics of one node, made when the node is first seen.
struct NodeTopics {
    scan: Channel<LaserScan>,
    status: Option<Arc<RawChannel>>,
}

fn json_channel(ctx: &Arc<Context>, topic: &str, schema: &str) -> Option<Arc<RawChannel>> {
    ChannelBuilder::new(topic)
        .context(ctx)
        .message_encoding("json")
        .schema(Schema::new(schema, "jsonschema", OBJECT_SCHEMA))
        .build_raw()
        .ok()
}

fn log_json(channel: Option<&Arc<RawChannel>>, value: &Value) {
    if let (Some(c), Ok(bytes)) = (channel, serde_json::to_vec(value)) {
        c.log(&bytes);
    }
}

/// The topics of `node` (made on first use).
fn topics<'a>(
    nodes: &'a mut [Option<NodeTopics>],
    node: u8,
    make: &dyn Fn(u8) -> NodeTopics,
) -> Option<&'a NodeTopics> {
    let slot = nodes.get_mut(usize::from(node))?;
    Some(&*slot.get_or_insert_with(|| make(node)))
}

/// The publishing thread: until the queue closes.
fn publish(ctx: &Arc<Context>, status_topic: &str, rx: &Receiver<Msg>) {
    let status = json_channel(ctx, status_topic, "scip2can.Status");
    let mut nodes: Vec<Option<NodeTopics>> = (0..16).map(|_| None).collect();
    let make = |node: u8| NodeTopics {
        scan: ChannelBuilder::new(format!("/scip2can/node{node}/scan"))
            .context(ctx)
            .build::<LaserScan>(),
        status: json_channel(
            ctx,
            &format!("/scip2can/node{node}/status"),
            "scip2can.BridgeStatus",
        ),
    };
    // What each bridge's status frames told about its sensor (range limits, scan speed).
    let mut infos = [crate::view::NodeInfo::default(); 16];
    while let Ok(msg) = rx.recv() {
        match msg {
            Msg::Status(v) => log_json(status.as_ref(), &v),
            Msg::Item(item) => match *item {
                Item::Scan(s) => {
                    let info = infos.get(usize::from(s.node)).copied().unwrap_or_default();
                    let frame = format!("scip2can_node{}", s.node);
                    if let (Some(t), Ok(scan)) = (
                        topics(&mut nodes, s.node, &make),
                        crate::view::laser_scan(&s, &info, &frame),
                    ) {
                        t.scan.log(&crate::view::foxglove::laser_scan(&scan));
                    }
                }
                Item::Status {
                    node,
                    time_us,
                    status,
                } => {
                    if let Some(info) = infos.get_mut(usize::from(node)) {
                        info.update(&status);
                    }
                    if let Some(t) = topics(&mut nodes, node, &make) {
                        let v = json::item(&Item::Status {
                            node,
                            time_us,
                            status,
                        });
                        log_json(t.status.as_ref(), &v);
                    }
                }
                Item::Answer { .. } | Item::Control { .. } => {}
            },
        }
    }
}

/// The bus load of the frames seen, over the time since the last reading: each frame's
/// worst-case time on the bus (SPEC 8; FD frames with their data phase at the data rate)
/// over the time elapsed.
#[derive(Debug, Clone)]
pub struct LoadMeter {
    rates: can_wire::bandwidth::BitRates,
    frames: u64,
    busy_ns: u64,
    since: std::time::Duration,
}

impl LoadMeter {
    /// A meter for a bus at `rates`.
    pub fn new(rates: can_wire::bandwidth::BitRates) -> Self {
        Self {
            rates,
            frames: 0,
            busy_ns: 0,
            since: std::time::Duration::ZERO,
        }
    }

    /// One frame on the bus.
    pub fn add(&mut self, frame: &can_wire::Frame) {
        let extended = matches!(frame.id(), embedded_can::Id::Extended(_));
        let bits = can_wire::bandwidth::frame_bits(frame.data().len(), frame.is_fd(), extended);
        self.frames = self.frames.saturating_add(1);
        self.busy_ns = self.busy_ns.saturating_add(bits.time_ns(self.rates));
    }

    /// Frames per second and the load in percent since the last call (`now` counts from
    /// the same start as the previous `now`); starts a new period.
    pub fn take(&mut self, now: std::time::Duration) -> (f64, f64) {
        let span = now.saturating_sub(self.since).as_secs_f64();
        let out = if span > 0.0 {
            (
                self.frames as f64 / span,
                self.busy_ns as f64 / 1e9 / span * 100.0,
            )
        } else {
            (0.0, 0.0)
        };
        self.since = now;
        self.frames = 0;
        self.busy_ns = 0;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn the_load_meter_follows_spec_8() {
        // SPEC 8: a classic 8-byte frame with an 11-bit ID is 34 + 64 + 13 +
        // floor(97 / 4) = 135 bits: 135 µs at 1 Mbit/s. 1000 of them in 1 s: 13.5 %.
        let mut m = LoadMeter::new(can_wire::bandwidth::BitRates::CLASSIC_1M);
        let id = embedded_can::Id::Standard(embedded_can::StandardId::new(0x130).unwrap());
        let f = can_wire::Frame::new(id, &[0; 8], false).unwrap();
        for _ in 0..1000 {
            m.add(&f);
        }
        let (fps, load) = m.take(Duration::from_secs(1));
        assert_eq!(fps, 1000.0);
        assert!((load - 13.5).abs() < 1e-9, "{load}");
        // A new period starts empty.
        assert_eq!(m.take(Duration::from_secs(2)), (0.0, 0.0));
    }
}
