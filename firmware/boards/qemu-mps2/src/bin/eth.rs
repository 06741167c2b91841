//! scip2can firmware for QEMU's `mps2-an386` machine with an Ethernet sensor: the
//! bridge over TCP (UST-10LX/20LX, UTM-30LX-EW, UXM-30LX-EW).
//!
//! - **LAN9118** (Ethernet): a TCP client ([`smoltcp`]) to the sensor, by default
//!   192.168.0.10:10940 as the sensors leave the factory, from 192.168.0.15/24. The
//!   stream's bytes go to [`bridge::engine::Bridge::on_uart`], the session's commands
//!   back over the connection. A connection made is [`Bridge::link_up`]; one closed,
//!   reset or failed is [`Bridge::link_down`], and the board connects again every
//!   [`RETRY_MS`]. A host may set the sensor's address at boot (`bootcfg`).
//! - **UART1** is the CAN port, SLCAN as in the UART binary; the scans go out as CAN FD
//!   frames of 64 bytes (1 Mbit/s arbitration, 5 Mbit/s data).
//! - **UART0** is unused.
//!
//! In QEMU (user networking, the host's loopback seen at the gateway address):
//!
//! ```text
//! qemu-system-arm -machine mps2-an386 -nographic -no-reboot \
//!   -nic user,model=lan9118,net=192.168.0.0/24,host=192.168.0.10 \
//!   -kernel scip2can-qemu-eth
//! ```
//! with `scip2can sim --model ust10lx --tcp 10940` on the host: the board's connection
//! to 192.168.0.10:10940 reaches the host's 127.0.0.1:10940.

#![no_std]
#![no_main]
#![deny(unsafe_code)]

#[path = "../bootcfg.rs"]
mod bootcfg;
#[path = "../can_port.rs"]
mod can_port;
#[path = "../config.rs"]
#[allow(dead_code)] // the UART settings are the UART binary's
mod config;
#[path = "../hw.rs"]
#[allow(dead_code)] // shared with the other binaries
mod hw;
#[path = "../lan9118.rs"]
mod lan9118;
#[path = "../meter.rs"]
mod meter;

use bridge::engine::{Bridge, BridgeConfig};
use bridge::link::LinkKind;
use bridge::session::Action;
use can_port::CanPort;
use can_wire::bandwidth::BitRates;
use can_wire::FrameFormat;
use cortex_m_rt::entry;
use smoltcp::iface::{Config, Interface, SocketSet, SocketStorage};
use smoltcp::socket::tcp;
use smoltcp::time::{Duration, Instant};
use smoltcp::wire::{EthernetAddress, HardwareAddress, IpAddress, IpCidr, Ipv4Address};

/// The board's address.
const OWN_IP: [u8; 4] = [192, 168, 0, 15];
/// Prefix length of the sensor's network.
const PREFIX: u8 = 24;
/// The sensor's address as Hokuyo ships its Ethernet sensors.
const SENSOR_IP: [u8; 4] = [192, 168, 0, 10];
/// The SCIP port of Hokuyo's Ethernet sensors.
const SENSOR_PORT: u16 = 10940;
/// A locally administered MAC address.
const MAC: [u8; 6] = [0x02, 0x53, 0x32, 0x43, 0x00, 0x01];
/// Pause between connection attempts, ms.
const RETRY_MS: u64 = 200;
/// A connection attempt that has not completed by then is given up, ms.
const CONNECT_TIMEOUT_MS: u64 = 1000;
/// TCP receive buffer: a whole UST-10LX scan (about 3.4 kB) and more. It is also the
/// window: the controller's RX FIFO (about 10 kB) holds all of it in flight.
const RX_BUF: usize = 8192;
/// TCP send buffer: commands only.
const TX_BUF: usize = 256;

/// The bridge of this binary: the UART binary's, over a TCP link (no `SS`), CAN FD.
fn bridge_config() -> Option<BridgeConfig> {
    let mut c = config::bridge()?;
    c.link = LinkKind::Tcp;
    c.session.bit_rate = None;
    c.budget.rates = BitRates::FD_1M_5M;
    c.budget.format = FrameFormat::FD64;
    Some(c)
}

