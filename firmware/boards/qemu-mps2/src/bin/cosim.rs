//! The bridge in lockstep with a host simulator (`scip2can-qemu-cosim`): the sensor
//! clock model (`time-estimate`) on the board's own clock, in exact virtual time.
//!
//! Run under `qemu-system-arm -icount shift=N,sleep=off -semihosting-config
//! enable=on,target=native`: virtual time advances with the instructions only, and
//! while the core sleeps it jumps to the next timer deadline (SysTick's). The sensor is
//! a simulator on the host, which runs in simulated time; the two advance together one
//! slot at a time (the host sets each slot's end: 1 ms, on SysTick's ticks, while the
//! sensor streams; 50 µs around commands), through two host pipes read and written
//! with semihosting calls (the protocol: the boards README, "Lockstep co-simulation"):
//!
//! 1. At the slot's start the board stops SysTick (its clock), writes the bridge's
//!    frames so far to UART1 as SLCAN lines, and asks the host for the sensor bytes of
//!    the slot, telling it the commands the session sent in the last one and when.
//! 2. The host answers (a semihosting call is one instruction to the guest: virtual
//!    time does not move meanwhile): the slot's end, and chunks of sensor bytes, each
//!    with the time its last byte arrives.
//! 3. The board restarts SysTick and hands each chunk to the core when its clock
//!    reaches the chunk's time, stamped by that clock ([`Bridge::on_uart_at`], as a
//!    board with a DMA ring and an idle-line interrupt would), polling the session in
//!    between; then it waits for the slot's end.
//!
//! So the board's clock (SysTick, µs = ticks / 25, stopped during the exchanges) is
//! the simulator's time, and a run depends on the firmware and the simulator only: two
//! runs give the same bytes on UART1. The SLCAN port is open from boot (no `O` needed)
//! and nothing is read from it: a host's input would arrive at host-dependent virtual
//! times.

#![no_std]
#![no_main]
#![deny(unsafe_code)]

#[path = "../config.rs"]
#[allow(dead_code)] // the board binary's settings: only the queue and the node are used
mod config;
#[path = "../hw.rs"]
#[allow(dead_code)] // shared with the bridge binary
mod hw;
#[path = "../semihosting.rs"]
mod semihosting;

use bridge::engine::{Bridge, BridgeConfig};
use bridge::session::Action;
use can_wire::{Encoding, FrameFormat, IdWindow};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::entry;
use embedded_io::Write;
use heapless::Vec;

/// The sensor link the host simulates: 5 Mbit/s (2 µs a byte), as the host-level test
/// of the clock model (`scan_clock`) assumes.
const UART_BIT_RATE: u32 = 5_000_000;

/// The request's first byte.
const REQUEST: u8 = b'Q';
/// The answer's first byte: chunks follow.
const ANSWER: u8 = b'A';

/// Capacity of one slot's answer after its head (at 2 µs a byte, 500 bytes and their
/// chunk heads; the host's `cosim::ANSWER_MAX`).
const ANSWER_CAP: usize = 1024;
/// The host's pipes, relative to QEMU's working folder.
const REQUESTS: &core::ffi::CStr = c"cosim-requests";
/// The host's answers.
const ANSWERS: &core::ffi::CStr = c"cosim-answers";
/// Capacity of the commands reported per slot.
const COMMANDS_CAP: usize = 256;

/// The bridge of the co-simulation: the host test's (`scan_clock`) settings, a UTM-30LX
/// class stream (plain millimetres, CAN FD 1/5 Mbit/s), the sensor clock model on.
fn bridge_config() -> Option<BridgeConfig> {
    Some(BridgeConfig {
        encoding: Encoding::PLAIN_MM,
        uart_bit_rate: UART_BIT_RATE,
        status_period_ms: 0,
        ..BridgeConfig::new(
            IdWindow::DEFAULT.node(config::NODE).ok()?,
            FrameFormat::FD64,
        )
    })
}

/// The board clock, µs: SysTick's ticks (25 per µs).
fn now_us() -> u64 {
    hw::ticks() / u64::from(hw::TICKS_PER_MS / 1000)
}

fn u64_at(bytes: &[u8], at: usize) -> Option<u64> {
    let b: [u8; 8] = bytes.get(at..at + 8)?.try_into().ok()?;
    Some(u64::from_le_bytes(b))
}

