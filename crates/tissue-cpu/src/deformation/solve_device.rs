//! [`SolveDevice`] for [`CpuSolve`]: the seam's calls on the CPU's state.

use std::convert::Infallible;
use std::sync::Arc;

use glam::{Mat3, Vec3};
use rayon::prelude::*;
use tissue_core::field::SurfaceField;
use tissue_solve::coarse::{CoarseSpace, ElasticCoarse, SharedLaplacian};
use tissue_solve::stage2::Spring;
use tissue_solve::stage2::{DescentDots, Pairing, Potential};
use tissue_solve::{DeformParams, ForceModel, Iteration, Plan, SolveDevice};

use super::{BatchStart, CpuSolve, elastic_potential};
use crate::kernels::descent::{descent_direction, descent_dots, descent_move};

impl SolveDevice for CpuSolve {
    type Error = Infallible;

    /// One iteration at a time: the stopping rule is checked after each, so
    /// nothing is ever replayed.
    fn batch(&self) -> usize {
        1
    }

    fn coarse_rho(&self) -> Option<f32> {
        self.coarse.as_deref().map(CoarseSpace::rho)
    }

    fn elastic_rho(&self) -> Option<f32> {
        self.iteration
            .filter(|it| it.correct && it.force == ForceModel::Elastic)
            .and(self.elastic_coarse.as_deref())
            .map(ElasticCoarse::rho)
    }

    fn volume_smoother(&self) -> bool {
        self.volume_smoother.is_some() && self.elastic_aggregates.is_some()
    }

    fn elastic_smoothed(&self) -> bool {
        self.elastic_rho().is_some()
            && self
                .elastic_coarse
                .as_deref()
                .is_some_and(|c| c.smoother().is_some())
    }

    fn write_positions(
        &mut self,
        positions: &[Vec3],
        turn: Option<Mat3>,
    ) -> Result<(), Infallible> {
        self.current.copy_from_slice(positions);
        if let Some(turn) = turn {
            // The warm-started rotations turn with the surface too.
            self.rotations.par_iter_mut().for_each(|r| *r = turn * *r);
        }
        Ok(())
    }

    fn begin(&mut self, iteration: Iteration) -> Result<(), Infallible> {
        self.previous.clone_from(&self.current);
        self.linearise(iteration);
        self.iteration = Some(iteration);
        Ok(())
    }

    fn run(&mut self, omegas: &[f32]) -> Result<Vec<(f32, f32)>, Infallible> {
        let Some(it) = self.iteration else {
            return Ok(Vec::new());
        };
        if omegas.len() > 1 {
            self.batch_start = Some(BatchStart {
                current: self.current.clone(),
                previous: self.previous.clone(),
                rotations: self.rotations.clone(),
                omegas: omegas.to_vec(),
            });
        }
        // The batch runs on one of the pool's threads, so that each pass's
        // parallel loop starts there rather than being handed to the pool
        // from outside and waited for (the elastic solves from rest at
        // 10,000 particles 1-5 % faster on two cores).
        Ok(rayon::scope(|_| {
            omegas
                .iter()
                .map(|&omega| self.iterate(it, omega))
                .collect()
        }))
    }

    fn replay(&mut self, count: usize) -> Result<(), Infallible> {
        let (Some(it), Some(start)) = (self.iteration, self.batch_start.take()) else {
            return Ok(());
        };
        (self.current, self.previous, self.rotations) =
            (start.current, start.previous, start.rotations);
        for &omega in start.omegas.iter().take(count) {
            self.iterate(it, omega);
        }
        Ok(())
    }

    /// Paired at the positions measured where the skin is paired with an
    /// observation: the potential is then a function of the positions
    /// alone, whatever pairing the last iteration had; `held` with the
    /// pulls the last save kept.
    fn potential(&mut self) -> Result<Option<Potential>, Infallible> {
        self.pair_at_current();
        let paired = self.pairs() && self.held_pulls.len() == self.current.len();
        let held: &[Spring] = if paired { &self.held_pulls } else { &[] };
        Ok(self.elastic.as_deref().map(|elastic| {
            let (parts, held_parts) = elastic_potential(
                &self.rest,
                &self.current,
                &self.connections,
                elastic,
                &self.loads,
                &self.pulls,
                held,
                &self.free,
                &self.rotations,
            );
            if paired {
                Potential::paired(parts, &held_parts)
            } else {
                Potential::of(parts)
            }
        }))
    }

