//! The markdown summary printed on stdout.

use std::fmt::Write;

use crate::{BackendName, Report};

/// Stage 1, stage 2 and memory tables, and the machine.
pub fn markdown(report: &Report) -> String {
    let mut out = String::new();
    let m = &report.machine;
    // Writing to a String cannot fail.
    let _ = writeln!(
        out,
        "machine: {} ({} logical processors, {} rayon threads), commit {}",
        m.cpu_model, m.cpu_logical_processors, m.rayon_threads, m.git_commit
    );
    if let Some(gpu) = &report.gpu {
        match (&gpu.adapter, &gpu.reason) {
            (Some(a), _) => {
                let _ = writeln!(
                    out,
                    "gpu: {} ({}, {}, driver {} {})",
                    a.name, a.backend, a.device_type, a.driver, a.driver_info
                );
            }
            (None, reason) => {
                let _ = writeln!(
                    out,
                    "gpu: skipped ({})",
                    reason.as_deref().unwrap_or("no adapter")
                );
            }
        }
    }
    let _ = writeln!(out, "mesh: {}\n", report.mesh);

    let _ = writeln!(out, "## Stage 1: sampling (CPU)\n");
    let _ = writeln!(
        out,
        "| particles | seconds | iterations | nn_cv | connections median | coverage |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|");
    for s in &report.sizes {
        let p = &s.sampling;
        let _ = writeln!(
            out,
            "| {} | {:.2} | {}{} | {:.3} | {} | {:.2} |",
            s.particles,
            p.seconds,
            p.iterations,
            if p.converged { "" } else { " (cap)" },
            p.nn_cv,
            p.connections_median,
            p.coverage
        );
    }

    let _ = writeln!(
        out,
        "\nWhere the sampling time goes (seconds; neighbour rebuilds are part of the iterations):\n"
    );
    let _ = writeln!(
        out,
        "| particles | field | initial | iterations | of which neighbours | connections | report |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|---|");
    for s in &report.sizes {
        let t = &s.sampling.stage_seconds;
        let _ = writeln!(
            out,
            "| {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
            s.particles, t.field, t.initial, t.iterations, t.neighbours, t.connections, t.report
        );
    }

    let _ = writeln!(out, "\n## Stage 2: deformation\n");
    let mut header = String::from(
        "| particles | backend | ms / iteration median (min-max) | floor MB / iteration | effective GB/s |",
    );
    let mut rule = String::from("|---|---|---|---|---|");
    for case in &report.cases {
        let _ = write!(header, " {case}: iterations, s |");
        rule.push_str("---|");
    }
    header.push_str(" tracking ms / frame p50 / p99 (iterations) |");
    rule.push_str("---|");
    let _ = writeln!(out, "{header}\n{rule}");
    for s in &report.sizes {
        for b in &s.backends {
            let name = backend_name(b.backend);
            let (Some(stage2), Some(floor)) = (&b.stage2, &b.floor) else {
                let _ = writeln!(
                    out,
                    "| {} | {name} | {}: {} |",
                    s.particles,
                    b.status,
                    b.reason.as_deref().unwrap_or("")
                );
                continue;
            };
            let it = &stage2.iteration.per_iteration;
            let _ = write!(
                out,
                "| {} | {name} ({}) | {:.3} ({:.3}-{:.3}) | {:.2} | {:.2} |",
                s.particles,
                if stage2.coarse_aggregates > 0 {
                    format!(
                        "{}, two-level over {} aggregates, prepared in {:.2} s",
                        stage2.rotations, stage2.coarse_aggregates, stage2.prepare_seconds
                    )
                } else {
                    stage2.rotations.clone()
                },
                it.median_ms,
                it.min_ms,
                it.max_ms,
                floor.bytes.bytes_per_iteration / 1e6,
                floor.effective_gb_per_s
            );
            for c in &stage2.converge {
                let mark = if c.converged { "" } else { " (not converged)" };
                let _ = write!(out, " {}, {:.3}{mark} |", c.iterations, c.seconds);
            }
            let t = &stage2.tracking;
            let (low, high) = (
                t.iterations.iter().min().copied().unwrap_or(0),
                t.iterations.iter().max().copied().unwrap_or(0),
            );
            let _ = writeln!(
                out,
                " {:.2} / {:.2} ({low}-{high}) |",
                t.latency.median_ms, t.latency.p99_ms
            );
        }
    }

    stage_table(&mut out, report);
    probe_table(&mut out, report);

    let _ = writeln!(out, "\n## Memory\n");
    let _ = writeln!(
        out,
        "| particles | CPU model B / particle | GPU state B / particle | GPU with deformer backups B / particle | peak RSS MB (process so far) |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|");
    for s in &report.sizes {
        let gpu = s
            .backends
            .iter()
            .find_map(|b| b.stage2.as_ref()?.gpu_state_bytes);
        let (state, all) = gpu.map_or(("-".to_owned(), "-".to_owned()), |g| {
            (
                format!("{:.1}", g.state_per_particle),
                format!("{:.1}", g.deformer_per_particle),
            )
        });
        let rss = s
            .peak_resident_bytes
            .map_or("-".to_owned(), |b| format!("{:.0}", b as f64 / 1e6));
        let _ = writeln!(
            out,
            "| {} | {:.1} | {state} | {all} | {rss} |",
            s.particles, s.cpu_model_bytes.per_particle
        );
    }
    let _ = writeln!(
        out,
        "\nfloor per particle: {}\ntotal {:.1} s",
        crate::FLOOR_FORMULA,
        report.total_seconds
    );
    out
}

