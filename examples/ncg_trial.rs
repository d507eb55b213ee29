//! A preconditioned nonlinear conjugate gradient for the elastic phase,
//! measured against the solve's own iteration from the same start.
//!
//! The solver's elastic phase is a Chebyshev-accelerated two-level
//! iteration whose potential is watched every 8 iterations
//! (docs/METHOD.md, "Elastic model", *The energy watch*). This example
//! takes the state where that phase starts (after the shear phase), and
//! from there descends the same potential by conjugate directions: the
//! two-level step `z = B r` at the current positions
//! (`CpuSolve::residual_and_step`, one linearisation where the phase
//! starts) is the preconditioned gradient, `d = z + beta d'` with
//! Polak-Ribiere's `beta = max(0, z . (r - r') / (z' . r'))` (`d = z`
//! where that is no descent), and each step is searched along `d`: the
//! potential at `t = 1`, the parabola through it, the potential and its
//! slope `-2 r . d` at `t = 0`, its vertex measured where it lies more
//! than a quarter from 1, and the step halved until it lowers the
//! potential by at least `1e-4 t (2 r . d)` (Armijo). Every accepted step
//! lowers the potential; nothing is linearised again.
//!
//! Printed per case (the bench's sag and indentation, its 16 probes, any
//! shared case given, and the phantom hanging under its weight with its
//! chest wall held):
//! the solver's iterations (elastic ones in brackets), retries and steps
//! back; the conjugate gradient's iterations until its step is below a
//! tenth of the tolerance, and until it lies within the tolerance of the
//! solver's answer; its potential measurements; its final potential
//! less the solver's; and how many particles each answer turned inside
//! out.
//!
//! `cargo run --release --example ncg_trial [particles] [CASE_DIR...]
//! [--no-conjugacy] [--relinearise-every N] [--only TEXT]` (`--only`: the
//! cases whose name holds `TEXT`)
//! (a case folder holds `rest.obj` and `deformed.obj`, as
//! `../shared/cases/breast_c` does: its deformed surface with
//! correspondence).

use std::convert::Infallible;
use std::path::PathBuf;

use glam::{Mat3, Vec3};
use tissue::advanced::coarse::SharedLaplacian;
use tissue::advanced::model::gravity_load;
use tissue::advanced::stage2::{
    DescentDots, Iteration, Pairing, Plan, Potential, SolveDevice, Spring, Tracker,
};
use tissue::deform::{Indentation, deform_surface, indented_breast, sagged_breast};
use tissue::deformation::{DeformParams, ForceModel, inversions};
use tissue::field::SurfaceField;
use tissue::{ParticleModel, SamplingParams, SurfaceMesh, phantom};
use tissue_cpu::deformation::CpuSolve;

/// The CPU's solve, keeping the state where the first elastic phase of
/// a solve starts and counting the elastic iterations.
struct Captured {
    solve: CpuSolve,
    start: Option<(Vec<Vec3>, Vec<Mat3>, Iteration)>,
    force: Option<ForceModel>,
    elastic_iterations: usize,
}

impl SolveDevice for Captured {
    type Error = Infallible;

