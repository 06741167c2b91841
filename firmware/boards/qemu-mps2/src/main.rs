//! scip2can firmware for QEMU's `mps2-an386` machine.
//!
//! UART0 is the sensor port, UART1 the output port. This first version
//! decodes the SCIP stream arriving on UART0 and prints one summary line per
//! response on UART1. A byte 0x04 (EOT, never part of SCIP) on UART0 ends
//! the program (see README.md).

#![no_std]
#![no_main]
#![deny(unsafe_code)]

mod hw;

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception};
use embedded_io::{Read, Write};

/// Bit rate of both UARTs (ignored by QEMU, kept realistic).
const BAUD: u32 = 115_200;

/// The byte that ends the program when it arrives on the sensor port.
const EOT: u8 = 0x04;

/// Milliseconds since boot, counted by SysTick.
static MILLIS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    MILLIS.fetch_add(1, Ordering::Relaxed);
}

/// Milliseconds since boot (wraps after 49 days).
fn now_ms() -> u32 {
    MILLIS.load(Ordering::Relaxed)
}

#[entry]
fn main() -> ! {
    let Some(mut cp) = cortex_m::Peripherals::take() else {
        hw::exit()
    };
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(hw::SYSCLK_HZ / 1000 - 1);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();
    cp.SYST.enable_interrupt();

    let Some(hw::Board {
        mut sensor,
        mut output,
    }) = hw::Board::take(BAUD)
    else {
        hw::exit()
    };

    // The banner goes to both ports: UART1 is the output port, and UART0 is
    // what `-nographic` alone shows on stdio.
    for port in [&mut output, &mut sensor] {
        let _ = write!(port, "{BANNER}\r\n");
    }

    let mut stats = Stats::default();
    let mut buf = [0u8; 64];
    loop {
        let n = match sensor.read(&mut buf) {
            Ok(n) => n,
            Err(_) => {
                stats.overruns += 1;
                continue;
            }
        };
        let chunk = buf.get(..n).unwrap_or_default();
        let (data, eot) = match chunk.iter().position(|&b| b == EOT) {
            Some(i) => (chunk.get(..i).unwrap_or_default(), true),
            None => (chunk, false),
        };
        stats.bytes += data.len() as u32;
        for &b in data {
            if b == b'\n' {
                if stats.line_len == 0 {
                    stats.responses += 1;
                    let _ = write!(output, "resp lines={}\r\n", stats.lines);
                    stats.lines = 0;
                } else {
                    stats.lines += 1;
                }
                stats.line_len = 0;
            } else {
                stats.line_len += 1;
            }
        }
        if eot {
            let _ = write!(
                output,
                "end bytes={} responses={} overruns={} uptime_ms={}\r\n",
                stats.bytes,
                stats.responses,
                stats.overruns,
                now_ms()
            );
            let _ = output.flush();
            hw::exit();
        }
    }
}

const BANNER: &str = concat!(
    "scip2can-qemu ",
    env!("CARGO_PKG_VERSION"),
    " mps2-an386: UART0=sensor UART1=output, EOT on UART0 exits"
);

#[derive(Default)]
struct Stats {
    bytes: u32,
    responses: u32,
    overruns: u32,
    lines: u32,
    line_len: u32,
}
