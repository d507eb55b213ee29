//! What every run must do: no output replaces an input, every
//! implausible result is flagged with its own exit code, output folders hold
//! only this run's files, and quiet runs are quiet.
#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

mod common;

use std::path::Path;

use common::{assets, json, s, sampled_model, shared_mesh, size, text, tissue, vtp_array};
use tissue::Vec3;

/// `surface` with the vertices within 15 mm of its highest one pushed down
/// by up to `depth` (fully at that vertex, fading to nothing 15 mm away):
/// a narrow poke into the phantom's tip (its base at z = 0, its tip at 55).
fn poked(surface: &tissue::SurfaceMesh, depth: f32) -> tissue::SurfaceMesh {
    let tip = surface
        .vertices
        .iter()
        .copied()
        .fold(Vec3::splat(f32::MIN), |a, b| if b.z > a.z { b } else { a });
    let mut poked = surface.clone();
    for v in &mut poked.vertices {
        let d = v.distance(tip);
        if d < 15.0 {
            v.z -= depth * (1.0 - d / 15.0);
        }
    }
    poked
}

/// No output may replace an input: each run below names an
/// input as an output, is refused before any work with both named, and
/// leaves every input byte for byte as it was.
#[test]
fn outputs_never_overwrite_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let sag = d("sag.obj");
    std::fs::copy(assets().join("phantom-sag.obj"), &sag).unwrap();
    let breast = d("breast.obj");
    std::fs::copy(assets().join("phantom-breast.obj"), &breast).unwrap();
    // The points file sits where `deform -o <dir>` writes its moved points.
    std::fs::create_dir(d("results")).unwrap();
    let points = d("results/points.csv");
    std::fs::write(&points, "x,y,z\n1,2,30\n").unwrap();
    // The tumour sits where `track -o <dir>` writes the first frame's.
    std::fs::create_dir(d("results/frame-0001")).unwrap();
    let tumour = d("results/frame-0001/tumour.obj");
    std::fs::copy(assets().join("phantom-tumour.obj"), &tumour).unwrap();
    let inputs = [&model, &sag, &breast, &points, &tumour];
    let before: Vec<Vec<u8>> = inputs.iter().map(|p| std::fs::read(p).unwrap()).collect();
    let results = d("results");
    let cases: Vec<(Vec<&str>, [&str; 2])> = vec![
        (
            vec![
                "deform",
                "--model",
                &model,
                "--surface",
                &sag,
                "--points",
                &points,
                "-o",
                &results,
            ],
            ["results/points.csv", "the points file"],
        ),
        (
            vec![
                "deform",
                "--model",
                &model,
                "--surface",
                &sag,
                "-o",
                &results,
                "--report",
                &model,
            ],
            ["would overwrite the model", "model.vtp"],
        ),
        (
            vec![
                "track",
                "--model",
                &model,
                "--frames",
                &sag,
                "--structure",
                &tumour,
                "-o",
                &results,
            ],
            ["frame-0001/tumour.obj", "would overwrite the structure"],
        ),
        (
            vec![
                "sample", &breast, "-n", "300", "-o", &model, "--report", &breast,
            ],
            ["would overwrite the surface", "breast.obj"],
        ),
    ];
    for (args, expected) in &cases {
        let out = tissue(args);
        let message = text(&out);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {message}");
        for expect in expected {
            assert!(
                message.contains(expect),
                "{args:?}: expected `{expect}` in {message}"
            );
        }
        assert!(!message.contains("panicked"), "{message}");
    }
    for (path, old) in inputs.iter().zip(&before) {
        assert_eq!(&std::fs::read(path).unwrap(), old, "{path} changed");
    }
}

/// A solve that does not converge writes its results, says so in
/// `report.json` / `track.json` (`status`), warns, and exits 2, so that a
/// script can tell; a converged one says `converged` and exits 0.
#[test]
fn an_unconverged_solve_exits_2_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    for (command, cap, code, status) in [
        ("deform", "2", Some(2), "not_converged"),
        ("deform", "5000", Some(0), "converged"),
        ("track", "2", Some(2), "not_converged"),
    ] {
        let out_dir = d(&format!("{command}-{cap}"));
        let frames_flag = if command == "deform" {
            "--surface"
        } else {
            "--frames"
        };
        let out = tissue(&[
            command,
            "--model",
            &model,
            frames_flag,
            &sag,
            "--max-iterations",
            cap,
            "-o",
            &out_dir,
            "-q",
        ]);
        let message = text(&out);
        assert_eq!(out.status.code(), code, "{command} cap {cap}: {message}");
        let report = if command == "deform" {
            json(&Path::new(&out_dir).join("report.json"))
        } else {
            json(&Path::new(&out_dir).join("track.json"))["totals"].clone()
        };
        assert_eq!(report["status"], status, "{report}");
        if code == Some(2) {
            assert!(message.contains("NOT converge"), "{message}");
            assert!(Path::new(&out_dir).exists());
        }
    }
}

