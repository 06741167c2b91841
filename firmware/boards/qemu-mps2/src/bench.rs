//! The deterministic work benchmark (shared by the `scip2can-qemu-bench` binaries, one
//! per encoding) for QEMU's `mps2-an386` machine.
//!
//! The bridge core of `scip2can-qemu`, with the same configuration, listening to a
//! sensor stream on UART0 (the session is never started, so the core sends nothing back):
//! the stream is cut into chunks of exactly [`CHUNK`] bytes, whatever pace the bytes
//! arrive at, and each chunk goes through `Bridge::on_uart` with SysTick read around the
//! call. The core's time is the stream position at [`config::BAUD`] (10 bits per byte),
//! so the run depends on the stream's bytes only: under `qemu-system-arm -icount
//! shift=0` (one instruction per ns, one SysTick tick per 40 instructions) two runs of
//! one stream give the same counts, and the host can run the same core the same way and
//! must get the same frames.
//!
//! The stream may begin with control frames (SPEC 6) that set the pipeline up, each as
//! a byte 0x01 (SOH, never part of SCIP), its length (at most 64) and its data: the core
//! takes each one as a control frame received from the bus (`Bridge::on_can_frame`),
//! and its answer is popped and dropped, before the measurement starts (the settings
//! apply from the stream's first scan). A byte 0x04 (EOT, never part of SCIP) on UART0
//! ends the stream; the result is one line on UART1:
//!
//! ```text
//! bench bytes=212453 chunks=3320 ticks=… max_chunk_ticks=… scans_in=100 scans_sent=100 \
//!   scans_aborted=0 frames=23900 frame_hash=0x1234abcd overruns=0 pop_ticks=…
//! ```
//! `ticks` is `on_uart` only; `pop_ticks` is every `Bridge::pop_frame_with` call (the
//! frames, and the last call that finds the queue empty), with the frame's identifier,
//! length and data copied out as a board copies them into its CAN controller.
//! `frame_hash` is FNV-1a (32 bit) over every frame popped, in order: the raw identifier
//! (4 bytes, little endian), the FD flag, the length, then the data bytes.

use crate::{config, frame_hash, hw};
use bridge::engine::Bridge;
use can_wire::Encoding;
use embedded_io::{Read, Write};

/// Bytes given to the core per call: what the STM32 boards read from their UART's DMA ring
/// per call at the streaming rate (`board_common::config::UART_CHUNK`; the host side's
/// `icount::CHUNK` must agree).
const CHUNK: usize = 128;

/// The byte that ends the stream.
const EOT: u8 = 0x04;

/// The byte that begins a control frame ahead of the stream.
const SOH: u8 = 0x01;

/// The next byte of UART0 (receive overruns are counted in `overruns`).
fn read_byte(sensor: &mut hw::Uart, overruns: &mut u32) -> u8 {
    let mut b = [0u8; 1];
    loop {
        match sensor.read(&mut b) {
            Ok(1) => return b[0],
            Ok(_) => {}
            Err(hw::UartError::Overrun) => *overruns = overruns.wrapping_add(1),
        }
    }
}

/// Takes the control frames ahead of the stream (SOH, length, data; see the module
/// docs) and drops their answers; returns the stream's first byte.
fn control_frames(
    bridge: &mut Bridge<{ config::QUEUE }>,
    sensor: &mut hw::Uart,
    overruns: &mut u32,
) -> u8 {
    let id = can_wire::IdWindow::DEFAULT
        .node(config::NODE)
        .map(|ids| ids.id(can_wire::Kind::Control));
    loop {
        let b = read_byte(sensor, overruns);
        if b != SOH {
            return b;
        }
        let len = usize::from(read_byte(sensor, overruns)).min(64);
        let mut data = [0u8; 64];
        for slot in data.iter_mut().take(len) {
            *slot = read_byte(sensor, overruns);
        }
        let frame = id.ok().and_then(|id| {
            can_wire::Frame::new(id, data.get(..len).unwrap_or_default(), len > 8).ok()
        });
        if let Some(frame) = frame {
            bridge.on_can_frame(&frame, 0);
        }
        while bridge.pop_frame_with(|_| ()).is_some() {}
    }
}

