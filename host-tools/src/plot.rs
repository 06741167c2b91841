//! `scip2can plot`: scans of a candump log drawn to a PNG, in the sensor frame.
//!
//! The picture is square, the sensor at its centre; x (forward, angle 0) points right,
//! y (left, counter-clockwise) points up; a grid line every metre (the axes darker), and
//! a small cross at the sensor. Points with a range are dots: blue for intact scans,
//! orange for scans that did not arrive intact; with `--all`, later scans are drawn over
//! earlier ones in a darker shade. No text is drawn, so no fonts are needed.

use std::path::PathBuf;

use anyhow::{bail, Context};
use can_wire::Distance;
use plotters::prelude::*;

use crate::decode::{decode_log, open_log, DecodedScan, Item, WindowArgs};

/// `scip2can plot` flags.
#[derive(Debug, Clone, clap::Args)]
pub struct PlotArgs {
    /// The candump log, or `-` for standard input.
    pub log: String,
    /// The PNG to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// The scan with this sequence number (default: the first scan of the log).
    #[arg(long, conflicts_with = "all")]
    pub scan: Option<u16>,
    /// Every scan of the log, over each other.
    #[arg(long)]
    pub all: bool,
    /// Width and height in pixels.
    #[arg(long, default_value_t = 800)]
    pub size: u32,
    /// Half the width shown, metres (default: the farthest point, rounded up).
    #[arg(long)]
    pub range: Option<f64>,
    /// Identifier window.
    #[command(flatten)]
    pub window: WindowArgs,
}

/// The points of a scan with a range, in metres: (x forward, y left).
pub fn points_xy(scan: &DecodedScan) -> Vec<(f64, f64)> {
    let h = &scan.header;
    scan.points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let Distance::Mm(mm) = p.as_ref()?.distance else {
                return None;
            };
            let a = f64::from(h.angle(u16::try_from(i).ok()?)?);
            let r = f64::from(mm) / 1000.0;
            Some((r * a.cos(), r * a.sin()))
        })
        .collect()
}

/// Draws `scans` into a `size`×`size` PNG at `path`, showing ±`range` metres.
pub fn draw(
    scans: &[DecodedScan],
    path: &std::path::Path,
    size: u32,
    range: f64,
) -> anyhow::Result<()> {
    let root = BitMapBackend::new(path, (size, size)).into_drawing_area();
    let err = |e: DrawingAreaErrorKind<_>| anyhow::anyhow!("drawing {}: {e:?}", path.display());
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .margin(8)
        .build_cartesian_2d(-range..range, -range..range)
        .map_err(err)?;
    let grid = RGBColor(225, 225, 225);
    let whole = range.ceil() as i64;
    for m in -whole..=whole {
        let v = m as f64;
        let style = if m == 0 {
            RGBColor(150, 150, 150)
        } else {
            grid
        };
        chart
            .draw_series(LineSeries::new([(v, -range), (v, range)], style))
            .map_err(err)?;
        chart
            .draw_series(LineSeries::new([(-range, v), (range, v)], style))
            .map_err(err)?;
    }
    let tick = range / 40.0;
    chart
        .draw_series(LineSeries::new(
            [(-tick, 0.0), (tick * 2.0, 0.0)],
            BLACK.stroke_width(2),
        ))
        .map_err(err)?;
    chart
        .draw_series(LineSeries::new(
            [(0.0, -tick), (0.0, tick)],
            BLACK.stroke_width(2),
        ))
        .map_err(err)?;
    let n = scans.len().max(1);
    for (k, scan) in scans.iter().enumerate() {
        // Later scans darker: shade from 40 % to 100 % of the colour.
        let shade = 0.4 + 0.6 * (k + 1) as f64 / n as f64;
        let mix = |c: u8| (255.0 - (255.0 - f64::from(c)) * shade) as u8;
        let color = if scan.completeness == can_wire::Completeness::Intact {
            RGBColor(mix(20), mix(80), mix(200))
        } else {
            RGBColor(mix(230), mix(120), mix(20))
        };
        chart
            .draw_series(
                points_xy(scan)
                    .into_iter()
                    .filter(|(x, y)| x.abs() <= range && y.abs() <= range)
                    .map(|p| Circle::new(p, 2, color.filled())),
            )
            .map_err(err)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// `scip2can plot`.
pub fn run(args: PlotArgs) -> anyhow::Result<()> {
    let window = args.window.window()?;
    let (items, _) = decode_log(open_log(&args.log)?, window)
        .with_context(|| format!("reading {}", args.log))?;
    let scans: Vec<DecodedScan> = items
        .into_iter()
        .filter_map(|i| match i {
            Item::Scan(s) => Some(s),
            _ => None,
        })
        .collect();
    let chosen: Vec<DecodedScan> = match (args.all, args.scan) {
        (true, _) => scans,
        (false, Some(seq)) => scans
            .into_iter()
            .filter(|s| s.header.seq == seq)
            .take(1)
            .collect(),
        (false, None) => scans.into_iter().take(1).collect(),
    };
    if chosen.is_empty() {
        bail!("{}: no such scan in the log", args.log);
    }
    if let Some(s) = chosen.iter().find(|s| !s.header.geometry_known()) {
        bail!(
            "{}: scan {} has no geometry (ares 0: the bridge knew no ARES/AFRT), so its \
             points have no angles; replay the capture with --model to give the sensor",
            args.log,
            s.header.seq
        );
    }
    if !(10..=8192).contains(&args.size) {
        bail!("--size must be 10..=8192 pixels");
    }
    let range = match args.range {
        Some(r) if r.is_finite() && r > 0.0 => r,
        Some(_) => bail!("--range must be > 0 m"),
        None => chosen
            .iter()
            .flat_map(points_xy)
            .map(|(x, y)| x.abs().max(y.abs()))
            .fold(1.0f64, f64::max)
            .ceil(),
    };
    draw(&chosen, &args.output, args.size, range)?;
    eprintln!(
        "{}: {} scan(s), ±{range} m",
        args.output.display(),
        chosen.len()
    );
    Ok(())
}