/// A landmark far outside the organ (a wrong frame or units) is carried by
/// extrapolation: the results are written, the report's `outside` counts it,
/// `status` says `flagged`, and the run exits 4 with a warning.
/// Points inside give none of that.
#[test]
fn a_landmark_outside_the_organ_is_flagged_and_exits_4() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    std::fs::write(d("far.csv"), "x,y,z\n15,-10,25\n200,0,0\n").unwrap();
    std::fs::write(d("near.csv"), "x,y,z\n15,-10,25\n").unwrap();
    for (points, code, status, outside) in [
        ("far.csv", Some(4), "flagged", 1),
        ("near.csv", Some(0), "converged", 0),
    ] {
        let out_dir = d(&format!("out-{points}"));
        let out = tissue(&[
            "deform",
            "--model",
            &model,
            "--surface",
            &sag,
            "--points",
            &d(points),
            "-o",
            &out_dir,
            "-q",
        ]);
        let message = text(&out);
        assert_eq!(out.status.code(), code, "{points}: {message}");
        let report = json(&Path::new(&out_dir).join("report.json"));
        assert_eq!(report["status"], status, "{report}");
        assert_eq!(report["points"]["outside"]["count"], outside, "{report}");
        if outside > 0 {
            // 200 mm in x from the phantom's skin: about 130 mm outside.
            let max = report["points"]["outside"]["max_mm"].as_f64().unwrap();
            assert!(max > 100.0, "{report}");
            assert!(
                message.contains("outside the model's rest surface"),
                "{message}"
            );
            assert!(Path::new(&out_dir).join("points.csv").exists());
        }
    }
}

/// A structure with a vertex outside the organ (a tetrahedron whose tip
/// stands 25 mm out of the phantom's skin) is flagged like a landmark:
/// `deform` and `track` exit 4, the report names the vertex outside, and
/// the same structure with its tip inside is not flagged.
#[test]
fn a_structure_vertex_outside_the_organ_is_flagged_in_deform_and_track() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    for (name, file) in [
        ("a.obj", "phantom-sag.obj"),
        ("b.obj", "phantom-indentation.obj"),
    ] {
        std::fs::copy(assets().join(file), frames.join(name)).unwrap();
    }
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let tetrahedron = |tip: f32| {
        format!(
            "v 15 -10 25\nv 17 -10 25\nv 15 -8 25\nv 15 -10 {tip}\n\
             f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
        )
    };
    std::fs::write(d("out.obj"), tetrahedron(80.0)).unwrap();
    std::fs::write(d("in.obj"), tetrahedron(30.0)).unwrap();
    for (name, code, status, outside) in [
        ("out.obj", Some(4), "flagged", 1),
        ("in.obj", Some(0), "converged", 0),
    ] {
        let sag = assets().join("phantom-sag.obj");
        let pattern = d("frames/*.obj");
        let structure = d(name);
        let commands = [
            ["deform", "--surface", s(&sag)],
            ["track", "--frames", &pattern],
        ];
        for command in commands {
            let out_dir = d(&format!("{}-{name}", command[0]));
            let mut args = command.to_vec();
            args.extend([
                "--model",
                &model,
                "--structure",
                &structure,
                "-o",
                &out_dir,
                "-q",
            ]);
            let out = tissue(&args);
            let message = text(&out);
            assert_eq!(out.status.code(), code, "{args:?}: {message}");
            let report = if command[0] == "deform" {
                json(&Path::new(&out_dir).join("report.json"))
            } else {
                let summary = json(&Path::new(&out_dir).join("track.json"));
                assert_eq!(summary["totals"]["status"], status, "{summary}");
                json(&Path::new(&out_dir).join("frame-0002/report.json"))
            };
            assert_eq!(report["status"], status, "{report}");
            assert_eq!(
                report["structures"][0]["outside"]["count"], outside,
                "{report}"
            );
        }
    }
}

/// A hand-edited model (a particle moved far outside, a surface particle
/// moved off its attachment) is refused before any work, naming the
/// particle, and exits 1; the model as sampled is accepted.
#[test]
fn a_hand_edited_model_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let free = (0..model.len()).find(|&i| !model.is_surface(i)).unwrap();
    let surface = (0..model.len()).find(|&i| model.is_surface(i)).unwrap();
    let mut far = model.clone();
    far.positions[free].x = 9999.0;
    let mut off = model.clone();
    off.positions[surface] += Vec3::splat(5.0 * model.mean_connection_length());
    for (name, edited, says) in [
        ("far.vtp", &far, format!("particle {free} at")),
        ("off.vtp", &off, format!("surface particle {surface} at")),
    ] {
        let path = dir.path().join(name);
        tissue::save_model(edited, &path).unwrap();
        let out = tissue(&[
            "deform",
            "--model",
            s(&path),
            "--surface",
            &sag,
            "-o",
            s(&dir.path().join(format!("out-{name}"))),
            "-q",
        ]);
        let message = text(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {message}");
        assert!(
            message.contains(&says),
            "{name}: expected `{says}` in {message}"
        );
        assert!(message.contains("edited or damaged"), "{message}");
        assert!(!dir.path().join(format!("out-{name}")).exists());
    }
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        &sag,
        "-o",
        s(&dir.path().join("out-good")),
        "-q",
    ]);
    assert!(out.status.success(), "{}", text(&out));
}

/// A rerun of `track` with fewer frames into the same folder leaves no
/// frame folder or summary of the earlier run: only this run's
/// frames and its own `track.json`; a folder the user put there stays.
#[test]
fn a_shorter_rerun_of_track_leaves_no_stale_frames() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let (three, one) = (dir.path().join("three"), dir.path().join("one"));
    std::fs::create_dir(&three).unwrap();
    std::fs::create_dir(&one).unwrap();
    for (k, name) in [
        "phantom-sag.obj",
        "phantom-indentation.obj",
        "phantom-sag.obj",
    ]
    .iter()
    .enumerate()
    {
        std::fs::copy(assets().join(name), three.join(format!("f{k}.obj"))).unwrap();
    }
    std::fs::copy(assets().join("phantom-indentation.obj"), one.join("f0.obj")).unwrap();
    let out = dir.path().join("out");
    let run = |frames: &Path| {
        let pattern = frames.join("*.obj");
        let result = tissue(&[
            "track",
            "--model",
            &model,
            "--frames",
            s(&pattern),
            "-o",
            s(&out),
            "-q",
        ]);
        assert!(result.status.success(), "{}", text(&result));
    };
    run(&three);
    assert!(out.join("frame-0003/report.json").exists());
    std::fs::create_dir(out.join("frame-9999")).unwrap();
    std::fs::write(out.join("frame-9999/notes.txt"), "mine").unwrap();
    run(&one);
    assert!(out.join("frame-0001/report.json").exists());
    assert!(!out.join("frame-0002").exists());
    assert!(!out.join("frame-0003").exists());
    assert!(out.join("frame-9999/notes.txt").exists(), "not ours: kept");
    let summary = json(&out.join("track.json"));
    assert_eq!(summary["frames"].as_array().unwrap().len(), 1, "{summary}");
}

