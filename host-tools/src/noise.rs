//! `scip2can noise`: the statistics of scans that decide what a predictive (FLAC-like)
//! coder of ranges and intensities gains, computed the same way on real captures and on
//! the simulator's scans, so that figures measured on simulated scans can be checked
//! against real ones.
//!
//! Every statistic looks at one scan at a time and at the first echo of each step:
//!
//! - **no-return**: the share of steps that carry an error code instead of a range,
//!   and the runs of consecutive error codes (count per scan, mean and longest length).
//! - **first differences** `d1 = r[i] - r[i-1]` of two consecutive steps that are both
//!   ranges: median and 90th percentile of `|d1|`, and the shares of `|d1| = 0` (a value
//!   repeated, as real units do), `<= 2 mm` and `<= 10 mm`.
//! - **second differences** `d2 = r[i] - 2 r[i-1] + r[i-2]` of three consecutive ranges:
//!   median and 90th percentile of `|d2|`.
//! - **edges**: the share of `d1` pairs with `|d1| > max(50 mm, 10 % of the nearer
//!   range)`: depth jumps a predictor cannot foresee.
//! - **range noise by distance**: the median `|r[i] - (r[i-1] + r[i+1]) / 2|` of triples
//!   on a smooth surface (`|r[i+1] - r[i-1]| <= 5 %` of `r[i]`), in bands of the middle
//!   range (below 1 m, 1-2 m, 2-4 m, 4 m and more). Geometry cancels out to first order,
//!   so this compares the noise of a real and a simulated unit even when they look at
//!   different rooms.
//! - **coding cost**: the empirical entropy of `d1` over all pairs (bits), and the cost
//!   of an ideal Rice coder of the `d1` (first-order) and `d2` (second-order) residuals
//!   in blocks of 16 consecutive residuals, each block with its own best parameter `k`
//!   (zigzag-mapped residual `u` costs `(u >> k) + 1 + k` bits; the parameter itself is
//!   not counted: 4 or 5 bits a block more is 0.25 to 0.31 bit per residual).
//! - **intensities** (when the scans carry them), over steps whose range is valid:
//!   the median level, median and 90th percentile of `|ΔI|`, `median |ΔI| / median
//!   level`, and the ideal Rice cost of `ΔI` as above.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{bail, Context};
use scip::{Decoder, Event, Range};
use serde::Serialize;

use crate::sim::SimOptions;

/// The range bands of [`NoiseStats::noise_by_band`], lower bounds in mm.
pub const BANDS_MM: [u32; 4] = [0, 1000, 2000, 4000];
/// Names of the bands of [`BANDS_MM`].
pub const BAND_NAMES: [&str; 4] = ["< 1 m", "1-2 m", "2-4 m", ">= 4 m"];
/// Residuals per Rice block.
pub const RICE_BLOCK: usize = 16;

/// One step of a scan: its index in the scan, its range (`None` = an error code) and its
/// second channel (0 when the scan has none).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Point {
    /// Index of the value in the scan; a gap means lost lines (damaged response).
    pub index: u16,
    /// The range in mm, `None` for an error code.
    pub range: Option<u32>,
    /// Intensity (or other second channel).
    pub aux: u32,
}

/// The first echoes of one scan, in order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Scan {
    /// The steps, in index order (indices may jump where a damaged response lost lines).
    pub points: Vec<Point>,
    /// The scan carries a second channel.
    pub has_aux: bool,
}

