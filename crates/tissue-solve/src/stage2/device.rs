//! What a device implements for a stage-2 solve ([`SolveDevice`]) and what
//! every iteration of one runs with ([`Iteration`]): the seam between the
//! device-neutral [`crate::stage2::tracker::Tracker`] and a device's kernels and
//! buffers.

use glam::{Mat3, Vec3};
use tissue_core::field::SurfaceField;

use crate::coarse::laplacian::SharedLaplacian;
use crate::stage2::pairing::Pairing;
use crate::stage2::params::{DeformParams, ForceModel, RotationMethod};
use crate::stage2::plan::Plan;

/// What every iteration of one solve runs with, from the plan and the
/// parameters at its start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Iteration {
    /// The force model.
    pub force: ForceModel,
    /// How the rotations are found.
    pub rotations: RotationMethod,
    /// The step `alpha = sigma / m` ([`crate::stage2::plan::Plan::alpha`]).
    pub alpha: f32,
    /// `c alpha`, what turns an error into the plain step ([`crate::stage2::plan::Plan::contraction`]).
    pub contraction: f32,
    /// Whether the device applies its correction: with the symmetric and
    /// the paper's force the Laplacian's coarse space, with the elastic force the elastic operator's, where the
    /// device has one (the Laplacian's is never applied to it).
    pub correct: bool,
    /// An elastic phase that starts from a state of its own (after the
    /// shear phase), not from the last elastic solve: a device whose
    /// elastic correction is linearised at a state makes it again here.
    pub relinearise: bool,
    /// The fraction of the volume smoother's two-level step a smoothed
    /// elastic iteration takes (the device scales its residual by it): 1,
    /// halved each time a watched phase steps back
    /// ([`crate::stage2::phase::MAX_BACKTRACKS`]). The other iterations
    /// ignore it.
    pub damping: f32,
}

/// The potential at one state ([`SolveDevice::potential`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Potential {
    /// The sum of the particles' parts.
    pub value: f64,
    /// The sum of their magnitudes: the scale of the rounding in `value`,
    /// whose parts a device may make in `f32`.
    pub magnitude: f64,
    /// Where the skin is paired with an observation, the potential at
    /// these positions under the pairing kept with the state
    /// [`SolveDevice::save`] kept (each particle's spring as it was paired
    /// there), summed as `value`: what the energy watch compares with that
    /// state's `value`, both under one pairing. `value` where nothing is
    /// paired.
    pub held: f64,
}

impl Potential {
    /// The potential of `parts`, summed in index order; `held` the same.
    pub fn of(parts: impl IntoIterator<Item = f64>) -> Self {
        let (value, magnitude) = parts
            .into_iter()
            .fold((0.0, 0.0), |(value, magnitude): (f64, f64), part| {
                (value + part, magnitude + part.abs())
            });
        Self {
            value,
            magnitude,
            held: value,
        }
    }

    /// The potential of `parts` (paired at these positions), `held` that of
    /// `held_parts` (under the kept state's pairing), each summed in index
    /// order.
    pub fn paired(parts: impl IntoIterator<Item = f64>, held_parts: &[f64]) -> Self {
        Self {
            held: held_parts.iter().sum(),
            ..Self::of(parts)
        }
    }
}

/// What the conjugate-gradient elastic phase reads at the current
/// positions ([`SolveDevice::descent_residual`]): sums over the particles
/// of their parts, each part made in `f32` or better and summed in `f64` in
/// index order ([`DescentDots::of`]), so every device adds the same way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DescentDots {
    /// `r . z`: the residual against the two-level step at these positions.
    pub residual_step: f64,
    /// `z . r'`: the step against the residual of the call before.
    pub step_last_residual: f64,
    /// `r . d'`: the residual against the last direction.
    pub residual_last_direction: f64,
    /// `max |z_i|`: the two-level step's largest move of one particle.
    pub step_largest: f32,
}

impl DescentDots {
    /// The sums of per-particle `parts`: `(r_i . z_i, z_i . r'_i,
    /// r_i . d'_i, |z_i|)`, the first three added in index order, the
    /// largest of the last.
    pub fn of(parts: impl IntoIterator<Item = [f64; 4]>) -> Self {
        parts.into_iter().fold(
            Self {
                residual_step: 0.0,
                step_last_residual: 0.0,
                residual_last_direction: 0.0,
                step_largest: 0.0,
            },
            |sum, [rz, zr, rd, z]| Self {
                residual_step: sum.residual_step + rz,
                step_last_residual: sum.step_last_residual + zr,
                residual_last_direction: sum.residual_last_direction + rd,
                step_largest: sum.step_largest.max(z as f32),
            },
        )
    }
}