    fn batch(&self) -> usize {
        self.solve.batch()
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

    fn set_springs(&mut self, springs: &[Spring]) -> Result<(), Infallible> {
        self.solve.set_springs(springs)
    }

    fn set_loads(&mut self, loads: &[Vec3]) -> Result<(), Infallible> {
        self.solve.set_loads(loads)
    }

    fn set_observation(&mut self, field: Option<&SurfaceField>) -> Result<(), Infallible> {
        self.solve.set_observation(field)
    }

    fn set_pairing(&mut self, pairing: Option<&Pairing>) -> Result<(), Infallible> {
        self.solve.set_pairing(pairing)
    }

    fn begin(&mut self, iteration: Iteration) -> Result<(), Infallible> {
        if iteration.force == ForceModel::Elastic && iteration.relinearise && self.start.is_none() {
            let Ok(positions) = self.solve.read_positions();
            let Ok(rotations) = SolveDevice::read_rotations(&mut self.solve);
            self.start = Some((positions, rotations, iteration));
        }
        self.force = Some(iteration.force);
        self.solve.begin(iteration)
    }

    fn run(&mut self, omegas: &[f32]) -> Result<Vec<(f32, f32)>, Infallible> {
        if self.force == Some(ForceModel::Elastic) {
            self.elastic_iterations += omegas.len();
        }
        self.solve.run(omegas)
    }

    fn replay(&mut self, count: usize) -> Result<(), Infallible> {
        self.solve.replay(count)
    }

    fn read_positions(&mut self) -> Result<Vec<Vec3>, Infallible> {
        self.solve.read_positions()
    }

    fn reset(&mut self) -> Result<(), Infallible> {
        self.start = None;
        self.elastic_iterations = 0;
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

fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| f64::from(x.dot(*y))).sum()
}

/// The potential at `positions`.
fn potential_at(solve: &mut CpuSolve, positions: &[Vec3]) -> f64 {
    let Ok(()) = solve.write_positions(positions, None);
    let Ok(potential) = solve.potential();
    potential.map_or(f64::NAN, |p| p.value)
}

/// How the conjugate gradient went from one start.
struct Descent {
    positions: Vec<Vec3>,
    potential: f64,
    iterations: usize,
    measurements: usize,
    converged: bool,
    /// The first iteration within `tolerance` of `answer`.
    within: Option<usize>,
}

/// How the descent runs.
#[derive(Clone, Copy)]
struct Options {
    /// Polak-Ribiere directions (without: steepest descent in the
    /// two-level step's metric).
    conjugacy: bool,
    /// Every this many iterations the correction is made again at the
    /// current state and the directions start afresh (0: never).
    relinearise_every: usize,
}

/// The conjugate gradient (or, without `conjugacy`, steepest descent in
/// the two-level step's metric) from `start`, until its largest step is
/// below a tenth of `tolerance` (at most 1,000 iterations).
fn descend(
    solve: &mut CpuSolve,
    start: &(Vec<Vec3>, Vec<Mat3>, Iteration),
    answer: &[Vec3],
    tolerance: f32,
    options: Options,
) -> Descent {
    let (positions, rotations, iteration) = start;
    let Ok(()) = solve.write_positions(positions, None);
    let Ok(()) = solve.write_rotations(rotations);
    let Ok(()) = solve.begin(*iteration);
    let mut x = positions.clone();
    let mut phi = potential_at(solve, &x);
    let mut measurements = 1;
    let mut last: Option<(Vec<Vec3>, Vec<Vec3>, f64)> = None;
    let (mut iterations, mut converged, mut within) = (0, false, None);
    while iterations < 1000 {
        let Ok(()) = solve.write_positions(&x, None);
        let Some((r, z)) = solve.residual_and_step() else {
            break;
        };
        let rz = dot(&r, &z);
        let mut d = z.clone();
        if let (true, Some((d_last, r_last, rz_last))) = (options.conjugacy, &last) {
            let change: Vec<Vec3> = r.iter().zip(r_last).map(|(a, b)| *a - *b).collect();
            let beta = (dot(&z, &change) / rz_last).max(0.0) as f32;
            for (d, d_last) in d.iter_mut().zip(d_last) {
                *d += *d_last * beta;
            }
            if dot(&r, &d) <= 0.0 {
                d.clone_from(&z);
            }
        }
        let slope = 2.0 * dot(&r, &d);
        let along = |t: f32| -> Vec<Vec3> { x.iter().zip(&d).map(|(x, d)| *x + *d * t).collect() };
        let mut t = 1.0f32;
        let mut phi_t = potential_at(solve, &along(t));
        measurements += 1;
        let curvature = 2.0 * (phi_t - phi + slope);
        if curvature > 0.0 {
            let vertex = ((slope / curvature) as f32).min(4.0);
            if (vertex - 1.0).abs() > 0.25 {
                let phi_vertex = potential_at(solve, &along(vertex));
                measurements += 1;
                if phi_vertex < phi_t {
                    (t, phi_t) = (vertex, phi_vertex);
                }
            }
        }
        while phi_t > phi - 1e-4 * f64::from(t) * slope && t > 1e-4 {
            t *= 0.5;
            phi_t = potential_at(solve, &along(t));
            measurements += 1;
        }
        if phi_t > phi - 1e-4 * f64::from(t) * slope {
            // No step along `d` lowers the potential enough: stopped
            // where it is, not converged.
            break;
        }
        let largest = d.iter().map(|d| (*d * t).length()).fold(0.0, f32::max);
        x = along(t);
        phi = phi_t;
        iterations += 1;
        last = Some((d, r, rz));
        if options.relinearise_every > 0 && iterations % options.relinearise_every == 0 {
            let Ok(()) = solve.write_positions(&x, None);
            let Ok(()) = solve.begin(Iteration {
                relinearise: true,
                ..*iteration
            });
            last = None;
        }
        if within.is_none() && largest_distance(&x, answer) < tolerance {
            within = Some(iterations);
        }
        if largest < 0.1 * tolerance {
            converged = true;
            break;
        }
    }
    Descent {
        positions: x,
        potential: phi,
        iterations,
        measurements,
        converged,
        within,
    }
}

fn largest_distance(a: &[Vec3], b: &[Vec3]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f32::max)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let particles = args
        .first()
        .and_then(|t| t.parse().ok())
        .unwrap_or(10_000usize);
    let options = Options {
        conjugacy: !args.iter().any(|a| a == "--no-conjugacy"),
        relinearise_every: args
            .iter()
            .position(|a| a == "--relinearise-every")
            .and_then(|k| args.get(k + 1))
            .and_then(|n| n.parse().ok())
            .unwrap_or(0),
    };
    let only: Option<&String> = args
        .iter()
        .position(|a| a == "--only")
        .and_then(|k| args.get(k + 1));
    // Folders: the arguments after the particles that are neither options
    // nor their values.
    let case_dirs: Vec<PathBuf> = args
        .iter()
        .enumerate()
        .skip(1)
        .filter(|&(k, a)| {
            !a.starts_with("--")
                && !args[k - 1].starts_with("--relinearise")
                && args[k - 1] != "--only"
        })
        .map(|(_, a)| PathBuf::from(a))
        .collect();
    let sampling = SamplingParams::with_particles(particles);
    let model = tissue::sample(&phantom::default_breast(), &sampling)?.model;
    // From rest, the solver alone, as the bench solves it.
    let params = DeformParams::default().with(|p| p.tuning.extrapolate = false);
    let mut cases: Vec<(String, ParticleModel, SurfaceMesh, DeformParams)> = vec![
        (
            "sag 12 mm".into(),
            model.clone(),
            sagged_breast(),
            params.clone(),
        ),
        (
            "indentation 8 mm".into(),
            model.clone(),
            indented_breast(),
            params.clone(),
        ),
    ];
    for depth in [15.0, 20.0, 25.0, 30.0] {
        for width in [8.0, 15.0, 25.0, 35.0] {
            if let Some(probe) = Indentation::down_at_top(&model.surface, depth, width) {
                cases.push((
                    format!("probe {depth} x {width} mm"),
                    model.clone(),
                    deform_surface(&model.surface, &probe),
                    params.clone(),
                ));
            }
        }
    }
    // Shared cases: the deformed surface with correspondence.
    for dir in &case_dirs {
        let rest = tissue::load_surface(&dir.join("rest.obj"))?;
        let case_model = tissue::sample(&rest, &sampling)?.model;
        let deformed = tissue::load_surface_as_written(&dir.join("deformed.obj"))?
            .as_frame_of(&case_model.surface, false);
        let name = dir
            .file_name()
            .map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into());
        cases.push((name, case_model, deformed, params.clone()));
    }
    // The phantom's skin free, its chest wall held (the rest vertices on
    // z = 0), hanging under its weight (2 kPa, 1,000 kg/m^3) towards its
    // feet, its back and its side: the posture's forward solves.
    let held: Vec<bool> = model
        .surface
        .vertices
        .iter()
        .map(|v| v.z.abs() < 1e-3)
        .collect();
    for (towards, gravity) in [
        ("the feet", Vec3::NEG_Y),
        ("the back", Vec3::NEG_Z),
        ("the side", Vec3::X),
    ] {
        let load = gravity_load(gravity, 1000.0, 2.0, params.poisson, 1e-3)?;
        cases.push((
            format!("hanging towards {towards}"),
            model.clone(),
            model.surface.clone(),
            params.clone().with(|p| {
                p.observed = Some(held.clone());
                p.load = load;
            }),
        ));
    }
    println!(
        "| case | solver: iterations (elastic) | retries | steps back | conjugate gradient: \
         iterations | within the tolerance of the solver's answer | potential measurements | \
         potential less the solver's | inverted particles (solver, conjugate gradient) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for (name, model, surface, params) in &cases {
        if only.is_some_and(|only| !name.contains(only.as_str())) {
            continue;
        }
        let (low, high) = model
            .positions
            .iter()
            .fold((Vec3::MAX, Vec3::MIN), |(l, h), &p| (l.min(p), h.max(p)));
        let size = (high - low).length();
        let tolerance = params.tolerance * size;
        let tracker = || {
            Tracker::new(model, params.clone(), |plan, params| {
                Ok::<_, tissue::Error>(Captured {
                    solve: CpuSolve::new(model, plan, params),
                    start: None,
                    force: None,
                    elastic_iterations: 0,
                })
            })
        };
        let (mut solver, mut trial) = (tracker()?, tracker()?);
        solver.set_surface::<tissue::Error>(surface)?;
        let Ok(report) = solver.solve();
        let Ok(answer) = solver.device_mut().read_positions();
        let Ok(Some(reached)) = solver.device_mut().potential() else {
            return Err("the elastic model measures a potential".into());
        };
        let Some(start) = solver.device().start.clone() else {
            return Err(format!("{name}: no elastic phase").into());
        };
        let descent = descend(
            &mut trial.device_mut().solve,
            &start,
            &answer,
            tolerance,
            options,
        );
        println!(
            "| {name} | {} ({}) | {} | {} | {}{} | {} | {} | {:.2e} (answers {:.1e} of the size apart) | {}, {} |",
            report.iterations,
            solver.device().elastic_iterations,
            report.elastic_retries,
            report.backtracks,
            descent.iterations,
            if descent.converged {
                ""
            } else {
                " (not converged)"
            },
            descent.within.map_or("-".into(), |k| k.to_string()),
            descent.measurements,
            descent.potential - reached.value,
            largest_distance(&descent.positions, &answer) / size,
            inversions(&model.positions, &answer, &model.connections).count,
            inversions(&model.positions, &descent.positions, &model.connections).count,
        );
    }
    Ok(())
}
