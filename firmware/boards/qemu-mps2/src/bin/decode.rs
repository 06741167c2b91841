//! The decoder check binary for QEMU's `mps2-an386` machine.
//!
//! UART0 is the sensor port, UART1 the output port. It feeds the SCIP stream
//! arriving on UART0 to the `scip` streaming decoder and prints one summary
//! line per response (and one per error) on UART1: the golden outputs of
//! `check.sh`. A byte 0x04 (EOT, never part of SCIP) on UART0 ends the
//! program (see README.md).

#![no_std]
#![no_main]
#![deny(unsafe_code)]

#[path = "../hw.rs"]
#[allow(dead_code)] // shared with the bridge binary
mod hw;
#[path = "../summary.rs"]
mod summary;

use cortex_m_rt::entry;
use embedded_io::{Read, Write};

/// Bit rate of both UARTs (ignored by QEMU, kept realistic).
const BAUD: u32 = 115_200;

/// The byte that ends the program when it arrives on the sensor port.
const EOT: u8 = 0x04;

#[entry]
fn main() -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else {
        hw::exit()
    };
    hw::start_systick(cp.SYST);

    let Some(hw::Board {
        uart0: mut sensor,
        uart1: mut output,
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
                hw::now_ms()
            );
            let _ = output.flush();
            hw::exit();
        }
    }
}

const BANNER: &str = concat!(
    "scip2can-qemu-decode ",
    env!("CARGO_PKG_VERSION"),
    " mps2-an386: UART0=sensor UART1=output, EOT on UART0 exits"
);
