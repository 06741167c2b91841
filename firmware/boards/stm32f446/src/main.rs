//! scip2can firmware for the NUCLEO-F446RE (STM32F446RE): a SCIP sensor on USART1, the
//! robot's bus on bxCAN (CAN1), classic CAN at 1 Mbit/s.
//!
//! Thin: this file binds the peripherals and spawns three tasks around the shared
//! bridge (`board_common`):
//!
//! - `main_loop` (the main task): sensor UART in and out, the session's commands, and
//!   every 5 ms the watchdog, the bus state with rate-limited bus-off recovery, and the
//!   CPU load (`board_common::sensor::run`);
//! - `can_tx`: frames from `Bridge::pop_frame` into the transmit mailboxes, in order;
//! - `can_rx`: control frames from the bus into `Bridge::on_can_frame`.
//!
//! Pins, clocks and bit rates are in `README.md` (one folder up).

#![no_std]
#![no_main]
#![deny(unsafe_code)]

mod bxcan;

use board_common::config::{self, CanBus};
use board_common::sensor::{self, Board};
use board_common::Shared;
use can_wire::BusState;
use defmt::info;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::can::{Can, CanRx, CanTx};
use embassy_stm32::mode::Async;
use embassy_stm32::peripherals::{self, IWDG};
use embassy_stm32::usart::{self, RingBufferedUartRx, Uart, UartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, dma, Config};
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    USART1 => usart::InterruptHandler<peripherals::USART1>;
    DMA2_STREAM2 => dma::InterruptHandler<peripherals::DMA2_CH2>;
    DMA2_STREAM7 => dma::InterruptHandler<peripherals::DMA2_CH7>;
    CAN1_TX => embassy_stm32::can::TxInterruptHandler<peripherals::CAN1>;
    CAN1_RX0 => embassy_stm32::can::Rx0InterruptHandler<peripherals::CAN1>;
    CAN1_RX1 => embassy_stm32::can::Rx1InterruptHandler<peripherals::CAN1>;
    CAN1_SCE => embassy_stm32::can::SceInterruptHandler<peripherals::CAN1>;
});

/// The bus this board drives.
const BUS: CanBus = CanBus::CLASSIC_1M;

static SHARED: StaticCell<Shared> = StaticCell::new();
static UART_RING: StaticCell<[u8; config::UART_RING]> = StaticCell::new();

/// Clocks: HSE 8 MHz from the ST-LINK's MCO (bypass; the NUCLEO's default, crystal X3
/// not fitted) → PLL: /4 ×168 = 336 MHz VCO; P /2 = 168 MHz system clock, Q /7 =
/// 48 MHz. APB1 /4 = 42 MHz (bxCAN: 1 Mbit/s = 6 × 7 time quanta), APB2 /2 = 84 MHz
/// (USART1).
fn clocks() -> Config {
    use embassy_stm32::rcc::{
        AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv,
        PllSource, Sysclk,
    };
    use embassy_stm32::time::Hertz;
    let mut config = Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(8_000_000),
        mode: HseMode::Bypass,
    });
    config.rcc.pll_src = PllSource::HSE;
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL168,
        divp: Some(PllPDiv::DIV2),
        divq: Some(PllQDiv::DIV7),
        divr: None,
    });
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV4;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.sys = Sysclk::PLL1_P;
    config
}

/// What the main loop drives on this board.
struct F446 {
    sensor: sensor::Uart<RingBufferedUartRx<'static>, UartTx<'static, Async>>,
    watchdog: IndependentWatchdog<'static, IWDG>,
    can: bxcan::Supervisor,
}

impl Board for F446 {
    type Sensor = sensor::Uart<RingBufferedUartRx<'static>, UartTx<'static, Async>>;

    fn sensor(&mut self) -> &mut Self::Sensor {
        &mut self.sensor
    }

    fn set_sensor_bit_rate(&mut self, bit_rate: u32) -> bool {
        // One baud-rate register for both directions.
        self.sensor.tx.set_baudrate(bit_rate).is_ok()
    }

    fn bus_state(&mut self) -> BusState {
        self.can.state()
    }

    fn take_bus_errors(&mut self) -> u32 {
        // Counted by the receive task (the driver reports each error once).
        0
    }

    fn recover_bus(&mut self) {
        self.can.recover();
    }

    fn feed_watchdog(&mut self) {
        self.watchdog.pet();
    }
}

/// Everything the tasks run on.
struct Setup {
    shared: &'static Shared,
    board: F446,
    can: Can<'static>,
}

/// The shared bridge, built in a frame of its own before `setup` runs (never inlined):
/// the bridge's temporaries (it is built on the stack, then moved into its static) are
/// then never on the stack together with `setup`'s peripherals.
#[inline(never)]
fn shared_bridge() -> &'static Shared {
    SHARED.init_with(|| {
        Shared::new(board_common::started(
            config::bridge(BUS),
            "bridge settings",
        ))
    })
}

/// Initialises the chip and the peripherals. A plain function outside the async main
/// and never inlined into it: its temporaries then take no room in the main task's
/// static future, and its stack frame exists once at boot, not on every poll.
#[inline(never)]
fn setup(shared: &'static Shared) -> Setup {
    let p = embassy_stm32::init(clocks());
    info!("scip2can-stm32f446 {}", env!("CARGO_PKG_VERSION"));

    let can_ids = shared.with(|b| board_common::config::accepted_ids(b));

    // Sensor: USART1, TX PA9, RX PA10 (Arduino D8 and D2), 8N1; DMA2 streams 7 and 2
    // (channel 4).
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = config::SENSOR_POWER_UP_BIT_RATE;
    let uart = board_common::started(
        Uart::new(
            p.USART1,
            p.PA10,
            p.PA9,
            p.DMA2_CH7,
            p.DMA2_CH2,
            Irqs,
            uart_config,
        ),
        "sensor UART",
    );
    let (tx, rx) = uart.split();
    let rx = rx.into_ring_buffered(UART_RING.init([0; config::UART_RING]));

    // CAN: CAN1, RX PA11, TX PA12 (morpho CN10 pins 14 and 12), to a CAN transceiver.
    let can = bxcan::configure(p.CAN1, p.PA11, p.PA12, Irqs, BUS, can_ids);

    // The watchdog stops while a debugger halts the core (otherwise every breakpoint
    // resets the MCU after 500 ms); it runs normally under `probe-rs run`.
    embassy_stm32::pac::DBGMCU
        .apb1fzr()
        .modify(|w| w.set_iwdg(true));
    let mut watchdog = IndependentWatchdog::new(p.IWDG, config::WATCHDOG_TIMEOUT_MS * 1000);
    watchdog.unleash();

    Setup {
        shared,
        board: F446 {
            sensor: sensor::Uart { rx, tx },
            watchdog,
            can: bxcan::Supervisor::new(),
        },
        can,
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let shared = shared_bridge();
    let Setup {
        shared,
        mut board,
        mut can,
    } = setup(shared);
    // The halves do not borrow `can`; the transmit task keeps `can` (dropping it would
    // reset the controller) and enables it, so that a bus that never goes idle holds
    // up only the CAN side, not the sensor loop and its watchdog.
    let (can_tx, can_rx): (CanTx<'static>, CanRx<'static>) = can.split();
    spawner.spawn(board_common::started(
        bxcan::rx_task(shared, can_rx),
        "CAN rx task",
    ));
    spawner.spawn(board_common::started(
        bxcan::tx_task(shared, can, can_tx),
        "CAN tx task",
    ));
    sensor::run(shared, &mut board).await
}