/// What a device does for a stage-2 solve: kernels and buffers, nothing
/// else. The iteration is the same on every device: rotations, force, the
/// plain step, the correction (a coarse space, if any), the
/// Chebyshev combine; its state is `current` and `previous` positions and
/// the rotations.
pub trait SolveDevice {
    /// The device's error (`std::convert::Infallible` where nothing can fail).
    type Error;

    /// The most iterations one [`SolveDevice::run`] may be asked for.
    fn batch(&self) -> usize;

    /// The two-level iteration's contraction, where the device runs one.
    fn coarse_rho(&self) -> Option<f32> {
        None
    }

    /// The contraction of the elastic phase's iteration where the device
    /// corrects it (asked after [`SolveDevice::begin`] of an elastic phase);
    /// `None` runs it on the plan's rate for the elastic operator.
    fn elastic_rho(&self) -> Option<f32> {
        None
    }

    /// Whether the device's corrected elastic phases smooth with the
    /// volume smoother (known from its preparation): the shear phase
    /// before one then also stops on the volumes' misfit
    /// ([`crate::stage2::params::SolverTuning::shear_volume_share`]). The plain elastic step is
    /// set from the stiffness at rest and needs the shear phase's whole
    /// way: every neighbourhood near its rest volume (on the phantom poked
    /// 40 mm deep at 2,000 particles, the uncorrected phase
    /// diverged once more after a shear phase stopped at half the misfit).
    fn volume_smoother(&self) -> bool {
        false
    }

    /// Whether the elastic phase (asked after [`SolveDevice::begin`] of
    /// one) runs the volume smoother, whose contraction
    /// ([`SolveDevice::elastic_rho`]) is measured closely enough for the
    /// accelerated stopping rule ([`crate::stage2::acceleration::StoppingRule::accelerated`]).
    fn elastic_smoothed(&self) -> bool {
        false
    }

    /// Sets every particle's position at a frame boundary (the prediction
    /// and the control points). `turn`, when the positions were carried by
    /// the surface's linear move, is that move's rotation: warm-started
    /// rotations turn with it.
    fn write_positions(
        &mut self,
        positions: &[Vec3],
        turn: Option<Mat3>,
    ) -> Result<(), Self::Error>;

    /// Sets every particle's spring towards the observation (the plan's,
    /// [`crate::stage2::plan::Plan::set_springs`]: one per particle, or none
    /// to take them away): the elastic force's next iterations pull with
    /// them, and its correction is made again with them at the next
    /// elastic phase's start.
    fn set_springs(
        &mut self,
        springs: &[crate::stage2::springs::Spring],
    ) -> Result<(), Self::Error>;

    /// [`SolveDevice::set_springs`] with the elastic correction in hand
    /// kept whatever the springs' stiffness: made with earlier springs at
    /// an earlier state, it is a preconditioner for springs that change
    /// little (a tracking sequence's next scan, paired as the last one
    /// was), as within a solve whose pairing turns the springs. Where no
    /// correction is in hand, or a device keeps none, as
    /// [`SolveDevice::set_springs`].
    fn set_springs_keeping_correction(
        &mut self,
        springs: &[crate::stage2::springs::Spring],
    ) -> Result<(), Self::Error> {
        self.set_springs(springs)
    }

    /// Sets every particle's body force (the plan's loads,
    /// [`crate::stage2::plan::Plan::set_load`]: one per particle, or none):
    /// the next iterations' plain steps and potentials take them; the
    /// state is kept.
    fn set_loads(&mut self, loads: &[Vec3]) -> Result<(), Self::Error>;

    /// Holds the observation the skin is paired with (its nearest points'
    /// field: a surface's, or a point cloud's), or none.
    fn set_observation(&mut self, field: Option<&SurfaceField>) -> Result<(), Self::Error>;

    /// Sets how the elastic force's iterations pair the skin with the
    /// observation held ([`crate::stage2::plan::Plan::set_pairing`]), or
    /// none: with both, each such iteration runs [`crate::stage2::Pass::Pair`]
    /// first, and the springs it writes act in that iteration and stay
    /// until the next one writes them.
    fn set_pairing(&mut self, pairing: Option<&Pairing>) -> Result<(), Self::Error>;

    /// Starts a solve from the current positions (`previous = current`)
    /// whose iterations run with `iteration`.
    fn begin(&mut self, iteration: Iteration) -> Result<(), Self::Error>;

    /// Runs one iteration per Chebyshev weight in `omegas` (at most
    /// [`SolveDevice::batch`]) and returns, per iteration, the largest and
    /// the RMS step the stopping rule measures. Keeps what
    /// [`SolveDevice::replay`] needs.
    fn run(&mut self, omegas: &[f32]) -> Result<Vec<(f32, f32)>, Self::Error>;