/// The scans of a sensor-to-host stream: every measurement response with data, first
/// echoes only; a damaged response keeps the lines decoded intact (its indices jump over
/// the lost ones).
pub fn scans_of_stream(stream: &[u8]) -> Vec<Scan> {
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    let mut cur: Option<Scan> = None;
    let flush = |cur: &mut Option<Scan>, out: &mut Vec<Scan>| {
        if let Some(s) = cur.take().filter(|s| !s.points.is_empty()) {
            out.push(s);
        }
    };
    let mut input = stream;
    while !input.is_empty() {
        let (used, ev) = dec.feed(input);
        input = input.get(used..).unwrap_or(&[]);
        match ev {
            Some(Event::Start { .. }) => {
                flush(&mut cur, &mut out);
                cur = Some(Scan::default());
            }
            Some(Event::Data(line)) => {
                let scan = cur.get_or_insert_with(Scan::default);
                scan.has_aux |= line.data.aux_width() > 0;
                for r in line.indexed().filter(|r| r.echo == 0) {
                    let range = match line.range(&r.reading()) {
                        Range::Mm(mm) => Some(mm),
                        Range::Error(_) => None,
                    };
                    scan.points.push(Point {
                        index: r.index,
                        range,
                        aux: r.aux,
                    });
                }
            }
            Some(Event::End(_)) => flush(&mut cur, &mut out),
            _ => {}
        }
    }
    flush(&mut cur, &mut out);
    out
}

/// The bytes of `scans` scans of a simulated sensor: `SCIP2.0` if it boots in SCIP 1.1,
/// then one `MD` (or `ME` for models with intensity) of the full range for `scans`
/// scans, in virtual time (the same options give the same bytes).
pub fn sim_scans(options: &SimOptions, scans: u32) -> anyhow::Result<Vec<Scan>> {
    if !(1..=99).contains(&scans) {
        bail!("--scans must be 1..=99 for a simulator (one MD/ME request)");
    }
    let mut sensor = options.build()?;
    let model = sensor.model().clone();
    let cmd = if model.intensity { "ME" } else { "MD" };
    let request = format!("{cmd}{:04}{:04}010{scans:02}\n", model.amin, model.amax);
    let mut out = Vec::new();
    let mut now = 0u64;
    if !sensor.is_scip2() {
        sensor.receive(now, b"SCIP2.0\n");
        out.extend(sensor.take_output(now));
        now += 1_000;
    }
    sensor.receive(now, request.as_bytes());
    out.extend(sensor.take_output(now));
    let give_up = now + (u64::from(scans) + 10) * 4 * sensor.scan_period_us();
    while let Some(next) = sensor.next_wakeup().filter(|&t| t <= give_up) {
        now = now.max(next);
        out.extend(sensor.take_output(now));
        if !sensor.is_streaming() {
            break;
        }
    }
    let got = scans_of_stream(&out);
    if got.len() != scans as usize {
        bail!(
            "the simulated {} sent {} of {scans} scans",
            model.kind.name(),
            got.len()
        );
    }
    Ok(got)
}

/// Range noise in one band of [`BANDS_MM`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BandNoise {
    /// Smooth triples in the band.
    pub samples: usize,
    /// Median `|r[i] - (r[i-1] + r[i+1]) / 2|` in mm (0 when there is no sample).
    pub median_mm: f64,
}

/// The statistics of a set of scans (see the module documentation).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NoiseStats {
    /// Scans.
    pub scans: usize,
    /// Steps (first echoes).
    pub points: usize,
    /// Share of steps that are error codes.
    pub no_return_share: f64,
    /// Runs of error codes per scan.
    pub no_return_runs_per_scan: f64,
    /// Mean length of a run of error codes (0 when none).
    pub no_return_run_mean: f64,
    /// Longest run of error codes.
    pub no_return_run_max: usize,
    /// Pairs of consecutive ranges.
    pub d1_pairs: usize,
    /// Median `|d1|`, mm.
    pub d1_median: f64,
    /// 90th percentile of `|d1|`, mm.
    pub d1_p90: f64,
    /// Share of `d1 = 0`.
    pub d1_zero: f64,
    /// Share of `|d1| <= 2 mm`.
    pub d1_le2: f64,
    /// Share of `|d1| <= 10 mm`.
    pub d1_le10: f64,
    /// Median `|d2|`, mm.
    pub d2_median: f64,
    /// 90th percentile of `|d2|`, mm.
    pub d2_p90: f64,
    /// Share of `d1` pairs that are edges.
    pub edge_share: f64,
    /// Range noise by band of [`BANDS_MM`].
    pub noise_by_band: [BandNoise; 4],
    /// Empirical entropy of `d1`, bits.
    pub d1_entropy: f64,
    /// Ideal block Rice cost of the `d1` residuals, bits per residual.
    pub rice_d1: f64,
    /// Ideal block Rice cost of the `d2` residuals, bits per residual.
    pub rice_d2: f64,
    /// Intensity statistics, when the scans carry them.
    pub intensity: Option<IntensityStats>,
}

