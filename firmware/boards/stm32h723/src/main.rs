//! scip2can firmware for the NUCLEO-H723ZG (STM32H723ZG): an Ethernet sensor (UST-10LX,
//! UST-20LX, UTM-30LX-EW, UXM-30LX-EW) over TCP on the board's RJ45, the robot's bus on
//! FDCAN1 with CAN FD (1 Mbit/s arbitration, 5 Mbit/s data, bit rate switching).
//!
//! Thin: this file binds the peripherals and spawns four tasks around the shared bridge
//! (`board_common`):
//!
//! - `main_loop` (the main task): the TCP connection to the sensor (connect and
//!   reconnect with back-off), the session's commands, and every 5 ms the watchdog, the
//!   bus state with rate-limited bus-off recovery, and the CPU load
//!   (`board_common::sensor::run`);
//! - `net_task`: the TCP/IP stack (`embassy_net::Runner`);
//! - `can_tx`, `can_rx`: FDCAN1, as on the NUCLEO-G474RE (the same `fdcan.rs`).
//!
//! Addresses (`net.rs`), pins, clocks and bit rates are in `README.md` (one folder up).

#![no_std]
#![no_main]
#![deny(unsafe_code)]

#[path = "../../stm32g474/src/fdcan.rs"]
mod fdcan;
mod net;

use board_common::config::{self, Bridge, CanBus};
use board_common::sensor::{self, Board, LinkState};
use board_common::Shared;
use can_wire::BusState;
use defmt::info;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_net::StackResources;
use embassy_stm32::eth::{self, Ethernet, GenericPhy, PacketQueue, Sma};
use embassy_stm32::peripherals::{self, ETH, ETH_SMA, IWDG1};
use embassy_stm32::rng::{self, Rng};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, Config};
use static_cell::StaticCell;

use crate::net::SensorLink;

bind_interrupts!(struct Irqs {
    ETH => eth::InterruptHandler;
    RNG => rng::InterruptHandler<peripherals::RNG>;
    FDCAN1_IT0 => embassy_stm32::can::IT0InterruptHandler<peripherals::FDCAN1>;
    FDCAN1_IT1 => embassy_stm32::can::IT1InterruptHandler<peripherals::FDCAN1>;
});

/// The bus this board drives.
const BUS: CanBus = CanBus::FD_1M_5M;

/// Ethernet DMA frames: 4 to send, 4 to receive (1.5 KiB each).
type Packets = PacketQueue<4, 4>;

/// The Ethernet MAC with the board's PHY.
type Device = Ethernet<'static, ETH, GenericPhy<Sma<'static, ETH_SMA>>>;

/// The TCP receive buffer: 8 KiB, about 60 ms of a UST-10LX's stream (40 scans/s of
/// 1 081 steps, 3-character encoding) before the window closes.
const TCP_RX: usize = 8192;

/// The TCP send buffer: SCIP commands are short lines.
const TCP_TX: usize = 256;

static SHARED: StaticCell<Shared> = StaticCell::new();
static PACKETS: StaticCell<Packets> = StaticCell::new();
/// Sockets: the TCP connection and the DHCP client.
static RESOURCES: StaticCell<StackResources<2>> = StaticCell::new();
static TCP_RX_BUF: StaticCell<[u8; TCP_RX]> = StaticCell::new();
static TCP_TX_BUF: StaticCell<[u8; TCP_TX]> = StaticCell::new();

/// Clocks: HSE 8 MHz from the ST-LINK's MCO (bypass) → PLL1: /2 ×200 = 800 MHz VCO;
/// P /2 = 400 MHz system clock, Q /10 = 80 MHz FDCAN kernel clock (the G474's: 1 Mbit/s
/// and 5 Mbit/s bit times are whole numbers of it, and its delay compensation offset is
/// the same); AHB /2 = 200 MHz, APBs /2 = 100 MHz; HSI48 for the RNG. Voltage scale 1
/// (400 MHz; 550 MHz would need scale 0 and buys nothing here).
fn clocks() -> Config {
    use embassy_stm32::rcc::{
        mux, AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllDiv, PllMul, PllPreDiv, PllSource,
        Sysclk, VoltageScale,
    };
    use embassy_stm32::time::Hertz;
    let mut config = Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(8_000_000),
        mode: HseMode::Bypass,
    });
    config.rcc.hsi48 = Some(Default::default());
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSE,
        prediv: PllPreDiv::DIV2,
        mul: PllMul::MUL200,
        divp: Some(PllDiv::DIV2),
        divq: Some(PllDiv::DIV10),
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV2;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale1;
    config.rcc.mux.fdcansel = mux::Fdcansel::PLL1_Q;
    config
}

/// What the main loop drives on this board.
struct H723 {
    sensor: SensorLink,
    watchdog: IndependentWatchdog<'static, IWDG1>,
    can: fdcan::Supervisor,
}

impl Board for H723 {
    type Sensor = SensorLink;

    const LINK_CAN_FAIL: bool = true;

