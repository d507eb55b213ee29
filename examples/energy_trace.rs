//! How the elastic solve's potential moves, iteration by iteration: after
//! every iteration of every elastic phase, `E / 2 - sum_k b_k . q_k` (the
//! elastic energy of docs/METHOD.md, "Elastic model", and the loads' work),
//! whose negative gradient is the force the iteration steps along. A solve
//! that only ever lowers it cannot diverge; this counts the iterations that
//! raised it instead, on the phantom's deformations, the bench's probe
//! sweep, and any shared case given.
//!
//! `cargo run --release --example energy_trace [particles] [CASE_DIR...]`
//! (a case folder holds `rest.obj` and `deformed.obj`, as
//! `../shared/cases/breast_c` does).

use std::convert::Infallible;
use std::path::PathBuf;

use glam::{Mat3, Vec3};
use tissue::advanced::coarse::SharedLaplacian;
use tissue::advanced::stage2::{DescentDots, Iteration, Plan, Potential, SolveDevice, Tracker};
use tissue::deform::{Indentation, Rigid, deform_surface, indented_breast, sagged_breast};
use tissue::deformation::{DeformParams, DeformReport, ForceModel};
use tissue::{ParticleModel, SamplingParams, SurfaceMesh, phantom};
use tissue_cpu::deformation::CpuSolve;

/// The CPU's solve, the potential ([`SolveDevice::potential`]) measured
/// after every elastic iteration.
struct Watched {
    solve: CpuSolve,
    /// The phase in hand's force.
    force: Option<ForceModel>,
    /// Per start of an elastic phase (its own, or after a step back to
    /// the state it accepted), the potential there and after each
    /// iteration.
    phases: Vec<Vec<f64>>,
}

impl Watched {
    fn potential_now(&mut self) -> f64 {
        let Ok(potential) = self.solve.potential();
        potential.map_or(f64::NAN, |p| p.value)
    }
}

impl SolveDevice for Watched {
    type Error = Infallible;

    fn batch(&self) -> usize {
        1
    }

    fn coarse_rho(&self) -> Option<f32> {
        self.solve.coarse_rho()
    }

    fn elastic_rho(&self) -> Option<f32> {
        self.solve.elastic_rho()
    }

    fn volume_smoother(&self) -> bool {
        SolveDevice::volume_smoother(&self.solve)
    }

    fn elastic_smoothed(&self) -> bool {
        self.solve.elastic_smoothed()
    }

    fn write_positions(
        &mut self,
        positions: &[Vec3],
        turn: Option<Mat3>,
    ) -> Result<(), Infallible> {
        self.solve.write_positions(positions, turn)
    }

    fn set_springs(
        &mut self,
        springs: &[tissue::advanced::stage2::Spring],
    ) -> Result<(), Infallible> {
        self.solve.set_springs(springs)
    }

    fn set_loads(&mut self, loads: &[Vec3]) -> Result<(), Infallible> {
        self.solve.set_loads(loads)
    }

    fn set_observation(
        &mut self,
        field: Option<&tissue::field::SurfaceField>,
    ) -> Result<(), Infallible> {
        self.solve.set_observation(field)
    }

    fn set_pairing(
        &mut self,
        pairing: Option<&tissue::advanced::stage2::Pairing>,
    ) -> Result<(), Infallible> {
        self.solve.set_pairing(pairing)
    }

    fn begin(&mut self, iteration: Iteration) -> Result<(), Infallible> {
        self.solve.begin(iteration)?;
        self.force = Some(iteration.force);
        if iteration.force == ForceModel::Elastic {
            let start = self.potential_now();
            self.phases.push(vec![start]);
        }
        Ok(())
    }

    fn run(&mut self, omegas: &[f32]) -> Result<Vec<(f32, f32)>, Infallible> {
        let steps = self.solve.run(omegas)?;
        if self.force == Some(ForceModel::Elastic) {
            let now = self.potential_now();
            if let Some(phase) = self.phases.last_mut() {
                phase.push(now);
            }
        }
        Ok(steps)
    }

    fn replay(&mut self, count: usize) -> Result<(), Infallible> {
        self.solve.replay(count)
    }

    fn read_positions(&mut self) -> Result<Vec<Vec3>, Infallible> {
        self.solve.read_positions()
    }

    fn reset(&mut self) -> Result<(), Infallible> {
        SolveDevice::reset(&mut self.solve)
    }

    fn read_rotations(&mut self) -> Result<Vec<Mat3>, Infallible> {
        SolveDevice::read_rotations(&mut self.solve)
    }

    fn write_rotations(&mut self, rotations: &[Mat3]) -> Result<(), Infallible> {
        self.solve.write_rotations(rotations)
    }

    type Correction = <CpuSolve as SolveDevice>::Correction;

    fn correction(&self) -> Self::Correction {
        self.solve.correction()
    }

    fn put_correction(&mut self, correction: Self::Correction) -> Result<(), Infallible> {
        self.solve.put_correction(correction)
    }

    fn potential(&mut self) -> Result<Option<Potential>, Infallible> {
        self.solve.potential()
    }