/// The bridge, built in a frame of its own (never inlined): `run`'s frame then holds
/// one bridge, not the temporaries of its construction too (the board has 24 KiB of
/// RAM for everything).
#[inline(never)]
fn new_bridge(encoding: Encoding) -> Option<Bridge<{ config::QUEUE }>> {
    let mut bridge = config::bridge_with(encoding).and_then(|c| Bridge::new(c).ok())?;
    // Built with SCIP2CAN_BENCH_TIME_ESTIMATE set: the sensor clock model runs on every
    // scan too (its cost per scan is the difference to a build without).
    bridge.set_time_estimation(option_env!("SCIP2CAN_BENCH_TIME_ESTIMATE").is_some());
    Some(bridge)
}

/// Runs the benchmark with the board's configuration in `encoding`.
pub fn run(encoding: Encoding) -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else {
        hw::exit()
    };
    hw::start_systick(cp.SYST);
    let Some(hw::Board {
        uart0: mut sensor,
        uart1: mut output,
    }) = hw::Board::take(config::BAUD)
    else {
        hw::exit()
    };
    // Borrowed where it was returned: a binding by value would be a second copy.
    let mut made = new_bridge(encoding);
    let Some(bridge) = made.as_mut() else {
        hw::exit()
    };
    measure(bridge, &mut sensor, &mut output)
}

/// The measurement loop, in a frame of its own (never inlined into `run`, whose frame
/// holds the bridge).
#[inline(never)]
fn measure(
    bridge: &mut Bridge<{ config::QUEUE }>,
    sensor: &mut hw::Uart,
    output: &mut hw::Uart,
) -> ! {
    let _ = write!(output, "{BANNER}\r\n");

    let mut hash = frame_hash::FrameHash::default();
    let (mut bytes, mut chunks, mut ticks, mut max_ticks) = (0u64, 0u32, 0u64, 0u32);
    let (mut frames, mut overruns, mut pop_ticks) = (0u32, 0u32, 0u64);
    let mut chunk = [0u8; CHUNK];
    let mut out = can_wire::Frame::default();
    let first = control_frames(bridge, sensor, &mut overruns);
    let mut eot = first == EOT;
    chunk[0] = first;
    let mut filled = usize::from(!eot);
    while !eot {
        // Exactly CHUNK bytes, or what is left before EOT.
        while filled < CHUNK && !eot {
            let dst = chunk.get_mut(filled..).unwrap_or_default();
            let n = match sensor.read(dst) {
                Ok(n) => n,
                Err(hw::UartError::Overrun) => {
                    overruns = overruns.wrapping_add(1);
                    continue;
                }
            };
            let got = chunk.get(filled..filled + n).unwrap_or_default();
            match got.iter().position(|&b| b == EOT) {
                Some(i) => {
                    filled += i;
                    eot = true;
                }
                None => filled += n,
            }
        }
        let data = chunk.get(..filled).unwrap_or_default();
        if !data.is_empty() {
            bytes += data.len() as u64;
            // The core's clock: when the chunk's last byte arrived at the nominal rate.
            let now = bytes * 10 * 1000 / u64::from(config::BAUD);
            let ((), t) = hw::measure(|| bridge.on_uart(data, now));
            ticks += u64::from(t);
            max_ticks = max_ticks.max(t);
            chunks = chunks.wrapping_add(1);
            loop {
                // Taking a frame off the queue is core work too (its bus bookkeeping).
                // As a board hands a frame to its CAN controller: its identifier, length
                // and data bytes copied out (here into `out`, hashed after).
                let (popped, t) = hw::measure(|| {
                    bridge.pop_frame_with(|frame| out.set(frame.id(), frame.data(), frame.is_fd()))
                });
                pop_ticks += u64::from(t);
                if popped.is_none() {
                    break;
                }
                hash.frame(&out);
                frames = frames.wrapping_add(1);
            }
        }
        filled = 0;
    }
    let s = bridge.stats();
    let _ = write!(
        output,
        "bench bytes={bytes} chunks={chunks} ticks={ticks} max_chunk_ticks={max_ticks} \
         scans_in={} scans_sent={} scans_aborted={} frames={frames} frame_hash={:#010x} \
         overruns={overruns} pop_ticks={pop_ticks}\r\n",
        s.scans_in, s.scans_sent, s.scans_aborted, hash.0
    );
    let _ = output.flush();
    hw::exit()
}

const BANNER: &str = concat!(
    "scip2can-qemu-bench ",
    env!("CARGO_PKG_VERSION"),
    " mps2-an386: UART0=sensor stream, EOT ends it; UART1=result"
);