/// The intensity part of [`NoiseStats`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct IntensityStats {
    /// Median intensity of steps with a range.
    pub median_level: f64,
    /// Median `|ΔI|` of consecutive steps with ranges.
    pub d1_median: f64,
    /// 90th percentile of `|ΔI|`.
    pub d1_p90: f64,
    /// `d1_median / median_level`.
    pub d1_relative: f64,
    /// Ideal block Rice cost of `ΔI`, bits per residual.
    pub rice_d1: f64,
}

/// Whether a `d1` between ranges `a` and `b` is an edge.
pub fn is_edge(a: u32, b: u32) -> bool {
    let jump = a.abs_diff(b);
    jump > 50 && u64::from(jump) * 10 > u64::from(a.min(b))
}

fn zigzag(x: i64) -> u64 {
    if x >= 0 {
        (x as u64) << 1
    } else {
        ((-x) as u64) * 2 - 1
    }
}

/// Bits of an ideal Rice coder of `residuals` in blocks of [`RICE_BLOCK`], each with its
/// best parameter (not counted).
pub fn rice_bits(residuals: &[i64]) -> u64 {
    residuals
        .chunks(RICE_BLOCK)
        .map(|block| {
            (0..32u32)
                .map(|k| {
                    block
                        .iter()
                        .map(|&r| (zigzag(r) >> k) + 1 + u64::from(k))
                        .sum::<u64>()
                })
                .min()
                .unwrap_or(0)
        })
        .sum()
}

/// Empirical entropy in bits of the values in `xs`.
pub fn entropy(xs: &[i64]) -> f64 {
    let mut counts: BTreeMap<i64, usize> = BTreeMap::new();
    for &x in xs {
        *counts.entry(x).or_default() += 1;
    }
    let n = xs.len() as f64;
    counts
        .values()
        .map(|&c| {
            let p = c as f64 / n;
            -p * p.log2()
        })
        .sum()
}

/// The `q`-quantile (0..=1) of `xs` (sorted in place), nearest rank; 0 when empty.
fn quantile(xs: &mut [f64], q: f64) -> f64 {
    if xs.is_empty() {
        return 0.0;
    }
    xs.sort_by(f64::total_cmp);
    let i = ((q * xs.len() as f64).ceil() as usize).clamp(1, xs.len()) - 1;
    xs[i]
}

fn share(n: usize, of: usize) -> f64 {
    if of == 0 {
        0.0
    } else {
        n as f64 / of as f64
    }
}