    fn sensor(&mut self) -> &mut SensorLink {
        &mut self.sensor
    }

    fn set_sensor_bit_rate(&mut self, _bit_rate: u32) -> bool {
        // TCP has no bit rate (and the session asks for none: `bit_rate` is `None`).
        false
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

    fn link_state(&mut self) -> LinkState {
        self.sensor.state()
    }

    fn open_link(&mut self) {
        self.sensor.open();
    }

    fn close_link(&mut self) {
        self.sensor.close();
    }

    /// The hook where the bridge learns that the sensor link came up or went down.
    fn link_changed(&mut self, bridge: &mut Bridge, up: bool, now_ms: u64) {
        // Link down: the scan in progress is aborted (reason "sensor link lost") and
        // the session held; link up: the session starts over (the sensor may have
        // rebooted), without bit-rate steps.
        if up {
            bridge.link_up(now_ms);
        } else {
            bridge.link_down(now_ms);
        }
    }
}

/// Everything the tasks run on.
struct Setup {
    shared: &'static Shared,
    board: H723,
    runner: embassy_net::Runner<'static, Device>,
    can_tx: embassy_stm32::can::CanTx<'static>,
    can_rx: embassy_stm32::can::CanRx<'static>,
}

/// The shared bridge, built in a frame of its own before `setup` runs (never inlined):
/// the bridge's temporaries are then never on the stack together with `setup`'s.
#[inline(never)]
fn shared_bridge() -> &'static Shared {
    SHARED.init_with(|| {
        Shared::new(board_common::started(
            config::ethernet_bridge(BUS),
            "bridge settings",
        ))
    })
}

/// A locally administered MAC address from the chip's unique ID (stable per board).
fn mac_address() -> [u8; 6] {
    let uid = embassy_stm32::uid::uid();
    let mut mac = [0x02, 0, 0, 0, 0, 0];
    for (i, b) in uid.iter().enumerate() {
        if let Some(m) = mac.get_mut(2 + i % 4) {
            *m ^= b;
        }
    }
    mac[1] = uid[0] ^ uid[11];
    mac
}

/// Initialises the chip and the peripherals (never inlined into the async main; see the
/// G474's `setup`).
#[inline(never)]
fn setup(shared: &'static Shared) -> Setup {
    let p = embassy_stm32::init(clocks());
    info!("scip2can-stm32h723 {}", env!("CARGO_PKG_VERSION"));

    let can_ids = shared.with(|b| board_common::config::accepted_ids(b));

    // Sensor: Ethernet, RMII to the board's LAN8742A PHY (RJ45 CN14): REF_CLK PA1,
    // CRS_DV PA7, RXD0 PC4, RXD1 PC5, TXD0 PG13, TXD1 PB13, TX_EN PG11; MDIO PA2, MDC PC1.
    let device = Ethernet::new(
        PACKETS.init(PacketQueue::new()),
        p.ETH,
        Irqs,
        p.PA1,
        p.PA7,
        p.PC4,
        p.PC5,
        p.PG13,
        p.PB13,
        p.PG11,
        mac_address(),
        p.ETH_SMA,
        p.PA2,
        p.PC1,
    );
    let mut rng = Rng::new(p.RNG, Irqs);
    let seed = rng.next_u64();
    let (ip, dhcp) = net::ip_config();
    let (stack, runner) = embassy_net::new(device, ip, RESOURCES.init(StackResources::new()), seed);
    let sensor = net::sensor_address();
    info!("sensor at {}, dhcp {}", sensor, dhcp);
    let link = SensorLink::new(
        stack,
        TCP_RX_BUF.init([0; TCP_RX]),
        TCP_TX_BUF.init([0; TCP_TX]),
        sensor,
    );

    // CAN: FDCAN1, RX PD0, TX PD1 (Zio connector CN9), to a CAN FD transceiver.
    let (can_tx, can_rx, supervisor) = fdcan::start(p.FDCAN1, p.PD0, p.PD1, Irqs, BUS, can_ids);

    // The watchdog stops while a debugger halts the core (see the G474).
    embassy_stm32::pac::DBGMCU
        .apb4fzr1()
        .modify(|w| w.set_iwdg1(true));
    let mut watchdog = IndependentWatchdog::new(p.IWDG1, config::WATCHDOG_TIMEOUT_MS * 1000);
    watchdog.unleash();

    Setup {
        shared,
        board: H723 {
            sensor: link,
            watchdog,
            can: supervisor,
        },
        runner,
        can_tx,
        can_rx,
    }
}

/// Runs the TCP/IP stack.
#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, Device>) -> ! {
    runner.run().await
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let shared = shared_bridge();
    let Setup {
        shared,
        mut board,
        runner,
        can_tx,
        can_rx,
    } = setup(shared);
    spawner.spawn(board_common::started(net_task(runner), "network task"));
    fdcan::spawn_tasks(spawner, shared, can_tx, can_rx);
    sensor::run(shared, &mut board).await
}
