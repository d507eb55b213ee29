//! The cut both panels draw: the particles in a slab one particle thick
//! across the view, each coloured by a value.

use tiny_skia::{FillRule, Mask, Transform};

use super::{Canvas, HEIGHT, Scene, View, WIDTH, colour_map, mesh_path, rgba};

impl Canvas {
    /// The particles of `scene` in `view`'s slab, farthest first, each a
    /// disc of its radius inside the deformed skin, coloured by its value
    /// of `values` (one per particle; zero past the end) from zero to the
    /// largest finite one, which it returns (the colour bar's top).
    pub(super) fn cut(&mut self, scene: &Scene<'_>, view: &View, values: &[f32]) -> f32 {
        let largest = values
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0, f32::max);
        let inside = mesh_path(scene.surface, view).and_then(|skin| {
            let mut mask = Mask::new(WIDTH, HEIGHT)?;
            mask.fill_path(&skin, FillRule::Winding, true, Transform::identity());
            Some(mask)
        });
        let mut slab: Vec<usize> = (0..scene.current.len())
            .filter(|&i| (scene.current[i][view.depth] - view.cut).abs() <= view.half)
            .collect();
        slab.sort_by(|&a, &b| {
            view.nearness(scene.current[a])
                .total_cmp(&view.nearness(scene.current[b]))
        });
        for &i in &slab {
            let at = view.to_screen(scene.current[i]);
            let radius = (scene.radii[i] * view.scale).max(1.0);
            let value = values.get(i).copied().unwrap_or(0.0);
            let [r, g, b] = colour_map(value / largest.max(f32::MIN_POSITIVE));
            self.fill_masked(rgba(r, g, b, 255), inside.as_ref(), |path| {
                path.push_circle(at.x, at.y, radius);
            });
        }
        largest
    }
}
