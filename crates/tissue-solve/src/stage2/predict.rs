//! Tracking: where a new frame's solve starts, from the surface's move and
//! the last frames' changes.

use glam::{DMat3, DVec3, Mat3, Vec3};
use rayon::prelude::*;
use tissue_core::field::SurfaceField;

use crate::stage2::pairing::Pairing;

/// The converged solutions of the last frames, oldest first, from which
/// [`predict`] takes the changes it fits a new frame's surface move with.
/// A solve that did not converge clears it: its state is no change worth
/// repeating.
#[derive(Debug, Clone, Default)]
pub struct FrameHistory {
    solutions: std::collections::VecDeque<Vec<Vec3>>,
}

impl FrameHistory {
    /// The history of a model at rest: the rest shape is a solved frame
    /// (the exact answer for the rest surface), so the first solve's change
    /// from it already gives the second frame a shape to fit
    /// (docs/METHOD.md, "The rest shape is a solved frame").
    pub fn at_rest(rest: &[Vec3], depth: usize) -> Self {
        let mut history = Self::default();
        history.record(rest, true, depth);
        history
    }

    /// Keeps `solution` (when `converged`) and the `depth` solutions
    /// before it, which give `depth` changes.
    pub fn record(&mut self, solution: &[Vec3], converged: bool, depth: usize) {
        if !converged || depth == 0 {
            self.solutions.clear();
            return;
        }
        let mut kept = Vec::new();
        while self.solutions.len() > depth {
            kept = self.solutions.pop_front().unwrap_or_default();
        }
        kept.clear();
        kept.extend_from_slice(solution);
        self.solutions.push_back(kept);
    }

    /// Forgets every frame (a reset, or a new model state).
    pub fn clear(&mut self) {
        self.solutions.clear();
    }

    /// Whether no solution is kept (after a solve that did not converge).
    pub fn is_empty(&self) -> bool {
        self.solutions.is_empty()
    }

    /// The number of frame-to-frame changes kept.
    pub fn changes(&self) -> usize {
        self.solutions.len().saturating_sub(1)
    }

    /// Starts again from two solutions: `from`, a converged state, and
    /// `to`, the answer reached from it (a solve of several stages whose
    /// stages' answers are no frames of their own), when `depth` keeps a
    /// change.
    pub fn restart(&mut self, from: &[Vec3], to: &[Vec3], depth: usize) {
        self.solutions.clear();
        self.record(from, true, depth);
        self.record(to, true, depth);
    }

    /// `(earlier, later)` solution pairs, newest first.
    fn pairs(&self) -> impl Iterator<Item = (&[Vec3], &[Vec3])> {
        let s = &self.solutions;
        (1..s.len())
            .rev()
            .map(move |k| (s[k - 1].as_slice(), s[k].as_slice()))
    }
}

