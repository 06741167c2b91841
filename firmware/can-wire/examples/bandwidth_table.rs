//! Prints the worst-case bus load table (markdown) for the sensors of the project.
//!
//! `cargo run -p can-wire --example bandwidth_table`

use can_wire::bandwidth::{scan_cost, BitRates};
use can_wire::*;

fn main() {
    let sensors = [("URG-04LX", 682u16, 10u32), ("UTM-30LX", 1081, 40)];
    let buses = [
        ("classic 1M", FrameFormat::Classic, BitRates::CLASSIC_1M),
        ("FD64 1/5M", FrameFormat::FD64, BitRates::FD_1M_5M),
        ("FD64 1/2M", FrameFormat::FD64, BitRates::FD_1M_2M),
    ];
    println!("| sensor | encoding | bits/point | bus | points/frame | frames/scan | bits/scan (nominal + data) | µs/scan | load |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for (name, points, hz) in sensors {
        for intensity in [
            IntensityEncoding::None,
            IntensityEncoding::I8,
            IntensityEncoding::I16,
        ] {
            for distance in DistanceEncoding::ALL {
                let e = Encoding {
                    distance,
                    intensity,
                    unit_exp: 0,
                };
                for (bus, format, rates) in buses {
                    let c = scan_cost(points, &e, format, false, rates);
                    println!(
                        "| {name} {points} pts {hz} Hz | {distance:?}+{intensity:?} | {} | {bus} | {} | {} | {} + {} | {:.1} | {:.1} % |",
                        c.bits_per_point,
                        c.points_per_frame,
                        c.frames,
                        c.nominal_bits,
                        c.data_bits,
                        c.time_ns as f64 / 1000.0,
                        c.load_ppm(hz * 1000) as f64 / 10_000.0,
                    );
                }
            }
        }
    }
}
