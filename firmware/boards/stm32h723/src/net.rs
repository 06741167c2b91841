//! The sensor link: Ethernet (the board's LAN8742A PHY on RMII), the TCP/IP stack, and
//! one TCP connection to the sensor's SCIP port.
//!
//! **Addresses** are compiled in, from two environment variables read at build time:
//!
//! - `SCIP2CAN_IP`: this board's address, `a.b.c.d/len` (default `192.168.0.20/24`,
//!   in the Hokuyo Ethernet sensors' factory subnet), or `dhcp`;
//! - `SCIP2CAN_SENSOR`: the sensor, `a.b.c.d:port` (default `192.168.0.10:10940`, the
//!   factory setting of the UST and UTM/UXM-EW sensors).
//!
//! A value that does not parse falls back to the default, with a warning in the log.
//!
//! **The connection** ([`SensorLink`]) is opened without waiting (the main loop keeps
//! ticking, see `board_common::sensor`): an attempt starts a TCP connect that the stack
//! completes in the background. It counts as down when the PHY reports no link (cable
//! pulled), when the stack has no address yet (DHCP), or when the connection is not
//! established (refused, reset by a rebooting sensor, closed). Keep-alive probes every
//! second and a 3 s timeout close a connection whose peer went silent.

use core::net::{Ipv4Addr, SocketAddrV4};
use core::str::FromStr;

use board_common::sensor::LinkState;
use embassy_net::tcp::{State, TcpSocket};
use embassy_net::{Ipv4Cidr, Stack, StaticConfigV4};
use embassy_time::Duration;
use embedded_io_async::{ErrorType, Read, Write};

/// This board's address when `SCIP2CAN_IP` is not set.
pub const DEFAULT_IP: &str = "192.168.0.20/24";

/// The sensor's address when `SCIP2CAN_SENSOR` is not set: the factory setting.
pub const DEFAULT_SENSOR: &str = "192.168.0.10:10940";

/// Keep-alive interval of the connection.
const KEEP_ALIVE: Duration = Duration::from_secs(1);

/// A connection (or connect) that hears nothing for this long is closed.
const TIMEOUT: Duration = Duration::from_secs(3);

/// The network configuration from `SCIP2CAN_IP` (or the default), and whether it is
/// DHCP.
pub fn ip_config() -> (embassy_net::Config, bool) {
    let text = option_env!("SCIP2CAN_IP").unwrap_or(DEFAULT_IP);
    if text.eq_ignore_ascii_case("dhcp") {
        return (embassy_net::Config::dhcpv4(Default::default()), true);
    }
    match parse_cidr(text).or_else(|| parse_cidr(DEFAULT_IP)) {
        Some(address) => {
            if parse_cidr(text).is_none() {
                defmt::warn!("SCIP2CAN_IP does not parse; using {}", DEFAULT_IP);
            }
            let config = StaticConfigV4 {
                address,
                gateway: None,
                dns_servers: Default::default(),
            };
            (embassy_net::Config::ipv4_static(config), false)
        }
        None => (embassy_net::Config::dhcpv4(Default::default()), true),
    }
}

/// `a.b.c.d/len`.
fn parse_cidr(text: &str) -> Option<Ipv4Cidr> {
    let (address, len) = text.split_once('/')?;
    let address = Ipv4Addr::from_str(address).ok()?;
    let len = u8::from_str(len).ok().filter(|l| *l <= 32)?;
    Some(Ipv4Cidr::new(address, len))
}

/// The sensor's address: `SCIP2CAN_SENSOR` (or the default).
pub fn sensor_address() -> SocketAddrV4 {
    let text = option_env!("SCIP2CAN_SENSOR").unwrap_or(DEFAULT_SENSOR);
    SocketAddrV4::from_str(text).unwrap_or_else(|_| {
        defmt::warn!("SCIP2CAN_SENSOR does not parse; using {}", DEFAULT_SENSOR);
        SocketAddrV4::new(Ipv4Addr::new(192, 168, 0, 10), 10940)
    })
}

/// The TCP connection to the sensor.
pub struct SensorLink {
    stack: Stack<'static>,
    socket: TcpSocket<'static>,
    sensor: SocketAddrV4,
}

impl SensorLink {
    /// A link to `sensor` over `stack`, with the socket's buffers; not yet open.
    pub fn new(
        stack: Stack<'static>,
        rx: &'static mut [u8],
        tx: &'static mut [u8],
        sensor: SocketAddrV4,
    ) -> Self {
        Self {
            stack,
            socket: TcpSocket::new(stack, rx, tx),
            sensor,
        }
    }

    /// The link's state for the main loop.
    pub fn state(&self) -> LinkState {
        if !self.stack.is_link_up() {
            return LinkState::Down;
        }
        match self.socket.state() {
            State::Established => LinkState::Up,
            State::SynSent | State::SynReceived => LinkState::Opening,
            _ => LinkState::Down,
        }
    }

    /// Starts a connection attempt: the SYN goes out, the stack finishes the handshake
    /// in the background ([`SensorLink::state`] follows it). Without a link or an
    /// address nothing starts (the attempt counts as failed).
    pub fn open(&mut self) {
        self.socket.abort();
        if !self.stack.is_link_up() || !self.stack.is_config_up() {
            return;
        }
        self.socket.set_timeout(Some(TIMEOUT));
        self.socket.set_keep_alive(Some(KEEP_ALIVE));
        // SCIP commands are single short lines: send each at once.
        self.socket.set_nagle_enabled(false);
        // The first poll sends the SYN; what is left of the future only waits for the
        // handshake, which `state` observes instead.
        let _ = embassy_futures::poll_once(self.socket.connect(self.sensor));
    }

    /// Closes the connection at once (a reset goes to the sensor).
    pub fn close(&mut self) {
        self.socket.abort();
    }
}

impl ErrorType for SensorLink {
    type Error = embassy_net::tcp::Error;
}

impl Read for SensorLink {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        self.socket.read(buf).await
    }
}

impl Write for SensorLink {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.socket.write(buf).await
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        self.socket.flush().await
    }
}
