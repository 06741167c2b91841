//! A small polled driver of the SMSC LAN9118 Ethernet controller of the MPS2 AN386 image
//! (QEMU models it at 0x4020_0000), as a smoltcp [`Device`].
//!
//! The controller moves whole frames through FIFOs: a received frame is a status word
//! (its length, CRC included) in the RX status FIFO and its bytes, little-endian 32-bit
//! words, in the RX data FIFO; a frame to send is two command words (buffer and frame
//! length, first and last segment) and its words into the TX data FIFO. No DMA, no
//! interrupts: [`Lan9118::receive`] looks at the RX status FIFO's fill level, and the
//! main loop polls it.
//!
//! This module and `hw` are the only ones with `unsafe` code: every `unsafe` block is a
//! volatile 32-bit access to a register of this controller, at a fixed, always-mapped
//! address of the machine, each with its `SAFETY:` argument.

#![allow(unsafe_code)]

use smoltcp::phy::{Device, DeviceCapabilities, Medium, RxToken, TxToken};
use smoltcp::time::Instant;

/// Base address of the LAN9118 in the AN385/AN386 images.
const BASE: usize = 0x4020_0000;

/// Register offsets (LAN9118 data sheet, 5.3; the FIFO ports are windows, any offset
/// in them reads or writes the FIFO).
mod reg {
    /// RX data FIFO port (read).
    pub const RX_DATA: usize = 0x00;
    /// TX data FIFO port (write).
    pub const TX_DATA: usize = 0x20;
    /// RX status FIFO port (read pops).
    pub const RX_STATUS: usize = 0x40;
    /// TX status FIFO port (read pops).
    pub const TX_STATUS: usize = 0x48;
    /// Chip identification and revision: 0x0118_xxxx.
    pub const ID_REV: usize = 0x50;
    /// Reads 0x8765_4321 whatever the bus's byte order.
    pub const BYTE_TEST: usize = 0x64;
    /// Transmitter configuration.
    pub const TX_CFG: usize = 0x70;
    /// Hardware configuration (soft reset).
    pub const HW_CFG: usize = 0x74;
    /// RX FIFO fill: bits 23:16 status words, 15:0 data bytes.
    pub const RX_FIFO_INF: usize = 0x7C;
    /// TX FIFO fill: bits 23:16 status words, 15:0 free data bytes.
    pub const TX_FIFO_INF: usize = 0x80;
    /// MAC control/status register access: command.
    pub const MAC_CSR_CMD: usize = 0xA4;
    /// MAC control/status register access: data.
    pub const MAC_CSR_DATA: usize = 0xA8;

    /// HW_CFG: soft reset (self-clearing).
    pub const HW_CFG_SRST: u32 = 1 << 0;
    /// TX_CFG: transmitter on.
    pub const TX_CFG_TX_ON: u32 = 1 << 1;
    /// MAC_CSR_CMD: start the access (busy until done).
    pub const CSR_BUSY: u32 = 1 << 31;

    /// MAC register: control.
    pub const MAC_CR: u32 = 1;
    /// MAC register: address bytes 4 and 5.
    pub const MAC_ADDRH: u32 = 2;
    /// MAC register: address bytes 0 to 3.
    pub const MAC_ADDRL: u32 = 3;
    /// MAC_CR: full duplex.
    pub const MAC_CR_FDPX: u32 = 1 << 20;
    /// MAC_CR: transmitter enable.
    pub const MAC_CR_TXEN: u32 = 1 << 3;
    /// MAC_CR: receiver enable.
    pub const MAC_CR_RXEN: u32 = 1 << 2;

    /// RX status: frame length (CRC included), bits 29:16.
    pub const RX_STS_LEN_SHIFT: u32 = 16;
    /// RX status: length mask after the shift.
    pub const RX_STS_LEN_MASK: u32 = 0x3FFF;
    /// RX status: error summary.
    pub const RX_STS_ES: u32 = 1 << 15;

    /// TX command A: first segment.
    pub const TX_CMD_A_FIRST: u32 = 1 << 13;
    /// TX command A: last segment.
    pub const TX_CMD_A_LAST: u32 = 1 << 12;
}

/// Largest Ethernet frame handled (no VLAN tag), without CRC.
pub const MTU: usize = 1514;

/// Frame buffer size: the largest frame plus its CRC, rounded up to words.
const BUF: usize = 1520;

/// Counters of the driver.
#[derive(Debug, Default, Clone, Copy)]
pub struct Stats {
    /// Frames received and handed on.
    pub rx_frames: u32,
    /// Frames received with an error status or too long, dropped.
    pub rx_errors: u32,
    /// Frames sent.
    pub tx_frames: u32,
}

/// The controller.
pub struct Lan9118 {
    rx: [u8; BUF],
    tx: [u8; BUF],
    stats: Stats,
}

fn read(offset: usize) -> u32 {
    // SAFETY: `BASE + offset` is one of the `reg` registers of the LAN9118, an aligned,
    // always-mapped 32-bit device register of this machine; reading it affects only the
    // controller (a FIFO port pops a word), never memory the program uses.
    unsafe { core::ptr::read_volatile((BASE + offset) as *const u32) }
}

fn write(offset: usize, value: u32) {
    // SAFETY: as in `read`; writing these registers affects only the controller.
    unsafe { core::ptr::write_volatile((BASE + offset) as *mut u32, value) }
}

fn mac_write(register: u32, value: u32) {
    write(reg::MAC_CSR_DATA, value);
    write(reg::MAC_CSR_CMD, reg::CSR_BUSY | register);
    let mut spins = 0u32;
    while read(reg::MAC_CSR_CMD) & reg::CSR_BUSY != 0 && spins < 100_000 {
        spins += 1;
    }
}

