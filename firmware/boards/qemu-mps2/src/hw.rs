//! The board's hardware access: the CMSDK APB UARTs of the MPS2 AN386 image,
//! the UART0 receive interrupt, the idle loop, reset, and the panic and
//! hard-fault handlers.
//!
//! This is the only module with `unsafe` code. Every `unsafe` block is a
//! volatile access to a fixed, always-mapped device register of this machine
//! or an interrupt-mask operation, each with its `SAFETY:` argument. Outside
//! this module the UARTs are seen only through `embedded-io`.

#![allow(unsafe_code)]

use core::fmt::Write as _;
use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::{NVIC, SCB};
use cortex_m_rt::exception;

/// Frequency of the MPS2 SYSCLK, which clocks the CPU, SysTick and the APB
/// peripherals (25 MHz in the AN385/AN386 images and in QEMU's model).
pub const SYSCLK_HZ: u32 = 25_000_000;

/// Base address of CMSDK APB UART0 (the sensor port).
const UART0_BASE: usize = 0x4000_4000;
/// Base address of CMSDK APB UART1 (the output port).
const UART1_BASE: usize = 0x4000_5000;

/// Register offsets and bits of the CMSDK APB UART (ARM DDI 0479, 4.3).
mod reg {
    /// Received byte (read) / byte to send (write), bits 7:0.
    pub const DATA: usize = 0x00;
    /// Status; write 1 to an overrun bit to clear it.
    pub const STATE: usize = 0x04;
    /// Control: enables.
    pub const CTRL: usize = 0x08;
    /// Interrupt status; write 1 to clear.
    pub const INTSTATUS: usize = 0x0C;
    /// Baud rate divider: SYSCLK / baud, at least 16.
    pub const BAUDDIV: usize = 0x10;

    /// STATE: the transmit buffer is full.
    pub const STATE_TX_FULL: u32 = 1 << 0;
    /// STATE: the receive buffer holds a byte.
    pub const STATE_RX_FULL: u32 = 1 << 1;
    /// STATE: a received byte was lost (receive overrun).
    pub const STATE_RX_OVERRUN: u32 = 1 << 3;

    /// CTRL: transmitter enable.
    pub const CTRL_TX_EN: u32 = 1 << 0;
    /// CTRL: receiver enable.
    pub const CTRL_RX_EN: u32 = 1 << 1;
    /// CTRL: receive interrupt enable.
    pub const CTRL_RX_INT_EN: u32 = 1 << 3;

    /// INTSTATUS: all four interrupt bits (TX, RX, TX overrun, RX overrun).
    pub const INTSTATUS_ALL: u32 = 0xF;
}

/// The device interrupts this board uses (NVIC numbers of the AN385/AN386
/// images: UART0 RX = 0, UART0 TX = 1, UART1 RX = 2, ...).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
enum Irq {
    /// CMSDK UART0 receive.
    Uart0Rx = 0,
}

// SAFETY: `number` returns the NVIC line of a real interrupt of this
// machine (the image has 32 lines), as `InterruptNumber` requires.
unsafe impl InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

/// Volatile access to one UART's register block.
struct Regs {
    base: usize,
}

impl Regs {
    fn read(&self, offset: usize) -> u32 {
        // SAFETY: `base` is one of the UART base addresses above and
        // `offset` one of the `reg` offsets: an aligned, always-mapped
        // 32-bit device register without read side effects that could break
        // memory safety (reading DATA only pops the receive buffer).
        unsafe { core::ptr::read_volatile((self.base + offset) as *const u32) }
    }

    fn write(&self, offset: usize, value: u32) {
        // SAFETY: as in `read`; writing these registers affects only the
        // UART itself, never memory the program uses.
        unsafe { core::ptr::write_volatile((self.base + offset) as *mut u32, value) }
    }
}

/// One CMSDK APB UART: 8N1, one-byte transmit and receive buffers.
pub struct Uart {
    regs: Regs,
}

/// What can go wrong on a UART.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UartError {
    /// A received byte arrived before the previous one was read and was lost.
    Overrun,
}

impl embedded_io::Error for UartError {
    fn kind(&self) -> embedded_io::ErrorKind {
        embedded_io::ErrorKind::Other
    }
}

impl core::fmt::Display for UartError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            UartError::Overrun => f.write_str("receive overrun"),
        }
    }
}

impl Uart {
    /// Sets the bit rate and enables transmitter and receiver. QEMU ignores
    /// the rate (bytes move as fast as the guest reads them), real hardware
    /// does not.
    fn init(&mut self, baud: u32, rx_interrupt: bool) {
        let div = (SYSCLK_HZ / baud.max(1)).max(16);
        self.regs.write(reg::CTRL, 0);
        self.regs.write(reg::BAUDDIV, div);
        self.regs.write(reg::STATE, reg::STATE_RX_OVERRUN);
        self.regs.write(reg::INTSTATUS, reg::INTSTATUS_ALL);
        let mut ctrl = reg::CTRL_TX_EN | reg::CTRL_RX_EN;
        if rx_interrupt {
            ctrl |= reg::CTRL_RX_INT_EN;
        }
        self.regs.write(reg::CTRL, ctrl);
    }

    fn rx_full(&self) -> bool {
        self.regs.read(reg::STATE) & reg::STATE_RX_FULL != 0
    }

    fn tx_full(&self) -> bool {
        self.regs.read(reg::STATE) & reg::STATE_TX_FULL != 0
    }

    /// Reports and clears a receive overrun.
    fn take_overrun(&mut self) -> bool {
        if self.regs.read(reg::STATE) & reg::STATE_RX_OVERRUN != 0 {
            self.regs.write(reg::STATE, reg::STATE_RX_OVERRUN);
            true
        } else {
            false
        }
    }

