//! The observed surface's error as a smooth random field: each sample a
//! Gaussian process along the vertex normals with a squared-exponential
//! correlation, made of random Fourier features (Rahimi and Recht 2007),
//! zero on the exact (held) vertices and rising to full strength over one
//! correlation length away from them.

use std::f64::consts::TAU;

use glam::{DVec3, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use rstar::RTree;
use tissue_core::SurfaceMesh;
use tissue_core::deform::vertex_normals;

/// Fourier features per sample: the field's variance is one in
/// expectation, its correlation the squared exponential's within a few
/// percent.
pub const FEATURES: usize = 64;

/// The surface error's samples: each a copy of `surface` whose vertices
/// moved along their normals by a field of standard deviation `sigma` and
/// correlation length `length`, scaled down to zero on the `exact`
/// vertices (one flag per vertex) by `min(1, d / length)` for a vertex `d`
/// from the nearest exact one. The same `seed` gives the same samples.
pub struct SurfaceNoise<'a> {
    surface: &'a SurfaceMesh,
    /// Where the field is read for each vertex: the vertex itself, or
    /// where it was on a reference surface ([`SurfaceNoise::attached_to`]).
    at: Vec<DVec3>,
    normals: Vec<DVec3>,
    strength: Vec<f64>,
    /// The exact vertices, for the strength anywhere else.
    held: RTree<[f32; 3]>,
    sigma: f64,
    length: f64,
    random: Pcg64,
}

/// One sample of the field ([`SurfaceNoise::next_sample`]): its Fourier
/// features, each a wave vector and a phase.
#[derive(Debug, Clone)]
pub struct NoiseSample {
    features: Vec<(DVec3, f64)>,
}

impl<'a> SurfaceNoise<'a> {
    /// The field's setting on `surface`.
    pub fn new(
        surface: &'a SurfaceMesh,
        exact: &[bool],
        sigma: f32,
        length: f32,
        seed: u64,
    ) -> Self {
        let normals = vertex_normals(surface)
            .into_iter()
            .map(|n| n.as_dvec3().normalize_or_zero())
            .collect();
        let held: Vec<[f32; 3]> = surface
            .vertices
            .iter()
            .zip(exact.iter().chain(std::iter::repeat(&false)))
            .filter(|(_, e)| **e)
            .map(|(v, _)| v.to_array())
            .collect();
        let mut noise = Self {
            surface,
            at: surface.vertices.iter().map(|v| v.as_dvec3()).collect(),
            normals,
            strength: Vec::new(),
            held: RTree::bulk_load(held),
            sigma: f64::from(sigma),
            length: f64::from(length),
            random: Pcg64::seed_from_u64(seed),
        };
        noise.strength = surface
            .vertices
            .iter()
            .map(|&v| noise.strength_at(v))
            .collect();
        noise
    }

    /// The field read where each vertex lies on `reference` (the same
    /// vertices, elsewhere: the rest surface the surface is a deformation
    /// of), so that a sample's error belongs to the surface's points and
    /// moves with them from one deformation to the next. Unchanged where
    /// `reference` has another vertex count.
    pub fn attached_to(mut self, reference: &SurfaceMesh) -> Self {
        if reference.vertices.len() == self.surface.vertices.len() {
            self.at = reference.vertices.iter().map(|v| v.as_dvec3()).collect();
        }
        self
    }

    /// How much of the field acts at `x`: `min(1, d / length)` for `x` `d`
    /// from the nearest exact vertex, 1 where none is.
    fn strength_at(&self, x: Vec3) -> f64 {
        match self.held.nearest_neighbor(x.to_array()) {
            None => 1.0,
            Some(h) => (f64::from(Vec3::from(*h).distance(x)) / self.length).min(1.0),
        }
    }

    /// The next sample's features.
    pub fn next_sample(&mut self) -> NoiseSample {
        let features = (0..FEATURES)
            .map(|_| {
                let w = DVec3::new(
                    normal(&mut self.random),
                    normal(&mut self.random),
                    normal(&mut self.random),
                ) / self.length;
                (w, self.random.random::<f64>() * TAU)
            })
            .collect();
        NoiseSample { features }
    }

    /// The field's value of `sample` at `x` with the strength `strength`.
    fn value(&self, sample: &NoiseSample, x: DVec3, strength: f64) -> f64 {
        let amplitude = self.sigma * (2.0 / FEATURES as f64).sqrt();
        let field: f64 = sample
            .features
            .iter()
            .map(|(w, b)| (w.dot(x) + b).cos())
            .sum();
        amplitude * field * strength
    }

    /// How far `sample` moves a point at `x` along its normal: the same
    /// field, scaled down near the exact vertices as the surface's are
    /// (an observation's points, which are not the surface's vertices).
    pub fn offset(&self, sample: &NoiseSample, x: Vec3) -> f32 {
        self.value(sample, x.as_dvec3(), self.strength_at(x)) as f32
    }