/// Where a new frame's solve starts: the current state carried along by the
/// surface's move, plus what the last frames' changes say about its
/// non-affine part. `controls` are the control particles' new positions;
/// `current` is the last solution (the newest in `history`, if any).
///
/// - `A`, the least-squares affine map of the control points from where
///   they are in `current` to where they go, carries every particle:
///   `A(q)`. Exact for a rigid or affine move, of the sequence or of the frame.
/// - The rest of the control points' move, `r = controls - A(current)`, is
///   fitted in least squares by the non-affine parts of the last frames'
///   changes at the control points: `r ~ sum_k beta_k d_k`, where `d_k` is
///   change `k` less the least-squares affine function of the *current*
///   control positions closest to it. One base for every change and for
///   `r` keeps the fit exact for moves in the span of the changes: with
///   fitted each on its own base (the positions the change started from),
///   the affine parts of a sag and an indentation mixed at two rhythms left
///   3-7 % of the move unfitted. With the rotations fixed the interior's
///   answer is linear in the surface's move, so every particle gets
///   `sum_k beta_k d_k` too. A sag growing by the same step gets `beta = 1`
///   (constant velocity); a breathing one the ratio of this step to the
///   last, negative where it turns.
/// - A change whose control part is below `noise` (the solve's tolerance,
///   as a length) everywhere is left out: it is affine, and its interior is
///   what the last solves left undone; extrapolating that made the error
///   grow frame after frame. So is a change the ones before it (newer)
///   nearly explain already (a hundredth of its length left), which would
///   otherwise amplify their noise. A tenth, as before the common base,
///   dropped the older change of a sag and an indentation mixed at two
///   rhythms (their changes differ by a few degrees at the surface); a
///   floor from the solve's tolerance dropped the single change of a slow
///   sag (docs/METHOD.md).
///
/// Returns the predicted positions and `L` (the identity when the control
/// points do not determine `A`, and nothing moves).
pub fn predict(
    current: &[Vec3],
    history: &FrameHistory,
    controls: &[(usize, Vec3)],
    noise: f32,
) -> (Vec<Vec3>, Mat3) {
    let from: Vec<Vec3> = controls.iter().map(|&(i, _)| current[i]).collect();
    let to: Vec<Vec3> = controls.iter().map(|&(_, q)| q).collect();
    let Some((linear, shift)) = affine_fit(&from, &to) else {
        return (current.to_vec(), Mat3::IDENTITY);
    };
    let carried = |q: Vec3| linear * q + shift;
    let changes: Vec<Vec<Vec3>> = history
        .pairs()
        .filter_map(|(earlier, later)| {
            let moved: Vec<Vec3> = controls
                .iter()
                .map(|&(i, _)| current[i] + (later[i] - earlier[i]))
                .collect();
            let (l, t) = affine_fit(&from, &moved)?;
            let d: Vec<Vec3> = earlier
                .par_iter()
                .zip(later)
                .zip(current)
                .map(|((&e, &q), &c)| (q - e) - (l * c + t - c))
                .collect();
            controls
                .iter()
                .any(|&(i, _)| d[i].length() >= noise)
                .then_some(d)
        })
        .collect();
    let flat = |points: &mut dyn Iterator<Item = Vec3>| -> Vec<f64> {
        points
            .flat_map(|p| p.as_dvec3().to_array())
            .collect::<Vec<f64>>()
    };
    let target = flat(&mut from.iter().zip(&to).map(|(&f, &t)| t - carried(f)));
    let columns: Vec<Vec<f64>> = changes
        .iter()
        .map(|d| flat(&mut controls.iter().map(|&(i, _)| d[i])))
        .collect();
    let beta = least_squares(&columns, &target, 0.01);
    let predicted = current
        .par_iter()
        .enumerate()
        .map(|(i, &q)| {
            let fitted: Vec3 = changes
                .iter()
                .zip(&beta)
                .map(|(d, &b)| b as f32 * d[i])
                .sum();
            carried(q) + fitted
        })
        .collect();
    (predicted, linear)
}

/// Where a tracking frame matched to an observation without
/// correspondence starts: the last answer `current` plus the combination
/// of the last frames' changes that brings its paired skin closest to the
/// observation, `current + sum_k beta_k d_k`. Nothing moves the control
/// points (the held region stays), so the changes themselves are the
/// basis: `beta` minimises the springs' potential
/// `sum_i (q_i - c_i)^T P_i (q_i - c_i) / 2` over the skin `pairing`
/// pairs on `field`, paired again at the prediction `rounds` times (the
/// springs move as the skin does). A sag growing by the same step gets
/// `beta = 1`, as a frame with correspondence does ([`predict`]). As
/// there, a change that moved no paired particle by `noise` (the solve's
/// tolerance as a length) is left out (a frame that did not move: its
/// change is what the solve left undone), and one with less than a
/// hundredth of its length (in the springs' norm) outside the newer ones'
/// span gets `beta = 0`. `None` where no change is left.
pub fn predict_paired(
    current: &[Vec3],
    history: &FrameHistory,
    field: &SurfaceField,
    pairing: &Pairing,
    rounds: usize,
    noise: f32,
) -> Option<Vec<Vec3>> {
    let changes: Vec<Vec<Vec3>> = history
        .pairs()
        .map(|(earlier, later)| -> Vec<Vec3> {
            later.iter().zip(earlier).map(|(&l, &e)| l - e).collect()
        })
        .filter(|d| {
            pairing
                .skin
                .iter()
                .any(|&i| d[i as usize].length() >= noise)
        })
        .collect();
    if changes.is_empty() {
        return None;
    }
    let count = changes.len();
    let moved = |beta: &[f64]| -> Vec<Vec3> {
        current
            .par_iter()
            .enumerate()
            .map(|(i, &q)| {
                q + changes
                    .iter()
                    .zip(beta)
                    .map(|(d, &b)| b as f32 * d[i])
                    .sum::<Vec3>()
            })
            .collect()
    };
    let mut at = current.to_vec();
    let mut fitted = None;
    for _ in 0..rounds.max(1) {
        let springs = pairing.springs(field, &at);
        // The normal equations `G beta = r` in the springs' norm, over the
        // paired skin: each particle's part made in parallel, summed in
        // index order (the same `beta` whatever the threads).
        let parts: Vec<(Vec<f64>, Vec<f64>)> = pairing
            .skin
            .par_iter()
            .map(|&i| {
                let i = i as usize;
                let spring = springs[i];
                let mut gram = vec![0.0; count * count];
                let mut right = vec![0.0; count];
                if spring.is_zero() {
                    return (gram, right);
                }
                let pulls: Vec<DVec3> = changes
                    .iter()
                    .map(|d| spring.times_f64(d[i].as_dvec3()))
                    .collect();
                let gap = (spring.point_of() - current[i]).as_dvec3();
                for k in 0..count {
                    right[k] = pulls[k].dot(gap);
                    for l in 0..count {
                        gram[k * count + l] = pulls[k].dot(changes[l][i].as_dvec3());
                    }
                }
                (gram, right)
            })
            .collect();
        let mut gram = vec![0.0; count * count];
        let mut right = vec![0.0; count];
        for (g, r) in &parts {
            gram.iter_mut().zip(g).for_each(|(a, b)| *a += b);
            right.iter_mut().zip(r).for_each(|(a, b)| *a += b);
        }
        let beta = solve_gram(&gram, &right, count, 1e-4)?;
        at = moved(&beta);
        fitted = Some(beta);
    }
    fitted.map(|_| at)
}