/// A quiet run prints nothing: on a headless machine Mesa's
/// Vulkan device-selection layer says `XDG_RUNTIME_DIR is invalid` while
/// the adapters are listed; that goes to the log (`RUST_LOG=info`), not to
/// the terminal. Both stages run on the default `auto` backend and on the
/// GPU, so the adapters are listed both ways.
#[test]
fn a_quiet_run_prints_nothing_on_a_headless_machine() {
    let dir = tempfile::tempdir().unwrap();
    let run = |backend: &str| {
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_tissue"));
        command
            .args(["demo", "-q", "-n", "1500", "--backend", backend, "-o"])
            .arg(dir.path().join(format!("demo-{backend}")))
            .env_remove("XDG_RUNTIME_DIR")
            .env_remove("WAYLAND_DISPLAY")
            .env_remove("DISPLAY")
            .env_remove("RUST_LOG");
        command.output().unwrap()
    };
    for backend in ["auto", "gpu"] {
        if backend == "gpu" && !common::gpu("a_quiet_run_prints_nothing_on_a_headless_machine") {
            continue;
        }
        let out = run(backend);
        assert!(out.status.success(), "--backend {backend}: {}", text(&out));
        assert!(
            out.stdout.is_empty() && out.stderr.is_empty(),
            "--backend {backend} -q printed: {}",
            text(&out)
        );
    }
}

/// `frames` frames from the rest skin towards the sagged phantom's, as
/// `dir/frames/skin-K.obj`; the pattern that names them.
fn sag_frames(dir: &Path, model: &tissue::ParticleModel, frames: usize) -> String {
    use tissue::deform::{Sag, deform_surface, interpolate};
    let sagged = deform_surface(&model.surface, &Sag::default());
    let folder = dir.join("frames");
    std::fs::create_dir_all(&folder).unwrap();
    for k in 1..=frames {
        let frame = interpolate(&model.surface, &sagged, k as f32 / frames as f32).unwrap();
        tissue::save_surface(&frame, &folder.join(format!("skin-{k}.obj"))).unwrap();
    }
    s(&folder.join("*.obj")).to_owned()
}

/// `track` reads and checks every frame before it solves the first (issue
/// 15): a broken last frame stops the run before anything is written,
/// naming the file.
#[test]
fn track_checks_every_frame_before_solving_the_first() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let pattern = sag_frames(dir.path(), &model, 3);
    // The fourth frame has lost a triangle.
    let mut broken = model.surface.clone();
    broken.triangles.pop();
    let broken_path = dir.path().join("frames/skin-4.obj");
    tissue::save_surface(&broken, &broken_path).unwrap();
    let out_dir = dir.path().join("out");
    let out = tissue(&[
        "track",
        "--model",
        s(&model_path),
        "--frames",
        &pattern,
        "-o",
        s(&out_dir),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(text(&out).contains("skin-4.obj"), "{}", text(&out));
    assert!(
        !out_dir.join("frame-0001").exists(),
        "a frame was solved before the bad one was found"
    );
}

/// `tissue` run with `args` and sent `kill -SIGNAL` once it reports its
/// first frame: how it exited and what it wrote to stderr.
fn signalled_after_first_frame(
    args: &[String],
    signal: &str,
) -> (std::process::ExitStatus, String) {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_tissue"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    while !line.starts_with("frame 1/") {
        line.clear();
        let read = std::io::BufRead::read_line(&mut stdout, &mut line).unwrap();
        assert!(read > 0, "track ended before its first frame");
    }
    let killed = std::process::Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let status = child.wait().unwrap();
    let mut printed = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut printed).unwrap();
    (status, printed)
}

/// SIGTERM (a job scheduler's or `kill`'s stop) stops `track` as Ctrl-C
/// does: after the frame in hand, with the summary written and exit 130.
#[test]
fn sigterm_stops_track_between_frames_as_ctrl_c_does() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let frames = 30;
    let pattern = sag_frames(dir.path(), &model, frames);
    let out = dir.path().join("out");
    let args = [
        "track",
        "--model",
        s(&model_path),
        "--frames",
        &pattern,
        "-o",
        s(&out),
    ]
    .map(str::to_owned);
    let (status, printed) = signalled_after_first_frame(&args, "TERM");
    assert_eq!(status.code(), Some(130), "{printed}");
    assert!(printed.contains("--resume"), "{printed}");
    let summary = json(&out.join("track.json"));
    let done = summary["frames"].as_array().unwrap().len();
    assert!((1..frames).contains(&done), "{summary}");
    assert_eq!(summary["totals"]["status"], "incomplete", "{summary}");
}

