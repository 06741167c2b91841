//! `BridgeConfig::new`: the defaults its documentation promises (those of the boards),
//! written out field by field here, for classic CAN, CAN FD and an extended window.

use bridge::engine::{Bridge, BridgeConfig};
use bridge::governor::Budget;
use bridge::link::LinkKind;
use bridge::pipeline::PipelineConfig;
use bridge::session::SessionConfig;
use can_wire::bandwidth::BitRates;
use can_wire::{DistanceEncoding, Encoding, FrameFormat, IdWindow, IntensityEncoding};

const LOSSLESS_I16: Encoding = Encoding {
    distance: DistanceEncoding::Lossless,
    intensity: IntensityEncoding::I16,
    unit_exp: 0,
};

#[test]
fn new_classic_is_the_whole_1_mbit_bus_with_the_boards_defaults() {
    let ids = IdWindow::DEFAULT.node(0).unwrap();
    let config = BridgeConfig::new(ids, FrameFormat::Classic);
    let expected = BridgeConfig {
        session: SessionConfig::default(),
        pipeline: PipelineConfig::default(),
        encoding: LOSSLESS_I16,
        budget: Budget {
            rates: BitRates::CLASSIC_1M,
            format: FrameFormat::Classic,
            extended: false,
            share_permille: 1000,
        },
        ids,
        uart_bit_rate: 115_200,
        status_period_ms: 1000,
        fd_capable: false,
        link: LinkKind::Uart,
    };
    assert_eq!(config, expected);
    assert!(Bridge::<64>::new(config).is_ok());
}

#[test]
fn new_fd_is_fd_capable_with_a_5_mbit_data_phase() {
    let ids = IdWindow::DEFAULT.node(7).unwrap();
    let config = BridgeConfig::new(ids, FrameFormat::FD64);
    let expected = BridgeConfig {
        session: SessionConfig::default(),
        pipeline: PipelineConfig::default(),
        encoding: LOSSLESS_I16,
        budget: Budget {
            rates: BitRates::FD_1M_5M,
            format: FrameFormat::FD64,
            extended: false,
            share_permille: 1000,
        },
        ids,
        uart_bit_rate: 115_200,
        status_period_ms: 1000,
        fd_capable: true,
        link: LinkKind::Uart,
    };
    assert_eq!(config, expected);
    assert!(Bridge::<64>::new(config).is_ok());
}

#[test]
fn new_in_an_extended_window_budgets_extended_identifiers() {
    let window = IdWindow::extended(0x1234_0000).unwrap();
    let config = BridgeConfig::new(window.node(2).unwrap(), FrameFormat::Classic);
    assert!(config.budget.extended);
    assert_eq!(config.ids.window(), window);
    assert!(Bridge::<64>::new(config).is_ok());
}

/// A network link: a TCP stream at 100 Mbit/s of byte time, no `SS`; everything else as
/// it was.
#[test]
fn on_network_is_a_tcp_stream_without_bit_rate_steps() {
    let ids = IdWindow::DEFAULT.node(1).unwrap();
    let serial = BridgeConfig {
        session: SessionConfig {
            bit_rate: Some(500_000),
            ..SessionConfig::default()
        },
        ..BridgeConfig::new(ids, FrameFormat::Classic)
    };
    let config = serial.on_network();
    assert_eq!(config.link, LinkKind::Tcp);
    assert_eq!(config.uart_bit_rate, 100_000_000);
    assert_eq!(config.session.bit_rate, None);
    let back = BridgeConfig {
        link: LinkKind::Uart,
        uart_bit_rate: serial.uart_bit_rate,
        session: serial.session,
        ..config
    };
    assert_eq!(back, serial);
    assert!(Bridge::<64>::new(config).is_ok());
}
