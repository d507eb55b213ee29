//! Pictures of a solve, drawn in software (tiny-skia) so that they need no
//! display and no GPU: a cut through the organ coloured by displacement
//! beside the solve's convergence (docs/FORMATS.md, "Pictures").
//!
//! The left panel looks along the axis the particles moved least along, so
//! that the motion lies in the picture; of the other two axes the one they
//! moved most along points up. It shows the deformed skin (translucent, its
//! outline dark) over the skin at rest (grey outline), the particles in a
//! slab one particle thick through the first structure's moved centre (else
//! through the organ's middle), each coloured by how far it moved, and each
//! structure at rest (black outline) and moved (red), with an arrow between
//! their centres. The right panel plots the error estimate of every
//! iteration against the tolerance, on a log scale. With `--uncertainty`
//! a lower half shows the same cut coloured by each particle's 95 %
//! radius, and each structure's centroid region as the shadow of its
//! 95 % ellipsoid.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{Result, anyhow, bail};
use font8x8::UnicodeFonts;
use glam::{Vec2, Vec3};
use tiny_skia::{
    Color, FillRule, LineCap, Mask, Paint, Path as Outline, PathBuilder, Pixmap, Rect, Stroke,
    StrokeDash, Transform,
};
use tissue::SurfaceMesh;

mod cut;
mod spread;

pub use spread::Spread;

/// The picture's size in pixels.
pub const WIDTH: u32 = 1400;
/// The picture's height in pixels.
pub const HEIGHT: u32 = 700;

/// The cut's panel: left, top, right, bottom.
const VIEW: [f32; 4] = [30.0, 70.0, 700.0, 600.0];
/// The colour bar: left, top, right, bottom.
const BAR: [f32; 4] = [730.0, 110.0, 752.0, 560.0];
/// The convergence plot's axes: left, top, right, bottom.
const PLOT: [f32; 4] = [930.0, 110.0, 1370.0, 560.0];

/// What a picture shows: one solve, or the last frame of a sequence.
#[derive(Debug, Clone)]
pub struct Scene<'a> {
    /// The line at the top.
    pub title: String,
    /// The particles at rest.
    pub rest: &'a [Vec3],
    /// The particles now, in the same order.
    pub current: &'a [Vec3],
    /// The particles' radii (the cut is one particle thick).
    pub radii: &'a [f32],
    /// The skin at rest.
    pub rest_surface: &'a SurfaceMesh,
    /// The skin now.
    pub surface: &'a SurfaceMesh,
    /// Each structure at rest and moved (same triangles).
    pub structures: Vec<(&'a SurfaceMesh, &'a SurfaceMesh)>,
    /// The error estimate after every iteration, frames one after another.
    pub residuals: &'a [f32],
    /// Where in `residuals` each frame after the first begins.
    pub frame_starts: Vec<usize>,
    /// The stopping tolerance, as a fraction of the size.
    pub tolerance: f32,
    /// With `--uncertainty`, what the lower half shows: the cut coloured
    /// by each particle's 95 % radius, the structures' centroid regions.
    pub spread: Option<Spread<'a>>,
}

/// How the cut is looked at: which axes are across, up and towards the
/// viewer, and where the model's coordinates land in the panel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// The axis drawn left to right.
    pub across: usize,
    /// The axis drawn bottom to top.
    pub up: usize,
    /// The axis along which the viewer looks.
    pub depth: usize,
    /// +1 when the depth axis points towards the viewer, -1 when away.
    pub towards: f32,
    /// Pixels per model unit.
    scale: f32,
    /// The model point at the panel's top-left corner (across, up).
    corner: Vec2,
    /// The slab's centre and half-thickness along the depth axis.
    pub cut: f32,
    /// Half the slab's thickness.
    pub half: f32,
}

const AXES: [&str; 3] = ["x", "y", "z"];

