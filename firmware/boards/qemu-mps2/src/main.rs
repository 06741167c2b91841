//! scip2can firmware for QEMU's `mps2-an386` machine.
//!
//! UART0 is the sensor port, UART1 the output port. This first version
//! feeds the SCIP stream arriving on UART0 to the `scip` streaming decoder
//! and prints one summary line per response (and one per error) on UART1.
//! A byte 0x04 (EOT, never part of SCIP) on UART0 ends the program (see
//! README.md).

#![no_std]
#![no_main]
#![deny(unsafe_code)]

mod hw;
mod summary;

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

    let mut decoder = scip::Decoder::new();
    let mut summary = summary::Summariser::new();
    let mut overruns: u32 = 0;
    let mut buf = [0u8; 64];
    loop {
        let n = match sensor.read(&mut buf) {
            Ok(n) => n,
            Err(hw::UartError::Overrun) => {
                // A lost byte shows up as a bad line in the decoder too.
                overruns = overruns.wrapping_add(1);
                continue;
            }
        };
        let chunk = buf.get(..n).unwrap_or_default();
        let (data, eot) = match chunk.iter().position(|&b| b == EOT) {
            Some(i) => (chunk.get(..i).unwrap_or_default(), true),
            None => (chunk, false),
        };
        let mut rest = data;
        while !rest.is_empty() {
            let (used, ev) = decoder.feed(rest);
            if let Some(ev) = ev {
                summary.event(&ev, &mut output);
            }
            // `feed` consumes at least one byte of non-empty input; the
            // guard keeps the loop bounded whatever it returns.
            match rest.get(used..) {
                Some(r) if used > 0 => rest = r,
                _ => break,
            }
        }
        if eot {
            if let Some(ev) = decoder.finish() {
                summary.event(&ev, &mut output);
            }
            let st = decoder.stats();
            let _ = write!(
                output,
                "end bytes={} responses={} errors={} resyncs={} overruns={} uptime_ms={}\r\n",
                st.bytes,
                st.responses,
                st.errors,
                st.resyncs,
                overruns,
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