impl Lan9118 {
    /// Resets the controller, sets its MAC address `mac`, and turns its receiver and
    /// transmitter on. `None` when no LAN9118 answers at the address.
    pub fn new(mac: [u8; 6]) -> Option<Self> {
        if read(reg::BYTE_TEST) != 0x8765_4321 || read(reg::ID_REV) >> 16 != 0x0118 {
            return None;
        }
        write(reg::HW_CFG, reg::HW_CFG_SRST);
        let mut spins = 0u32;
        while read(reg::HW_CFG) & reg::HW_CFG_SRST != 0 && spins < 100_000 {
            spins += 1;
        }
        let [a0, a1, a2, a3, a4, a5] = mac.map(u32::from);
        mac_write(reg::MAC_ADDRL, a0 | a1 << 8 | a2 << 16 | a3 << 24);
        mac_write(reg::MAC_ADDRH, a4 | a5 << 8);
        // Exact address match and broadcast (ARP); not promiscuous.
        mac_write(
            reg::MAC_CR,
            reg::MAC_CR_FDPX | reg::MAC_CR_TXEN | reg::MAC_CR_RXEN,
        );
        write(reg::TX_CFG, reg::TX_CFG_TX_ON);
        Some(Self {
            rx: [0; BUF],
            tx: [0; BUF],
            stats: Stats::default(),
        })
    }

    /// Counters.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// Reads the next received frame into the RX buffer; its length without CRC.
    /// Frames with an error status or longer than [`MTU`] are dropped (counted).
    fn pop_frame(&mut self) -> Option<usize> {
        loop {
            if (read(reg::RX_FIFO_INF) >> 16) & 0xFF == 0 {
                return None;
            }
            let status = read(reg::RX_STATUS);
            let len = ((status >> reg::RX_STS_LEN_SHIFT) & reg::RX_STS_LEN_MASK) as usize;
            let words = len.div_ceil(4);
            let good = status & reg::RX_STS_ES == 0 && len > 4 && words * 4 <= BUF;
            for i in 0..words {
                let w = read(reg::RX_DATA);
                if good {
                    if let Some(dst) = self.rx.get_mut(i * 4..i * 4 + 4) {
                        dst.copy_from_slice(&w.to_le_bytes());
                    }
                }
            }
            if good {
                self.stats.rx_frames = self.stats.rx_frames.wrapping_add(1);
                return Some(len - 4);
            }
            self.stats.rx_errors = self.stats.rx_errors.wrapping_add(1);
        }
    }

    /// Whether the TX data FIFO can take a whole frame now.
    fn tx_room(&self) -> bool {
        (read(reg::TX_FIFO_INF) & 0xFFFF) as usize >= BUF + 8
    }
}

/// A received frame, in the driver's RX buffer.
pub struct Rx<'a> {
    frame: &'a [u8],
}

impl RxToken for Rx<'_> {
    fn consume<R, F>(self, f: F) -> R
    where
        F: FnOnce(&[u8]) -> R,
    {
        f(self.frame)
    }
}

/// Writes `frame` (at most [`MTU`] bytes) into the TX FIFO as one frame: it leaves with
/// its last word.
fn send(frame: &[u8]) {
    // Pop the TX status words (one per frame sent) so that their FIFO never fills.
    while (read(reg::TX_FIFO_INF) >> 16) & 0xFF != 0 {
        let _ = read(reg::TX_STATUS);
    }
    // At most MTU bytes: fits the 11-bit length fields.
    let n = frame.len().min(MTU) as u32;
    write(reg::TX_DATA, reg::TX_CMD_A_FIRST | reg::TX_CMD_A_LAST | n);
    // Command B: the frame's length (its tag, the high half, unused).
    write(reg::TX_DATA, n);
    for chunk in frame.chunks(4) {
        let mut w = [0u8; 4];
        w.get_mut(..chunk.len())
            .unwrap_or_default()
            .copy_from_slice(chunk);
        write(reg::TX_DATA, u32::from_le_bytes(w));
    }
}

impl Device for Lan9118 {
    type RxToken<'a> = Rx<'a>;
    type TxToken<'a> = TxOnly<'a>;

    fn receive(&mut self, _timestamp: Instant) -> Option<(Self::RxToken<'_>, Self::TxToken<'_>)> {
        let len = self.pop_frame()?;
        let Self { rx, tx, stats } = self;
        Some((
            Rx {
                frame: rx.get(..len).unwrap_or_default(),
            },
            TxOnly { tx, stats },
        ))
    }

    fn transmit(&mut self, _timestamp: Instant) -> Option<Self::TxToken<'_>> {
        if !self.tx_room() {
            return None;
        }
        let Self { tx, stats, .. } = self;
        Some(TxOnly { tx, stats })
    }

    fn capabilities(&self) -> DeviceCapabilities {
        let mut caps = DeviceCapabilities::default();
        caps.medium = Medium::Ethernet;
        caps.max_transmission_unit = MTU;
        caps.max_burst_size = Some(1);
        caps
    }
}

/// The transmit token: the TX buffer and the counters (not the RX buffer, which the
/// receive token of the same call holds).
pub struct TxOnly<'a> {
    tx: &'a mut [u8; BUF],
    stats: &'a mut Stats,
}

impl TxToken for TxOnly<'_> {
    fn consume<R, F>(self, len: usize, f: F) -> R
    where
        F: FnOnce(&mut [u8]) -> R,
    {
        let len = len.min(MTU);
        let r = f(self.tx.get_mut(..len).unwrap_or_default());
        send(self.tx.get(..len).unwrap_or_default());
        self.stats.tx_frames = self.stats.tx_frames.wrapping_add(1);
        r
    }
}
