//! The shared breast cases with gravity and a stiffness given by hand
//! (docs/ACCURACY.md): the unloaded shape from
//! the rest posture (its gravity, the chest wall held, the rest of the skin
//! free), then the deformed posture from it with the whole deformed skin
//! imposed, with and without the deformed posture's gravity inside. The
//! probes and the tumour centre are written for `score.py`.
//!
//! `cargo run --release --example gravity_cases -- MODEL.vtp CASE_DIR E_KPA`
//!
//! The model is `tissue sample CASE_DIR/rest.obj --particles 10000`. The
//! stiffness is NOT something the program may use (each case's
//! `truth.json` gives the true one under `source.material`, for checking):
//! this example measures what gravity and the unloaded shape give when
//! it is known (`tissue deform` fits it from the skin).
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "an example")]

use std::collections::HashMap;

use glam::{Mat3, Vec3};
use tissue::advanced::model::{Postures, fit_stiffness, free_skin_targets};
use tissue::advanced::model::{Unloading, gravity_load, held_vertices, unloaded_shape};
use tissue::deformation::{DeformParams, Deformer, ForceModel};
use tissue::structures::Embedding;

fn obj_vertices(path: &str) -> Vec<Vec3> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| l.starts_with("v "))
        .map(|l| {
            let v: Vec<f32> = l
                .split_whitespace()
                .skip(1)
                .map(|t| t.parse().unwrap())
                .collect();
            Vec3::new(v[0], v[1], v[2])
        })
        .collect()
}

fn key(v: Vec3) -> [u32; 3] {
    [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]
}