impl View {
    /// The view of `scene` (module docs): axes from the particles' motion,
    /// the scale that fits rest and current skins and particles in the
    /// panel, the slab through the first structure.
    pub fn of(scene: &Scene<'_>) -> Self {
        let mut moved = [0.0f64; 3];
        for (p, q) in scene.rest.iter().zip(scene.current) {
            let d = *q - *p;
            for (k, m) in moved.iter_mut().enumerate() {
                *m += f64::from(d[k] * d[k]);
            }
        }
        // Ties: the later axis looks, the earlier one goes across.
        let depth = (0..3)
            .rev()
            .min_by(|&a, &b| moved[a].total_cmp(&moved[b]))
            .unwrap_or(2);
        let (a, b) = ((depth + 1) % 3, (depth + 2) % 3);
        let (across, up) = if moved[b] >= moved[a] { (a, b) } else { (b, a) };
        // across x up points towards the viewer: +depth when (across, up,
        // depth) is cyclic.
        let towards = if (across + 1) % 3 == up { 1.0 } else { -1.0 };

        let points = || {
            scene
                .rest
                .iter()
                .chain(scene.current)
                .chain(&scene.rest_surface.vertices)
                .chain(&scene.surface.vertices)
        };
        let (lo, hi) = points().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let (lo, hi) = if lo.x <= hi.x {
            (lo, hi)
        } else {
            (Vec3::ZERO, Vec3::ONE)
        };
        let extent = (hi - lo).max(Vec3::splat(1e-6));
        let [left, top, right, bottom] = VIEW;
        let scale = 0.95 * ((right - left) / extent[across]).min((bottom - top) / extent[up]);
        let middle = Vec2::new(0.5 * (lo[across] + hi[across]), 0.5 * (lo[up] + hi[up]));
        let corner = Vec2::new(
            middle.x - 0.5 * (right - left) / scale,
            middle.y + 0.5 * (bottom - top) / scale,
        );
        let cut = match scene.structures.first() {
            Some((_, moved)) if !moved.vertices.is_empty() => {
                moved.vertices.iter().map(|v| v[depth]).sum::<f32>() / moved.vertices.len() as f32
            }
            _ => 0.5 * (lo[depth] + hi[depth]),
        };
        let mut radii: Vec<f32> = scene
            .radii
            .iter()
            .copied()
            .filter(|r| r.is_finite())
            .collect();
        radii.sort_by(f32::total_cmp);
        let half = radii.get(radii.len() / 2).map_or(0.0, |r| 1.2 * r);
        Self {
            across,
            up,
            depth,
            towards,
            scale,
            corner,
            cut,
            half,
        }
    }

    /// Where the model point `p` lands in the picture, in pixels.
    pub fn to_screen(self, p: Vec3) -> Vec2 {
        Vec2::new(
            VIEW[0] + (p[self.across] - self.corner.x) * self.scale,
            VIEW[1] + (self.corner.y - p[self.up]) * self.scale,
        )
    }

    /// How near `p` is to the viewer (larger is nearer).
    fn nearness(&self, p: Vec3) -> f32 {
        self.towards * p[self.depth]
    }

    /// "looking along -x".
    fn describe(&self) -> String {
        let sign = if self.towards > 0.0 { '-' } else { '+' };
        format!(
            "looking along {sign}{}, {} to the right, {} up",
            AXES[self.depth], AXES[self.across], AXES[self.up]
        )
    }
}

/// The colour map of displacement, 0 to 1 (viridis, by five of its colours).
pub fn colour_map(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f32;
    let k = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - k as f32;
    let mix = |c: usize| (STOPS[k][c] + f * (STOPS[k + 1][c] - STOPS[k][c])).round() as u8;
    [mix(0), mix(1), mix(2)]
}

/// Draws `scene`.
pub fn render(scene: &Scene<'_>) -> Result<Pixmap> {
    if scene.rest.len() != scene.current.len() || scene.rest.len() != scene.radii.len() {
        bail!(
            "a picture needs as many current positions and radii as rest particles ({}, {}, {})",
            scene.rest.len(),
            scene.current.len(),
            scene.radii.len()
        );
    }
    let mut canvas = Canvas::new()?;
    let view = View::of(scene);
    let displacement: Vec<f32> = scene
        .rest
        .iter()
        .zip(scene.current)
        .map(|(p, q)| p.distance(*q))
        .collect();

    canvas.text(VIEW[0], 20.0, 2.0, &scene.title, opaque(INK));
    // The deformed skin filled; its outline and the rest skin's over the cut.
    canvas.fill_mesh(scene.surface, &view, rgba(120, 150, 190, 60));
    let largest = canvas.cut(scene, &view, &displacement);
    canvas.outline(scene.rest_surface, &view, rgba(150, 150, 150, 255), 1.5);
    canvas.outline(scene.surface, &view, rgba(40, 60, 90, 255), 2.0);
    // The structures: at rest, moved, and the arrow between.
    for (rest, moved) in &scene.structures {
        canvas.fill_mesh(rest, &view, rgba(255, 255, 255, 110));
        canvas.outline(rest, &view, rgba(0, 0, 0, 255), 2.0);
        canvas.fill_mesh(moved, &view, rgba(220, 30, 30, 120));
        canvas.outline(moved, &view, rgba(200, 0, 0, 255), 2.0);
        if let (Some(from), Some(to)) = (centre(&rest.vertices), centre(&moved.vertices)) {
            canvas.arrow(view.to_screen(from), view.to_screen(to), opaque(INK));
        }
    }
    canvas.text(
        VIEW[0],
        VIEW[3] + 22.0,
        1.5,
        &format!(
            "{}; the particles within {} of {} = {}",
            view.describe(),
            number(view.half),
            AXES[view.depth],
            number(view.cut)
        ),
        opaque(INK),
    );
    canvas.legend(VIEW[0], VIEW[3] + 50.0, !scene.structures.is_empty());
    canvas.colour_bar(largest, "moved");
    canvas.convergence(scene);
    match &scene.spread {
        Some(spread) => spread::stacked(&canvas.pixmap, scene, spread),
        None => Ok(canvas.pixmap),
    }
}