    /// Waits until the transmit buffer is free, then sends `byte`.
    fn write_byte(&mut self, byte: u8) {
        while self.tx_full() {
            core::hint::spin_loop();
        }
        self.regs.write(reg::DATA, u32::from(byte));
    }
}

impl embedded_io::ErrorType for Uart {
    type Error = UartError;
}

impl embedded_io::Read for Uart {
    /// Sleeps until at least one byte is there, then returns every byte
    /// that is ready without waiting more.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        if buf.is_empty() {
            return Ok(0);
        }
        sleep_until(|| self.rx_full() || self.regs.read(reg::STATE) & reg::STATE_RX_OVERRUN != 0);
        if self.take_overrun() {
            return Err(UartError::Overrun);
        }
        let mut n = 0;
        for slot in buf.iter_mut() {
            if !self.rx_full() {
                break;
            }
            // Truncation intended: the byte is in DATA bits 7:0.
            *slot = (self.regs.read(reg::DATA) & 0xFF) as u8;
            n += 1;
        }
        Ok(n)
    }
}

impl embedded_io::ReadReady for Uart {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.rx_full())
    }
}

impl embedded_io::Write for Uart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let Some((&first, rest)) = buf.split_first() else {
            return Ok(0);
        };
        self.write_byte(first);
        let mut n = 1;
        for &byte in rest {
            if self.tx_full() {
                break;
            }
            self.regs.write(reg::DATA, u32::from(byte));
            n += 1;
        }
        Ok(n)
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        while self.tx_full() {
            core::hint::spin_loop();
        }
        Ok(())
    }
}

impl embedded_io::WriteReady for Uart {
    fn write_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(!self.tx_full())
    }
}

/// The board's UARTs, handed out once.
pub struct Board {
    /// UART0, towards the laser range finder.
    pub sensor: Uart,
    /// UART1, the output port (summaries now; SLCAN later).
    pub output: Uart,
}

static TAKEN: AtomicBool = AtomicBool::new(false);

impl Board {
    /// Takes and initialises the UARTs (8N1 at `baud`) and unmasks the UART0
    /// receive interrupt, which wakes the core from `sleep_until`. Returns
    /// `None` when called a second time.
    pub fn take(baud: u32) -> Option<Board> {
        if TAKEN.swap(true, Ordering::AcqRel) {
            return None;
        }
        let mut board = Board {
            sensor: Uart {
                regs: Regs { base: UART0_BASE },
            },
            output: Uart {
                regs: Regs { base: UART1_BASE },
            },
        };
        board.sensor.init(baud, true);
        board.output.init(baud, false);
        NVIC::unpend(Irq::Uart0Rx);
        // SAFETY: the handler of this line (`DefaultHandler` below) only
        // clears the UART's interrupt status; unmasking it cannot break a
        // critical section because none uses UART0's interrupt state.
        unsafe { NVIC::unmask(Irq::Uart0Rx) };
        Some(board)
    }
}

/// Sleeps (WFI) until `ready()` holds. Interrupts wake the core: the UART0
/// receive interrupt and SysTick. `ready` is checked with interrupts masked
/// so that a wake-up between the check and the WFI cannot be missed.
pub fn sleep_until(mut ready: impl FnMut() -> bool) {
    // `is_inactive`: PRIMASK is set, configurable-priority interrupts are off.
    if cortex_m::register::primask::read().is_inactive() {
        // Called with interrupts already masked (from a critical section):
        // never unmask them here, just poll.
        while !ready() {
            core::hint::spin_loop();
        }
        return;
    }
    loop {
        cortex_m::interrupt::disable();
        let done = ready();
        if !done {
            // A pending interrupt ends WFI even while PRIMASK masks it.
            cortex_m::asm::wfi();
        }
        // SAFETY: interrupts were enabled on entry (checked above) and this
        // function holds no state that a handler could observe half-updated.
        unsafe { cortex_m::interrupt::enable() };
        if done {
            return;
        }
    }
}

/// Ends the program: requests a system reset. QEMU started with
/// `-no-reboot` exits (status 0) instead of rebooting.
pub fn exit() -> ! {
    SCB::sys_reset()
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    if irqn == Irq::Uart0Rx as i16 {
        // The receive interrupt only wakes the idle loop; the main loop
        // reads the byte. Clear the latched status so the line drops.
        Regs { base: UART0_BASE }.write(reg::INTSTATUS, reg::INTSTATUS_ALL);
    }
}

/// Prints the panic on the output port (UART1) and on UART0, then exits.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    cortex_m::interrupt::disable();
    report(format_args!("panic: {info}"));
    exit()
}

/// Prints the faulting PC on both UARTs, then exits, so a test sees the fault
/// at once instead of a hung QEMU.
#[exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    report(format_args!(
        "hardfault: pc={:#010x} lr={:#010x}",
        frame.pc(),
        frame.lr()
    ));
    exit()
}

/// Writes one line on UART1 and UART0 with fresh handles: the owner may be
/// mid-write, but this runs only on the way out.
fn report(msg: core::fmt::Arguments<'_>) {
    for base in [UART1_BASE, UART0_BASE] {
        let regs = Regs { base };
        // Make sure the transmitter is on even if this came before init.
        regs.write(reg::CTRL, regs.read(reg::CTRL) | reg::CTRL_TX_EN);
        let mut out = PanicWriter(Uart { regs });
        let _ = write!(out, "\r\n{msg}\r\n");
    }
}

struct PanicWriter(Uart);

impl core::fmt::Write for PanicWriter {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for &b in s.as_bytes() {
            self.0.write_byte(b);
        }
        Ok(())
    }
}