fn rotations(rest: &[Vec3], current: &[Vec3], model: &tissue::ParticleModel) -> Vec<Mat3> {
    (0..rest.len())
        .map(|i| {
            let m = tissue::advanced::model::offsets_product(rest, current, &model.connections, i);
            tissue::advanced::model::rotation_of(m)
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    // The stiffness: given (kPa), or `fit` (from the skin, starting at 3 kPa).
    let (model_path, dir, given) = match &args[..] {
        [_, model, dir, e] => (model.clone(), dir.clone(), e.parse::<f32>().ok()),
        _ => panic!("usage: gravity_cases MODEL.vtp CASE_DIR E_KPA|fit"),
    };
    let case = std::path::Path::new(&dir)
        .file_name()
        .unwrap()
        .to_string_lossy()
        .to_string();
    let poisson = DeformParams::default().poisson;
    let model = tissue::load_model(std::path::Path::new(&model_path)).unwrap();
    let rest_v = obj_vertices(&format!("{dir}/rest.obj"));
    let def_v = obj_vertices(&format!("{dir}/deformed.obj"));
    let index: HashMap<[u32; 3], usize> = rest_v
        .iter()
        .enumerate()
        .map(|(i, v)| (key(*v), i))
        .collect();
    let mut deformed = model.surface.clone();
    for v in &mut deformed.vertices {
        *v = def_v[index[&key(*v)]];
    }
    // The chest wall: the vertices that do not move between the postures.
    let held = held_vertices(&model.surface, &deformed, 1e-3).unwrap();
    println!(
        "{case}: {} of {} surface vertices held, E {given:?} kPa given by hand",
        held.iter().filter(|&&h| h).count(),
        held.len()
    );
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(format!("{dir}/truth.json")).unwrap())
            .unwrap();
    let g = |name: &str| -> Vec3 {
        let a = &truth["program_may_use"][name];
        Vec3::new(
            a[0].as_f64().unwrap() as f32,
            a[1].as_f64().unwrap() as f32,
            a[2].as_f64().unwrap() as f32,
        )
    };
    let (g_rest, g_def) = (g("gravity_rest"), g("gravity_deformed"));
    let density = truth["program_may_use"]["density_kg_m3"].as_f64().unwrap() as f32;
    let per_kpa = |g: Vec3| gravity_load(g, density, 1.0, poisson, 1e-3).unwrap();
    let base = DeformParams::default().with(|p| {
        p.force = ForceModel::Elastic;
        p.poisson = poisson;
    });
    let rest = model.positions.clone();
    let surface: Vec<bool> = (0..model.len()).map(|i| model.is_surface(i)).collect();
    let started = std::time::Instant::now();
    // Loads `guess` with `body`: the chest wall held, the rest of the skin free.
    let solve = |guess: &[Vec3], body: Vec3, warm: Option<&[Vec3]>| {
        let m0 = tissue::ParticleModel {
            positions: guess.to_vec(),
            ..model.clone()
        };
        let params = base.clone().with(|p| {
            p.observed = Some(held.clone());
            p.load = body;
        });
        let mut d = Deformer::new(&m0, params)?;
        d.set_surface(&model.surface)?;
        if let Some(warm) = warm {
            d.warm_start(warm)?;
        }
        let report = d.solve();
        Ok((d.positions().to_vec(), report))
    };
    let (e_kpa, shape) = match given {
        Some(e) => (
            e,
            unloaded_shape(&rest, &surface, Unloading::MILLIMETRES, |x, warm, _| {
                solve(x, per_kpa(g_rest) / e, warm)
            })
            .unwrap(),
        ),
        None => {
            // Where the observed deformed skin puts each free skin particle.
            let targets = free_skin_targets(&model, &deformed, &held);
            let postures = Postures {
                rest: &rest,
                surface: &surface,
                targets: &targets,
                rest_load_per_kpa: per_kpa(g_rest),
                deformed_load_per_kpa: per_kpa(g_def),
            };
            let fit = fit_stiffness(
                &postures,
                3.0,
                (0.1, 100.0),
                Unloading::MILLIMETRES,
                |x, load, warm, _| solve(x, load, warm),
            )
            .unwrap();
            let truth_e = truth["source"]["material"]["E_kPa"].as_f64().unwrap();
            println!(
                "{case}: fitted E {:.3} kPa (true {truth_e} kPa, for checking: {:+.1} %), free skin {:.3} mm from the observed, trials {:?}, {:.1} s",
                fit.stiffness_kpa,
                100.0 * (f64::from(fit.stiffness_kpa) / truth_e - 1.0),
                fit.residual,
                fit.trials
                    .iter()
                    .map(|t| (t.stiffness_kpa, t.residual))
                    .collect::<Vec<_>>(),
                started.elapsed().as_secs_f64()
            );
            (fit.stiffness_kpa, fit.unloaded)
        }
    };
    let load = |g: Vec3| per_kpa(g) / e_kpa;
    println!(
        "{case}: unloaded shape in {} rounds ({:?} iterations), loaded again {:.4} mm RMS from the rest surface particles ({:.4} mm over all), converged {}, {:.1} s",
        shape.rounds,
        shape
            .reports
            .iter()
            .map(|r| r.iterations)
            .collect::<Vec<_>>(),
        shape.residual,
        shape.residual_all,
        shape.converged,
        started.elapsed().as_secs_f64()
    );
    let unloaded = shape.positions;
    // The deformed posture from the unloaded shape, the whole surface imposed.
    let mut m0 = model.clone();
    m0.positions = unloaded.clone();
    for (label, body) in [("gravity", load(g_def)), ("no gravity", Vec3::ZERO)] {
        let params = base.clone().with(|p| {
            p.load = body;
        });
        let mut d = Deformer::new(&m0, params).unwrap();
        d.set_surface(&deformed).unwrap();
        let r = d.solve();
        let fin = d.positions().to_vec();
        let rot = rotations(&rest, &fin, &model);
        let probes: Vec<Vec3> = truth["probes_rest"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                Vec3::new(
                    p[0].as_f64().unwrap() as f32,
                    p[1].as_f64().unwrap() as f32,
                    p[2].as_f64().unwrap() as f32,
                )
            })
            .collect();
        let c = &truth["tumour_centroid_rest"];
        let centre = Vec3::new(
            c[0].as_f64().unwrap() as f32,
            c[1].as_f64().unwrap() as f32,
            c[2].as_f64().unwrap() as f32,
        );
        let mut pts = probes.clone();
        pts.push(centre);
        let moved = Embedding::new(&rest, &pts).moved(&rest, &fin, &rot);
        let out =
            std::env::temp_dir().join(format!("gravity-{case}-{}.csv", label.replace(' ', "_")));
        let mut s = String::from("x,y,z\n");
        for p in &moved[..moved.len() - 1] {
            s += &format!("{},{},{}\n", p.x, p.y, p.z);
        }
        std::fs::write(&out, s).unwrap();
        let t = moved[moved.len() - 1];
        println!(
            "  from it, the deformed posture with {label}: {} iterations ({:?}); probes in {}, tumour centroid {} {} {}",
            r.iterations,
            r.stopped_by,
            out.display(),
            t.x,
            t.y,
            t.z
        );
    }
}
