//! CAN1 (bxCAN): set-up, the transmit and receive tasks, and the bus supervision the
//! main loop needs (error state, explicit bus-off recovery).
//!
//! **Transmit order.** The three transmit mailboxes are scheduled in request order
//! (`MCR.TXFP = 1`, [`Can::set_tx_fifo_scheduling`]). With the default priority
//! scheduling the bxCAN sends the mailbox with the lowest identifier first, and among
//! equal identifiers the lowest mailbox number, not the oldest request (embassy then
//! refuses a second frame with a pending frame's identifier, which serialises a scan's
//! data frames to one in flight). In FIFO order frames leave as the bridge queued them:
//! control answers and status first, then each scan's header, data and trailer.
//!
//! **Bus-off.** Embassy's `enable` sets `MCR.ABOM` (automatic bus-off management); the
//! transmit task clears it right after, so after bus-off the controller stays off the
//! bus until [`Supervisor::recover`] requests and leaves initialisation mode, which the
//! main loop does at most once per 100 ms (`board_common::recovery`).
//!
//! **Errors.** The driver reports each error interrupt (`MSR.ERRI`: a new last-error
//! code or an error-state change) once, as an error result of `read`; the receive task
//! counts those with `Bridge::on_bus_error`.
//!
//! Register access that embassy does not offer (`MCR.ABOM`, `MCR.INRQ`, `ESR`) goes
//! through `embassy_stm32::pac` (the `unstable-pac` feature).

use board_common::config::CanBus;
use board_common::Shared;
use can_wire::BusState;
use embassy_stm32::can::filter::ListEntry32;
use embassy_stm32::can::util::calc_can_timings;
use embassy_stm32::can::{
    Can, CanRx, CanTx, Fifo, Frame, Rx0InterruptHandler, Rx1InterruptHandler, RxPin,
    SceInterruptHandler, TxInterruptHandler, TxPin,
};
use embassy_stm32::interrupt::typelevel::{Binding, CAN1_RX0, CAN1_RX1, CAN1_SCE, CAN1_TX};
use embassy_stm32::pac;
use embassy_stm32::peripherals::CAN1;
use embassy_stm32::Peri;
use embedded_can::Id;

/// Reads of `MSR` to wait for the initialisation-mode acknowledge during a recovery
/// (the controller is off the bus then, so it acknowledges within a few cycles; the
/// bound only keeps a faulty controller from hanging the main loop: well under 1 ms).
const INIT_ACK_READS: u32 = 10_000;

/// Sets up CAN1 on `rx`/`tx` for `bus`: bit timing, FIFO transmit order, only the data
/// frames of the identifiers `ids` accepted (this bridge's control frames and the time
/// master's, `board_common::config::accepted_ids`: filter bank 0, a list of two, into
/// FIFO 0). The
/// controller stays asleep until the transmit task enables it.
pub fn configure(
    peri: Peri<'static, CAN1>,
    rx: Peri<'static, impl RxPin<CAN1>>,
    tx: Peri<'static, impl TxPin<CAN1>>,
    irqs: impl Binding<CAN1_TX, TxInterruptHandler<CAN1>>
        + Binding<CAN1_RX0, Rx0InterruptHandler<CAN1>>
        + Binding<CAN1_RX1, Rx1InterruptHandler<CAN1>>
        + Binding<CAN1_SCE, SceInterruptHandler<CAN1>>
        + 'static,
    bus: CanBus,
    ids: [Id; 2],
) -> Can<'static> {
    let mut can = Can::new(peri, rx, tx, irqs);
    let entries = ids.map(ListEntry32::data_frames_with_id);
    can.modify_filters().enable_bank(0, Fifo::Fifo0, entries);
    // The bit timing as embassy's `set_bitrate` works it out, but a rate the clock cannot
    // make is a panic naming the step (`board_common::started`): `unwrap` linked
    // `core::fmt`'s `Debug` machinery (about 1.5 KB of flash) for the message, and
    // `defmt::unwrap!` the error's `defmt::Format`.
    let timing = board_common::started(
        calc_can_timings(embassy_stm32::rcc::frequency::<CAN1>(), bus.rates.nominal),
        "CAN bit timing",
    );
    // Dropping the configuration proxy leaves initialisation mode (into sleep).
    can.modify_config()
        .set_bit_timing(timing)
        .set_automatic_retransmit(true);
    can.set_tx_fifo_scheduling(true);
    can
}