/// Ctrl-C during `track` finishes the frame in hand, writes the summary
/// (status `incomplete`, the frames done) and exits 130; `--resume`
/// continues from the next frame, and its last frame is an uninterrupted
/// run's, to the bit. A resume with other options, other files, or with
/// nothing to resume, is refused.
#[test]
fn ctrl_c_stops_track_between_frames_and_resume_finishes_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    // Enough that the signal lands long before the last frame.
    let frames = 30;
    let pattern = sag_frames(dir.path(), &model, frames);
    let model_arg = s(&model_path).to_owned();
    let args = |out: &Path| -> Vec<String> {
        [
            "track",
            "--model",
            &model_arg,
            "--frames",
            &pattern,
            "-o",
            s(out),
        ]
        .map(str::to_owned)
        .to_vec()
    };

    let run = |args: &[String]| tissue(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let whole = dir.path().join("whole");
    let out = run(&args(&whole));
    assert!(out.status.success(), "{}", text(&out));

    // Stopped by SIGINT once the first frame is reported.
    let cut = dir.path().join("cut");
    let (status, printed) = signalled_after_first_frame(&args(&cut), "INT");
    assert_eq!(status.code(), Some(130), "{printed}");
    assert!(printed.contains("--resume"), "{printed}");
    let summary = json(&cut.join("track.json"));
    let done = summary["frames"].as_array().unwrap().len();
    assert!((1..frames).contains(&done), "{summary}");
    assert_eq!(summary["totals"]["status"], "incomplete", "{summary}");
    assert_eq!(summary["totals"]["planned"], frames, "{summary}");
    assert!(cut.join(format!("frame-{done:04}/report.json")).exists());
    assert!(!cut.join(format!("frame-{:04}", done + 1)).exists());

    // Other options: refused, naming what differs.
    let mut other = args(&cut);
    other.extend(["--resume", "--tolerance", "1e-3"].map(str::to_owned));
    let refused = run(&other);
    assert_eq!(refused.status.code(), Some(1), "{}", text(&refused));
    assert!(
        text(&refused).contains("params differ"),
        "{}",
        text(&refused)
    );

    // A frame file changed since the stop (one not solved yet), under the
    // same name: refused, naming it; the run resumes once it is back.
    let last_frame = dir.path().join(format!("frames/skin-{frames}.obj"));
    let original = std::fs::read(&last_frame).unwrap();
    let mut changed = original.clone();
    changed.extend_from_slice(b"# edited\n");
    std::fs::write(&last_frame, &changed).unwrap();
    let mut again = args(&cut);
    again.push("--resume".into());
    let refused = run(&again);
    assert_eq!(refused.status.code(), Some(1), "{}", text(&refused));
    assert!(
        text(&refused).contains(&format!("skin-{frames}.obj is not what the run")),
        "{}",
        text(&refused)
    );
    std::fs::write(&last_frame, &original).unwrap();
    let resumed = run(&again);
    assert!(resumed.status.success(), "{}", text(&resumed));
    assert!(
        text(&resumed).contains(&format!("resuming at frame {}", done + 1)),
        "{}",
        text(&resumed)
    );
    let summary = json(&cut.join("track.json"));
    assert_eq!(summary["frames"].as_array().unwrap().len(), frames);
    assert_eq!(summary["totals"]["status"], "converged", "{summary}");
    assert_eq!(summary["totals"]["resumed_at"], done + 1, "{summary}");

    let last = format!("frame-{frames:04}/particles.vtp");
    let displacement = |dir: &Path| {
        vtp_array(
            &std::fs::read_to_string(dir.join(&last)).unwrap(),
            "displacement",
        )
    };
    // The frames before the resume are solved again, unwritten: the
    // resumed run's frames are the uninterrupted run's, to the bit.
    let (a, b) = (displacement(&whole), displacement(&cut));
    assert_eq!(a.len(), b.len());
    assert!(
        a == b,
        "stopped after frame {done}: the resumed run's last frame differs from the \
         uninterrupted run's"
    );

    // A finished run: nothing to continue, said so.
    let finished = run(&again);
    assert_eq!(finished.status.code(), Some(1), "{}", text(&finished));
    assert!(
        text(&finished).contains(&format!("has done all of its {frames} frames")),
        "{}",
        text(&finished)
    );
    // A frame whose report was removed is where the run resumes.
    std::fs::remove_file(cut.join("frame-0003/report.json")).unwrap();
    let redone = run(&again);
    assert!(redone.status.success(), "{}", text(&redone));
    assert!(
        text(&redone).contains("resuming at frame 3"),
        "{}",
        text(&redone)
    );
    let summary = json(&cut.join("track.json"));
    assert_eq!(summary["frames"].as_array().unwrap().len(), frames);
    assert!(cut.join("frame-0003/report.json").is_file());

    // Nothing to resume in a fresh folder.
    let mut fresh = args(&dir.path().join("fresh"));
    fresh.push("--resume".into());
    let nothing = run(&fresh);
    assert_eq!(nothing.status.code(), Some(1), "{}", text(&nothing));
    assert!(
        text(&nothing).contains("no run to continue"),
        "{}",
        text(&nothing)
    );
}