/// `G beta = r` for a symmetric positive semidefinite `G` (`count` by
/// `count`, row-major) by a Cholesky factor taken column by column in
/// order: a column whose pivot falls below `keep` of its diagonal (less
/// than `sqrt(keep)` of its length outside the span of the columns before
/// it) gets `beta = 0`. `None` where every column is dropped.
fn solve_gram(gram: &[f64], right: &[f64], count: usize, keep: f64) -> Option<Vec<f64>> {
    let mut factor = vec![0.0_f64; count * count];
    let mut kept = vec![false; count];
    for j in 0..count {
        let diagonal = gram[j * count + j];
        let pivot = diagonal - (0..j).map(|k| factor[j * count + k].powi(2)).sum::<f64>();
        if !(diagonal > 0.0 && pivot > keep * diagonal) {
            continue;
        }
        kept[j] = true;
        let root = pivot.sqrt();
        factor[j * count + j] = root;
        for i in j + 1..count {
            let dot: f64 = (0..j)
                .map(|k| factor[i * count + k] * factor[j * count + k])
                .sum();
            factor[i * count + j] = (gram[i * count + j] - dot) / root;
        }
    }
    if !kept.contains(&true) {
        return None;
    }
    // Forward and back substitution over the kept columns.
    let mut y = vec![0.0; count];
    for i in (0..count).filter(|&i| kept[i]) {
        let dot: f64 = (0..i)
            .filter(|&k| kept[k])
            .map(|k| factor[i * count + k] * y[k])
            .sum();
        y[i] = (right[i] - dot) / factor[i * count + i];
    }
    let mut beta = vec![0.0; count];
    for i in (0..count).rev().filter(|&i| kept[i]) {
        let dot: f64 = (i + 1..count)
            .filter(|&k| kept[k])
            .map(|k| factor[k * count + i] * beta[k])
            .sum();
        beta[i] = (y[i] - dot) / factor[i * count + i];
    }
    beta.iter().all(|b| b.is_finite()).then_some(beta)
}