#[entry]
fn main() -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else {
        hw::exit()
    };
    let mut syst = cp.SYST;
    start_clock(&mut syst);
    let Some(hw::Board {
        uart0: _,
        uart1: mut can,
    }) = hw::Board::take(config::BAUD)
    else {
        hw::exit()
    };
    let Some(bridge_config) = bridge_config() else {
        hw::exit()
    };
    let Ok(mut bridge) = Bridge::<{ config::QUEUE }>::new(bridge_config) else {
        hw::exit()
    };
    bridge.set_bus_state(can_wire::BusState::ErrorActive);
    bridge.set_time_estimation(true);
    bridge.start(0);

    // The host's pipes (its requests first: the host opens them in this order).
    let (Some(requests), Some(answers)) = (
        semihosting::open(REQUESTS, semihosting::MODE_WRITE),
        semihosting::open(ANSWERS, semihosting::MODE_READ),
    ) else {
        hw::exit()
    };
    // The commands sent in the current slot: (time µs, length, bytes) each.
    let mut commands: Vec<u8, COMMANDS_CAP> = Vec::new();
    let mut sent: u8 = 0;
    let mut answer = [0u8; ANSWER_CAP];
    // The start of the next slot, board µs.
    let mut slot_us: u64 = 0;
    loop {
        // The slot boundary: on a millisecond, sleep to the tick (virtual time jumps
        // there); within one, count to it.
        if slot_us % 1000 == 0 {
            let ms = u32::try_from(slot_us / 1000).unwrap_or(u32::MAX);
            hw::sleep_until(|| hw::now_ms() >= ms);
        }
        while now_us() < slot_us {}
        syst.disable_counter();
        send_frames(&mut bridge, &mut can);
        let mut head = [0u8; 10];
        head[0] = REQUEST;
        head[1..9].copy_from_slice(&slot_us.to_le_bytes());
        head[9] = sent;
        let _ = semihosting::write(requests, &head);
        let _ = semihosting::write(requests, &commands);
        commands.clear();
        sent = 0;
        let mut tag = [0u8; 11];
        if !semihosting::read_exact(answers, &mut tag) {
            hw::exit()
        }
        let end = u64_at(&tag, 1).unwrap_or(0);
        let len = usize::from(u16::from_le_bytes([tag[9], tag[10]]));
        let Some(body) = answer.get_mut(..len) else {
            hw::exit()
        };
        if tag[0] != ANSWER || !semihosting::read_exact(answers, body) {
            // The end of the run (or a broken lockstep): whatever the last slot made,
            // then stop.
            send_frames(&mut bridge, &mut can);
            while can.tx_full() {}
            hw::exit()
        }
        syst.enable_counter();
        let body = answer.get(..len).unwrap_or_default();
        let mut at = 0;
        while let Some(due) = u64_at(body, at) {
            let n = usize::from(body.get(at + 8).copied().unwrap_or(0));
            let bytes = body.get(at + 9..at + 9 + n).unwrap_or_default();
            at += 9 + n;
            while now_us() < due {}
            bridge.on_uart_at(bytes, now_us());
            poll(&mut bridge, &mut commands, &mut sent);
        }
        poll(&mut bridge, &mut commands, &mut sent);
        slot_us = end;
    }
}

/// The session's actions at the board clock's now: commands are recorded for the host
/// with their send time.
fn poll(
    bridge: &mut Bridge<{ config::QUEUE }>,
    commands: &mut Vec<u8, COMMANDS_CAP>,
    sent: &mut u8,
) {
    loop {
        let now = now_us();
        let Some(action) = bridge.poll_at(now) else {
            return;
        };
        if let Action::Send(request) = action {
            let mut line = [0u8; scip::REQUEST_MAX];
            let room = commands.capacity() - commands.len();
            if let Some(len) = request
                .encode(&mut line)
                .ok()
                .filter(|&len| len + 9 <= room)
            {
                *sent = sent.saturating_add(1);
                let _ = commands.extend_from_slice(&now.to_le_bytes());
                let _ = commands.push(len.min(255) as u8);
                let _ = commands.extend_from_slice(line.get(..len).unwrap_or_default());
            }
        }
    }
}

/// Writes every queued frame to UART1 as an SLCAN line (`d`/`b`/`t`), waiting for the
/// UART: called with the clock stopped, so the wait costs no board time.
fn send_frames(bridge: &mut Bridge<{ config::QUEUE }>, can: &mut hw::Uart) {
    while let Some(Some(line)) = bridge.pop_frame_with(|frame| {
        let kind = if frame.is_fd() {
            slcan::FrameKind::FdBrs
        } else {
            slcan::FrameKind::Data
        };
        let f = slcan::Frame::new(frame.id(), kind, frame.data()).ok()?;
        let mut buf = [0u8; slcan::LINE_MAX];
        let n = f.emit(None, &mut buf).ok()?;
        Some((buf, n))
    }) {
        let (buf, n) = line;
        let _ = can.write_all(buf.get(..n).unwrap_or_default());
    }
}

/// SysTick on the core clock, a 1 ms period and its interrupt (as `hw::start_systick`,
/// keeping the peripheral to stop and restart it).
fn start_clock(syst: &mut SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(hw::TICKS_PER_MS - 1);
    syst.clear_current();
    syst.enable_counter();
    syst.enable_interrupt();
}
