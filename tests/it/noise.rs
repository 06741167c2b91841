//! The simulator's noise against the real captures: the statistics of `scip2can noise`
//! (what a predictive coder of scans gains) computed the same way on the recordings and
//! on simulated scans of the same model. Simulated scans must not be smoother than the
//! real ones by more than the tolerances below, so that coding figures measured on the
//! simulator do not flatter the coder. The comparison is in BENCHMARKS.md.

use scip2can_host::noise::{scans_of_source, NoiseStats, Scan, BAND_NAMES};

/// Rice cost (bits per residual) the simulator may be below the real capture.
const RICE_TOLERANCE: f64 = 0.3;
/// Intensity Rice cost the simulator may be below the real capture (the sim's surfaces
/// have no texture: its ΔI has lighter tails, see BENCHMARKS.md).
const INTENSITY_RICE_TOLERANCE: f64 = 1.0;
/// Share of pairs (d1 = 0, |d1| <= 2 mm) the simulator may be above the real capture.
const SHARE_TOLERANCE: f64 = 0.1;
/// Least ratio sim / real of the range noise in a band both fill, of the relative
/// intensity noise, and of the edge share.
const NOISE_RATIO: f64 = 0.75;
const EDGE_RATIO: f64 = 0.4;
/// More no-return share than real (error runs are cheap to code) the sim may have.
const NO_RETURN_TOLERANCE: f64 = 0.15;
/// Smooth triples a band needs on both sides to be compared.
const BAND_SAMPLES: usize = 40;

/// Simulated scans of `model`: 10 scans of each of seeds 1 to 3, plus `extra` options.
fn sim(model: &str, extra: &str) -> Vec<Scan> {
    (1..=3)
        .flat_map(|seed| {
            scans_of_source(&format!("sim:model={model},seed={seed}{extra}"), 10).unwrap()
        })
        .collect()
}

/// Where `sim` is smoother than `real` by more than the tolerances.
fn smoother(real: &NoiseStats, sim: &NoiseStats) -> Vec<String> {
    let mut v = Vec::new();
    let mut check = |ok: bool, what: String| {
        if !ok {
            v.push(what);
        }
    };
    check(
        sim.rice_d1 >= real.rice_d1 - RICE_TOLERANCE,
        format!("Rice d1 {:.2} < real {:.2}", sim.rice_d1, real.rice_d1),
    );
    check(
        sim.rice_d2 >= real.rice_d2 - RICE_TOLERANCE,
        format!("Rice d2 {:.2} < real {:.2}", sim.rice_d2, real.rice_d2),
    );
    check(
        sim.d1_zero <= real.d1_zero + SHARE_TOLERANCE,
        format!("d1 = 0 share {:.3} > real {:.3}", sim.d1_zero, real.d1_zero),
    );
    check(
        sim.d1_le2 <= real.d1_le2 + SHARE_TOLERANCE,
        format!(
            "|d1| <= 2 share {:.3} > real {:.3}",
            sim.d1_le2, real.d1_le2
        ),
    );
    check(
        sim.edge_share >= real.edge_share * EDGE_RATIO,
        format!(
            "edge share {:.4} < real {:.4}",
            sim.edge_share, real.edge_share
        ),
    );
    check(
        sim.no_return_share <= real.no_return_share + NO_RETURN_TOLERANCE,
        format!(
            "no-return share {:.3} > real {:.3}",
            sim.no_return_share, real.no_return_share
        ),
    );
    check(
        real.no_return_run_max == 0 || sim.no_return_run_max > 0,
        "no no-return runs".into(),
    );
    let mut bands = 0;
    for ((r, s), name) in real
        .noise_by_band
        .iter()
        .zip(&sim.noise_by_band)
        .zip(BAND_NAMES)
    {
        if r.samples >= BAND_SAMPLES && s.samples >= BAND_SAMPLES {
            bands += 1;
            check(
                s.median_mm >= r.median_mm * NOISE_RATIO,
                format!("range noise {name} {} < real {}", s.median_mm, r.median_mm),
            );
        }
    }
    check(bands >= 2, format!("only {bands} range bands to compare"));
    match (&real.intensity, &sim.intensity) {
        (Some(r), Some(s)) => {
            check(
                s.rice_d1 >= r.rice_d1 - INTENSITY_RICE_TOLERANCE,
                format!("intensity Rice {:.2} < real {:.2}", s.rice_d1, r.rice_d1),
            );
            check(
                s.d1_relative >= r.d1_relative * NOISE_RATIO,
                format!(
                    "relative intensity noise {:.4} < real {:.4}",
                    s.d1_relative, r.d1_relative
                ),
            );
        }
        (Some(_), None) => check(false, "no intensities".into()),
        _ => {}
    }
    v
}

#[test]
fn the_simulator_is_not_smoother_than_the_real_captures() {
    let Some(dir) =
        scip2can_tests::recordings_or_skip("the_simulator_is_not_smoother_than_the_real_captures")
    else {
        return;
    };
    for (file, model) in [
        ("hokuyoaist_example_urg_04lx.rx.scip", "urg04lx"),
        ("hokuyoaist_example_utm_30lx.rx.scip", "utm30lx"),
    ] {
        let path = dir.join(file);
        let real = NoiseStats::of(&scans_of_source(path.to_str().unwrap(), 1).unwrap());
        // What the real capture is (decoded by hand in recordings.rs: one scan).
        assert_eq!(real.scans, 1);
        let ours = NoiseStats::of(&sim(model, ""));
        assert_eq!(ours.scans, 30);
        let bad = smoother(&real, &ours);
        assert!(
            bad.is_empty(),
            "{model}: the simulator is smoother: {bad:?}"
        );
        // The check has teeth: the scene's exact values (noise=0) and a constant 1 mm
        // noise are both caught.
        for extra in [",noise=0", ",noise=1"] {
            let flat = NoiseStats::of(&sim(model, extra));
            assert!(
                !smoother(&real, &flat).is_empty(),
                "{model}{extra}: not caught"
            );
        }
    }
}
