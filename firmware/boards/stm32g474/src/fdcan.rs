//! FDCAN1: set-up, the transmit and receive tasks, and the bus supervision the main loop
//! needs (error state, error count, explicit bus-off recovery).
//!
//! **Transmit order.** The controller's three transmit buffers run as a FIFO
//! (`TXBC.TFQM = 0`, [`TxBufferMode::Fifo`]), not as the priority queue embassy
//! configures by default. In queue mode the FDCAN sends the pending buffer with the
//! lowest identifier first, and among equal identifiers the lowest buffer index, not the
//! oldest request: the data frames of one scan (all on the same identifier) could leave
//! out of order, and a new scan's header (lower identifier) could overtake the previous
//! scan's trailer. In FIFO mode frames leave in the order they are written, which is the
//! bridge's queue order (control answers and status first, then each scan's header, data
//! and trailer). Priority against other nodes is still settled by arbitration on the bus.
//!
//! **Bus-off.** Embassy's interrupt handler would clear `CCCR.INIT` as soon as the
//! controller enters bus-off (its automatic recovery); that is switched off, so after
//! bus-off the controller stays in `INIT` until [`Supervisor::recover`] clears it, which
//! the main loop does at most once per 100 ms (`board_common::recovery`).
//!
//! **Errors.** `ECR.CEL` counts the protocol errors that raised an error counter and
//! clears on read; the main loop adds it to the bridge's bus error count every tick. The
//! receive task ignores the driver's error results (they come from the same events, as
//! last-error codes, and would be counted twice).
//!
//! **CAN FD data phase.** 5 Mbit/s needs transmitter delay compensation, which embassy
//! does not configure: `TDCR.TDCO` and `DBTP.TDC` are written right after start-up
//! (`enable_delay_compensation`). The offset is derived from the data bit timing embassy
//! programmed (read back from `DBTP`): its sample point in kernel clock periods
//! (`board_common::tdc`; 14 for 5 Mbit/s on the 80 MHz kernel clock).
//!
//! The NUCLEO-H723ZG board (`stm32h723`) builds this same file (`#[path]`): its FDCAN1
//! has the registers and the embassy API used here, and the same 80 MHz kernel clock.
//!
//! Register access that embassy does not offer (`CCCR.INIT`, `ECR.CEL`, `TDCR`,
//! `DBTP.TDC`) goes through `embassy_stm32::pac` (the `unstable-pac` feature).

use board_common::config::CanBus;
use board_common::tdc::DataBitTiming;
use board_common::Shared;
use can_wire::BusState;
use embassy_stm32::can::config::{
    self as can_config, FrameTransmissionConfig, GlobalFilter, NominalBitTiming, TxBufferMode,
};
use embassy_stm32::can::enums::BusErrorMode;
use embassy_stm32::can::filter::{
    Action, ExtendedFilter, ExtendedFilterSlot, FilterType, StandardFilter, StandardFilterSlot,
};
use embassy_stm32::can::frame::{FdFrame, Header};
use embassy_stm32::can::util::calc_can_timings;
use embassy_stm32::can::{
    CanConfigurator, CanRx, CanTx, IT0InterruptHandler, IT1InterruptHandler, Properties, RxPin,
    TxPin,
};
use embassy_stm32::interrupt::typelevel::{Binding, FDCAN1_IT0, FDCAN1_IT1};
use embassy_stm32::pac;
use embassy_stm32::peripherals::FDCAN1;
use embassy_stm32::Peri;
use embedded_can::Id;

/// Reads of `CCCR` to wait for `INIT` to take effect (a few kernel clock cycles; the bound
/// only keeps a faulty controller from hanging the boot).
const INIT_ACK_READS: u32 = 10_000;

