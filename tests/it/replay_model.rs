//! A raw capture without PP through `scip2can replay`: its scans say "geometry unknown"
//! (SPEC 3.2) unless `--model` names the sensor; `decode` gives no angles for them and
//! `plot` refuses them.

use bridge::engine::BridgeConfig;
use can_wire::{Encoding, FrameFormat, IdWindow};
use clap::Parser;
use scip2can_host::decode::{decode_log, json, DecodedScan, Item};
use scip2can_host::replay::args::{KnownModel, ReplayArgs};
use scip2can_host::replay::{replay_stream_as, Replayed};
use scip2can_tests::recordings_or_skip;

fn config() -> BridgeConfig {
    BridgeConfig {
        encoding: Encoding::PLAIN_MM,
        status_period_ms: 0,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(0).unwrap(), FrameFormat::FD64)
    }
}

fn scans(r: &Replayed) -> Vec<DecodedScan> {
    let text: String = r
        .records("can0", true)
        .iter()
        .map(|rec| format!("{rec}\n"))
        .collect();
    let (items, _) = decode_log(text.as_bytes(), IdWindow::DEFAULT).unwrap();
    items
        .into_iter()
        .filter_map(|i| match i {
            Item::Scan(s) => Some(s),
            _ => None,
        })
        .collect()
}

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    replay: ReplayArgs,
}

#[test]
fn model_flag_parses_the_five_models() {
    let model = |name: &str| {
        Cli::try_parse_from(["replay", "capture.scip", "--model", name])
            .map(|c| c.replay.model)
            .ok()
    };
    assert_eq!(model("urg04lx"), Some(Some(KnownModel::Urg04lx)));
    assert_eq!(model("UTM-30LX"), Some(Some(KnownModel::Utm30lx)));
    assert_eq!(model("ust10lx"), Some(Some(KnownModel::Ust10lx)));
    assert_eq!(model("ust20lx"), Some(Some(KnownModel::Ust20lx)));
    assert_eq!(model("uxm30lxe"), Some(Some(KnownModel::Uxm30lxE)));
    assert_eq!(model("lms200"), None);
    // The geometry of the PP answers (scip-reference §6 / the recordings).
    let geometry = |m: KnownModel| {
        let p = m.params();
        (p.ares, p.afrt)
    };
    assert_eq!(geometry(KnownModel::Urg04lx), (Some(1024), Some(384)));
    assert_eq!(geometry(KnownModel::Utm30lx), (Some(1440), Some(540)));
    assert_eq!(geometry(KnownModel::Ust20lx), (Some(1440), Some(540)));
}

#[test]
fn a_capture_without_pp_has_unknown_geometry_unless_the_model_is_given() {
    let Some(dir) = recordings_or_skip("replay --model") else {
        return;
    };
    // An URG-04LX MD stream over steps 46..=600, with no PP before it.
    let bytes = std::fs::read(dir.join("eeros_md_0046_0600.scip")).unwrap();
    let unknown = scans(&replay_stream_as(&bytes, config(), None).unwrap());
    assert!(!unknown.is_empty());
    for s in &unknown {
        let h = &s.header;
        assert_eq!(
            (h.ares, h.first_step),
            (0, 46),
            "the sensor step of point 0"
        );
        let v = json::scan(s);
        assert_eq!(v["ares"], 0);
        assert!(v["first_angle_rad"].is_null() && v["angle_increment_rad"].is_null());
        let mut csv = Vec::new();
        json::write_csv(&mut csv, s).unwrap();
        let csv = String::from_utf8(csv).unwrap();
        // seq,index,angle_rad,...: the angle is left empty.
        assert!(
            csv.lines().all(|l| l.split(',').nth(2) == Some("")),
            "{csv}"
        );
        assert!(scip2can_host::plot::points_xy(s).is_empty());
    }
    let urg = Some(KnownModel::Urg04lx.params());
    let known = scans(&replay_stream_as(&bytes, config(), urg).unwrap());
    assert_eq!(known.len(), unknown.len());
    for s in &known {
        // URG-04LX: ARES 1024, AFRT 384; step 46 is 46 - 384 = -338 from the front.
        assert_eq!((s.header.ares, s.header.first_step), (1024, -338));
        let a0 = s.header.angle(0).unwrap();
        assert!((a0 - (-338.0 * std::f32::consts::TAU / 1024.0)).abs() < 1e-6);
    }
}