    /// Puts the state back where the last [`SolveDevice::run`] started and
    /// runs its first `count` iterations again, with the same weights: the
    /// stopping rule held inside the batch.
    fn replay(&mut self, count: usize) -> Result<(), Self::Error>;

    /// The current positions.
    fn read_positions(&mut self) -> Result<Vec<Vec3>, Self::Error>;

    /// Back to the rest shape, rotations included.
    fn reset(&mut self) -> Result<(), Self::Error>;

    /// Every particle's rotation (rest offsets onto current offsets) as
    /// the last iteration left it: what carries points with the particles.
    fn read_rotations(&mut self) -> Result<Vec<Mat3>, Self::Error>;

    /// A copy of the device in the state it is in, which solves as this
    /// one would from here and apart from it (so that independent solves
    /// may run side by side); `None` where the device cannot copy its state
    /// cheaply.
    fn fork(&self) -> Option<Self>
    where
        Self: Sized,
    {
        None
    }

    /// Sets every particle's rotation: a state read back earlier
    /// ([`SolveDevice::read_rotations`]) put back with its positions.
    fn write_rotations(&mut self, rotations: &[Mat3]) -> Result<(), Self::Error>;

    /// The elastic phase's correction in hand, as the device keeps it
    /// (`()` for a device that keeps none): what a tracker's checkpoint
    /// holds, so that solves made after it and undone leave the
    /// correction a later phase reuses as it was
    /// ([`SolveDevice::set_springs_keeping_correction`]).
    type Correction: Clone + std::fmt::Debug + Send;

    /// The elastic correction in hand (none before an elastic phase made
    /// one, or after springs of another stiffness put it away).
    fn correction(&self) -> Self::Correction;

    /// Puts back a correction [`SolveDevice::correction`] gave: an elastic
    /// phase that does not make its own runs with it.
    fn put_correction(&mut self, correction: Self::Correction) -> Result<(), Self::Error>;

    /// The potential the elastic force descends at the current positions,
    /// `E / 2 - sum_k b_k . q_k` over the free particles (docs/METHOD.md,
    /// "Elastic model"), each particle's part summed in `f64` in index
    /// order; `None` without the elastic model. Measured every
    /// [`crate::stage2::phase::ENERGY_WATCH`] iterations of an elastic
    /// phase: a device may read its parts back.
    fn potential(&mut self) -> Result<Option<Potential>, Self::Error>;

    /// Keeps the current positions and rotations for
    /// [`SolveDevice::restore`]: the last state an elastic phase accepted;
    /// where the skin is paired, also the springs as the last
    /// [`SolveDevice::potential`] paired them, which [`Potential::held`]
    /// is measured with until the next save.
    fn save(&mut self) -> Result<(), Self::Error>;

    /// Puts back the positions and rotations [`SolveDevice::save`] kept;
    /// the solve goes on from them after a [`SolveDevice::begin`].
    fn restore(&mut self) -> Result<(), Self::Error>;

    /// The conjugate-gradient elastic phase's first call of an iteration
    /// (docs/METHOD.md, "Elastic model", *The conjugate-gradient phase*):
    /// at the current positions, left where they are, the elastic phase's
    /// residual `r = (f + b) / 2` and its two-level step `z` (smoothed and
    /// corrected, undamped: the passes of an iteration up to its combine,
    /// the skin paired first where it is paired), both kept; returns
    /// their [`DescentDots`] with `r'`, the residual this call kept last
    /// time, and `d'`, the direction [`SolveDevice::descent_direction`]
    /// made last (zero before the first). `r'` is then `r`. `None` outside
    /// an elastic phase that smooths with the volume smoother. The warm
    /// rotations are those of the current positions afterwards, as after
    /// an iteration.
    fn descent_residual(&mut self) -> Result<Option<DescentDots>, Self::Error>;

    /// The direction `d = z + beta d'` from the step the last
    /// [`SolveDevice::descent_residual`] kept, which replaces `d'`; the
    /// current positions are kept as the base the line search moves from.
    fn descent_direction(&mut self, beta: f32) -> Result<(), Self::Error>;

    /// Moves every particle to `base + t d`: the base and the direction
    /// of the last [`SolveDevice::descent_direction`] (`t = 0` puts the
    /// base back).
    fn descent_move(&mut self, t: f32) -> Result<(), Self::Error>;

    /// What the device prepared that depends only on the connections and
    /// the free particles (its coarse space, if any), with `plan` and
    /// `params` the solve's, for another solve of the model in another
    /// rest shape.
    fn shared_laplacian(&self, plan: &Plan, params: &DeformParams) -> SharedLaplacian;
}
