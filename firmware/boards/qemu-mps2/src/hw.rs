//! The board's hardware access: the CMSDK APB UARTs of the MPS2 AN386 image,
//! their receive interrupts, the millisecond SysTick and a 25 MHz tick count,
//! the CMSDK watchdog, stack painting, the idle loop, reset, and the panic,
//! hard-fault and watchdog (NMI) handlers.
//!
//! This is the only module with `unsafe` code. Every `unsafe` block is a
//! volatile access to a fixed, always-mapped device register of this machine
//! or an interrupt-mask operation, each with its `SAFETY:` argument. Outside
//! this module the UARTs are seen only through `embedded-io`.

#![allow(unsafe_code)]

use core::fmt::Write as _;
use core::sync::atomic::{AtomicBool, Ordering};

use core::sync::atomic::{AtomicU32, AtomicU8, AtomicUsize};

use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{NVIC, SCB, SYST};
use cortex_m_rt::exception;

/// Frequency of the MPS2 SYSCLK, which clocks the CPU, SysTick and the APB
/// peripherals (25 MHz in the AN385/AN386 images and in QEMU's model).
pub const SYSCLK_HZ: u32 = 25_000_000;

/// Base address of CMSDK APB UART0 (the sensor port).
const UART0_BASE: usize = 0x4000_4000;
/// Base address of CMSDK APB UART1 (the output / CAN port).
const UART1_BASE: usize = 0x4000_5000;
/// Base address of the CMSDK APB watchdog (its interrupt is the NMI).
const WATCHDOG_BASE: usize = 0x4000_8000;