/// SIGKILL while a file is being written leaves the previous good file,
/// never a cut-off one: `tissue sample` writes a model over an
/// earlier one and is killed as soon as its temporary file appears; the
/// model file then still loads, and is the earlier one byte for byte unless
/// the rename won the race (then it is the whole new one).
#[test]
fn a_write_killed_midway_leaves_the_previous_file_whole() {
    let dir = tempfile::tempdir().unwrap();
    let breast = assets().join("phantom-breast.obj");
    let model = dir.path().join("model.vtp");
    let sample = |seed: &str| {
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_tissue"));
        command.args([
            "sample",
            s(&breast),
            "-n",
            "20000",
            "--seed",
            seed,
            "--backend",
            "cpu",
            "-q",
            "-o",
            s(&model),
        ]);
        command
    };
    let first = sample("1").output().unwrap();
    assert!(first.status.success(), "{}", text(&first));
    let good = std::fs::read(&model).unwrap();
    let mut caught = 0;
    for attempt in 0..3 {
        let mut child = sample(&format!("{}", attempt + 2)).spawn().unwrap();
        let started = std::time::Instant::now();
        let mut killed_writing = false;
        while started.elapsed() < std::time::Duration::from_secs(120) {
            let writing = std::fs::read_dir(dir.path())
                .unwrap()
                .flatten()
                .any(|e| e.file_name().to_string_lossy().ends_with(".part"));
            if writing {
                child.kill().unwrap();
                killed_writing = true;
                break;
            }
            if child.try_wait().unwrap().is_some() {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let status = child.wait().unwrap();
        let now = std::fs::read(&model).unwrap();
        tissue::load_model(&model).unwrap_or_else(|e| {
            panic!("attempt {attempt}: the model file is damaged after SIGKILL ({status}): {e}")
        });
        if killed_writing && now == good {
            caught += 1;
        }
        // Put the good file back for the next attempt if the new one landed.
        std::fs::write(&model, &good).unwrap();
    }
    assert!(
        caught > 0,
        "no attempt killed the process while it was writing (the test did not test)"
    );
}

/// Particles turned inside out by a solve are flagged: a poke
/// 40 mm deep and 15 mm wide into the phantom's tip folds the tissue under
/// the symmetric force (the elastic force, the default, resists it and
/// folds nothing); the report counts the inverted particles, `status` is
/// `flagged` and the exit code 4. The bundled indentation, a gentle one,
/// inverts nothing under either force.
#[test]
fn particles_turned_inside_out_are_flagged_and_exit_4() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let poked = poked(&model.surface, 40.0);
    let poked_path = dir.path().join("poked.obj");
    tissue::save_surface(&poked, &poked_path).unwrap();
    let deform = |surface: &Path, out: &str, force: &str| {
        let out_dir = dir.path().join(out);
        let result = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(surface),
            "--force",
            force,
            "-o",
            s(&out_dir),
        ]);
        (result, json(&out_dir.join("report.json")))
    };
    let (out, report) = deform(&poked_path, "poked", "symmetric");
    assert_eq!(out.status.code(), Some(4), "{}", text(&out));
    assert!(text(&out).contains("turned inside out"), "{}", text(&out));
    assert_eq!(report["status"], "flagged", "{report}");
    assert_eq!(report["converged"], true, "{report}");
    assert!(
        report["inverted"]["count"].as_u64().unwrap() > 0,
        "{report}"
    );
    assert!(report["inverted"]["min_volume_ratio"].as_f64().unwrap() <= 0.0);

    let (out, report) = deform(&poked_path, "poked-elastic", "elastic");
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(report["inverted"]["count"], 0, "{report}");
    for force in ["symmetric", "elastic"] {
        let gentle = format!("gentle-{force}");
        let (out, report) = deform(&assets().join("phantom-indentation.obj"), &gentle, force);
        assert!(out.status.success(), "{}", text(&out));
        assert_eq!(report["inverted"]["count"], 0, "{report}");
        assert!(report["inverted"]["min_volume_ratio"].as_f64().unwrap() > 0.2);
    }
}

/// A frame in which two vertices touch is still the rest mesh, not
/// welded to one vertex fewer and refused; an STL frame, which
/// stores every corner, is welded back to the rest mesh.
#[test]
fn frames_with_touching_vertices_and_stl_frames_are_read_as_the_rest_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let mut touching = model.surface.clone();
    touching.vertices[10] = touching.vertices[11];
    let obj = dir.path().join("touching.obj");
    tissue::save_surface(&touching, &obj).unwrap();
    let mut moved = model.surface.clone();
    for v in &mut moved.vertices {
        v.z *= 0.98;
    }
    let stl = dir.path().join("moved.stl");
    tissue::save_surface(&moved, &stl).unwrap();
    // An STL file stores every corner apart: its touching vertices are
    // read by the corners of the triangles, listed in the rest's order.
    let touching_stl = dir.path().join("touching.stl");
    tissue::save_surface(&touching, &touching_stl).unwrap();
    for (surface, out) in [
        (&obj, "touching"),
        (&stl, "stl"),
        (&touching_stl, "touching-stl"),
    ] {
        let result = tissue(&[
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(surface),
            "-o",
            s(&dir.path().join(out)),
        ]);
        assert!(result.status.success(), "{out}: {}", text(&result));
        // Followed as a frame, not matched as another surface.
        let report = json(&dir.path().join(out).join("report.json"));
        assert!(report.get("observation").is_none(), "{out}: {report}");
    }
}

