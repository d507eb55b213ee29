//! The uncertainty's reliability diagram of `docs/ACCURACY.md`: for runs
//! of `tissue deform --uncertainty --points PROBES.csv` on the shared cases
//! (`PROBES.csv`: the case's 500 probes, then its tumour centroid, at rest),
//! the share of the probes whose true position lies in their region at each
//! level, against the level asked; drawn as a PNG and printed as a table.
//!
//! `cargo run --release --example reliability -- OUT.png LABEL RUN_DIR CASE_DIR [LABEL RUN_DIR CASE_DIR ...]`
//!
//! `RUN_DIR` holds the run's `report.json` and `points.csv`; `CASE_DIR` is
//! one of `../shared/cases/breast_*` (its `truth.json`). A probe's region at
//! level `p` is its ellipsoid `e^T C^-1 e <= q(p)`, `q` the chi-square
//! quantile with three degrees of freedom, `C` from the 95 % semi-axes with
//! the thinnest floored at a thousandth of the largest eigenvalue.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "an example")]

use std::path::Path;

use font8x8::UnicodeFonts;
use glam::Vec3;
use tiny_skia::{Color, FillRule, Paint, PathBuilder, Pixmap, Rect, Stroke, Transform};

/// The levels the diagram is drawn at.
const LEVELS: [f64; 7] = [0.2, 0.5, 0.68, 0.8, 0.9, 0.95, 0.99];

/// The chi-square distribution's CDF with three degrees of freedom.
fn chi2_3(x: f64) -> f64 {
    let s = (0.5 * x).sqrt();
    erf(s) - (2.0 * x / std::f64::consts::PI).sqrt() * (-0.5 * x).exp()
}

/// The error function by its Maclaurin series (to rounding for the
/// arguments of the quantiles here, below 4).
fn erf(x: f64) -> f64 {
    let mut sum = 0.0f64;
    let mut term = x;
    let mut n = 0.0f64;
    while term.abs() > 1e-17 * sum.abs().max(1e-300) || n < 5.0 {
        sum += term / (2.0 * n + 1.0);
        n += 1.0;
        term *= -x * x / n;
        if n > 400.0 {
            break;
        }
    }
    2.0 / std::f64::consts::PI.sqrt() * sum
}

/// The chi-square quantile with three degrees of freedom, by bisection.
fn quantile(p: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, 60.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi2_3(mid) < p { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

fn vec3(v: &serde_json::Value) -> Vec3 {
    Vec3::new(
        v[0].as_f64().unwrap() as f32,
        v[1].as_f64().unwrap() as f32,
        v[2].as_f64().unwrap() as f32,
    )
}

/// One run: per probe (and the tumour centroid last) its error and its
/// region's axes, variances and 95 % radius.
struct Run {
    label: String,
    errors: Vec<Vec3>,
    axes: Vec<[Vec3; 3]>,
    variances: Vec<[f64; 3]>,
    radii: Vec<f32>,
}

impl Run {
    fn read(label: &str, run: &Path, case: &Path) -> Self {
        let truth: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(case.join("truth.json")).unwrap())
                .unwrap();
        let mut true_positions: Vec<Vec3> = truth["probes_deformed"]
            .as_array()
            .unwrap()
            .iter()
            .map(vec3)
            .collect();
        true_positions.push(vec3(&truth["tumour_centroid_deformed"]));
        let predicted: Vec<Vec3> = std::fs::read_to_string(run.join("points.csv"))
            .unwrap()
            .lines()
            .skip(1)
            .map(|line| {
                let v: Vec<f32> = line
                    .split(',')
                    .take(3)
                    .map(|x| x.parse().unwrap())
                    .collect();
                Vec3::new(v[0], v[1], v[2])
            })
            .collect();
        assert_eq!(predicted.len(), true_positions.len(), "{}", run.display());
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run.join("report.json")).unwrap())
                .unwrap();
        let points = report["uncertainty"]["points"]
            .as_array()
            .expect("a run with --uncertainty and --points");
        let q95 = quantile(0.95);
        let (mut axes, mut variances, mut radii) = (Vec::new(), Vec::new(), Vec::new());
        for point in points {
            let a: Vec<Vec3> = point["axes"].as_array().unwrap().iter().map(vec3).collect();
            let semi: Vec<f64> = point["semi_axes_mm"]
                .as_array()
                .unwrap()
                .iter()
                .map(|s| s.as_f64().unwrap())
                .collect();
            let largest = semi[0] * semi[0] / q95;
            variances.push([0, 1, 2].map(|k| (semi[k] * semi[k] / q95).max(1e-3 * largest)));
            axes.push([a[0], a[1], a[2]]);
            radii.push(point["radius_mm"].as_f64().unwrap() as f32);
        }
        Self {
            label: label.to_string(),
            errors: true_positions
                .iter()
                .zip(&predicted)
                .map(|(t, p)| *t - *p)
                .collect(),
            axes,
            variances,
            radii,
        }
    }

    /// Each probe's `e^T C^-1 e` (the tumour centroid left out).
    fn distances(&self) -> Vec<f64> {
        let probes = self.errors.len() - 1;
        (0..probes)
            .map(|i| {
                (0..3)
                    .map(|k| {
                        let along = f64::from(self.errors[i].dot(self.axes[i][k]));
                        along * along / self.variances[i][k]
                    })
                    .sum()
            })
            .collect()
    }

    /// The share of the probes inside their regions at `level`.
    fn inside(&self, level: f64) -> f64 {
        let q = quantile(level);
        let distances = self.distances();
        distances.iter().filter(|&&d| d <= q).count() as f64 / distances.len() as f64
    }
}