impl NoiseStats {
    /// The statistics of `scans`.
    pub fn of(scans: &[Scan]) -> Self {
        let mut points = 0;
        let mut errors = 0;
        let mut runs: Vec<usize> = Vec::new();
        let mut d1s: Vec<i64> = Vec::new();
        let mut d2s: Vec<i64> = Vec::new();
        let mut rice1 = 0u64;
        let mut rice2 = 0u64;
        let mut edges = 0;
        let mut bands: [Vec<f64>; 4] = Default::default();
        let mut levels: Vec<f64> = Vec::new();
        let mut di: Vec<i64> = Vec::new();
        let mut rice_i = 0u64;
        let has_aux = scans.iter().any(|s| s.has_aux);
        for scan in scans {
            points += scan.points.len();
            let (mut s_d1, mut s_d2, mut s_di) = (Vec::new(), Vec::new(), Vec::new());
            let mut run = 0;
            let mut prev: Option<Point> = None;
            for (i, p) in scan.points.iter().enumerate() {
                let follows = prev.is_some_and(|q| q.index.wrapping_add(1) == p.index);
                if p.range.is_none() {
                    errors += 1;
                    run = if follows { run + 1 } else { 1 };
                } else if run > 0 {
                    runs.push(run);
                    run = 0;
                }
                if let Some(r) = p.range {
                    levels.push(f64::from(p.aux));
                    if let Some(a) = prev.filter(|_| follows).and_then(|q| q.range) {
                        s_d1.push(i64::from(r) - i64::from(a));
                        s_di.push(i64::from(p.aux) - i64::from(prev.map_or(0, |q| q.aux)));
                        edges += usize::from(is_edge(a, r));
                        // Triples: the one before `prev`.
                        let before = i.checked_sub(2).and_then(|j| scan.points.get(j));
                        if let Some(b) = before
                            .filter(|b| b.index.wrapping_add(2) == p.index)
                            .and_then(|b| b.range)
                        {
                            s_d2.push(i64::from(r) - 2 * i64::from(a) + i64::from(b));
                            let smooth = u64::from(r.abs_diff(b)) * 20 <= u64::from(a);
                            if smooth {
                                let dev = f64::from(a) - (f64::from(r) + f64::from(b)) / 2.0;
                                let band = BANDS_MM.iter().rposition(|&lo| a >= lo).unwrap_or(0);
                                bands[band].push(dev.abs());
                            }
                        }
                    }
                }
                prev = Some(*p);
            }
            if run > 0 {
                runs.push(run);
            }
            rice1 += rice_bits(&s_d1);
            rice2 += rice_bits(&s_d2);
            rice_i += rice_bits(&s_di);
            d1s.extend(s_d1);
            d2s.extend(s_d2);
            di.extend(s_di);
        }
        let abs = |xs: &[i64]| {
            xs.iter()
                .map(|&x| x.unsigned_abs() as f64)
                .collect::<Vec<_>>()
        };
        let mut a1 = abs(&d1s);
        let mut a2 = abs(&d2s);
        let count = |xs: &[f64], lim: f64| xs.iter().filter(|&&x| x <= lim).count();
        let noise_by_band = core::array::from_fn(|i| {
            let mut v = bands[i].clone();
            BandNoise {
                samples: v.len(),
                median_mm: quantile(&mut v, 0.5),
            }
        });
        let intensity = has_aux.then(|| {
            let mut ai = abs(&di);
            let median_level = quantile(&mut levels, 0.5);
            let d1_median = quantile(&mut ai, 0.5);
            IntensityStats {
                median_level,
                d1_median,
                d1_p90: quantile(&mut ai, 0.9),
                d1_relative: if median_level > 0.0 {
                    d1_median / median_level
                } else {
                    0.0
                },
                rice_d1: share(rice_i as usize, di.len()),
            }
        });
        Self {
            scans: scans.len(),
            points,
            no_return_share: share(errors, points),
            no_return_runs_per_scan: share(runs.len(), scans.len()),
            no_return_run_mean: share(runs.iter().sum(), runs.len()),
            no_return_run_max: runs.iter().copied().max().unwrap_or(0),
            d1_pairs: d1s.len(),
            d1_zero: share(count(&a1, 0.0), a1.len()),
            d1_le2: share(count(&a1, 2.0), a1.len()),
            d1_le10: share(count(&a1, 10.0), a1.len()),
            d1_median: quantile(&mut a1, 0.5),
            d1_p90: quantile(&mut a1, 0.9),
            d2_median: quantile(&mut a2, 0.5),
            d2_p90: quantile(&mut a2, 0.9),
            edge_share: share(edges, d1s.len()),
            noise_by_band,
            d1_entropy: entropy(&d1s),
            rice_d1: share(rice1 as usize, d1s.len()),
            rice_d2: share(rice2 as usize, d2s.len()),
            intensity,
        }
    }