/// SysTick ticks per millisecond.
pub const TICKS_PER_MS: u32 = SYSCLK_HZ / 1000;

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
    /// CMSDK UART1 receive.
    Uart1Rx = 2,
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

    /// Whether the transmit buffer is full (a write would not be taken now).
    pub fn tx_full(&self) -> bool {
        self.regs.read(reg::STATE) & reg::STATE_TX_FULL != 0
    }

    fn rx_full(&self) -> bool {
        self.regs.read(reg::STATE) & reg::STATE_RX_FULL != 0
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

    /// The next received byte, if one is there (never waits). An overrun is
    /// reported (and cleared) before the byte that follows it.
    pub fn try_read(&mut self) -> Result<Option<u8>, UartError> {
        if self.take_overrun() {
            return Err(UartError::Overrun);
        }
        if !self.rx_full() {
            return Ok(None);
        }
        // Truncation intended: the byte is in DATA bits 7:0.
        Ok(Some((self.regs.read(reg::DATA) & 0xFF) as u8))
    }

    /// Sends `byte` if the transmit buffer is free; false (nothing sent) if not.
    pub fn try_write(&mut self, byte: u8) -> bool {
        if self.tx_full() {
            return false;
        }
        self.regs.write(reg::DATA, u32::from(byte));
        true
    }

    /// Whether a received byte (or an overrun) is waiting.
    pub fn rx_pending(&self) -> bool {
        self.regs.read(reg::STATE) & (reg::STATE_RX_FULL | reg::STATE_RX_OVERRUN) != 0
    }

    /// Changes the bit rate (QEMU ignores it; a real UART would follow).
    pub fn set_baud(&mut self, baud: u32) {
        let div = (SYSCLK_HZ / baud.max(1)).max(16);
        self.regs.write(reg::BAUDDIV, div);
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
    pub uart0: Uart,
    /// UART1: the CAN port (SLCAN) of the bridge, the summary output of the
    /// decoder binary.
    pub uart1: Uart,
}

static TAKEN: AtomicBool = AtomicBool::new(false);

impl Board {
    /// Takes and initialises the UARTs (8N1 at `baud`) and unmasks their
    /// receive interrupts, which wake the core from `sleep_until`. Returns
    /// `None` when called a second time.
    pub fn take(baud: u32) -> Option<Board> {
        if TAKEN.swap(true, Ordering::AcqRel) {
            return None;
        }
        let mut board = Board {
            uart0: Uart {
                regs: Regs { base: UART0_BASE },
            },
            uart1: Uart {
                regs: Regs { base: UART1_BASE },
            },
        };
        board.uart0.init(baud, true);
        board.uart1.init(baud, true);
        for irq in [Irq::Uart0Rx, Irq::Uart1Rx] {
            NVIC::unpend(irq);
            // SAFETY: the handler of these lines (`DefaultHandler` below) only
            // clears the UART's interrupt status; unmasking them cannot break a
            // critical section because none uses the UARTs' interrupt state.
            unsafe { NVIC::unmask(irq) };
        }
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
    // The receive interrupts only wake the idle loop; the main loop reads the
    // bytes. Clear the latched status so the line drops.
    if irqn == Irq::Uart0Rx as i16 {
        let regs = Regs { base: UART0_BASE };
        regs.write(reg::INTSTATUS, reg::INTSTATUS_ALL);
        if RX0_RING.load(Ordering::Relaxed) {
            rx0_fill(&regs);
        }
    } else if irqn == Irq::Uart1Rx as i16 {
        Regs { base: UART1_BASE }.write(reg::INTSTATUS, reg::INTSTATUS_ALL);
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

/// Milliseconds since boot, counted by SysTick.
static MILLIS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    MILLIS.fetch_add(1, Ordering::Relaxed);
}

/// Starts SysTick on the core clock with a 1 ms period and its interrupt.
pub fn start_systick(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(TICKS_PER_MS - 1);
    syst.clear_current();
    syst.enable_counter();
    syst.enable_interrupt();
}

/// Milliseconds since boot (wraps after 49 days).
pub fn now_ms() -> u32 {
    MILLIS.load(Ordering::Relaxed)
}

/// SysTick ticks (25 MHz core clock) since boot: the millisecond count and
/// the counter within the millisecond. Under `qemu-system-arm -icount
/// shift=0` one instruction takes 1 ns of virtual time, so one tick is 40
/// instructions. Call with interrupts enabled (the millisecond count must
/// follow the counter's wrap).
pub fn ticks() -> u64 {
    loop {
        let ms = now_ms();
        let pending = SCB::is_pendst_pending();
        let current = SYST::get_current();
        if now_ms() == ms && SCB::is_pendst_pending() == pending {
            // QEMU takes a pending interrupt only at the end of a translated block:
            // a wrap whose interrupt is still pending has not been counted yet.
            let ms = u64::from(ms) + u64::from(pending);
            let within = (TICKS_PER_MS - 1).saturating_sub(current);
            return ms * u64::from(TICKS_PER_MS) + u64::from(within);
        }
    }
}

/// Register offsets of the CMSDK APB watchdog (ARM DDI 0479, 4.5).
mod wdog {
    /// Reload value; writing it restarts the count.
    pub const LOAD: usize = 0x00;
    /// Control: bit 0 interrupt (and counter) enable, bit 1 reset enable.
    pub const CTRL: usize = 0x08;
    /// Write anything: clears the interrupt and reloads the counter.
    pub const INTCLR: usize = 0x0C;
    /// Write the key to unlock the other registers, anything else to lock.
    pub const LOCK: usize = 0xC00;
    /// The unlock key.
    pub const KEY: u32 = 0x1ACC_E551;
    /// CTRL: counter and interrupt on, reset on the second time-out.
    pub const CTRL_INTEN_RESEN: u32 = 0b11;
}

/// The CMSDK watchdog: counts down at 25 MHz; the first time-out raises the
/// NMI (which reports and resets), a second one resets the system.
pub struct Watchdog {
    regs: Regs,
}

impl Watchdog {
    /// Starts the watchdog with a time-out of `timeout_ms`.
    pub fn start(timeout_ms: u32) -> Watchdog {
        let regs = Regs {
            base: WATCHDOG_BASE,
        };
        regs.write(wdog::LOCK, wdog::KEY);
        regs.write(wdog::LOAD, timeout_ms.saturating_mul(TICKS_PER_MS));
        regs.write(wdog::CTRL, wdog::CTRL_INTEN_RESEN);
        regs.write(wdog::LOCK, 0);
        Watchdog { regs }
    }

    /// Restarts the count.
    pub fn feed(&mut self) {
        self.regs.write(wdog::LOCK, wdog::KEY);
        self.regs.write(wdog::INTCLR, 1);
        self.regs.write(wdog::LOCK, 0);
    }
}

// SAFETY (cortex-m-rt's requirement for an NMI handler): it takes no lock
// and shares no state with the interrupted code; it only writes the UARTs
// and resets.
#[exception]
unsafe fn NonMaskableInt() {
    // Only the watchdog drives the NMI on this board.
    report(format_args!("watchdog: main loop stalled"));
    exit()
}

/// The byte painted over the free stack at boot.
const PAINT: u32 = 0xC0DE_5AFE;

extern "C" {
    /// Start of the heap = end of the static data (cortex-m-rt's `link.x`).
    static mut __sheap: u32;
    /// Initial stack pointer: the top of RAM (cortex-m-rt's `link.x`).
    static mut _stack_start: u32;
}

fn stack_bounds() -> (usize, usize) {
    // Only the addresses of the linker symbols are taken, never their values.
    let bottom = core::ptr::addr_of!(__sheap) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    (bottom, top)
}

/// The stack reservation: from the end of the static data to the top of RAM,
/// in bytes.
pub fn stack_size() -> usize {
    let (bottom, top) = stack_bounds();
    top.saturating_sub(bottom)
}

/// Paints the free stack (below the current frame, minus a margin) so that
/// [`stack_used`] can find the deepest point reached. Call first thing in
/// `main`.
#[inline(never)]
pub fn paint_stack() {
    let (bottom, _) = stack_bounds();
    // Leave the frames above us (and this function's) alone.
    let sp = cortex_m::register::msp::read() as usize;
    let end = sp.saturating_sub(64) & !3;
    let mut p = (bottom + 3) & !3;
    while p < end {
        // SAFETY: `p` is word-aligned and lies between the end of the static
        // data and the stack pointer minus a margin: RAM that no live object
        // occupies (the stack grows down and is above `end`).
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// The most stack ever used since [`paint_stack`], in bytes: the distance
/// from the top of RAM to the lowest word no longer painted.
pub fn stack_used() -> usize {
    let (bottom, top) = stack_bounds();
    let mut p = (bottom + 3) & !3;
    while p < top {
        // SAFETY: word-aligned reads of RAM inside the stack reservation.
        let word = unsafe { core::ptr::read_volatile(p as *const u32) };
        if word != PAINT {
            break;
        }
        p += 4;
    }
    top.saturating_sub(p)
}

/// Capacity of UART0's receive ring (a power of two).
const RX0_CAP: usize = 256;
/// Whether the UART0 interrupt moves received bytes into the ring (the
/// bridge) or only wakes the core (the decoder binary reads the UART).
static RX0_RING: AtomicBool = AtomicBool::new(false);
/// UART0's receive ring: the interrupt handler writes `RX0_HEAD`, the main
/// loop `RX0_TAIL` (single producer, single consumer, no lock needed).
static RX0: [AtomicU8; RX0_CAP] = [const { AtomicU8::new(0) }; RX0_CAP];
static RX0_HEAD: AtomicUsize = AtomicUsize::new(0);
static RX0_TAIL: AtomicUsize = AtomicUsize::new(0);
/// Bytes lost: the ring was full, or the UART reported an overrun.
static RX0_LOST: AtomicU32 = AtomicU32::new(0);

/// Moves every byte UART0 holds into the ring (from its interrupt).
fn rx0_fill(regs: &Regs) {
    loop {
        let state = regs.read(reg::STATE);
        if state & reg::STATE_RX_OVERRUN != 0 {
            regs.write(reg::STATE, reg::STATE_RX_OVERRUN);
            RX0_LOST.fetch_add(1, Ordering::Relaxed);
        }
        if state & reg::STATE_RX_FULL == 0 {
            return;
        }
        // Truncation intended: the byte is in DATA bits 7:0.
        let byte = (regs.read(reg::DATA) & 0xFF) as u8;
        let head = RX0_HEAD.load(Ordering::Relaxed);
        let tail = RX0_TAIL.load(Ordering::Acquire);
        if head.wrapping_sub(tail) >= RX0_CAP {
            RX0_LOST.fetch_add(1, Ordering::Relaxed);
            continue;
        }
        if let Some(slot) = RX0.get(head % RX0_CAP) {
            slot.store(byte, Ordering::Relaxed);
        }
        RX0_HEAD.store(head.wrapping_add(1), Ordering::Release);
    }
}

/// From now on UART0's interrupt fills a receive ring, read with
/// [`rx0_read`] (the bridge: bytes arrive in bursts while the main loop
/// works, as with a DMA ring on a real MCU).
pub fn rx0_use_ring() {
    RX0_RING.store(true, Ordering::Release);
}

/// Takes up to `buf.len()` bytes from UART0's receive ring.
pub fn rx0_read(buf: &mut [u8]) -> usize {
    let head = RX0_HEAD.load(Ordering::Acquire);
    let mut tail = RX0_TAIL.load(Ordering::Relaxed);
    let mut n = 0;
    for slot in buf.iter_mut() {
        if tail == head {
            break;
        }
        *slot = RX0
            .get(tail % RX0_CAP)
            .map_or(0, |b| b.load(Ordering::Relaxed));
        tail = tail.wrapping_add(1);
        n += 1;
    }
    RX0_TAIL.store(tail, Ordering::Release);
    n
}

/// Bytes waiting in UART0's receive ring.
pub fn rx0_len() -> usize {
    RX0_HEAD
        .load(Ordering::Acquire)
        .wrapping_sub(RX0_TAIL.load(Ordering::Relaxed))
}

/// Bytes lost on UART0 so far (ring full or UART overrun).
pub fn rx0_lost() -> u32 {
    RX0_LOST.load(Ordering::Relaxed)
}

/// SysTick ticks spent in `work`, with interrupts masked so that no handler
/// is counted. The work must take less than 1 ms: the counter counts down, so
/// an end value above the start value means one wrap. (The pending bit cannot
/// tell: under QEMU the counter reads as wrapped before the interrupt is
/// pended at the end of a translated block.)
pub fn measure<R>(work: impl FnOnce() -> R) -> (R, u32) {
    cortex_m::interrupt::free(|_| {
        let start = SYST::get_current();
        let out = work();
        let end = SYST::get_current();
        let ticks = if end > start {
            start + TICKS_PER_MS - end
        } else {
            start - end
        };
        (out, ticks)
    })
}