/// Draws `scene` into the PNG file `path`, through a temporary file.
pub fn save(scene: &Scene<'_>, path: &Path) -> Result<()> {
    let png = render(scene)?
        .encode_png()
        .map_err(|e| anyhow!("{}: cannot encode the picture: {e}", path.display()))?;
    tissue::io::write_atomically(path, |out| out.write_all(&png))?;
    Ok(())
}

/// Refuses a picture name that is not `.png`, before any work.
pub fn check_name(path: &Path) -> Result<()> {
    let png = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !png {
        bail!(
            "{}: a picture is written as PNG: name it <name>.png",
            path.display()
        );
    }
    Ok(())
}

/// The mean of `points`, if any.
fn centre(points: &[Vec3]) -> Option<Vec3> {
    (!points.is_empty()).then(|| points.iter().copied().sum::<Vec3>() / points.len() as f32)
}

/// Text, axes, arrows.
const INK: [u8; 3] = [20, 20, 20];
/// The convergence curve.
const PLOT_LINE: [u8; 3] = [31, 119, 180];
/// The tolerance's line.
const TOLERANCE_LINE: [u8; 3] = [214, 39, 40];

fn opaque([r, g, b]: [u8; 3]) -> Color {
    Color::from_rgba8(r, g, b, 255)
}

fn rgba(r: u8, g: u8, b: u8, a: u8) -> Color {
    Color::from_rgba8(r, g, b, a)
}

/// A white picture and the ways of drawing on it.
struct Canvas {
    pixmap: Pixmap,
}

impl Canvas {
    fn new() -> Result<Self> {
        let mut pixmap =
            Pixmap::new(WIDTH, HEIGHT).ok_or_else(|| anyhow!("cannot allocate the picture"))?;
        pixmap.fill(Color::WHITE);
        Ok(Self { pixmap })
    }

