//! The picture's lower half with `--uncertainty`: the same cut, each
//! particle coloured by its 95 % radius, and each structure's centroid
//! region drawn as the shadow of its 95 % ellipsoid on the cut.

use anyhow::{Result, anyhow};
use glam::{Vec2, Vec3};
use tiny_skia::{Color, Pixmap, PixmapPaint, Transform};

use super::{AXES, Canvas, HEIGHT, INK, PLOT, Scene, VIEW, View, WIDTH, number, opaque, rgba};

/// The chi-square's 95 % point with three degrees of freedom: the shadow
/// of the 95 % ellipsoid `e^T C^-1 e <= CHI2` on a plane is the ellipse of
/// the covariance's part in that plane with the same bound.
const CHI2: f32 = 7.814_728;

/// What the lower half shows.
#[derive(Debug, Clone)]
pub struct Spread<'a> {
    /// Each particle's 95 % radius.
    pub radii: &'a [f32],
    /// Each structure's moved centroid, its covariance (xx, yy, zz, xy,
    /// xz, yz), and what it says in words (a line or two).
    pub centroids: Vec<(Vec3, [f64; 6], String)>,
}

/// `top` with the spread's panel drawn below it, one picture twice as tall.
pub(super) fn stacked(top: &Pixmap, scene: &Scene<'_>, spread: &Spread<'_>) -> Result<Pixmap> {
    let lower = panel(scene, spread)?;
    let mut both =
        Pixmap::new(WIDTH, 2 * HEIGHT).ok_or_else(|| anyhow!("cannot allocate the picture"))?;
    both.fill(Color::WHITE);
    let paint = PixmapPaint::default();
    both.draw_pixmap(0, 0, top.as_ref(), &paint, Transform::identity(), None);
    let below = i32::try_from(HEIGHT).map_err(|_| anyhow!("the picture is too tall"))?;
    both.draw_pixmap(
        0,
        below,
        lower.as_ref(),
        &paint,
        Transform::identity(),
        None,
    );
    Ok(both)
}

/// The lower panel: the cut coloured by the 95 % radius, the skin, the
/// structures moved and their centroids' regions.
fn panel(scene: &Scene<'_>, spread: &Spread<'_>) -> Result<Pixmap> {
    let mut canvas = Canvas::new()?;
    let view = View::of(scene);
    canvas.text(
        VIEW[0],
        20.0,
        2.0,
        "how sure: each particle's 95 % radius; each structure's centroid region",
        opaque(INK),
    );
    canvas.fill_mesh(scene.surface, &view, rgba(120, 150, 190, 60));
    let largest = canvas.cut(scene, &view, spread.radii);
    canvas.outline(scene.surface, &view, rgba(40, 60, 90, 255), 2.0);
    for (_, moved) in &scene.structures {
        canvas.outline(moved, &view, rgba(200, 0, 0, 255), 2.0);
    }
    for (k, (centre, covariance, line)) in spread.centroids.iter().enumerate() {
        let ring = shadow(*centre, *covariance, &view);
        for pair in ring.windows(2) {
            canvas.line(pair[0], pair[1], opaque(INK), 2.5);
        }
        canvas.disc(view.to_screen(*centre), 3.0, opaque(INK));
        for (row, text) in line.lines().enumerate() {
            let top = PLOT[1] + 60.0 * k as f32 + 20.0 * row as f32;
            canvas.text(PLOT[0] - 60.0, top, 1.5, text, opaque(INK));
        }
    }
    canvas.text(
        VIEW[0],
        VIEW[3] + 22.0,
        1.5,
        &format!(
            "the same cut ({} = {}); black: a centroid's 95 % region, its shadow on the cut",
            AXES[view.depth],
            number(view.cut)
        ),
        opaque(INK),
    );
    canvas.colour_bar(largest, "95 %");
    Ok(canvas.pixmap)
}

