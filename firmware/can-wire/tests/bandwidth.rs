//! The bus load targets of the project, from the worst-case model of SPEC section 8.

use can_wire::bandwidth::{scan_cost, BitRates};
use can_wire::*;

fn encodings(intensity: IntensityEncoding) -> impl Iterator<Item = Encoding> {
    DistanceEncoding::ALL
        .into_iter()
        .map(move |distance| Encoding {
            distance,
            intensity,
            unit_exp: 0,
        })
}

fn best_load_ppm(points: u16, hz: u32, format: FrameFormat, rates: BitRates) -> u64 {
    encodings(IntensityEncoding::None)
        .map(|e| scan_cost(points, &e, format, false, rates).load_ppm(hz * 1000))
        .min()
        .unwrap()
}

#[test]
fn urg_04lx_full_resolution_fits_a_quarter_of_classic_1m() {
    // 682 points, 10 Hz.
    let ppm = best_load_ppm(682, 10, FrameFormat::Classic, BitRates::CLASSIC_1M);
    assert!(ppm <= 250_000, "{ppm} ppm");
    // D12: 2 headers + 171 data frames + trailer; 170 full 135-bit frames, the last one
    // with 5 bytes: 34 + 40 + 13 + floor(73/4) = 105 bits; headers and trailer 135.
    let d12 = Encoding {
        distance: DistanceEncoding::D12,
        intensity: IntensityEncoding::None,
        unit_exp: 1,
    };
    let c = scan_cost(682, &d12, FrameFormat::Classic, false, BitRates::CLASSIC_1M);
    assert_eq!(c.nominal_bits, 173 * 135 + 105);
    assert_eq!(c.load_ppm(10_000), 234_600);
}

#[test]
fn utm_30lx_full_resolution_fits_35_percent_of_fd_1m_5m() {
    // 1081 points, 40 Hz, distance only.
    let ppm = best_load_ppm(1081, 40, FrameFormat::FD64, BitRates::FD_1M_5M);
    assert!(ppm <= 350_000, "{ppm} ppm");
}

#[test]
fn utm_30lx_does_not_fit_classic_1m() {
    // The reason CAN FD exists in this project: even D12 needs more than the bus.
    let ppm = best_load_ppm(1081, 40, FrameFormat::Classic, BitRates::CLASSIC_1M);
    assert!(ppm > 1_000_000, "{ppm} ppm");
}