    fn paint(colour: Color) -> Paint<'static> {
        let mut paint = Paint::default();
        paint.set_color(colour);
        paint.anti_alias = true;
        paint
    }

    /// Fills `path` (built by `build`), if it has any area.
    fn fill(&mut self, colour: Color, build: impl FnOnce(&mut PathBuilder)) {
        self.fill_masked(colour, None, build);
    }

    /// Fills `path` (built by `build`) where `mask` lets it, if it has any area.
    fn fill_masked(
        &mut self,
        colour: Color,
        mask: Option<&Mask>,
        build: impl FnOnce(&mut PathBuilder),
    ) {
        let mut builder = PathBuilder::new();
        build(&mut builder);
        if let Some(path) = builder.finish() {
            self.fill_outline(&path, colour, mask);
        }
    }

    /// Fills `path` where `mask` lets it, if it has any area.
    fn fill_outline(&mut self, path: &Outline, colour: Color, mask: Option<&Mask>) {
        let bounds = path.bounds();
        if bounds.width() > 0.0 && bounds.height() > 0.0 {
            self.pixmap.fill_path(
                path,
                &Self::paint(colour),
                FillRule::Winding,
                Transform::identity(),
                mask,
            );
        }
    }

    /// Strokes `path` (built by `build`).
    fn stroke(
        &mut self,
        colour: Color,
        width: f32,
        dash: Option<StrokeDash>,
        build: impl FnOnce(&mut PathBuilder),
    ) {
        let mut builder = PathBuilder::new();
        build(&mut builder);
        if let Some(path) = builder.finish() {
            let stroke = Stroke {
                width,
                line_cap: LineCap::Round,
                dash,
                ..Stroke::default()
            };
            self.pixmap.stroke_path(
                &path,
                &Self::paint(colour),
                &stroke,
                Transform::identity(),
                None,
            );
        }
    }

    /// The area `mesh` covers, filled once with `colour` however many
    /// layers of it lie there.
    fn fill_mesh(&mut self, mesh: &SurfaceMesh, view: &View, colour: Color) {
        if let Some(path) = mesh_path(mesh, view) {
            self.fill_outline(&path, colour, None);
        }
    }

    /// The outline of `mesh` as seen: edges between a triangle that faces
    /// the viewer and one that faces away, and open edges.
    fn outline(&mut self, mesh: &SurfaceMesh, view: &View, colour: Color, width: f32) {
        let edges = silhouette(mesh, view);
        self.stroke(colour, width, None, |path| {
            for (a, b) in edges {
                let (a, b) = (view.to_screen(a), view.to_screen(b));
                path.move_to(a.x, a.y);
                path.line_to(b.x, b.y);
            }
        });
    }

    fn disc(&mut self, at: Vec2, radius: f32, colour: Color) {
        self.fill(colour, |path| path.push_circle(at.x, at.y, radius));
    }

    fn rect(&mut self, left: f32, top: f32, width: f32, height: f32, colour: Color) {
        if let Some(rect) = Rect::from_xywh(left, top, width, height) {
            self.pixmap
                .fill_rect(rect, &Self::paint(colour), Transform::identity(), None);
        }
    }

    fn line(&mut self, from: Vec2, to: Vec2, colour: Color, width: f32) {
        self.stroke(colour, width, None, |path| {
            path.move_to(from.x, from.y);
            path.line_to(to.x, to.y);
        });
    }

    /// A line from `from` to `to` with a head at `to`, if it is longer than
    /// a few pixels.
    fn arrow(&mut self, from: Vec2, to: Vec2, colour: Color) {
        let along = to - from;
        let length = along.length();
        if length < 4.0 {
            return;
        }
        let unit = along / length;
        let head = 10.0f32.min(0.5 * length);
        let base = to - head * unit;
        let side = 0.5 * head * unit.perp();
        self.line(from, base, colour, 2.5);
        self.fill(colour, |path| {
            path.move_to(to.x, to.y);
            path.line_to(base.x + side.x, base.y + side.y);
            path.line_to(base.x - side.x, base.y - side.y);
            path.close();
        });
    }

    /// `text` in the 8x8 bitmap font, `scale` pixels per font pixel, its
    /// top-left corner at (`left`, `top`).
    fn text(&mut self, left: f32, top: f32, scale: f32, text: &str, colour: Color) {
        self.fill(colour, |path| {
            for (k, ch) in text.chars().enumerate() {
                let glyph = font8x8::BASIC_FONTS
                    .get(ch)
                    .or_else(|| font8x8::BASIC_FONTS.get('?'))
                    .unwrap_or([0; 8]);
                let x0 = left + k as f32 * 8.0 * scale;
                for (row, bits) in glyph.iter().enumerate() {
                    for column in 0..8 {
                        if bits >> column & 1 == 1
                            && let Some(rect) = Rect::from_xywh(
                                x0 + column as f32 * scale,
                                top + row as f32 * scale,
                                scale,
                                scale,
                            )
                        {
                            path.push_rect(rect);
                        }
                    }
                }
            }
        });
    }

    /// The legend under the cut.
    fn legend(&mut self, left: f32, top: f32, structures: bool) {
        let mut x = left;
        let mut entry = |canvas: &mut Self, swatch: Color, filled: bool, label: &str| {
            if filled {
                canvas.rect(x, top, 24.0, 12.0, swatch);
            } else {
                canvas.line(
                    Vec2::new(x, top + 6.0),
                    Vec2::new(x + 24.0, top + 6.0),
                    swatch,
                    2.5,
                );
            }
            canvas.text(x + 30.0, top, 1.5, label, opaque(INK));
            x += 30.0 + label.len() as f32 * 12.0 + 24.0;
        };
        entry(self, rgba(150, 150, 150, 255), false, "skin at rest");
        entry(self, rgba(40, 60, 90, 255), false, "skin now");
        if structures {
            entry(self, rgba(0, 0, 0, 255), false, "structure at rest");
            entry(self, rgba(220, 30, 30, 200), true, "moved");
        }
    }

    /// The colour bar, 0 at the bottom to `largest` at the top, headed
    /// `label`.
    fn colour_bar(&mut self, largest: f32, label: &str) {
        let [left, top, right, bottom] = BAR;
        let rows = (bottom - top).round() as usize;
        for row in 0..rows {
            let t = 1.0 - row as f32 / (rows - 1).max(1) as f32;
            let [r, g, b] = colour_map(t);
            self.rect(
                left,
                top + row as f32,
                right - left,
                1.0,
                rgba(r, g, b, 255),
            );
        }
        self.stroke(opaque(INK), 1.0, None, |path| {
            if let Some(rect) = Rect::from_ltrb(left, top, right, bottom) {
                path.push_rect(rect);
            }
        });
        self.text(left - 10.0, top - 40.0, 1.5, label, opaque(INK));
        for k in 0..=4 {
            let t = k as f32 / 4.0;
            let y = bottom - t * (bottom - top);
            self.line(
                Vec2::new(right, y),
                Vec2::new(right + 5.0, y),
                opaque(INK),
                1.0,
            );
            self.text(right + 9.0, y - 6.0, 1.5, &number(t * largest), opaque(INK));
        }
        self.text(left - 10.0, bottom + 14.0, 1.5, "(mm)", opaque(INK));
    }

    /// The error estimate per iteration against the tolerance, log scale.
    fn convergence(&mut self, scene: &Scene<'_>) {
        let [left, top, right, bottom] = PLOT;
        self.text(
            left - 60.0,
            VIEW[1] - 10.0,
            1.5,
            "error estimate / size, each iteration",
            opaque(INK),
        );
        self.stroke(opaque(INK), 1.0, None, |path| {
            path.move_to(left, top);
            path.line_to(left, bottom);
            path.line_to(right, bottom);
        });
        let logs: Vec<Option<f32>> = scene
            .residuals
            .iter()
            .map(|&r| (r.is_finite() && r > 0.0).then(|| r.log10()))
            .collect();
        let known = logs.iter().flatten().copied();
        let tolerance = (scene.tolerance > 0.0).then(|| scene.tolerance.log10());
        let (lo, hi) = known
            .chain(tolerance)
            .fold((f32::MAX, f32::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
        let iterations = scene.residuals.len();
        if iterations == 0 || lo > hi {
            self.text(
                left + 20.0,
                0.5 * (top + bottom),
                1.5,
                "no iteration: the skin did not move",
                opaque(INK),
            );
            return;
        }
        let (lo, hi) = (lo.floor(), hi.ceil().max(lo.floor() + 1.0));
        let x_of = |i: f32| left + (i - 1.0) / (iterations.max(2) - 1) as f32 * (right - left);
        let y_of = |log: f32| bottom - (log - lo) / (hi - lo) * (bottom - top);
        // Decades up the side, round numbers of iterations along the bottom.
        let decades = (hi - lo) as usize;
        let every = decades.div_ceil(8).max(1);
        for d in (0..=decades).step_by(every) {
            let log = lo + d as f32;
            let y = y_of(log);
            self.line(
                Vec2::new(left - 5.0, y),
                Vec2::new(left, y),
                opaque(INK),
                1.0,
            );
            self.line(
                Vec2::new(left, y),
                Vec2::new(right, y),
                rgba(225, 225, 225, 255),
                1.0,
            );
            let label = format!("1e{}", log as i32);
            self.text(
                left - 10.0 - label.len() as f32 * 12.0,
                y - 6.0,
                1.5,
                &label,
                opaque(INK),
            );
        }
        let step = tick_step(iterations);
        let mut tick = step;
        let mut ticks = vec![1];
        while tick <= iterations {
            ticks.push(tick);
            tick += step;
        }
        for tick in ticks {
            let x = x_of(tick as f32);
            self.line(
                Vec2::new(x, bottom),
                Vec2::new(x, bottom + 5.0),
                opaque(INK),
                1.0,
            );
            let label = tick.to_string();
            self.text(
                x - label.len() as f32 * 6.0,
                bottom + 10.0,
                1.5,
                &label,
                opaque(INK),
            );
        }
        let label = if scene.frame_starts.is_empty() {
            "iteration"
        } else {
            "iteration (frames one after another)"
        };
        self.text(
            0.5 * (left + right) - label.len() as f32 * 6.0,
            bottom + 34.0,
            1.5,
            label,
            opaque(INK),
        );
        for &start in &scene.frame_starts {
            let x = x_of(start as f32 + 0.5);
            self.line(
                Vec2::new(x, top),
                Vec2::new(x, bottom),
                rgba(190, 190, 190, 255),
                1.0,
            );
        }
        if let Some(log) = tolerance {
            let y = y_of(log);
            self.stroke(
                opaque(TOLERANCE_LINE),
                2.0,
                StrokeDash::new(vec![8.0, 5.0], 0.0),
                |path| {
                    path.move_to(left, y);
                    path.line_to(right, y);
                },
            );
            self.text(
                right - 9.0 * 12.0,
                y - 18.0,
                1.5,
                "tolerance",
                opaque(TOLERANCE_LINE),
            );
        }
        // The curve breaks where a frame begins or a value is not positive.
        let points: Vec<Option<Vec2>> = logs
            .iter()
            .enumerate()
            .map(|(i, log)| log.map(|l| Vec2::new(x_of(i as f32 + 1.0), y_of(l))))
            .collect();
        let starts = &scene.frame_starts;
        self.stroke(opaque(PLOT_LINE), 2.0, None, |path| {
            let mut pen_down = false;
            for (i, point) in points.iter().enumerate() {
                match point {
                    Some(p) if pen_down && !starts.contains(&i) => path.line_to(p.x, p.y),
                    Some(p) => {
                        path.move_to(p.x, p.y);
                        pen_down = true;
                    }
                    None => pen_down = false,
                }
            }
        });
        for point in points.iter().flatten() {
            self.disc(*point, 3.0, opaque(PLOT_LINE));
        }
    }
}

/// A round step between iteration ticks: at most about eight of them.
fn tick_step(iterations: usize) -> usize {
    let mut step = 1;
    loop {
        for factor in [1, 2, 5] {
            if iterations / (step * factor) <= 8 {
                return step * factor;
            }
        }
        step *= 10;
    }
}

/// A label for a value: three significant figures at most.
pub fn number(value: f32) -> String {
    let size = value.abs();
    if size == 0.0 {
        "0".into()
    } else if size >= 100.0 {
        format!("{value:.0}")
    } else if size >= 10.0 {
        format!("{value:.1}")
    } else if size >= 1.0 {
        format!("{value:.2}")
    } else {
        format!("{value:.3}")
    }
}

/// The area `mesh` covers on the screen: its triangles, each wound the
/// same way there, so that the winding rule fills their union once.
fn mesh_path(mesh: &SurfaceMesh, view: &View) -> Option<Outline> {
    let mut path = PathBuilder::new();
    for t in &mesh.triangles {
        let corner = |k: usize| mesh.vertices.get(t[k] as usize).map(|&v| view.to_screen(v));
        let (Some(a), Some(b), Some(c)) = (corner(0), corner(1), corner(2)) else {
            continue;
        };
        let (b, c) = if (b - a).perp_dot(c - a) < 0.0 {
            (c, b)
        } else {
            (b, c)
        };
        path.move_to(a.x, a.y);
        path.line_to(b.x, b.y);
        path.line_to(c.x, c.y);
        path.close();
    }
    path.finish()
}

/// The edges of `mesh` on its outline as seen in `view` (see
/// [`Canvas::outline`]).
fn silhouette(mesh: &SurfaceMesh, view: &View) -> Vec<(Vec3, Vec3)> {
    let mut towards = Vec3::ZERO;
    towards[view.depth] = view.towards;
    let mut edges: HashMap<(u32, u32), (bool, usize)> = HashMap::new();
    let mut mixed: HashMap<(u32, u32), bool> = HashMap::new();
    for t in &mesh.triangles {
        let Some([a, b, c]) = [t[0], t[1], t[2]]
            .iter()
            .map(|&v| mesh.vertices.get(v as usize).copied())
            .collect::<Option<Vec<_>>>()
            .and_then(|v| <[Vec3; 3]>::try_from(v).ok())
        else {
            continue;
        };
        let facing = (b - a).cross(c - a).dot(towards) > 0.0;
        for (p, q) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            let key = (p.min(q), p.max(q));
            let entry = edges.entry(key).or_insert((facing, 0));
            entry.1 += 1;
            if entry.0 != facing {
                mixed.insert(key, true);
            }
        }
    }
    edges
        .into_iter()
        .filter(|(key, (_, count))| *count == 1 || mixed.contains_key(key))
        .map(|((p, q), _)| (mesh.vertices[p as usize], mesh.vertices[q as usize]))
        .collect()
}