/// One iteration pass by pass, per size and backend.
/// The probe sweep (`--probes`): one row per probe, size and backend, and
/// the sums per size and backend.
fn probe_table(out: &mut String, report: &Report) {
    let ran = report.sizes.iter().flat_map(|s| {
        s.backends
            .iter()
            .filter_map(move |b| Some((s.particles, b.backend, b.stage2.as_ref()?)))
    });
    let ran: Vec<_> = ran
        .filter(|(_, _, stage2)| !stage2.probes.is_empty())
        .collect();
    if ran.is_empty() {
        return;
    }
    let _ = writeln!(out, "\n## Probes from rest\n");
    let _ = writeln!(
        out,
        "| particles | backend | depth x width mm | iterations | retries | steps back | stopped by | seconds | inverted |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|---|---|---|");
    for (particles, backend, stage2) in &ran {
        for p in &stage2.probes {
            let _ = writeln!(
                out,
                "| {particles} | {} | {:.0} x {:.0} | {} | {} | {} | {}{} | {:.3} | {} |",
                backend_name(*backend),
                p.depth_mm,
                p.width_mm,
                p.iterations,
                p.retries,
                p.backtracks,
                p.stopped_by,
                if p.converged { "" } else { " (not converged)" },
                p.seconds,
                p.inverted
            );
        }
    }
    let _ = writeln!(out);
    for (particles, backend, stage2) in &ran {
        let probes = &stage2.probes;
        let _ = writeln!(
            out,
            "{particles} particles, {}: {} probes, {} iterations and {:.2} s in all, {} to the tolerance, {} retried, {} with particles inverted",
            backend_name(*backend),
            probes.len(),
            probes.iter().map(|p| p.iterations).sum::<usize>(),
            probes.iter().map(|p| p.seconds).sum::<f64>(),
            probes
                .iter()
                .filter(|p| p.stopped_by == "Tolerance")
                .count(),
            probes.iter().filter(|p| p.retries > 0).count(),
            probes.iter().filter(|p| p.inverted > 0).count()
        );
    }
}

fn stage_table(out: &mut String, report: &Report) {
    let _ = writeln!(out, "\n## One iteration, pass by pass\n");
    let _ = writeln!(
        out,
        "| particles | backend | method | pass | ms median (min-max) | share of the sum |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|");
    let mut notes = Vec::new();
    for s in &report.sizes {
        for b in &s.backends {
            let Some(stage2) = &b.stage2 else { continue };
            let name = backend_name(b.backend);
            let stages = &stage2.stages;
            let sum = stages.sum_of_medians_ms.max(f64::MIN_POSITIVE);
            for t in &stages.stages {
                let _ = writeln!(
                    out,
                    "| {} | {name} | {} | {} | {:.3} ({:.3}-{:.3}) | {:.0} % |",
                    s.particles,
                    stages.method,
                    t.stage,
                    t.time.median_ms,
                    t.time.min_ms,
                    t.time.max_ms,
                    100.0 * t.time.median_ms / sum
                );
            }
            let it = &stages.iteration;
            let _ = writeln!(
                out,
                "| {} | {name} | {} | sum of medians; passes back to back | {:.3}; {:.3} ({:.3}-{:.3}) | |",
                s.particles,
                stages.method,
                stages.sum_of_medians_ms,
                it.median_ms,
                it.min_ms,
                it.max_ms
            );
            if !notes.contains(&(stages.method, &stages.note)) {
                notes.push((stages.method, &stages.note));
            }
        }
    }
    for (method, note) in notes {
        let _ = writeln!(out, "\n{method}: {note}");
    }
}

/// A backend's name in the tables.
fn backend_name(backend: BackendName) -> &'static str {
    match backend {
        BackendName::Cpu => "cpu",
        BackendName::Gpu => "gpu",
    }
}