    /// The rows of the comparison table: (statistic, value as text).
    pub fn rows(&self) -> Vec<(String, String)> {
        let mut rows = vec![
            (
                "scans × steps".to_owned(),
                format!("{} × {}", self.scans, self.points / self.scans.max(1)),
            ),
            (
                "no-return share".into(),
                format!("{:.3}", self.no_return_share),
            ),
            (
                "no-return runs per scan".into(),
                format!("{:.1}", self.no_return_runs_per_scan),
            ),
            (
                "no-return run mean / longest".into(),
                format!(
                    "{:.1} / {}",
                    self.no_return_run_mean, self.no_return_run_max
                ),
            ),
            ("median abs(d1), mm".into(), format!("{}", self.d1_median)),
            ("p90 abs(d1), mm".into(), format!("{}", self.d1_p90)),
            ("share d1 = 0".into(), format!("{:.3}", self.d1_zero)),
            (
                "share abs(d1) <= 2 mm".into(),
                format!("{:.3}", self.d1_le2),
            ),
            (
                "share abs(d1) <= 10 mm".into(),
                format!("{:.3}", self.d1_le10),
            ),
            ("median abs(d2), mm".into(), format!("{}", self.d2_median)),
            ("p90 abs(d2), mm".into(), format!("{}", self.d2_p90)),
            ("edge share of d1".into(), format!("{:.4}", self.edge_share)),
        ];
        for (b, name) in self.noise_by_band.iter().zip(BAND_NAMES) {
            rows.push((
                format!("range noise {name}: median mm (n)"),
                if b.samples == 0 {
                    "-".into()
                } else {
                    format!("{:.1} ({})", b.median_mm, b.samples)
                },
            ));
        }
        rows.push((
            "entropy of d1, bits".into(),
            format!("{:.2}", self.d1_entropy),
        ));
        rows.push((
            "Rice d1, bits/residual".into(),
            format!("{:.2}", self.rice_d1),
        ));
        rows.push((
            "Rice d2, bits/residual".into(),
            format!("{:.2}", self.rice_d2),
        ));
        let i = self.intensity.as_ref();
        let text = |f: &dyn Fn(&IntensityStats) -> String| i.map_or("-".into(), f);
        rows.push((
            "intensity median".into(),
            text(&|i| format!("{}", i.median_level)),
        ));
        rows.push((
            "intensity median abs(ΔI)".into(),
            text(&|i| format!("{}", i.d1_median)),
        ));
        rows.push((
            "intensity p90 abs(ΔI)".into(),
            text(&|i| format!("{}", i.d1_p90)),
        ));
        rows.push((
            "intensity median abs(ΔI) / median".into(),
            text(&|i| format!("{:.4}", i.d1_relative)),
        ));
        rows.push((
            "intensity Rice ΔI, bits/residual".into(),
            text(&|i| format!("{:.2}", i.rice_d1)),
        ));
        rows
    }
}

/// A markdown table: one row per statistic, one column per named source.
pub fn table(columns: &[(String, NoiseStats)]) -> String {
    let mut out = String::from("| statistic |");
    for (name, _) in columns {
        let _ = write!(out, " {name} |");
    }
    out.push_str("\n|---|");
    for _ in columns {
        out.push_str("---:|");
    }
    out.push('\n');
    let rows: Vec<_> = columns.iter().map(|(_, s)| s.rows()).collect();
    let n = rows.first().map_or(0, Vec::len);
    for r in 0..n {
        let name = rows
            .first()
            .and_then(|c| c.get(r))
            .map_or("", |x| x.0.as_str());
        let _ = write!(out, "| {name} |");
        for col in &rows {
            let _ = write!(out, " {} |", col.get(r).map_or("", |x| x.1.as_str()));
        }
        out.push('\n');
    }
    out
}