#[cfg(test)]
#[allow(clippy::expect_used, reason = "tests")]
pub(super) mod tests {
    use super::*;

    /// The closed box from `lo` to `hi`, faces wound outward.
    pub(super) fn cuboid(lo: Vec3, hi: Vec3) -> SurfaceMesh {
        let corner = |k: u32| {
            Vec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            )
        };
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        SurfaceMesh {
            vertices: (0..8).map(corner).collect(),
            triangles: quads
                .iter()
                .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
                .collect(),
        }
    }

    /// `render`, kept as `name.png` in `$TISSUE_TEST_PICTURES` when that
    /// is set, to be looked at.
    pub(super) fn drawn(scene: &Scene<'_>, name: &str) -> Pixmap {
        let picture = render(scene).expect("drawn");
        if let Some(dir) = std::env::var_os("TISSUE_TEST_PICTURES") {
            let path = Path::new(&dir).join(format!("{name}.png"));
            save(scene, &path).expect("saved");
        }
        picture
    }

    pub(super) fn pixel(picture: &Pixmap, at: Vec2) -> [u8; 3] {
        picture
            .pixel(at.x.round() as u32, at.y.round() as u32)
            .map(|p| p.demultiply())
            .map_or([0; 3], |c| [c.red(), c.green(), c.blue()])
    }

    /// Whether a pixel within one of `at` (a line's centre, which
    /// anti-aliasing may share between two rows) satisfies `test`.
    fn near(picture: &Pixmap, at: Vec2, test: impl Fn([u8; 3]) -> bool) -> bool {
        (-1..=1)
            .any(|dx| (-1..=1).any(|dy| test(pixel(picture, at + Vec2::new(dx as f32, dy as f32)))))
    }

    fn close(a: [u8; 3], b: [u8; 3], within: i32) -> bool {
        a.iter()
            .zip(&b)
            .all(|(&x, &y)| (i32::from(x) - i32::from(y)).abs() <= within)
    }

    /// A 10 x 10 x 10 block of particles, each moved along z by `shift`
    /// times its x: the view looks along the axis they did not move along
    /// that is latest (y), z goes up, and the colours run from the map's
    /// first colour at x = 0 to its last at x = 9.
    #[test]
    fn the_cut_is_coloured_by_displacement_and_looks_across_the_motion() {
        let rest: Vec<Vec3> = (0..1000)
            .map(|k| Vec3::new((k % 10) as f32, (k / 10 % 10) as f32, (k / 100) as f32))
            .collect();
        let current: Vec<Vec3> = rest
            .iter()
            .map(|p| *p + Vec3::new(0.0, 0.0, 0.3 * p.x))
            .collect();
        let radii = vec![0.5; rest.len()];
        let skin = cuboid(Vec3::splat(-0.5), Vec3::splat(9.5));
        let history = [1e-1, 1e-2, 1e-3, 1e-5];
        let scene = Scene {
            title: "test".into(),
            rest: &rest,
            current: &current,
            radii: &radii,
            rest_surface: &skin,
            surface: &skin,
            structures: Vec::new(),
            residuals: &history,
            frame_starts: Vec::new(),
            tolerance: 1e-4,
            spread: None,
        };
        let view = View::of(&scene);
        assert_eq!((view.across, view.up, view.depth), (0, 2, 1));
        let picture = drawn(&scene, "cut");
        assert_eq!((picture.width(), picture.height()), (WIDTH, HEIGHT));
        // The particles of the middle row (z = 4 at rest), in the cut y = 4.5 +- 0.6.
        let still = view.to_screen(current[400 + 50]);
        let most = view.to_screen(current[409 + 50]);
        assert!(most.x > still.x + 100.0, "x runs to the right");
        assert!(most.y < still.y, "the one moved up is drawn higher");
        assert!(close(pixel(&picture, still), colour_map(0.0), 2));
        assert!(close(pixel(&picture, most), colour_map(1.0), 2));
        // Outside the skin: white.
        assert_eq!(
            pixel(&picture, Vec2::new(VIEW[0] + 2.0, VIEW[3] - 2.0)),
            [255; 3]
        );
    }

    /// A structure moved right is drawn red where it went and white with a
    /// black outline where it was.
    #[test]
    fn a_structure_is_drawn_at_rest_and_moved() {
        let rest: Vec<Vec3> = (0..8 * 8 * 8)
            .map(|k| 10.0 * Vec3::new((k % 8) as f32, (k / 8 % 8) as f32, (k / 64) as f32))
            .collect();
        // Sheared in x (up the picture) with a little z (across it).
        let current: Vec<Vec3> = rest
            .iter()
            .map(|p| *p + Vec3::new(0.3 * p.z, 0.0, 0.05 * p.x))
            .collect();
        let radii = vec![5.0; rest.len()];
        let skin = cuboid(Vec3::splat(-5.0), Vec3::splat(75.0));
        let moved_skin = SurfaceMesh {
            vertices: skin
                .vertices
                .iter()
                .map(|v| *v + Vec3::X * 0.3 * v.z)
                .collect(),
            triangles: skin.triangles.clone(),
        };
        let tumour = cuboid(Vec3::new(10.0, 30.0, 10.0), Vec3::new(20.0, 40.0, 20.0));
        let moved = SurfaceMesh {
            vertices: tumour
                .vertices
                .iter()
                .map(|v| *v + Vec3::new(25.0, 0.0, 0.0))
                .collect(),
            triangles: tumour.triangles.clone(),
        };
        let scene = Scene {
            title: "test".into(),
            rest: &rest,
            current: &current,
            radii: &radii,
            rest_surface: &skin,
            surface: &moved_skin,
            structures: vec![(&tumour, &moved)],
            residuals: &[],
            frame_starts: Vec::new(),
            tolerance: 1e-4,
            spread: None,
        };
        let view = View::of(&scene);
        assert_eq!(view.depth, 1, "y: the axis nothing moved along");
        let picture = drawn(&scene, "structure");
        let inside_moved = pixel(&picture, view.to_screen(Vec3::new(38.0, 35.0, 12.0)));
        assert!(
            inside_moved[0] > inside_moved[1] + 60 && inside_moved[0] > inside_moved[2] + 60,
            "red where it went: {inside_moved:?}"
        );
        let inside_rest = pixel(&picture, view.to_screen(Vec3::new(12.0, 35.0, 18.0)));
        assert!(
            inside_rest.iter().all(|&c| c > 100) && inside_rest[0] <= inside_rest[2] + 20,
            "pale where it was: {inside_rest:?}"
        );
        let edge = view.to_screen(Vec3::new(10.0, 35.0, 15.0));
        assert!(
            near(&picture, edge, |c| c.iter().all(|&c| c < 30)),
            "its outline is black"
        );
    }

    /// The curve falls from the first iteration to the last, crosses the
    /// tolerance's line, and a frame boundary breaks it.
    #[test]
    fn the_convergence_plot_follows_the_residuals() {
        let rest = vec![Vec3::ZERO, Vec3::X];
        let radii = vec![0.5; 2];
        let skin = cuboid(Vec3::splat(-1.0), Vec3::splat(2.0));
        let history = [1e-1, 1e-2, 1e-3, 1e-5, 1e-2, 1e-6];
        let scene = Scene {
            title: "test".into(),
            rest: &rest,
            current: &rest,
            radii: &radii,
            rest_surface: &skin,
            surface: &skin,
            structures: Vec::new(),
            residuals: &history,
            frame_starts: vec![4],
            tolerance: 1e-4,
            spread: None,
        };
        let picture = drawn(&scene, "convergence");
        let [left, top, right, bottom] = PLOT;
        let curve_at = |x: f32| {
            (top as u32..=bottom as u32)
                .find(|&y| close(pixel(&picture, Vec2::new(x, y as f32)), [31, 119, 180], 10))
                .map(|y| y as f32)
        };
        // Decades 1e-6 .. 1e-1: iteration i at log10 r.
        let y_of = |log: f32| bottom - (log + 6.0) / 5.0 * (bottom - top);
        let x_of = |i: f32| left + (i - 1.0) / 5.0 * (right - left);
        for (i, r) in history.iter().enumerate() {
            let found = curve_at(x_of(i as f32 + 1.0));
            let expected = y_of(r.log10());
            assert!(
                found.is_some_and(|y| (y - expected).abs() <= 4.0),
                "iteration {}: curve at {found:?}, expected {expected}",
                i + 1
            );
        }
        // Between the frames (iterations 4 and 5) the curve is not drawn.
        let between = curve_at(x_of(4.5));
        assert!(between.is_none(), "frame boundary crossed at {between:?}");
        let tolerance_y = y_of(-4.0);
        let dashes = (left as u32..right as u32)
            .filter(|&x| {
                near(&picture, Vec2::new(x as f32, tolerance_y), |c| {
                    close(c, [214, 39, 40], 20)
                })
            })
            .count();
        assert!(dashes > 100, "the tolerance's dashed line: {dashes} pixels");
    }

    #[test]
    fn pictures_are_png_files() {
        assert!(check_name(Path::new("out/cut.PNG")).is_ok());
        let refused = check_name(Path::new("cut.jpg")).map_err(|e| e.to_string());
        assert!(
            refused
                .as_ref()
                .is_err_and(|e| e.contains("cut.jpg") && e.contains(".png")),
            "{refused:?}"
        );
    }
}
