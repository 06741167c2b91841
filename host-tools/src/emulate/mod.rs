//! `scip2can emulate`: the simulator, the real firmware in QEMU, and the decoder, wired.
//!
//! ```text
//!  simulator (in-process, TCP) ◀──UART0── qemu-system-arm mps2-an386 ──UART1──▶ this process
//!   SCIP sensor, faults          (client)   scip2can-qemu firmware      (SLCAN)   S8, O, F; frames
//!                                                                                  ─▶ reassembly
//! ```
//! QEMU connects to two TCP listeners of this process: the simulator's (its first
//! `-serial`, UART0, the sensor) and the SLCAN port's (its second, UART1, the CAN port).
//! Nothing is listening in between, so no byte is lost and no port number needs to be
//! known in advance. [`Uart1::Server`] makes QEMU the server of UART1 instead, for an
//! outside SLCAN client (python-can's `slcan` interface with `socket://host:port`).
//!
//! The simulator's bytes towards UART0 are recorded with their time, so that a test can
//! run the same stream through the same core on the host ([`Emulation::sensor_stream`]).
//!
//! With [`SensorLink::Tcp`] the sensor is an Ethernet one instead: the firmware
//! `scip2can-qemu-eth` connects over the emulated LAN9118 to 192.168.0.10 (QEMU's user
//! networking, whose gateway address reaches this host's loopback), on the simulator's
//! port, which it is told at boot (a word block QEMU's loader device writes). The
//! simulator serves one connection after another, so the board can reconnect after
//! [`Emulation::drop_sensor_link`] or a sensor reboot (which drops the connection, as
//! Ethernet sensors do).
//!
//! The parts: `build` (building the firmware), `qemu` (the simulator and QEMU wired up:
//! [`Emulation`]), `link` (the SLCAN link to UART1: [`SlcanLink`]), `cli` (the command:
//! [`EmulateArgs`], [`run`]) and `report` (its periodic report).

mod build;
mod cli;
mod link;
pub(crate) mod qemu;
mod report;

pub use build::{
    boards_dir, build_firmware, build_firmware_eth, build_in_boards, default_firmware, firmware,
    BUILD_COMMAND,
};
pub use cli::{run, EmulateArgs};
pub use link::{Diagnostics, Incoming, SlcanLink};
pub use qemu::{qemu_available, Emulation, Recorded, Setup, Uart1};

/// The firmware binary's name.
pub const FIRMWARE: &str = "scip2can-qemu";

/// The Ethernet firmware binary's name (same package as [`FIRMWARE`]).
pub const FIRMWARE_ETH: &str = "scip2can-qemu-eth";

/// The sensor's address as the Ethernet firmware sees it (the default of the real
/// sensors); QEMU's user networking maps it to this host's loopback.
pub const SENSOR_IP: [u8; 4] = [192, 168, 0, 10];

/// How the simulated sensor reaches the firmware.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SensorLink {
    /// UART0 (a URG-04LX-class sensor), firmware [`FIRMWARE`].
    #[default]
    Uart,
    /// TCP over the emulated Ethernet controller (UST-10LX class), firmware
    /// [`FIRMWARE_ETH`].
    Tcp,
}
