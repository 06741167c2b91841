//! scip2can firmware for the NUCLEO-G474RE (STM32G474RE): a SCIP sensor on USART1, the
//! robot's bus on FDCAN1 with CAN FD (1 Mbit/s arbitration, 5 Mbit/s data, bit rate
//! switching).
//!
//! Thin: this file binds the peripherals and spawns three tasks around the shared
//! bridge (`board_common`):
//!
//! - `main_loop` (the main task): sensor UART in and out, the session's commands, and
//!   every 5 ms the watchdog, the bus state with rate-limited bus-off recovery, and the
//!   CPU load (`board_common::sensor::run`);
//! - `can_tx`: frames from `Bridge::pop_frame` into FDCAN1's transmit FIFO, in order;
//! - `can_rx`: control frames from the bus into `Bridge::on_can_frame`.
//!
//! Pins, clocks and bit rates are in `README.md` (one folder up).

#![no_std]
#![no_main]
#![deny(unsafe_code)]

mod fdcan;

use board_common::config::{self, CanBus};
use board_common::sensor::{self, Board};
use board_common::Shared;
use can_wire::BusState;
use defmt::info;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::mode::Async;
use embassy_stm32::peripherals::{self, IWDG};
use embassy_stm32::usart::{self, RingBufferedUartRx, Uart, UartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, dma, Config};
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    USART1 => usart::InterruptHandler<peripherals::USART1>;
    DMA1_CHANNEL1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
    DMA1_CHANNEL2 => dma::InterruptHandler<peripherals::DMA1_CH2>;
    FDCAN1_IT0 => embassy_stm32::can::IT0InterruptHandler<peripherals::FDCAN1>;
    FDCAN1_IT1 => embassy_stm32::can::IT1InterruptHandler<peripherals::FDCAN1>;
});

/// The bus this board drives.
const BUS: CanBus = CanBus::FD_1M_5M;

static SHARED: StaticCell<Shared> = StaticCell::new();
static UART_RING: StaticCell<[u8; config::UART_RING]> = StaticCell::new();

/// Clocks: HSE 24 MHz crystal (X3 on the NUCLEO) → PLL: /6 ×80 = 320 MHz VCO;
/// R /2 = 160 MHz system clock, Q /4 = 80 MHz FDCAN kernel clock (80 MHz divides into
/// 1 Mbit/s and 5 Mbit/s bit times exactly). APB1 and APB2 undivided (USART1 at
/// 160 MHz).
fn clocks() -> Config {
    use embassy_stm32::rcc::{
        mux, Hse, HseMode, Pll, PllMul, PllPreDiv, PllQDiv, PllRDiv, PllSource, Sysclk,
    };
    use embassy_stm32::time::Hertz;
    let mut config = Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(24_000_000),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll = Some(Pll {
        source: PllSource::HSE,
        prediv: PllPreDiv::DIV6,
        mul: PllMul::MUL80,
        divp: None,
        divq: Some(PllQDiv::DIV4),
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    config.rcc.boost = true;
    config.rcc.mux.fdcansel = mux::Fdcansel::PLL1_Q;
    config
}

/// What the main loop drives on this board.
struct G474 {
    sensor: sensor::Uart<RingBufferedUartRx<'static>, UartTx<'static, Async>>,
    watchdog: IndependentWatchdog<'static, IWDG>,
    can: fdcan::Supervisor,
}

impl Board for G474 {
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
        self.can.take_errors()
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
    board: G474,
    can_tx: embassy_stm32::can::CanTx<'static>,
    can_rx: embassy_stm32::can::CanRx<'static>,
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
    info!("scip2can-stm32g474 {}", env!("CARGO_PKG_VERSION"));

    let can_ids = shared.with(|b| board_common::config::accepted_ids(b));

    // Sensor: USART1, TX PC4, RX PC5 (morpho CN10 pins 34 and 6), 8N1.
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = config::SENSOR_POWER_UP_BIT_RATE;
    let uart = board_common::started(
        Uart::new(
            p.USART1,
            p.PC5,
            p.PC4,
            p.DMA1_CH2,
            p.DMA1_CH1,
            Irqs,
            uart_config,
        ),
        "sensor UART",
    );
    let (tx, rx) = uart.split();
    let rx = rx.into_ring_buffered(UART_RING.init([0; config::UART_RING]));

    // CAN: FDCAN1, RX PA11, TX PA12 (morpho CN10 pins 14 and 12), to a CAN FD transceiver.
    let (can_tx, can_rx, supervisor) = fdcan::start(p.FDCAN1, p.PA11, p.PA12, Irqs, BUS, can_ids);

    // The watchdog stops while a debugger halts the core (otherwise every breakpoint
    // resets the MCU after 500 ms); it runs normally under `probe-rs run`.
    embassy_stm32::pac::DBGMCU
        .apb1lfzr()
        .modify(|w| w.set_iwdg(true));
    let mut watchdog = IndependentWatchdog::new(p.IWDG, config::WATCHDOG_TIMEOUT_MS * 1000);
    watchdog.unleash();

    Setup {
        shared,
        board: G474 {
            sensor: sensor::Uart { rx, tx },
            watchdog,
            can: supervisor,
        },
        can_tx,
        can_rx,
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let shared = shared_bridge();
    let Setup {
        shared,
        mut board,
        can_tx,
        can_rx,
    } = setup(shared);
    fdcan::spawn_tasks(spawner, shared, can_tx, can_rx);
    sensor::run(shared, &mut board).await
}