/// The coefficients `beta` minimising `|target - sum_k beta_k columns_k|`,
/// by modified Gram-Schmidt. A column with less than `keep` of its length
/// outside the span of the columns before it gets `beta = 0`: nearly
/// dependent columns would only amplify their noise.
fn least_squares(columns: &[Vec<f64>], target: &[f64], keep: f64) -> Vec<f64> {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    // The kept columns' orthonormal basis, their column of R, and index.
    let mut basis: Vec<Vec<f64>> = Vec::new();
    let mut r: Vec<Vec<f64>> = Vec::new();
    let mut kept: Vec<usize> = Vec::new();
    for (k, column) in columns.iter().enumerate() {
        let length = dot(column, column).sqrt();
        let mut v = column.clone();
        let mut coefficients = Vec::with_capacity(basis.len() + 1);
        for q in &basis {
            let c = dot(q, &v);
            v.iter_mut().zip(q).for_each(|(v, q)| *v -= c * q);
            coefficients.push(c);
        }
        let rest = dot(&v, &v).sqrt();
        if !(length > 0.0 && rest > keep * length) {
            continue;
        }
        v.iter_mut().for_each(|v| *v /= rest);
        coefficients.push(rest);
        basis.push(v);
        r.push(coefficients);
        kept.push(k);
    }
    let y: Vec<f64> = basis.iter().map(|q| dot(q, target)).collect();
    let mut solved = vec![0.0; kept.len()];
    for i in (0..kept.len()).rev() {
        let later: f64 = (i + 1..kept.len()).map(|j| r[j][i] * solved[j]).sum();
        solved[i] = (y[i] - later) / r[i][i];
    }
    let mut beta = vec![0.0; columns.len()];
    for (k, b) in kept.into_iter().zip(solved) {
        beta[k] = b;
    }
    beta
}