/// The bxCAN frame for a bridge frame (classic only: the bridge never makes CAN FD
/// frames on a controller that is not FD-capable).
fn to_bxcan(frame: &can_wire::Frame) -> Option<Frame> {
    if frame.is_fd() {
        return None;
    }
    Frame::new_data(frame.id(), frame.data()).ok()
}

/// The bridge frame for a received data frame (remote frames give `None`).
fn from_bxcan(frame: &Frame) -> Option<can_wire::Frame> {
    if frame.header().rtr() {
        return None;
    }
    can_wire::Frame::new(*frame.id(), frame.data(), false).ok()
}

/// Enables the controller (waits for 11 recessive bits), hands bus-off recovery to the
/// main loop, then moves the bridge's frames into the mailboxes, in order. Keeps `can`
/// alive: dropping it would reset the controller.
#[embassy_executor::task]
pub async fn tx_task(shared: &'static Shared, mut can: Can<'static>, mut tx: CanTx<'static>) {
    can.enable().await;
    pac::CAN1.mcr().modify(|w| w.set_abom(false));
    defmt::info!("CAN1 on the bus");
    loop {
        let frame = shared.next_frame().await;
        match to_bxcan(&frame) {
            Some(f) => {
                // FIFO scheduling never displaces a pending frame.
                let _ = tx.write(&f).await;
            }
            None => defmt::warn!("frame not representable on bxCAN: {}", frame.data().len()),
        }
    }
}

/// Hands received control frames to the bridge (their answers are queued at once) and
/// counts bus errors.
#[embassy_executor::task]
pub async fn rx_task(shared: &'static Shared, mut rx: CanRx<'static>) {
    loop {
        match rx.read().await {
            Ok(envelope) => {
                if let Some(frame) = from_bxcan(&envelope.frame) {
                    // The reception time (a time master's SYNC, SPEC 9, is taken at it):
                    // embassy stamps the frame in the receive interrupt, as it takes it
                    // from the controller's FIFO (bxCAN's own 16-bit stamp counts bit
                    // times and would need the bit rate to be turned into µs).
                    let now_us = envelope.ts.as_micros();
                    if shared.with(|b| b.on_can_frame_at(&frame, now_us)) {
                        shared.notify_frames();
                    }
                }
            }
            Err(_) => shared.with(|b| b.on_bus_error()),
        }
    }
}

/// The bus supervision the main loop uses.
pub struct Supervisor;

impl Supervisor {
    /// The supervision of CAN1.
    pub fn new() -> Self {
        Self
    }

    /// The controller's error state (`ESR.BOFF`, `ESR.EPVF`).
    pub fn state(&self) -> BusState {
        let esr = pac::CAN1.esr().read();
        if esr.boff() {
            BusState::BusOff
        } else if esr.epvf() {
            BusState::ErrorPassive
        } else {
            BusState::ErrorActive
        }
    }

    /// Starts bus-off recovery: with `ABOM` clear, entering and leaving initialisation
    /// mode makes the controller wait for 128 occurrences of 11 recessive bits, then
    /// take part in bus traffic again. Pending mailboxes stay pending.
    pub fn recover(&mut self) {
        let can = pac::CAN1;
        can.mcr().modify(|w| w.set_inrq(true));
        for _ in 0..INIT_ACK_READS {
            if can.msr().read().inak() {
                break;
            }
        }
        can.mcr().modify(|w| w.set_inrq(false));
    }
}