    /// The surface with its vertices moved along their normals by `sample`
    /// (read where [`SurfaceNoise::attached_to`] put them).
    pub fn moved(&self, sample: &NoiseSample) -> SurfaceMesh {
        let mut moved = self.surface.clone();
        // A cosine per vertex and feature: on every thread.
        moved
            .vertices
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, v)| {
                let value = self.value(sample, self.at[i], self.strength[i]);
                *v = (v.as_dvec3() + self.normals[i] * value).as_vec3();
            });
        moved
    }

    /// The next sample: the surface moved by [`SurfaceNoise::next_sample`].
    pub fn sample(&mut self) -> SurfaceMesh {
        let sample = self.next_sample();
        self.moved(&sample)
    }
}

/// A standard normal number (Box and Muller).
fn normal(random: &mut Pcg64) -> f64 {
    let u: f64 = 1.0 - random.random::<f64>();
    let v: f64 = random.random();
    (-2.0 * u.ln()).sqrt() * (TAU * v).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tissue_core::phantom;

    /// Over many samples a free vertex moves with about the asked standard
    /// deviation along its normal, an exact one not at all, and the same
    /// seed gives the same samples.
    #[test]
    fn the_field_has_its_spread_and_spares_the_exact_vertices() {
        let surface = phantom::default_breast();
        let low = surface
            .vertices
            .iter()
            .map(|v| v.z)
            .fold(f32::INFINITY, f32::min);
        let exact: Vec<bool> = surface.vertices.iter().map(|v| v.z < low + 1e-3).collect();
        assert!(exact.iter().any(|&e| e));
        let mut noise = SurfaceNoise::new(&surface, &exact, 0.5, 10.0, 7);
        let samples: Vec<SurfaceMesh> = (0..200).map(|_| noise.sample()).collect();
        let top = surface
            .vertices
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.z.total_cmp(&b.1.z))
            .map(|(i, _)| i)
            .unwrap_or(0);
        let spread = (samples
            .iter()
            .map(|s| s.vertices[top].distance_squared(surface.vertices[top]))
            .sum::<f32>()
            / samples.len() as f32)
            .sqrt();
        assert!((0.4..0.6).contains(&spread), "{spread}");
        for (i, _) in exact.iter().enumerate().filter(|(_, e)| **e) {
            assert!(samples.iter().all(|s| s.vertices[i] == surface.vertices[i]));
        }
        let again = SurfaceNoise::new(&surface, &exact, 0.5, 10.0, 7).sample();
        assert_eq!(again.vertices, samples[0].vertices);
    }

    /// Attached to the rest surface, a sample moves each vertex of a
    /// deformed surface by the field where the vertex was at rest, along
    /// its deformed normal: a translated surface moves as the rest one
    /// does; unattached, the field is read where the vertices are now.
    #[test]
    fn an_attached_sample_moves_each_vertex_by_the_field_at_its_rest_place() {
        let rest = phantom::default_breast();
        let exact = vec![false; rest.vertices.len()];
        let mut shifted = rest.clone();
        for v in &mut shifted.vertices {
            *v += Vec3::new(7.0, -3.0, 2.0);
        }
        let mut at_rest = SurfaceNoise::new(&rest, &exact, 0.5, 10.0, 11);
        let sample = at_rest.next_sample();
        let attached = SurfaceNoise::new(&shifted, &exact, 0.5, 10.0, 11).attached_to(&rest);
        let unattached = SurfaceNoise::new(&shifted, &exact, 0.5, 10.0, 11);
        let offsets = |noise: &SurfaceNoise<'_>, surface: &SurfaceMesh| -> Vec<Vec3> {
            noise
                .moved(&sample)
                .vertices
                .iter()
                .zip(&surface.vertices)
                .map(|(m, v)| *m - *v)
                .collect()
        };
        let expected = offsets(&at_rest, &rest);
        let got = offsets(&attached, &shifted);
        let largest = expected.iter().map(|o| o.length()).fold(0.0, f32::max);
        assert!(largest > 0.1, "{largest}");
        for (i, (a, b)) in expected.iter().zip(&got).enumerate() {
            assert!((*a - *b).length() <= 1e-4, "vertex {i}: {a} against {b}");
        }
        let moved_off = offsets(&unattached, &shifted)
            .iter()
            .zip(&expected)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0, f32::max);
        assert!(moved_off > 0.1 * largest, "{moved_off}");
    }

    /// The moved surface is made on every thread: the same on one thread
    /// as on four, and each free vertex moved along its normal by the
    /// field's offset there.
    #[test]
    #[allow(clippy::expect_used, reason = "tests fail loudly on purpose")]
    fn a_sample_moves_the_surface_alike_on_any_number_of_threads() {
        let surface = phantom::default_breast();
        let exact = vec![false; surface.vertices.len()];
        let mut noise = SurfaceNoise::new(&surface, &exact, 0.5, 10.0, 3);
        let sample = noise.next_sample();
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool")
                .install(|| noise.moved(&sample))
        };
        let one = on(1);
        assert_eq!(one.vertices, on(4).vertices);
        assert_eq!(one.triangles, surface.triangles);
        for (i, (&v, &w)) in surface.vertices.iter().zip(&one.vertices).enumerate() {
            let along = f64::from(noise.offset(&sample, v));
            let moved = (w - v).as_dvec3();
            assert!(
                (moved - noise.normals[i] * along).length() <= 1e-5,
                "vertex {i}: moved {moved}, offset {along}"
            );
        }
        assert!(surface.vertices != one.vertices);
    }
}