/// The affine map `x -> L x + t` that moves the points `from` closest to
/// `to` in least squares, in `f64`; `None` when the points do not span 3D
/// well enough to determine it (fewer than four, or nearly coplanar).
pub fn affine_fit(from: &[Vec3], to: &[Vec3]) -> Option<(Mat3, Vec3)> {
    if from.len() != to.len() || from.len() < 4 {
        return None;
    }
    let count = from.len() as f64;
    let mean = |points: &[Vec3]| points.iter().map(|p| p.as_dvec3()).sum::<DVec3>() / count;
    let (from_mean, to_mean) = (mean(from), mean(to));
    let mut spread = DMat3::ZERO;
    let mut cross = DMat3::ZERO;
    for (a, b) in from.iter().zip(to) {
        let a = a.as_dvec3() - from_mean;
        let b = b.as_dvec3() - to_mean;
        spread += outer(a, a);
        cross += outer(b, a);
    }
    // Nearly coplanar points leave the map along the normal undetermined:
    // a condition number of 1e8 in the spread is about 1e4 in distances.
    let trace = spread.x_axis.x + spread.y_axis.y + spread.z_axis.z;
    let determinant = spread.determinant();
    if !(trace > 0.0 && determinant > 1e-24 * trace * trace * trace) {
        return None;
    }
    let linear = cross * spread.inverse();
    let shift = to_mean - linear * from_mean;
    let linear = linear.as_mat3();
    let shift = shift.as_vec3();
    (linear.is_finite() && shift.is_finite()).then_some((linear, shift))
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path of `n` free nodes between two fixed ends: eigenvalues
    /// `2 - 2 cos(k pi / (n + 1))`, k = 1..n.
    #[test]
    fn an_affine_fit_recovers_an_affine_map_and_refuses_flat_points() {
        let linear = Mat3::from_cols(
            Vec3::new(1.1, 0.2, -0.1),
            Vec3::new(-0.3, 0.9, 0.05),
            Vec3::new(0.0, 0.4, 1.3),
        );
        let shift = Vec3::new(5.0, -2.0, 30.0);
        let from: Vec<Vec3> = (0..50)
            .map(|k| {
                let k = k as f32;
                Vec3::new((k * 1.3).sin(), (k * 0.7).cos(), (k * 0.37).sin()) * 40.0
            })
            .collect();
        let to: Vec<Vec3> = from.iter().map(|&p| linear * p + shift).collect();
        let Some((l, t)) = affine_fit(&from, &to) else {
            panic!("no fit through 50 points in general position");
        };
        assert!(l.abs_diff_eq(linear, 1e-5), "{l} vs {linear}");
        assert!(t.abs_diff_eq(shift, 1e-3), "{t} vs {shift}");
        let flat: Vec<Vec3> = from.iter().map(|p| Vec3::new(p.x, p.y, 0.0)).collect();
        assert_eq!(affine_fit(&flat, &to), None);
        assert_eq!(affine_fit(&from[..3], &to[..3]), None);
    }

    /// Eight control points on a unit cube's corners and two free particles
    /// inside; `bulge` and `dent` are two non-affine moves (a corner pulled
    /// out, another pushed in) with what they do to the free particles.
    fn cube() -> (Vec<Vec3>, [Vec<Vec3>; 2]) {
        let mut rest: Vec<Vec3> = (0..8)
            .map(|k| Vec3::new((k & 1) as f32, (k >> 1 & 1) as f32, (k >> 2) as f32))
            .collect();
        rest.extend([Vec3::splat(0.3), Vec3::splat(0.7)]);
        let mut bulge = vec![Vec3::ZERO; 10];
        bulge[7] = Vec3::splat(0.02);
        bulge[9] = Vec3::splat(0.01);
        let mut dent = vec![Vec3::ZERO; 10];
        dent[0] = Vec3::new(0.0, 0.0, 0.03);
        dent[8] = Vec3::new(0.0, 0.0, 0.012);
        (rest, [bulge, dent])
    }

    /// `rest + a bulge + b dent`, then translated by `shift`.
    fn cube_state(a: f32, b: f32, shift: Vec3) -> Vec<Vec3> {
        let (rest, [bulge, dent]) = cube();
        (0..rest.len())
            .map(|i| rest[i] + a * bulge[i] + b * dent[i] + shift)
            .collect()
    }

    fn history_of(states: &[Vec<Vec3>]) -> FrameHistory {
        let mut history = FrameHistory::default();
        for state in states {
            history.record(state, true, states.len() - 1);
        }
        history
    }

    fn controls_of(state: &[Vec3]) -> Vec<(usize, Vec3)> {
        (0..8).map(|i| (i, state[i])).collect()
    }

    #[test]
    fn a_prediction_fits_the_surface_move_with_the_last_changes() {
        // A bulge growing by 1, then by 0.5, then turning back by 0.75, with
        // a translation on top: the free particles follow by the same
        // fraction of the last change (constant velocity would say +1),
        // exactly (to rounding): every change is fitted on the same base.
        let shift = Vec3::new(0.5, -0.2, 0.1);
        let states = [
            cube_state(0.0, 0.0, Vec3::ZERO),
            cube_state(1.0, 0.0, Vec3::ZERO),
        ];
        let history = history_of(&states);
        assert_eq!(history.changes(), 1);
        for step in [1.0, 0.5, -0.75] {
            let next = cube_state(1.0 + step, 0.0, shift);
            let (predicted, _) = predict(&states[1], &history, &controls_of(&next), 1e-4);
            for i in 8..10 {
                assert!(
                    predicted[i].distance(next[i]) < 1e-6,
                    "step {step}, particle {i}: {} vs {}",
                    predicted[i],
                    next[i]
                );
            }
        }
        // Two changes of two shapes (a bulge, then a dent) fit a move of both.
        let states = [
            cube_state(0.0, 0.0, Vec3::ZERO),
            cube_state(1.0, 0.0, Vec3::ZERO),
            cube_state(1.0, 1.0, Vec3::ZERO),
        ];
        let history = history_of(&states);
        assert_eq!(history.changes(), 2);
        let next = cube_state(0.6, 1.5, shift);
        let (predicted, _) = predict(&states[2], &history, &controls_of(&next), 1e-4);
        for i in 8..10 {
            assert!(
                predicted[i].distance(next[i]) < 1e-6,
                "particle {i}: {} vs {}",
                predicted[i],
                next[i]
            );
        }
    }

    #[test]
    fn a_prediction_leaves_out_changes_affine_on_the_surface() {
        // The control points only translate from frame to frame while a free
        // particle drifts (what a solve leaves undone): the drift is not
        // extrapolated, however large, and the next frame is carried by the
        // affine map alone.
        let mut earlier = cube_state(0.0, 0.0, Vec3::ZERO);
        let mut last = cube_state(0.0, 0.0, Vec3::X);
        earlier[8] += Vec3::Y * 0.1;
        last[8] += Vec3::Y * 0.2;
        let history = history_of(&[earlier, last.clone()]);
        let next = cube_state(0.0, 0.0, 2.0 * Vec3::X);
        let (predicted, _) = predict(&last, &history, &controls_of(&next), 1e-3);
        assert!(
            predicted[8].abs_diff_eq(last[8] + Vec3::X, 1e-5),
            "{} vs {}",
            predicted[8],
            last[8] + Vec3::X
        );
    }

    #[test]
    fn frame_history_keeps_depth_changes_and_forgets_on_divergence() {
        let state = |k: f32| vec![Vec3::splat(k); 3];
        let mut history = FrameHistory::default();
        for k in 0..5 {
            history.record(&state(k as f32), true, 2);
        }
        assert_eq!(history.changes(), 2);
        let newest: Vec<f32> = history.pairs().map(|(_, later)| later[0].x).collect();
        assert_eq!(newest, [4.0, 3.0]);
        history.record(&state(5.0), true, 1);
        assert_eq!(history.changes(), 1);
        history.record(&state(6.0), false, 2);
        assert_eq!(history.changes(), 0);
        history.record(&state(7.0), true, 0);
        assert_eq!(history.changes(), 0);
        // At rest, the rest shape is the first solved frame.
        let mut history = FrameHistory::at_rest(&state(0.0), 2);
        assert_eq!(history.changes(), 0);
        history.record(&state(1.0), true, 2);
        let firsts: Vec<f32> = history.pairs().map(|(e, l)| l[0].x - e[0].x).collect();
        assert_eq!(firsts, [1.0]);
        assert_eq!(FrameHistory::at_rest(&state(0.0), 0).changes(), 0);
    }

    /// A scanned plane `z = height` (points half a unit apart) as an
    /// observation, and a patch of skin under it paired with it.
    fn plane_scan(height: f32) -> (SurfaceField, Pairing) {
        let points: Vec<Vec3> = (0..=40)
            .flat_map(|x| (0..=40).map(move |y| Vec3::new(x as f32 * 0.5, y as f32 * 0.5, height)))
            .collect();
        let Ok(cloud) = crate::stage2::observation::Cloud::new(points) else {
            panic!("a plane's points make no cloud");
        };
        let Ok(field) = cloud.field(8.0) else {
            panic!("a plane's cloud makes no field");
        };
        let rule = crate::stage2::pairing::PairingRule {
            weight: 1.0,
            edge: 1.0,
            robust: crate::stage2::pairing::NO_LIMIT,
            cloud: true,
            smooth: 0.5,
        };
        let pairing = Pairing {
            skin: (0..25).collect(),
            rule,
        };
        (field, pairing)
    }

    /// The skin: 25 particles on a grid at height `z`, shifted along x by
    /// `x`.
    fn skin_at(x: f32, z: f32) -> Vec<Vec3> {
        (0..25)
            .map(|k| Vec3::new(6.0 + (k % 5) as f32 + x, 6.0 + (k / 5) as f32, z))
            .collect()
    }

    #[test]
    fn a_paired_prediction_carries_the_last_change_onto_the_observation() {
        // The skin rose by 1 (sliding 0.3 along x) in the last frame; the
        // scan now lies 2 above it: twice the change, slide included.
        let mut history = FrameHistory::at_rest(&skin_at(0.0, 0.0), 2);
        history.record(&skin_at(0.3, 1.0), true, 2);
        let (field, pairing) = plane_scan(3.0);
        let current = skin_at(0.3, 1.0);
        let Some(predicted) = predict_paired(&current, &history, &field, &pairing, 3, 1e-4) else {
            panic!("no prediction from one change");
        };
        for (p, q) in predicted.iter().zip(skin_at(0.9, 3.0)) {
            assert!(p.abs_diff_eq(q, 1e-4), "{p} against {q}");
        }
        // A frame that did not move (the newest change below the noise)
        // is left out; the one before it still predicts.
        history.record(&current, true, 2);
        let Some(again) = predict_paired(&current, &history, &field, &pairing, 3, 1e-4) else {
            panic!("no prediction past a frame that did not move");
        };
        for (p, q) in again.iter().zip(skin_at(0.9, 3.0)) {
            assert!(p.abs_diff_eq(q, 1e-4), "{p} against {q}");
        }
        // Nothing that moved, nothing to predict with.
        let still = FrameHistory::at_rest(&current, 2);
        assert!(predict_paired(&current, &still, &field, &pairing, 3, 1e-4).is_none());
    }

    #[test]
    fn the_gram_solve_gives_a_dependent_column_nothing() {
        // Columns d and 2d with r = G's first column times 3: beta (3, 0).
        let gram = [1.0, 2.0, 2.0, 4.0];
        assert_eq!(
            solve_gram(&gram, &[3.0, 6.0], 2, 1e-4),
            Some(vec![3.0, 0.0])
        );
        // Independent columns: the exact solution.
        let gram = [2.0, 1.0, 1.0, 3.0];
        let Some(beta) = solve_gram(&gram, &[4.0, 7.0], 2, 1e-4) else {
            panic!("no solution with independent columns");
        };
        assert!(
            (beta[0] - 1.0).abs() < 1e-12 && (beta[1] - 2.0).abs() < 1e-12,
            "{beta:?}"
        );
        assert!(solve_gram(&[0.0], &[1.0], 1, 1e-4).is_none());
    }
}