    fn descent_residual(&mut self) -> Result<Option<DescentDots>, Infallible> {
        self.solve.descent_residual()
    }

    fn descent_direction(&mut self, beta: f32) -> Result<(), Infallible> {
        self.solve.descent_direction(beta)
    }

    fn descent_move(&mut self, t: f32) -> Result<(), Infallible> {
        self.solve.descent_move(t)
    }

    fn save(&mut self) -> Result<(), Infallible> {
        self.solve.save()
    }

    fn restore(&mut self) -> Result<(), Infallible> {
        self.solve.restore()
    }

    fn shared_laplacian(&self, plan: &Plan, params: &DeformParams) -> SharedLaplacian {
        self.solve.shared_laplacian(plan, params)
    }
}

/// One solve of `model` onto `deformed`, watched.
fn watched(
    model: &ParticleModel,
    deformed: &SurfaceMesh,
) -> Result<(DeformReport, Vec<Vec<f64>>), tissue::Error> {
    let params = DeformParams::default();
    let mut tracker = Tracker::new(model, params, |plan, params| {
        Ok::<_, tissue::Error>(Watched {
            solve: CpuSolve::new(model, plan, params),
            force: None,
            phases: Vec::new(),
        })
    })?;
    tracker.set_surface::<tissue::Error>(deformed)?;
    let Ok(report) = tracker.solve();
    Ok((report, tracker.device().phases.clone()))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let mut args = std::env::args().skip(1);
    let particles = args
        .next()
        .and_then(|t| t.parse().ok())
        .unwrap_or(10_000usize);
    let cases_dirs: Vec<PathBuf> = args.map(PathBuf::from).collect();
    let sampling = SamplingParams::with_particles(particles);
    let breast = tissue::sample(&phantom::default_breast(), &sampling)?.model;
    let turn = Rigid::about_axis(
        Vec3::new(1.0, 2.0, 0.5),
        30f32.to_radians(),
        Vec3::new(0.0, 0.0, 25.0),
        Vec3::ZERO,
    );
    let mut cases: Vec<(String, ParticleModel, SurfaceMesh)> = vec![
        (
            "phantom rotate 30°".into(),
            breast.clone(),
            deform_surface(&breast.surface, &turn),
        ),
        ("phantom sag 12 mm".into(), breast.clone(), sagged_breast()),
        (
            "phantom indentation 8 mm".into(),
            breast.clone(),
            indented_breast(),
        ),
    ];
    // The bench's probe sweep (`tissue-bench --probes`): 15-30 mm deep,
    // 8-35 mm wide, straight down at the phantom's top.
    for depth in [15.0, 20.0, 25.0, 30.0] {
        for width in [8.0, 15.0, 25.0, 35.0] {
            if let Some(probe) = Indentation::down_at_top(&breast.surface, depth, width) {
                cases.push((
                    format!("probe {depth} mm deep, {width} mm wide"),
                    breast.clone(),
                    deform_surface(&breast.surface, &probe),
                ));
            }
        }
    }
    for dir in &cases_dirs {
        let rest = tissue::load_surface(&dir.join("rest.obj"))?;
        let model = tissue::sample(&rest, &sampling)?.model;
        let deformed = tissue::load_surface_as_written(&dir.join("deformed.obj"))?
            .as_frame_of(&model.surface, false);
        tissue::deformation::check_same_topology(&model.surface, &deformed)?;
        let name = dir
            .file_name()
            .map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into());
        cases.push((name, model, deformed));
    }
    println!(
        "| case | converged | iterations | went on (retries) | steps back | elastic starts | elastic \
         iterations | raised the potential | largest rise / largest fall | rises in the first 5 of a \
         start | starts left that rose in their first 5 |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, model, deformed) in &cases {
        let (report, phases) = watched(model, deformed)?;
        let (mut iterations, mut raised, mut early) = (0usize, 0usize, 0usize);
        // The starts left (all but the last: stepped back from, or
        // linearised again), and those of them whose potential rose within
        // their first five iterations.
        let again = phases.len().saturating_sub(1);
        let early_in_again = phases[..again]
            .iter()
            .filter(|phase| phase.windows(2).take(5).any(|pair| pair[1] > pair[0]))
            .count();
        let mut largest = 0.0f64;
        let mut fall = 0.0f64;
        for phase in &phases {
            iterations += phase.len().saturating_sub(1);
            if let Some(first) = phase.first() {
                let lowest = phase.iter().copied().fold(f64::INFINITY, f64::min);
                fall = fall.max(first - lowest);
            }
            for (k, pair) in phase.windows(2).enumerate() {
                let rise = pair[1] - pair[0];
                if rise > 0.0 {
                    raised += 1;
                    largest = largest.max(rise);
                    if k < 5 {
                        early += 1;
                    }
                }
            }
        }
        println!(
            "| {name} | {} | {} | {} | {} | {} | {iterations} | {raised} | {:.2e} | {early} | \
             {early_in_again} of {again} |",
            report.converged,
            report.iterations,
            report.elastic_retries,
            report.backtracks,
            phases.len(),
            if fall > 0.0 { largest / fall } else { f64::NAN },
        );
    }
    Ok(())
}