/// Sets up FDCAN1 on `rx`/`tx` for `bus` and starts it: FIFO transmit order, no automatic
/// bus-off recovery, only the identifiers `ids` accepted (this bridge's control frames and
/// the time master's, `board_common::config::accepted_ids`; standard filter slots 0 and 1
/// or extended slots 0 and 1, into receive FIFO 0).
pub fn start(
    peri: Peri<'static, FDCAN1>,
    rx: Peri<'static, impl RxPin<FDCAN1>>,
    tx: Peri<'static, impl TxPin<FDCAN1>>,
    irqs: impl Binding<FDCAN1_IT0, IT0InterruptHandler<FDCAN1>>
        + Binding<FDCAN1_IT1, IT1InterruptHandler<FDCAN1>>
        + 'static,
    bus: CanBus,
    ids: [Id; 2],
) -> (CanTx<'static>, CanRx<'static>, Supervisor) {
    let mut can = CanConfigurator::new(peri, rx, tx, irqs);
    // The bit timings as embassy's `set_bitrate` and `set_fd_data_bitrate` work them out,
    // but a rate the kernel clock cannot make is a panic naming the step
    // (`board_common::started`): their `unwrap` linked `core::fmt`'s `Debug` machinery
    // (about 1.5 KB of flash) for the message, and `defmt::unwrap!` the error's
    // `defmt::Format`.
    let clock = embassy_stm32::rcc::frequency::<FDCAN1>();
    let nominal = board_common::started(
        calc_can_timings(clock, bus.rates.nominal),
        "CAN nominal bit timing",
    );
    let mut config = can.config().set_nominal_bit_timing(NominalBitTiming {
        sync_jump_width: nominal.sync_jump_width,
        prescaler: nominal.prescaler,
        seg1: nominal.seg1,
        seg2: nominal.seg2,
    });
    if bus.fd_capable {
        let data = board_common::started(
            calc_can_timings(clock, bus.rates.data),
            "CAN data bit timing",
        );
        // The delay compensation flag is not written by embassy (below).
        config = config
            .set_data_bit_timing(can_config::DataBitTiming {
                transceiver_delay_compensation: true,
                sync_jump_width: data.sync_jump_width,
                prescaler: data.prescaler,
                seg1: data.seg1,
                seg2: data.seg2,
            })
            .set_frame_transmit(FrameTransmissionConfig::AllowFdCanAndBRS);
    }
    let config = config
        .set_tx_buffer_mode(TxBufferMode::Fifo)
        .set_automatic_bus_off_recovery(false)
        .set_global_filter(GlobalFilter::reject_all());
    can.set_config(config);
    for (n, id) in ids.into_iter().enumerate() {
        let (standard, extended) = if n == 0 {
            (StandardFilterSlot::_0, ExtendedFilterSlot::_0)
        } else {
            (StandardFilterSlot::_1, ExtendedFilterSlot::_1)
        };
        match id {
            Id::Standard(id) => can.properties().set_standard_filter(
                standard,
                StandardFilter {
                    filter: FilterType::DedicatedSingle(id),
                    action: Action::StoreInFifo0,
                },
            ),
            Id::Extended(id) => can.properties().set_extended_filter(
                extended,
                ExtendedFilter {
                    filter: FilterType::DedicatedSingle(id),
                    action: Action::StoreInFifo0,
                },
            ),
        }
    }
    let can = can.into_normal_mode();
    if bus.fd_capable {
        enable_delay_compensation();
    }
    let (tx, rx, properties) = can.split();
    (tx, rx, Supervisor { properties })
}

/// Sets `TDCR.TDCO` and `DBTP.TDC`. Embassy 0.6 takes a delay-compensation flag but
/// never writes either (and rewrites `DBTP` when it starts the controller), so they are
/// set here, in a short stay in configuration mode right after start-up, before any
/// frame is queued (both registers are writable only with `INIT` and `CCE` set). The
/// offset is the sample point of the data bit timing `DBTP` holds; a timing whose sample
/// point does not fit `TDCO` leaves compensation off (logged).
fn enable_delay_compensation() {
    let regs = pac::FDCAN1;
    let dbtp = regs.dbtp().read();
    let timing = DataBitTiming {
        dbrp: dbtp.dbrp(),
        dtseg1: dbtp.dtseg1(),
        dtseg2: dbtp.dtseg2(),
    };
    let Some(offset) = timing.tdc_offset() else {
        defmt::warn!(
            "CAN FD: data sample point {} kernel clocks does not fit TDCO; no delay compensation",
            timing.sample_point_mtq()
        );
        return;
    };
    defmt::info!("CAN FD: delay compensation offset {} kernel clocks", offset);
    regs.cccr().modify(|w| w.set_init(true));
    for _ in 0..INIT_ACK_READS {
        if regs.cccr().read().init() {
            break;
        }
    }
    regs.cccr().modify(|w| w.set_cce(true));
    regs.tdcr().write(|w| {
        w.set_tdco(offset);
        w.set_tdcf(0);
    });
    regs.dbtp().modify(|w| w.set_tdc(true));
    // As embassy leaves configuration mode: CCE first, then INIT; the controller then
    // synchronises to the bus again (11 recessive bits).
    regs.cccr().modify(|w| w.set_cce(false));
    regs.cccr().modify(|w| w.set_init(false));
}