/// The shadow on the view's plane of the 95 % ellipsoid of `covariance`
/// about `centre`, as a closed ring of screen points.
fn shadow(centre: Vec3, covariance: [f64; 6], view: &View) -> Vec<Vec2> {
    let full = |i: usize, j: usize| -> f32 {
        let index = match (i.min(j), i.max(j)) {
            (0, 0) => 0,
            (1, 1) => 1,
            (2, 2) => 2,
            (0, 1) => 3,
            (0, 2) => 4,
            _ => 5,
        };
        covariance[index] as f32
    };
    let (a, u) = (view.across, view.up);
    let (caa, cuu, cau) = (full(a, a), full(u, u), full(a, u));
    // The 2x2 part's eigenvalues and its first eigenvector's angle.
    let mean = 0.5 * (caa + cuu);
    let spread = (0.25 * (caa - cuu).powi(2) + cau * cau).sqrt();
    let (l1, l2) = ((mean + spread).max(0.0), (mean - spread).max(0.0));
    let angle = 0.5 * (2.0 * cau).atan2(caa - cuu);
    let (s1, s2) = ((CHI2 * l1).sqrt(), (CHI2 * l2).sqrt());
    (0..=64)
        .map(|k| {
            let t = k as f32 / 64.0 * std::f32::consts::TAU;
            let (x, y) = (s1 * t.cos(), s2 * t.sin());
            let mut p = centre;
            p[a] += x * angle.cos() - y * angle.sin();
            p[u] += x * angle.sin() + y * angle.cos();
            view.to_screen(p)
        })
        .collect()
}

#[cfg(test)]
#[allow(clippy::expect_used, reason = "tests")]
mod tests {
    use super::super::colour_map;
    use super::super::tests::{cuboid, drawn, pixel};
    use super::*;

    /// With a spread the picture is twice as tall; its lower half colours
    /// the cut by the radius (the particle with the largest the top of the
    /// colour map) and rings the structure's centroid at the shadow of its
    /// 95 % ellipsoid.
    #[test]
    fn the_lower_half_colours_by_the_radius_and_rings_the_centroid() {
        let skin = cuboid(Vec3::splat(-10.0), Vec3::splat(10.0));
        let rest: Vec<Vec3> = (0..9)
            .flat_map(|i| {
                (0..9).map(move |j| Vec3::new(i as f32 * 2.0 - 8.0, j as f32 * 2.0 - 8.0, 0.0))
            })
            .collect();
        let current: Vec<Vec3> = rest
            .iter()
            .map(|p| *p + Vec3::new(0.3, -0.5, 0.0))
            .collect();
        let radii = vec![1.0; rest.len()];
        let spread_radii: Vec<f32> = rest.iter().map(|p| p.x + 10.0).collect();
        let tumour = cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        let moved = cuboid(Vec3::new(-1.0, -1.5, -1.0), Vec3::new(1.0, 0.5, 1.0));
        let centre = Vec3::new(0.0, -0.5, 0.0);
        let scene = Scene {
            title: "spread".into(),
            rest: &rest,
            current: &current,
            radii: &radii,
            rest_surface: &skin,
            surface: &skin,
            structures: vec![(&tumour, &moved)],
            residuals: &[1e-2, 1e-3, 1e-5],
            frame_starts: Vec::new(),
            tolerance: 1e-4,
            spread: Some(Spread {
                radii: &spread_radii,
                centroids: vec![(
                    centre,
                    [1.0, 1.0, 1.0, 0.0, 0.0, 0.0],
                    "tumour\nwithin 2.79 (95 %)".into(),
                )],
            }),
        };
        let picture = drawn(&scene, "spread");
        assert_eq!((picture.width(), picture.height()), (WIDTH, 2 * HEIGHT));
        let view = View::of(&scene);
        let below = Vec2::new(0.0, HEIGHT as f32);
        // The ring: the shadow of a unit covariance is a circle of radius
        // sqrt(7.81) model units; its rightmost point is black.
        let mut edge = centre;
        edge[view.across] += CHI2.sqrt();
        let at = view.to_screen(edge) + below;
        let dark = (-2..=2).any(|d| {
            let p = pixel(&picture, at + Vec2::new(d as f32, 0.0));
            p.iter().all(|&c| c < 90)
        });
        assert!(dark, "no ring at {at}");
        // The particle with the largest radius has the map's top colour.
        let top = rest.len() - 1;
        let colour = pixel(&picture, view.to_screen(current[top]) + below);
        let [r, g, b] = colour_map(1.0);
        let off = |x: u8, y: u8| (i32::from(x) - i32::from(y)).abs();
        assert!(
            off(colour[0], r) + off(colour[1], g) + off(colour[2], b) < 60,
            "{colour:?}"
        );
    }
}
