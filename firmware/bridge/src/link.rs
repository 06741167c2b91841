//! The sensor link: how the sensor's bytes reach the bridge.
//!
//! The protocol, the pipeline and the CAN side are the same over every link; only a few
//! things differ:
//!
//! | | [`LinkKind::Uart`] | [`LinkKind::Tcp`] |
//! |---|---|---|
//! | sensors | URG-04LX class (USB/RS-232 SCIP) | UST-10LX/20LX, UTM-30LX-EW, UXM-30LX-EW |
//! | bit rate, `SS` | [`BridgeConfig::uart_bit_rate`], `SS` if configured | none: no `SS` step |
//! | link state | always up | up while the TCP connection is: the board reports [`Bridge::link_up`] / [`Bridge::link_down`] |
//! | a scan's arrival | its bytes at the bit rate | at once (a burst at network speed) |
//!
//! On a link that can go down, [`Bridge::link_down`] ends the scan in progress with an
//! abort (`LinkLost`, SPEC 3.5), drops any partial response and holds the session
//! ([`crate::session::State::LinkDown`]: no commands, no timeouts) until
//! [`Bridge::link_up`], which brings the sensor up from the start (`QT`, `VV`, `PP`, ...):
//! a sensor that rebooted while its connection was down is identified again.
//!
//! [`BridgeConfig::uart_bit_rate`]: crate::engine::BridgeConfig::uart_bit_rate
//! [`Bridge::link_up`]: crate::engine::Bridge::link_up
//! [`Bridge::link_down`]: crate::engine::Bridge::link_down

/// The speed of a network link to the sensor, bit/s, taken as its byte time
/// ([`crate::engine::BridgeConfig::on_network`]): 100 Mbit/s, so a scan arrives as one
/// burst and must fit the queue's free room (the TCP link is never the bottleneck, the
/// CAN bus is), and the bytes of a chunk are dated a network's byte time apart.
pub const NETWORK_BIT_RATE: u32 = 100_000_000;

/// The kind of link to the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkKind {
    /// A UART (or USB serial): always up, bytes at
    /// [`crate::engine::BridgeConfig::uart_bit_rate`].
    #[default]
    Uart,
    /// A TCP stream (an Ethernet sensor): no bit rate, so no `SS`; starts down, the board
    /// reports its connection with [`crate::engine::Bridge::link_up`] and
    /// [`crate::engine::Bridge::link_down`].
    Tcp,
}

impl LinkKind {
    /// Whether the link has a bit rate that `SS` can change.
    pub fn has_bit_rate(self) -> bool {
        self == Self::Uart
    }

    /// Whether the link is up before the board says anything (a UART is; a TCP stream is
    /// not until connected).
    pub fn up_at_start(self) -> bool {
        self == Self::Uart
    }
}