/// `text` in the 8x8 bitmap font, `scale` pixels a font pixel.
fn text(pixmap: &mut Pixmap, left: f32, top: f32, scale: f32, text: &str, colour: Color) {
    let mut path = PathBuilder::new();
    for (k, ch) in text.chars().enumerate() {
        let glyph = font8x8::BASIC_FONTS.get(ch).unwrap_or([0; 8]);
        for (row, bits) in glyph.iter().enumerate() {
            for column in 0..8 {
                if bits >> column & 1 == 1 {
                    let x = left + (8 * k + column) as f32 * scale;
                    if let Some(rect) = Rect::from_xywh(x, top + row as f32 * scale, scale, scale) {
                        path.push_rect(rect);
                    }
                }
            }
        }
    }
    if let Some(path) = path.finish() {
        let mut paint = Paint::default();
        paint.set_color(colour);
        pixmap.fill_path(
            &path,
            &paint,
            FillRule::Winding,
            Transform::identity(),
            None,
        );
    }
}

fn line(pixmap: &mut Pixmap, points: &[(f32, f32)], colour: Color, width: f32) {
    let mut path = PathBuilder::new();
    path.move_to(points[0].0, points[0].1);
    for &(x, y) in &points[1..] {
        path.line_to(x, y);
    }
    let mut paint = Paint::default();
    paint.set_color(colour);
    paint.anti_alias = true;
    let stroke = Stroke {
        width,
        ..Stroke::default()
    };
    if let Some(path) = path.finish() {
        pixmap.stroke_path(&path, &paint, &stroke, Transform::identity(), None);
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    assert!(
        args.len() >= 4 && (args.len() - 1).is_multiple_of(3),
        "usage: OUT.png LABEL RUN_DIR CASE_DIR [LABEL RUN_DIR CASE_DIR ...]"
    );
    let runs: Vec<Run> = args[1..]
        .chunks(3)
        .map(|c| Run::read(&c[0], Path::new(&c[1]), Path::new(&c[2])))
        .collect();
    print!("| run |");
    for level in LEVELS {
        print!(" {:.0} % |", 100.0 * level);
    }
    println!(" radius 95 % | tumour |");
    for run in &runs {
        print!("| {} |", run.label);
        for level in LEVELS {
            print!(" {:.0} |", 100.0 * run.inside(level));
        }
        let probes = run.errors.len() - 1;
        let in_radius = (0..probes)
            .filter(|&i| run.errors[i].length() <= run.radii[i])
            .count();
        let tumour = run.errors.len() - 1;
        let tumour_in = (0..3)
            .map(|k| {
                let along = f64::from(run.errors[tumour].dot(run.axes[tumour][k]));
                along * along / run.variances[tumour][k]
            })
            .sum::<f64>()
            <= quantile(0.95);
        println!(
            " {:.1} | {} |",
            100.0 * in_radius as f64 / probes as f64,
            if tumour_in { "in" } else { "out" }
        );
    }

    // The diagram: the level asked across, the share inside up.
    let (size, margin) = (720.0f32, 70.0f32);
    let mut pixmap = Pixmap::new(size as u32, size as u32 + 30 * runs.len() as u32 / 2).unwrap();
    pixmap.fill(Color::WHITE);
    let plot = size - 2.0 * margin;
    let at = |level: f64, share: f64| {
        (
            margin + plot * level as f32,
            margin + plot * (1.0 - share as f32),
        )
    };
    let grey = Color::from_rgba8(150, 150, 150, 255);
    let black = Color::BLACK;
    line(
        &mut pixmap,
        &[
            at(0.0, 0.0),
            at(1.0, 0.0),
            at(1.0, 1.0),
            at(0.0, 1.0),
            at(0.0, 0.0),
        ],
        black,
        1.5,
    );
    line(&mut pixmap, &[at(0.0, 0.0), at(1.0, 1.0)], grey, 1.5);
    for tick in [0.0, 0.2, 0.4, 0.6, 0.8, 1.0] {
        let (x, y) = at(tick, 0.0);
        text(
            &mut pixmap,
            x - 12.0,
            y + 8.0,
            1.5,
            &format!("{:.0}", 100.0 * tick),
            black,
        );
        let (x, y) = at(0.0, tick);
        text(
            &mut pixmap,
            x - 40.0,
            y - 6.0,
            1.5,
            &format!("{:>3.0}", 100.0 * tick),
            black,
        );
    }
    text(
        &mut pixmap,
        margin + 0.25 * plot,
        size - margin + 32.0,
        2.0,
        "level asked (%)",
        black,
    );
    text(
        &mut pixmap,
        8.0,
        20.0,
        2.0,
        "probes inside their region (%)",
        black,
    );
    let colours = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
        (0, 0, 128),
        (128, 0, 0),
    ];
    for (k, run) in runs.iter().enumerate() {
        let (r, g, b) = colours[k % colours.len()];
        let colour = Color::from_rgba8(r, g, b, 255);
        let points: Vec<(f32, f32)> = LEVELS.iter().map(|&l| at(l, run.inside(l))).collect();
        line(&mut pixmap, &points, colour, 2.5);
        let (column, row) = ((k % 2) as f32, (k / 2) as f32);
        let (x, y) = (margin + column * 0.5 * plot, size - 10.0 + row * 30.0);
        line(
            &mut pixmap,
            &[(x, y + 6.0), (x + 30.0, y + 6.0)],
            colour,
            3.0,
        );
        text(&mut pixmap, x + 38.0, y, 1.5, &run.label, black);
    }
    pixmap.save_png(&args[0]).unwrap();
    println!("wrote {}", args[0]);
}