/// A frame of a rest surface that already passes through itself
/// (`liver-smooth.obj`, whose triangles 810 and 811 fold over their
/// neighbours) is solved with a warning that its crossing is the rest's,
/// not refused as a skin pushed through itself.
#[test]
fn a_frame_crossing_itself_where_its_rest_surface_does_is_solved_with_a_warning() {
    let Some(liver) = shared_mesh("liver-smooth.obj") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("liver.vtp");
    let sampled = tissue(&["sample", s(&liver), "-n", "2000", "-o", s(&model), "-q"]);
    assert!(sampled.status.success(), "{}", text(&sampled));
    let rest = tissue::load_model(&model).unwrap().surface;
    let mut frame = rest.clone();
    for v in &mut frame.vertices {
        v.z *= 0.99;
    }
    let frame_path = dir.path().join("frame.obj");
    tissue::save_surface(&frame, &frame_path).unwrap();
    let out = tissue(&[
        "deform",
        "--model",
        s(&model),
        "--surface",
        s(&frame_path),
        "-o",
        s(&dir.path().join("out")),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        text(&out).contains("cross, as the rest surface's do"),
        "{}",
        text(&out)
    );
    let report = json(&dir.path().join("out/report.json"));
    assert_eq!(report["status"], "converged", "{report}");
}

/// A frame whose name is not UTF-8 is not skipped without a word (issue
/// 15): the pattern cannot match it, so `track` refuses to run and names it.
#[cfg(unix)]
#[test]
fn a_frame_with_a_name_that_is_not_utf8_is_refused_not_skipped() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    let sag = assets().join("phantom-sag.obj");
    std::fs::copy(&sag, frames.join("a.obj")).unwrap();
    let odd = std::ffi::OsStr::from_bytes(b"b\xff.obj");
    std::fs::copy(&sag, frames.join(odd)).unwrap();
    let out = tissue(&[
        "track",
        "--model",
        s(&model_path),
        "--frames",
        s(&frames.join("*.obj")),
        "-o",
        s(&dir.path().join("out")),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(text(&out).contains("not valid UTF-8"), "{}", text(&out));
    assert!(!dir.path().join("out/frame-0001").exists());
}

/// A deformed skin that passes through itself is refused, naming two
/// triangles that cross: the phantom's tip pushed 80 mm down,
/// through its own base. A 40 mm poke stays inside and is solved.
#[test]
fn a_skin_pushed_through_itself_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let out_dir = dir.path().join("out");
    let pushed = poked(&model.surface, 80.0);
    let path = dir.path().join("through.obj");
    tissue::save_surface(&pushed, &path).unwrap();
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        s(&path),
        "-o",
        s(&out_dir),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(
        text(&out).contains("passes through itself"),
        "{}",
        text(&out)
    );
    assert!(!out_dir.join("particles.vtp").exists());
}

/// 300 frames of `track` at 3,000 particles: the skin sags and
/// recovers 13 times (a period of 23 frames), starting and ending at rest.
/// No drift: the last frame's particles are back at rest within 1e-4 of
/// the size. Flat effort: the last cycle's frames take no more iterations
/// than the first cycle's, two more at most.
#[test]
fn a_300_frame_soak_does_not_drift() {
    use tissue::deform::{Sag, deform_surface, interpolate};
    let dir = tempfile::tempdir().unwrap();
    let breast = assets().join("phantom-breast.obj");
    let model_path = dir.path().join("model.vtp");
    let out = tissue(&[
        "sample",
        s(&breast),
        "-n",
        "3000",
        "-o",
        s(&model_path),
        "-q",
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let model = tissue::load_model(&model_path).unwrap();
    let sagged = deform_surface(&model.surface, &Sag::default());
    let (period, frames) = (23, 300);
    let shapes = dir.path().join("shapes");
    let folder = dir.path().join("frames");
    std::fs::create_dir(&shapes).unwrap();
    std::fs::create_dir(&folder).unwrap();
    for phase in 0..period {
        let t = 0.5 * (1.0 - (std::f32::consts::TAU * phase as f32 / period as f32).cos());
        let shape = interpolate(&model.surface, &sagged, t).unwrap();
        tissue::save_surface(&shape, &shapes.join(format!("phase-{phase}.obj"))).unwrap();
    }
    // One file per phase, linked once per frame that shows it.
    for k in 0..frames {
        std::fs::hard_link(
            shapes.join(format!("phase-{}.obj", k % period)),
            folder.join(format!("frame-{k:03}.obj")),
        )
        .unwrap();
    }
    let out_dir = dir.path().join("out");
    let out = tissue(&[
        "track",
        "--model",
        s(&model_path),
        "--frames",
        s(&folder.join("*.obj")),
        "-o",
        s(&out_dir),
        "-q",
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let summary = json(&out_dir.join("track.json"));
    let iterations: Vec<u64> = summary["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["iterations"].as_u64().unwrap())
        .collect();
    assert_eq!(iterations.len(), frames);
    let first: u64 = iterations[1..period].iter().copied().max().unwrap();
    let last: u64 = iterations[frames - period..].iter().copied().max().unwrap();
    eprintln!("iterations: first cycle at most {first}, last cycle at most {last}");
    assert!(last <= first + 2, "{iterations:?}");

    let back = vtp_array(
        &std::fs::read_to_string(out_dir.join(format!("frame-{frames:04}/particles.vtp"))).unwrap(),
        "displacement",
    );
    let drift = back.iter().fold(0.0f32, |m, d| m.max(d.abs()));
    eprintln!("drift {drift} (size {})", size(&model));
    assert!(
        drift <= 1e-4 * size(&model),
        "the last frame is {drift} from rest"
    );
}

/// A closed box `size` (OBJ), corner at the origin.
fn write_box(path: &Path, size: Vec3) {
    let corner = |i: usize| {
        Vec3::new(
            (i >> 2 & 1) as f32 * size.x,
            (i >> 1 & 1) as f32 * size.y,
            (i & 1) as f32 * size.z,
        )
    };
    let triangles: Vec<[u32; 3]> = vec![
        [0, 1, 3],
        [0, 3, 2],
        [4, 6, 7],
        [4, 7, 5],
        [0, 4, 5],
        [0, 5, 1],
        [2, 3, 7],
        [2, 7, 6],
        [0, 2, 6],
        [0, 6, 4],
        [1, 5, 7],
        [1, 7, 3],
    ];
    let mesh = tissue::SurfaceMesh::new((0..8).map(corner).collect(), triangles);
    tissue::save_surface(&mesh, path).unwrap();
}

/// Models stage 2 cannot use are not written: a slab one
/// particle thick, ten particles for the phantom, a box scaled by 1e-30
/// (refused at once for its size: it took a minute to fail); each exits 1
/// saying why, and no model file appears. The elastic force on a poke 40
/// mm deep into the phantom's tip, which diverged before the tracker ran a
/// diverged elastic phase again with half the step, converges after one
/// such retry (the report says so) and folds nothing.
#[test]
fn unusable_models_are_not_written_and_a_deep_poke_converges_stepping_back() {
    let dir = tempfile::tempdir().unwrap();
    let slab = dir.path().join("slab.obj");
    write_box(&slab, Vec3::new(100.0, 100.0, 1.0));
    let tiny = dir.path().join("tiny.obj");
    write_box(&tiny, Vec3::splat(50e-30));
    let breast = assets().join("phantom-breast.obj");
    for (surface, particles, why) in [
        (&slab, "2000", "sample more particles"),
        (&breast, "10", "sample more particles"),
        (&tiny, "2000", "rescale it"),
    ] {
        let model = dir.path().join("model.vtp");
        let out = tissue(&[
            "sample",
            s(surface),
            "-n",
            particles,
            "-o",
            s(&model),
            "--backend",
            "cpu",
        ]);
        assert_eq!(out.status.code(), Some(1), "{}", text(&out));
        assert!(text(&out).contains(why), "{}", text(&out));
        assert!(
            !model.exists(),
            "{}: a model was written",
            surface.display()
        );
    }

    let (model_path, model) = sampled_model(dir.path());
    let poked = poked(&model.surface, 40.0);
    let poked_path = dir.path().join("poked.obj");
    tissue::save_surface(&poked, &poked_path).unwrap();
    let out_dir = dir.path().join("out");
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        s(&poked_path),
        "--force",
        "elastic",
        "-o",
        s(&out_dir),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let report = json(&out_dir.join("report.json"));
    // The full two-level step raises the potential: the phase steps back
    // to the state it accepted and goes on with half of it, with no
    // retry; the summary says so.
    assert_eq!(report["elastic_retries"], 0, "{report}");
    let backtracks = report["backtracks"].as_u64().unwrap();
    assert!(backtracks >= 1, "{report}");
    assert!(
        text(&out).contains("the elastic phase stepped back"),
        "{}",
        text(&out)
    );
    assert_eq!(report["inverted"]["count"], 0, "{report}");
}

/// A rerun into the same folder leaves none of the earlier run's files
/// that it does not write again: the report's `files` of the
/// earlier `deform`, and of each earlier `track` frame, name what to
/// remove; a file the user put there stays.
#[test]
fn a_rerun_leaves_no_files_of_the_earlier_run() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let sag = assets().join("phantom-sag.obj");
    let tumour = assets().join("phantom-tumour.obj");
    let points = dir.path().join("points.csv");
    std::fs::write(&points, "x,y,z\n15,-10,25\n").unwrap();
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    std::fs::copy(&sag, frames.join("f1.obj")).unwrap();
    let out = dir.path().join("out");
    let track = dir.path().join("track");
    let run = |carry: &[&str]| {
        let mut deform = vec![
            "deform",
            "--model",
            s(&model_path),
            "--surface",
            s(&sag),
            "-o",
            s(&out),
            "-q",
        ];
        deform.extend(carry);
        let result = tissue(&deform);
        assert!(result.status.success(), "{}", text(&result));
        let pattern = frames.join("*.obj");
        let mut tracked = vec![
            "track",
            "--model",
            s(&model_path),
            "--frames",
            s(&pattern),
            "-o",
            s(&track),
            "-q",
        ];
        tracked.extend(carry);
        let result = tissue(&tracked);
        assert!(result.status.success(), "{}", text(&result));
    };
    run(&["--points", s(&points), "--structure", s(&tumour)]);
    for written in [
        out.join("points.csv"),
        out.join("phantom-tumour.obj"),
        track.join("frame-0001/points.csv"),
        track.join("frame-0001/phantom-tumour.obj"),
    ] {
        assert!(written.exists(), "{}", written.display());
    }
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    run(&[]);
    for stale in [
        out.join("points.csv"),
        out.join("phantom-tumour.obj"),
        track.join("frame-0001/points.csv"),
        track.join("frame-0001/phantom-tumour.obj"),
    ] {
        assert!(
            !stale.exists(),
            "{} is left from the earlier run",
            stale.display()
        );
    }
    assert!(out.join("particles.vtp").exists());
    assert!(out.join("notes.txt").exists(), "not ours: kept");
    let report = json(&out.join("report.json"));
    assert_eq!(report["files"].as_array().unwrap().len(), 2, "{report}");
}

/// Output paths are checked before any work: an output under a
/// regular file is refused before the surface is even read (a broken
/// surface is not what the error names) and before a solve.
#[test]
fn outputs_are_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a-file");
    std::fs::write(&file, "").unwrap();
    let broken = dir.path().join("broken.obj");
    std::fs::write(&broken, "v 0 0 0\nf 1 2 3\n").unwrap();
    let out = tissue(&[
        "sample",
        s(&broken),
        "-n",
        "2000",
        "-o",
        s(&file.join("model.vtp")),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(text(&out).contains("cannot write"), "{}", text(&out));
    assert!(!text(&out).contains("broken.obj"), "{}", text(&out));

    let (model_path, _) = sampled_model(dir.path());
    let out = tissue(&[
        "deform",
        "--model",
        s(&model_path),
        "--surface",
        s(&assets().join("phantom-sag.obj")),
        "-o",
        s(&file.join("out")),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(text(&out).contains("cannot write"), "{}", text(&out));
    assert!(
        !text(&out).contains("iterations"),
        "it solved first: {}",
        text(&out)
    );
}

/// The files in `dir` whose names do not start with a dot (a run's
/// outputs; hidden ones are staged or temporary files), sorted.
fn visible_files(dir: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut names: Vec<String> = entries
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| !n.starts_with('.'))
        .collect();
    names.sort();
    names
}

/// A run that fails leaves none of its outputs: a landmark at 1e20 and a
/// rigid structure at 1e30 (refused before the solve, naming the point and
/// `another unit`); a displacement field named like an existing folder; a
/// write that fails as on a full disk (a file-size limit, `ulimit -f`,
/// with its signal ignored); and a run killed while it writes (the same
/// limit's signal), whose staged files the next run removes.
#[test]
fn a_failed_run_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, _) = sampled_model(dir.path());
    let model = s(&model_path).to_owned();
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let far = dir.path().join("far.csv");
    std::fs::write(&far, "x,y,z\n15,-10,25\n1e20,0,0\n").unwrap();
    let mut huge = tissue::phantom::default_tumour();
    for v in &mut huge.vertices {
        *v *= 1e30;
    }
    let huge_path = dir.path().join("huge.obj");
    tissue::save_surface(&huge, &huge_path).unwrap();
    let folder = dir.path().join("taken.nrrd");
    std::fs::create_dir_all(&folder).unwrap();
    let cases: [(&str, &str, &[&str]); 3] = [
        ("--points", s(&far), &["far.csv", "point 2", "another unit"]),
        (
            "--rigid-structure",
            s(&huge_path),
            &["huge.obj", "another unit"],
        ),
        ("--displacement-field", s(&folder), &["it is a folder"]),
    ];
    for (flag, value, expected) in cases {
        let out_dir = dir.path().join(format!("out{flag}"));
        let out = tissue(&[
            "deform",
            "--model",
            &model,
            "--surface",
            &sag,
            flag,
            value,
            "-o",
            s(&out_dir),
        ]);
        assert_eq!(out.status.code(), Some(1), "{flag}: {}", text(&out));
        for word in expected {
            assert!(text(&out).contains(word), "{flag}: {}", text(&out));
        }
        assert_eq!(visible_files(&out_dir), Vec::<String>::new(), "{flag}");
    }

    // A write that fails as on a full disk: the file-size limit with its
    // signal ignored makes the write fail (EFBIG), and the run says so.
    let out_dir = dir.path().join("full");
    let run = |shell: &str| {
        let command = format!(
            "{shell}exec '{}' deform --model '{model}' --surface '{sag}' --displacement-field \
             '{}' -o '{}' -q",
            env!("CARGO_BIN_EXE_tissue"),
            s(&out_dir.join("field.nrrd")),
            s(&out_dir)
        );
        std::process::Command::new("bash")
            .args(["-c", &command])
            .output()
            .unwrap()
    };
    let full = run("trap '' XFSZ; ulimit -f 64; ");
    assert_eq!(full.status.code(), Some(1), "{}", text(&full));
    assert!(text(&full).contains("File too large"), "{}", text(&full));
    assert_eq!(
        std::fs::read_dir(&out_dir).unwrap().count(),
        0,
        "files left"
    );
    // Killed by the file-size limit on its first large write.
    let killed = run("ulimit -f 64; ");
    assert!(!killed.status.success(), "{}", text(&killed));
    assert_eq!(visible_files(&out_dir), Vec::<String>::new());
    let whole = run("");
    assert!(whole.status.success(), "{}", text(&whole));
    let left = std::fs::read_dir(&out_dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect::<Vec<_>>();
    assert!(left.is_empty(), "left behind: {left:?}");
    assert_eq!(
        visible_files(&out_dir),
        ["field.nrrd", "particles.vtp", "report.json"]
    );
}

/// Two runs into one output folder at once: the second is refused before
/// any work (exit 1, naming the folder and the lock), its files never mixed
/// with the first's; once the first ends the folder is free again. The
/// first run is played by this test holding the folder's lock.
#[test]
fn a_second_run_into_a_busy_output_folder_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (model_path, model) = sampled_model(dir.path());
    let sag = s(&assets().join("phantom-sag.obj")).to_owned();
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let lock = std::fs::File::create(out.join(".tissue.lock")).unwrap();
    lock.lock().unwrap();
    let pattern = sag_frames(dir.path(), &model, 2);
    let runs: [Vec<&str>; 2] = [
        vec!["deform", "--model", s(&model_path), "--surface", &sag],
        vec!["track", "--model", s(&model_path), "--frames", &pattern],
    ];
    for run in &runs {
        let mut args = run.clone();
        args.extend(["-o", s(&out), "-q"]);
        let refused = tissue(&args);
        assert_eq!(refused.status.code(), Some(1), "{}", text(&refused));
        assert!(
            text(&refused).contains("another tissue run is writing into"),
            "{}",
            text(&refused)
        );
        assert_eq!(visible_files(&out), Vec::<String>::new());
    }
    lock.unlock().unwrap();
    drop(lock);
    let mut args = runs[0].clone();
    args.extend(["-o", s(&out), "-q"]);
    let free = tissue(&args);
    assert!(free.status.success(), "{}", text(&free));
    assert!(!out.join(".tissue.lock").exists(), "the lock file stays");
}