    fn descent_residual(&mut self) -> Result<Option<DescentDots>, Infallible> {
        let Some((residual, step)) = self.residual_and_step() else {
            return Ok(None);
        };
        let descent = &mut self.descent;
        for kept in [&mut descent.last_residual, &mut descent.direction] {
            kept.resize(residual.len(), Vec3::ZERO);
        }
        let parts = descent_dots(
            &residual,
            &step,
            &mut descent.last_residual,
            &descent.direction,
        );
        descent.step = step;
        Ok(Some(DescentDots::of(parts)))
    }

    fn descent_direction(&mut self, beta: f32) -> Result<(), Infallible> {
        let descent = &mut self.descent;
        descent.base.resize(self.current.len(), Vec3::ZERO);
        descent_direction(
            &descent.step,
            beta,
            &mut descent.direction,
            &self.current,
            &mut descent.base,
        );
        Ok(())
    }

    fn descent_move(&mut self, t: f32) -> Result<(), Infallible> {
        let descent = &self.descent;
        if descent.base.len() == self.current.len() && descent.direction.len() == descent.base.len()
        {
            descent_move(&descent.base, &descent.direction, t, &mut self.current);
        }
        Ok(())
    }

    fn save(&mut self) -> Result<(), Infallible> {
        let saved = self.saved.get_or_insert_with(Default::default);
        saved.0.clone_from(&self.current);
        saved.1.clone_from(&self.rotations);
        if self.pairs() {
            self.held_pulls.clone_from(&self.pulls);
        }
        Ok(())
    }

    fn restore(&mut self) -> Result<(), Infallible> {
        if let Some((current, rotations)) = &self.saved {
            self.current.clone_from(current);
            self.rotations.clone_from(rotations);
        }
        Ok(())
    }

    /// The coarse space, made for `params`.
    fn shared_laplacian(&self, plan: &Plan, params: &DeformParams) -> SharedLaplacian {
        SharedLaplacian::new(
            plan.laplacian_key,
            plan,
            params,
            self.coarse.clone(),
            self.volume_smoother,
        )
    }

    fn read_positions(&mut self) -> Result<Vec<Vec3>, Infallible> {
        Ok(self.current.clone())
    }

    fn read_rotations(&mut self) -> Result<Vec<Mat3>, Infallible> {
        Ok(self.rotations.clone())
    }

    fn write_rotations(&mut self, rotations: &[Mat3]) -> Result<(), Infallible> {
        rotations.clone_into(&mut self.rotations);
        Ok(())
    }

    /// Shared, not copied.
    type Correction = Option<Arc<ElasticCoarse>>;

    fn correction(&self) -> Self::Correction {
        self.elastic_coarse.clone()
    }

    fn put_correction(&mut self, correction: Self::Correction) -> Result<(), Infallible> {
        self.elastic_coarse = correction;
        Ok(())
    }

    /// The state's vectors copied, its prepared parts (the coarse spaces,
    /// the elastic model, the observation) shared.
    fn fork(&self) -> Option<Self> {
        Some(self.clone())
    }

    fn set_springs(&mut self, springs: &[Spring]) -> Result<(), Infallible> {
        // Its operator holds the stiffness of the springs it was made
        // with: kept where only their points move.
        if !Spring::all_same_stiffness(springs, &self.springs) {
            self.elastic_coarse = None;
        }
        self.set_springs_keeping_correction(springs)
    }

    fn set_springs_keeping_correction(&mut self, springs: &[Spring]) -> Result<(), Infallible> {
        if let Some(coarse) = &mut self.elastic_coarse {
            Arc::make_mut(coarse).set_pulls(springs);
        }
        springs.clone_into(&mut self.springs);
        springs.clone_into(&mut self.pulls);
        Ok(())
    }

    fn set_loads(&mut self, loads: &[Vec3]) -> Result<(), Infallible> {
        loads.clone_into(&mut self.loads);
        Ok(())
    }

    fn set_observation(&mut self, field: Option<&SurfaceField>) -> Result<(), Infallible> {
        self.observation = field.map(|f| Arc::new(f.clone()));
        Ok(())
    }

    fn set_pairing(&mut self, pairing: Option<&Pairing>) -> Result<(), Infallible> {
        self.held_pulls.clear();
        self.pairing = pairing.cloned();
        if self.pairing.is_some() && self.pulls.is_empty() {
            self.pulls = vec![Spring::ZERO; self.rest.len()];
        }
        Ok(())
    }

    fn reset(&mut self) -> Result<(), Infallible> {
        self.current.clone_from(&self.rest);
        self.rotations.fill(Mat3::IDENTITY);
        Ok(())
    }
}