/// Flags of `scip2can noise`.
#[derive(Debug, Clone, clap::Args)]
pub struct NoiseArgs {
    /// Sources: a recorded stream (raw capture or `scip2can record` file), or
    /// `sim:key=value,...` (a simulator, as for the clients).
    #[arg(required = true)]
    pub sources: Vec<String>,
    /// Scans to take from each simulator (1..=99).
    #[arg(short = 'n', long, default_value_t = 20)]
    pub scans: u32,
    /// One JSON object per source instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// The scans of one source (a file or a `sim:` spec).
pub fn scans_of_source(source: &str, sim_scans_n: u32) -> anyhow::Result<Vec<Scan>> {
    if let Some(spec) = source.strip_prefix("sim:") {
        let options = SimOptions::from_spec(spec)?;
        return sim_scans(&options, sim_scans_n);
    }
    let path = PathBuf::from(source);
    let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let stream = crate::sensor::record_file::sensor_bytes(&bytes)
        .with_context(|| format!("reading {}", path.display()))?;
    let scans = scans_of_stream(&stream);
    if scans.is_empty() {
        bail!("{} holds no scan", path.display());
    }
    Ok(scans)
}

/// Runs `scip2can noise`.
pub fn run(args: NoiseArgs) -> anyhow::Result<()> {
    let mut columns = Vec::new();
    for source in &args.sources {
        let scans = scans_of_source(source, args.scans)?;
        let name = match source.strip_prefix("sim:") {
            Some(_) => source.clone(),
            None => PathBuf::from(source)
                .file_name()
                .map_or(source.clone(), |n| n.to_string_lossy().into_owned()),
        };
        columns.push((name, NoiseStats::of(&scans)));
    }
    if args.json {
        for (name, stats) in &columns {
            let mut v = serde_json::to_value(stats)?;
            if let Some(o) = v.as_object_mut() {
                o.insert("source".into(), name.clone().into());
            }
            println!("{v}");
        }
    } else {
        print!("{}", table(&columns));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(ranges: &[Option<u32>]) -> Scan {
        Scan {
            points: ranges
                .iter()
                .enumerate()
                .map(|(i, &range)| Point {
                    index: i as u16,
                    range,
                    aux: 0,
                })
                .collect(),
            has_aux: false,
        }
    }

    #[test]
    fn rice_cost_by_hand() {
        // Zigzag: 0 1 -1 2 -> 0 2 1 4. k = 0: 1+3+2+5 = 11; k = 1: (0+2) + (1+2) +
        // (0+2) + (2+2) = 11; k = 2: 3+3+3+4 = 13. Best 11.
        assert_eq!(rice_bits(&[0, 1, -1, 2]), 11);
        // Two blocks are priced apart: 16 zeros (16 bits) then one 1000 (zigzag 2000:
        // k = 10 gives 1 + 1 + 10 = 12, k = 9 gives 3 + 1 + 9 = 13).
        let mut v = vec![0; 16];
        v.push(1000);
        assert_eq!(rice_bits(&v), 16 + 12);
        assert_eq!(entropy(&[3, 3, 5, 5]), 1.0);
    }

    #[test]
    fn statistics_by_hand() {
        let s = NoiseStats::of(&[scan(&[
            Some(1000),
            Some(1000),
            Some(1002),
            Some(1010),
            None,
            None,
            Some(2000),
            Some(1500),
            None,
        ])]);
        assert_eq!(s.points, 9);
        assert!((s.no_return_share - 3.0 / 9.0).abs() < 1e-12);
        assert_eq!((s.no_return_runs_per_scan, s.no_return_run_max), (2.0, 2));
        assert_eq!(s.no_return_run_mean, 1.5);
        // d1: 0, 2, 8, -500.
        assert_eq!(s.d1_pairs, 4);
        assert_eq!((s.d1_zero, s.d1_le2, s.d1_le10), (0.25, 0.5, 0.75));
        assert_eq!((s.d1_median, s.d1_p90), (2.0, 500.0));
        // d2: 2, 6.
        assert_eq!((s.d2_median, s.d2_p90), (2.0, 6.0));
        // 2000 -> 1500 is an edge (500 > 150), 1002 -> 1010 is not.
        assert_eq!(s.edge_share, 0.25);
        // Smooth triples: (1000,1000,1002) dev 1, (1000,1002,1010) dev 3, both 1-2 m.
        assert_eq!(s.noise_by_band[1].samples, 2);
        assert_eq!(s.noise_by_band[1].median_mm, 1.0);
        assert_eq!(s.noise_by_band[0].samples, 0);
    }

    #[test]
    fn index_gaps_break_pairs() {
        let mut s = scan(&[Some(1000), Some(1001)]);
        s.points[1].index = 5;
        assert_eq!(NoiseStats::of(&[s]).d1_pairs, 0);
    }
}