/// The FDCAN frame for a bridge frame: CAN FD frames switch to the data bit rate.
fn to_fdcan(frame: &can_wire::Frame) -> Option<FdFrame> {
    let data = frame.data();
    let len = u8::try_from(data.len()).ok()?;
    let header = if frame.is_fd() {
        Header::new_fd(frame.id(), len, false, true)
    } else {
        Header::new(frame.id(), len, false)
    };
    FdFrame::new(header, data).ok()
}

/// The bridge frame for a received FDCAN frame (remote frames are refused by the
/// filter; a malformed one gives `None`).
fn from_fdcan(frame: &FdFrame) -> Option<can_wire::Frame> {
    let header = frame.header();
    if header.rtr() {
        return None;
    }
    can_wire::Frame::new(*header.id(), frame.data(), header.fdcan()).ok()
}

/// Starts the transmit and receive tasks on the FDCAN's two halves (both boards that
/// build this file start them so).
pub fn spawn_tasks(
    spawner: embassy_executor::Spawner,
    shared: &'static Shared,
    tx: CanTx<'static>,
    rx: CanRx<'static>,
) {
    spawner.spawn(board_common::started(tx_task(shared, tx), "CAN tx task"));
    spawner.spawn(board_common::started(rx_task(shared, rx), "CAN rx task"));
}

/// Moves the bridge's frames into the transmit FIFO, in order. Waits (without blocking
/// anything else) while the FIFO is full, e.g. during bus-off.
#[embassy_executor::task]
pub async fn tx_task(shared: &'static Shared, mut tx: CanTx<'static>) {
    loop {
        let frame = shared.next_frame().await;
        match to_fdcan(&frame) {
            // In FIFO mode nothing is ever displaced, so the result is always `None`.
            Some(f) => {
                let _ = tx.write_fd(&f).await;
            }
            None => defmt::warn!("frame not representable on FDCAN: {}", frame.data().len()),
        }
    }
}

/// Hands received control frames to the bridge; their answers are queued at once.
#[embassy_executor::task]
pub async fn rx_task(shared: &'static Shared, mut rx: CanRx<'static>) {
    loop {
        // Errors are counted from ECR.CEL by the main loop (see the module docs).
        let Ok(envelope) = rx.read_fd().await else {
            continue;
        };
        if let Some(frame) = from_fdcan(&envelope.frame) {
            // The reception time (a time master's SYNC, SPEC 9, is taken at it): embassy
            // stamps the frame in the receive interrupt and, for classic frames, moves
            // the stamp back to the controller's RX timestamp (its counter in bit times);
            // with bit-rate switching the counter's rate changes within a frame, so FD
            // frames keep the interrupt's time.
            let now_us = envelope.ts.as_micros();
            if shared.with(|b| b.on_can_frame_at(&frame, now_us)) {
                shared.notify_frames();
            }
        }
    }
}

/// The bus supervision the main loop uses.
pub struct Supervisor {
    properties: Properties,
}

impl Supervisor {
    /// The controller's error state (`PSR.BO`, `PSR.EP`).
    pub fn state(&self) -> BusState {
        match self.properties.bus_error_mode() {
            BusErrorMode::ErrorActive => BusState::ErrorActive,
            BusErrorMode::ErrorPassive => BusState::ErrorPassive,
            BusErrorMode::BusOff => BusState::BusOff,
        }
    }

    /// Protocol errors since the last call (`ECR.CEL`, cleared by the read; it saturates
    /// at 255 between two reads, 5 ms apart).
    pub fn take_errors(&mut self) -> u32 {
        u32::from(pac::FDCAN1.ecr().read().cel())
    }

    /// Starts bus-off recovery: clearing `CCCR.INIT` makes the controller wait for 129
    /// occurrences of 11 recessive bits, then take part in bus traffic again.
    pub fn recover(&mut self) {
        pac::FDCAN1.cccr().modify(|w| w.set_init(false));
    }
}