/// Milliseconds since boot as the core wants them: SysTick's 32-bit count extended.
struct Clock {
    last: u32,
    high: u64,
}

impl Clock {
    fn now(&mut self) -> u64 {
        let ms = hw::now_ms();
        if ms < self.last {
            self.high += 1 << 32;
        }
        self.last = ms;
        self.high | u64::from(ms)
    }
}

/// Where the connection to the sensor is.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Link {
    /// No connection; the next attempt at this time.
    Down { retry_at: u64 },
    /// `SYN` sent at this time.
    Connecting { since: u64 },
    /// Established: the bridge's link is up.
    Up,
}

/// Link events, for the `?` line.
#[derive(Default)]
struct LinkStats {
    connects: u32,
    drops: u32,
    failed: u32,
}

#[entry]
fn main() -> ! {
    hw::paint_stack();
    let Some(cp) = cortex_m::Peripherals::take() else {
        hw::exit()
    };
    hw::start_systick(cp.SYST);
    let Some(hw::Board { uart1: mut can, .. }) = hw::Board::take(config::BAUD) else {
        hw::exit()
    };
    let mut watchdog = hw::Watchdog::start(config::WATCHDOG_MS);
    let Some(mut nic) = lan9118::Lan9118::new(MAC) else {
        hw::exit()
    };
    let Some(bridge_config) = bridge_config() else {
        hw::exit()
    };
    let Ok(mut bridge) = Bridge::<{ config::QUEUE }>::new(bridge_config) else {
        hw::exit()
    };
    bridge.set_bus_state(can_wire::BusState::ErrorActive);

    let (ip, port) = bootcfg::sensor();
    let [a, b, c, d] = ip.map_or(SENSOR_IP, u32::to_be_bytes);
    let sensor = (Ipv4Address::new(a, b, c, d), port.unwrap_or(SENSOR_PORT));

    let mut clock = Clock { last: 0, high: 0 };
    let now = clock.now();
    let mut iface_config = Config::new(HardwareAddress::Ethernet(EthernetAddress(MAC)));
    iface_config.random_seed = hw::ticks();
    let mut iface = Interface::new(iface_config, &mut nic, Instant::from_millis(now as i64));
    iface.update_ip_addrs(|addrs| {
        let [a, b, c, d] = OWN_IP;
        let _ = addrs.push(IpCidr::new(IpAddress::v4(a, b, c, d), PREFIX));
    });
    let mut storage = [SocketStorage::EMPTY; 1];
    let mut sockets = SocketSet::new(&mut storage[..]);
    let mut rx_buf = [0u8; RX_BUF];
    let mut tx_buf = [0u8; TX_BUF];
    let mut socket = tcp::Socket::new(
        tcp::SocketBuffer::new(&mut rx_buf[..]),
        tcp::SocketBuffer::new(&mut tx_buf[..]),
    );
    socket.set_nagle_enabled(false);
    // A sensor that vanishes without a FIN or RST (cable pulled) is given up after 2 s
    // of unacknowledged data or of keep-alive silence.
    socket.set_timeout(Some(Duration::from_millis(2000)));
    socket.set_keep_alive(Some(Duration::from_millis(500)));
    let handle = sockets.add(socket);

    let mut port_can = CanPort::new(config::SLCAN_VERSION, *b"QETH");
    let mut meter = meter::Meter::default();
    let mut link = Link::Down { retry_at: now };
    let mut link_stats = LinkStats::default();
    let mut local_port: u16 = 49152;
    let mut last_ms = u64::from(hw::now_ms());
    let mut tx_lost = 0u32;
    bridge.start(now);

    loop {
        let now = clock.now();
        let ms = hw::now_ms();
        if u64::from(ms) != last_ms {
            last_ms = u64::from(ms);
            watchdog.feed();
            // SLCAN's "transmit FIFO full" when the bridge lost frames or whole scans to
            // a full queue.
            let lost = bridge
                .health()
                .tx_overflows
                .wrapping_add(bridge.stats().queue_overflows)
                .wrapping_add(bridge.governor().stats().dropped_queue);
            if lost != tx_lost {
                tx_lost = lost;
                port_can.raise(slcan::StatusFlags::TX_FIFO_FULL);
            }
        }
        let stamp = Instant::from_millis(now as i64);
        iface.poll(stamp, &mut nic, &mut sockets);

        // The connection.
        let socket = sockets.get_mut::<tcp::Socket>(handle);
        match link {
            Link::Down { retry_at } if now >= retry_at => {
                socket.abort();
                local_port = if local_port >= 65000 {
                    49152
                } else {
                    local_port + 1
                };
                if socket.connect(iface.context(), sensor, local_port).is_ok() {
                    link = Link::Connecting { since: now };
                } else {
                    link = Link::Down {
                        retry_at: now + RETRY_MS,
                    };
                }
            }
            Link::Down { .. } => {}
            Link::Connecting { since } => {
                if socket.state() == tcp::State::Established {
                    link = Link::Up;
                    link_stats.connects += 1;
                    bridge.link_up(now);
                } else if !socket.is_active() || now.saturating_sub(since) > CONNECT_TIMEOUT_MS {
                    socket.abort();
                    link_stats.failed += 1;
                    link = Link::Down {
                        retry_at: now + RETRY_MS,
                    };
                }
            }
            Link::Up => {
                // The sensor's bytes into the core, as they come.
                while socket.can_recv() {
                    let read_at = hw::ticks();
                    let sent_before = bridge.stats().scans_sent;
                    let got = socket.recv(|data| {
                        let ((), ticks) = hw::measure(|| bridge.on_uart(data, now));
                        (data.len(), (data.len(), ticks))
                    });
                    match got {
                        Ok((n, ticks)) if n > 0 => {
                            meter.uart(n, read_at, ticks, sent_before, bridge.stats())
                        }
                        _ => break,
                    }
                }
                if !socket.may_recv() || socket.state() != tcp::State::Established {
                    // Closed by the sensor (FIN), reset, or timed out.
                    socket.abort();
                    link_stats.drops += 1;
                    bridge.link_down(now);
                    link = Link::Down {
                        retry_at: now + RETRY_MS,
                    };
                }
            }
        }

        // The session's commands to the sensor.
        while let Some(action) = bridge.poll(now) {
            if let Action::Send(request) = action {
                let mut line = [0u8; scip::REQUEST_MAX];
                if let (Ok(len), Link::Up) = (request.encode(&mut line), link) {
                    let _ = socket.send_slice(line.get(..len).unwrap_or_default());
                }
            }
            // `SetBitRate` never comes: a TCP link has no bit rate.
        }
        iface.poll(stamp, &mut nic, &mut sockets);

        // Control and time frames from the bus (the SLCAN host), the bridge's frames
        // onto it.
        if can_port::serve(&mut port_can, &mut can, &mut bridge, &mut meter, ms) {
            diagnostics(&mut port_can, &mut can, &bridge, &meter, &link_stats, &nic);
        }

        let output_moves = port_can.has_output() && !can.tx_full();
        let frames_wait = bridge.queued() > 0 && port_can.has_room_for_frame();
        if !(can.rx_pending() || output_moves || frames_wait) {
            // The controller raises no interrupt here: it is polled every millisecond.
            hw::sleep_until(|| can.rx_pending() || hw::now_ms() != ms);
        }
    }
}

/// The `?` line: firmware, stack, the work counters of `meter`, the link's events and
/// the controller's counters.
fn diagnostics(
    port: &mut CanPort,
    can: &mut hw::Uart,
    bridge: &Bridge<{ config::QUEUE }>,
    meter: &meter::Meter,
    link: &LinkStats,
    nic: &lan9118::Lan9118,
) {
    while port.has_output() {
        port.flush(can);
    }
    let core = meter::CoreFields {
        meter,
        stats: bridge.stats(),
        governor: bridge.governor().stats(),
    };
    let e = nic.stats();
    port.text(format_args!(
        "?fw={}-eth {core} connects={} drops={} connect_failures={} \
         eth_rx={} eth_rx_errors={} eth_tx={} link_up={} ms={}",
        env!("CARGO_PKG_VERSION"),
        link.connects,
        link.drops,
        link.failed,
        e.rx_frames,
        e.rx_errors,
        e.tx_frames,
        u8::from(bridge.link_is_up()),
        hw::now_ms(),
    ));
}
