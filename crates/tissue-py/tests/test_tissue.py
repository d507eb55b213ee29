"""The Python package against the library: what the README's example
does, the numbers it must give, and the errors it must raise."""

import re
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest

import tissue


@pytest.fixture(scope="module")
def model():
    return tissue.sample(tissue.phantom_breast(), particles=1500, seed=3)


def test_sampling_fills_the_phantom_with_the_asked_particles(model):
    assert len(model) == 1500
    positions = model.positions
    assert positions.shape == (1500, 3) and positions.dtype == np.float64
    assert model.radii.shape == (1500,) and (model.radii > 0).all()
    assert 0 < model.on_surface.sum() < 1500
    report = model.report
    assert report["particles"] == 1500 and report["converged"]
    vertices, triangles = model.surface
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    assert (positions >= lo - 1e-3).all() and (positions <= hi + 1e-3).all()


def test_the_same_seed_gives_the_same_model(model):
    again = tissue.sample(tissue.phantom_breast(), particles=1500, seed=3)
    np.testing.assert_array_equal(again.positions, model.positions)


def test_a_sag_moves_the_surface_particles_onto_the_sagged_skin(model):
    deformer = model.deformer(backend="cpu")
    assert deformer.backend == "cpu"
    sagged, _ = tissue.phantom_breast_sagged()
    report = deformer.solve(sagged)
    assert report["converged"] and report["iterations"] > 0
    moved = deformer.positions - model.positions
    # The sag is 12 mm at most; the surface particles move, the chest wall stays.
    assert 5.0 < np.linalg.norm(moved, axis=1).max() <= 12.5
    # A point carried along moves with the particles around it.
    inside = model.positions[~model.on_surface][:20]
    carried = deformer.carry(inside)
    assert carried.shape == (20, 3)
    assert np.linalg.norm(carried - inside, axis=1).max() > 0.1
    # Back at rest, within ten times the solve's tolerance (3e-5 of the size).
    deformer.reset()
    rest, _ = model.surface
    assert deformer.solve(rest)["converged"]
    size = np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))
    assert np.abs(deformer.positions - model.positions).max() <= 3e-4 * size


def test_a_rigid_motion_of_the_skin_carries_points_rigidly(model):
    vertices, _ = model.surface
    angle = np.radians(30.0)
    turn = np.array(
        [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0, 0, 1]]
    )
    shift = np.array([5.0, -3.0, 2.0])
    deformer = model.deformer(backend="cpu")
    assert deformer.solve(vertices @ turn.T + shift)["converged"]
    size = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    np.testing.assert_allclose(
        deformer.positions, model.positions @ turn.T + shift, atol=1e-4 * size
    )
    tumour = model.positions[~model.on_surface][:30] * 0.9
    np.testing.assert_allclose(
        deformer.carry(tumour), tumour @ turn.T + shift, atol=1e-4 * size
    )
    moved, transform = deformer.carry_rigid(tumour)
    np.testing.assert_allclose(moved, tumour @ turn.T + shift, atol=1e-4 * size)
    np.testing.assert_allclose(transform[:3, :3], turn, atol=1e-4)
    np.testing.assert_allclose(transform[:3, 3], shift, atol=1e-4 * size)
    np.testing.assert_array_equal(transform[3], [0, 0, 0, 1])
    with pytest.raises(tissue.TissueError, match="at least one vertex"):
        deformer.carry_rigid(np.zeros((0, 3)))


def test_lists_and_float32_arrays_are_taken_as_points(model):
    deformer = model.deformer(backend="cpu")
    sagged, _ = tissue.phantom_breast_sagged()
    deformer.solve(sagged.astype(np.float32))
    point = model.positions[7]
    from_list = deformer.carry([list(point)])
    assert from_list.shape == (1, 3)


def test_a_surface_from_arrays_and_from_a_file_give_the_same_model(tmp_path):
    vertices, triangles = tissue.phantom_breast()
    path = tmp_path / "breast.obj"
    with open(path, "w") as f:
        for v in vertices:
            f.write("v {} {} {}\n".format(*v))
        for t in triangles:
            f.write("f {} {} {}\n".format(*(t + 1)))
    from_file = tissue.sample(str(path), particles=300)
    from_arrays = tissue.sample((vertices, triangles), particles=300)
    np.testing.assert_allclose(from_file.positions, from_arrays.positions, atol=1e-4)
    saved = tmp_path / "model.vtp"
    from_file.save(str(saved))
    loaded = tissue.load_model(saved)
    np.testing.assert_allclose(loaded.positions, from_file.positions, atol=1e-5)
    assert loaded.report is None


def test_bad_input_raises_tissue_errors_naming_the_problem(model):
    vertices, triangles = tissue.phantom_breast()
    with pytest.raises(tissue.TissueError, match="open"):
        tissue.sample((vertices, triangles[:-1]), particles=100)
    with pytest.raises(tissue.TissueError, match="triangle 0 names vertex"):
        tissue.sample((vertices, triangles + len(vertices)), particles=100)
    with pytest.raises(tissue.TissueError, match=r"\(n, 3\)"):
        model.deformer(backend="cpu").solve(vertices[:, :2])
    with pytest.raises(tissue.TissueError, match="not finite"):
        bad = vertices.copy()
        bad[3, 1] = np.nan
        model.deformer(backend="cpu").solve(bad)
    with pytest.raises(tissue.TissueError):
        model.deformer(backend="cpu").solve(vertices[:-1])
    with pytest.raises(tissue.TissueError, match="unknown force"):
        model.deformer(force="stiff")
    with pytest.raises(tissue.TissueError, match="unknown backend"):
        model.deformer(backend="tpu")
    with pytest.raises(tissue.TissueError):
        tissue.sample("/nonexistent/breast.stl", particles=100)
    with pytest.raises(tissue.TissueError):
        tissue.sample(tissue.phantom_breast(), particles=0)


def test_a_solve_that_does_not_converge_warns(model):
    deformer = model.deformer(backend="cpu", max_iterations=2)
    sagged, _ = tissue.phantom_breast_sagged()
    with pytest.warns(RuntimeWarning, match="did not converge"):
        report = deformer.solve(sagged)
    assert not report["converged"] and report["iterations"] == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert model.deformer(backend="cpu").solve(sagged)["converged"]


def test_progress_is_told_every_iteration(model):
    steps = []
    sampled = tissue.sample(tissue.phantom_breast(), particles=500, progress=steps.append)
    assert [s["iteration"] for s in steps] == list(range(1, sampled.report["iterations"] + 1))
    assert all(isinstance(s["iteration"], int) and s["step_rms"] >= 0 for s in steps)

    solves = []
    sagged, _ = tissue.phantom_breast_sagged()
    report = model.deformer(backend="cpu").solve(sagged, progress=solves.append)
    assert [s["iteration"] for s in solves] == list(range(1, report["iterations"] + 1))
    assert [s["residual"] for s in solves] == pytest.approx(report["residual_history"])


def test_the_preparation_tells_its_stages(model):
    symmetric = []
    model.deformer(backend="cpu", force="symmetric", progress=symmetric.append)
    assert [s["stage"] for s in symmetric] == ["plan", "coarse_space"]
    assert all(s["description"] for s in symmetric)
    # The elastic force is the default.
    for force in [{}, {"force": "elastic"}]:
        elastic = []
        model.deformer(backend="cpu", progress=elastic.append, **force)
        assert [s["stage"] for s in elastic] == [
            "plan",
            "elastic_model",
            "coarse_space",
            "elastic_coarse",
        ]


def test_a_posture_with_a_given_stiffness_solves_from_the_unloaded_shape(model):
    sagged, _ = tissue.phantom_breast_sagged()
    steps = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        posed = model.deformer_in_posture(
            sagged, (0, 0, -1), (0, -1, 0), stiffness_kpa=3.0, backend="cpu",
            progress=steps.append,
        )
    posture = posed.posture
    assert posture["stiffness_kpa"] == 3.0 and not posture["stiffness_fitted"]
    assert posture["fit_residual"] is None and posture["fit_trials"] == []
    assert posture["unloaded_converged"] and 0 <= posture["unloaded_residual"] < 0.1
    assert 0 < posture["held_vertices"] < len(sagged)
    assert [s["solve"] for s in steps] == list(range(1, posture["solves"] + 1))
    # What happened in the solves, told of each and summed in the posture.
    assert posture["elastic_retries"] == sum(s["elastic_retries"] for s in steps)
    assert posture["backtracks"] == sum(s["backtracks"] for s in steps)
    # The deformed posture's gravity (towards -y) is the load inside.
    assert posture["load"][1] < 0 and posture["load"][0] == posture["load"][2] == 0
    assert posed.solve(sagged)["converged"]
    plain = model.deformer(backend="cpu", force="elastic")
    assert plain.posture is None
    assert plain.solve(sagged)["converged"]
    # The skin is the same; the interior hangs differently.
    apart = np.linalg.norm(posed.positions - plain.positions, axis=1)
    assert apart[model.on_surface].max() < 1e-3 < apart.max()


def test_a_posture_fits_the_stiffness_from_the_skin(model):
    sagged, _ = tissue.phantom_breast_sagged()
    posed = model.deformer_in_posture(sagged, (0, 0, -1), (0, -1, 0), backend="cpu")
    posture = posed.posture
    assert posture["stiffness_fitted"] and 0.1 <= posture["stiffness_kpa"] <= 100
    trials = [t for t in posture["fit_trials"] if t[1] is not None]
    # The first trial, then at least one small-strain estimate.
    assert len(trials) >= 2
    # The least residual wins, and it is the fit's.
    best = min(trials, key=lambda t: t[1])
    assert best[0] == pytest.approx(posture["stiffness_kpa"])
    assert best[1] == pytest.approx(posture["fit_residual"])
    assert posed.solve(sagged)["converged"]
    # The model has 1,500 particles, fewer than twice the coarse default
    # (2,000): fitted on itself; asked for 500, on a coarse model of the
    # surface.
    assert posture["fit_particles"] == len(model)
    coarse = model.deformer_in_posture(
        sagged, (0, 0, -1), (0, -1, 0), backend="cpu", fit_particles=500
    ).posture
    assert coarse["fit_particles"] == 500 and coarse["unloaded_converged"]


def test_the_held_region_is_given_as_indices_or_flags(model):
    sagged, _ = tissue.phantom_breast_sagged()
    rest, _ = model.surface
    still = np.linalg.norm(sagged - rest, axis=1) < 1e-6
    found = []
    for held in [None, still, np.flatnonzero(still), still.tolist()]:
        posed = model.deformer_in_posture(
            sagged, (0, 0, -1), (0, -1, 0), stiffness_kpa=3.0, held=held, backend="cpu"
        )
        found.append(posed.posture["held_vertices"])
    # Found: those that moved less than a thousandth of a connection
    # length, so the still ones and a few more.
    assert found[1:] == [still.sum()] * 3 and still.sum() <= found[0] < len(rest)


def test_a_posture_without_a_change_of_gravity_is_the_plain_deformer(model):
    sagged, _ = tissue.phantom_breast_sagged()
    with pytest.warns(RuntimeWarning, match="does not change"):
        posed = model.deformer_in_posture(sagged, (0, 0, -1), (0, 0, -1), backend="cpu")
    assert posed.posture["stiffness_kpa"] is None
    assert posed.solve(sagged)["converged"]


def test_bad_postures_raise_naming_the_problem(model):
    sagged, _ = tissue.phantom_breast_sagged()
    cases = [
        ({"gravity_rest": (0, 0, -20)}, "gravity_rest"),
        ({"density": -1.0}, "density"),
        ({"stiffness_kpa": 0.0}, "stiffness_kpa"),
        ({"unit": "ft"}, "unknown unit"),
        ({"held": []}, "no surface vertex is held"),
        ({"held": [10**9]}, "not a surface vertex"),
        ({"held": [True, False]}, "one per surface vertex"),
        ({"deformed": sagged[:-1]}, "vertices"),
        ({"fit_particles": 10}, "fit_particles"),
    ]
    for change, message in cases:
        arguments = {
            "deformed": sagged,
            "gravity_rest": (0, 0, -1),
            "gravity_deformed": (0, -1, 0),
            "stiffness_kpa": 3.0,
            "backend": "cpu",
        }
        arguments.update(change)
        with pytest.raises(tissue.TissueError, match=message):
            model.deformer_in_posture(**arguments)


def test_an_exception_in_progress_is_raised_after_the_work(model):
    def fail(step):
        raise ValueError(f"stop at {step['iteration']}")

    sagged, _ = tissue.phantom_breast_sagged()
    with pytest.raises(ValueError, match="stop at 1"):
        model.deformer(backend="cpu").solve(sagged, progress=fail)


def test_the_gil_is_released_while_sampling():
    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(1)
            stop.wait(0.001)

    thread = threading.Thread(target=tick)
    thread.start()
    before = len(ticks)
    tissue.sample(tissue.phantom_breast(), particles=3000)
    during = len(ticks) - before
    stop.set()
    thread.join()
    # Held, the GIL would let the other thread run only between calls.
    assert during > 20, during


def test_the_readme_example_runs_as_written(capsys):
    readme = Path(__file__).resolve().parents[3] / "README.md"
    blocks = re.findall(r"```python\n(.*?)```", readme.read_text(), re.S)
    assert len(blocks) == 1, "the README has one Python example"
    exec(compile(blocks[0], str(readme), "exec"), {})
    out = capsys.readouterr().out
    assert "converged: True" in out and "the tumour moved to" in out
    assert re.search(r"\d\.\d\d kPa; the tumour moved to", out)


def test_save_writes_what_the_extension_names(model, tmp_path):
    model.save(tmp_path / "m.vtp")
    assert len(tissue.load_model(tmp_path / "m.vtp")) == len(model)
    model.save(tmp_path / "m.csv")
    rows = (tmp_path / "m.csv").read_text().strip().splitlines()
    assert len(rows) == len(model) + 1, rows[:2]  # a header, then a row each
    first = np.array([float(x) for x in rows[1].split(",")])
    np.testing.assert_allclose(first, model.positions[0], rtol=1e-6)
    model.save(tmp_path / "m.ply")
    head = (tmp_path / "m.ply").read_bytes()[:200].decode("ascii", "replace")
    assert head.startswith("ply") and f"element vertex {len(model)}" in head
    with pytest.raises(tissue.TissueError):
        tissue.load_model(tmp_path / "m.csv")
    with pytest.raises(tissue.TissueError):
        model.save(tmp_path / "m.xyz")


def _renumbered(vertices, triangles, seed):
    """The same mesh with its vertices in another order, as another tool
    may write it."""
    order = np.random.default_rng(seed).permutation(len(vertices))
    where = np.empty_like(order)
    where[order] = np.arange(len(order))
    return vertices[order], where[triangles]


def test_a_deformed_mesh_in_its_own_vertex_order_is_matched_by_triangles(model, tmp_path):
    sagged, triangles = tissue.phantom_breast_sagged()
    rest, rest_triangles = model.surface
    np.testing.assert_array_equal(triangles, rest_triangles)
    expected = model.deformer(backend="cpu")
    expected.solve(sagged)
    vertices, shuffled = _renumbered(sagged, triangles, 5)
    deformer = model.deformer(backend="cpu")
    assert deformer.solve((vertices, shuffled))["converged"]
    np.testing.assert_allclose(deformer.positions, expected.positions, atol=1e-5)
    # A file another tool wrote, in its order: a path is read as the CLI reads it.
    path = tmp_path / "sagged.ply"
    with open(path, "w") as f:
        f.write(f"ply\nformat ascii 1.0\nelement vertex {len(vertices)}\n")
        f.write("property float x\nproperty float y\nproperty float z\n")
        f.write(f"element face {len(shuffled)}\nproperty list uchar int vertex_indices\n")
        f.write("end_header\n")
        for v in vertices:
            f.write("{!r} {!r} {!r}\n".format(*(float(x) for x in v)))
        for t in shuffled:
            f.write("3 {} {} {}\n".format(*t))
    from_file = model.deformer(backend="cpu")
    assert from_file.solve(str(path))["converged"]
    np.testing.assert_allclose(from_file.positions, expected.positions, atol=1e-4)
    # Another mesh is refused, naming the mismatch.
    with pytest.raises(tissue.TissueError, match="vertices|triangles"):
        model.deformer(backend="cpu").solve((vertices[:-3], shuffled[:-6]))


def test_points_outside_the_organ_warn_and_points_no_particle_reaches_raise(model):
    deformer = model.deformer(backend="cpu")
    deformer.solve(tissue.phantom_breast_sagged()[0])
    inside = model.positions[~model.on_surface][:5]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        deformer.carry(inside)
    with pytest.warns(RuntimeWarning, match="outside the model's rest surface"):
        deformer.carry([[1000.0, 0.0, 0.0]])
    with pytest.warns(RuntimeWarning, match="outside the model's rest surface"):
        deformer.carry_rigid(inside + [0.0, 0.0, 500.0])
    with pytest.raises(tissue.TissueError, match="another unit"):
        deformer.carry([[1e20, 0.0, 0.0]])


def test_one_point_and_bad_counts_are_told_plainly(model):
    deformer = model.deformer(backend="cpu")
    one = deformer.carry(model.positions[~model.on_surface][0])
    assert one.shape == (1, 3)
    with pytest.raises(tissue.TissueError, match="3 numbers"):
        deformer.carry([1.0, 2.0])
    with pytest.raises(tissue.TissueError, match="at least 4"):
        tissue.sample(tissue.phantom_breast(), particles=-5)


def test_the_connections_are_pairs_of_particles(model):
    pairs = model.connections
    assert pairs.ndim == 2 and pairs.shape[1] == 2 and len(pairs) > len(model)
    assert pairs.min() >= 0 and pairs.max() < len(model)
    assert (pairs[:, 0] != pairs[:, 1]).all()
    assert len({tuple(sorted(p)) for p in pairs.tolist()}) == len(pairs)


def test_the_package_ships_type_stubs_and_a_stripped_module():
    package = Path(tissue.__file__).parent
    assert (package / "py.typed").is_file()
    stubs = (package / "_tissue.pyi").read_text()
    for name in ["def sample", "class Model", "class Deformer", "def carry_rigid"]:
        assert name in stubs
    (module,) = [p for p in package.iterdir() if p.name.startswith("_tissue") and p.suffix in (".so", ".pyd")]
    assert module.stat().st_size < 20 * 2**20, f"{module.stat().st_size} bytes"


def test_meshes_of_trimesh_and_meshio_are_taken_as_they_are(model):
    trimesh = pytest.importorskip("trimesh")
    meshio = pytest.importorskip("meshio")
    vertices, triangles = tissue.phantom_breast()
    from_trimesh = tissue.sample(
        trimesh.Trimesh(vertices, triangles, process=False), particles=300
    )
    from_meshio = tissue.sample(
        meshio.Mesh(vertices, [("triangle", triangles)]), particles=300
    )
    from_arrays = tissue.sample((vertices, triangles), particles=300)
    np.testing.assert_array_equal(from_trimesh.positions, from_arrays.positions)
    np.testing.assert_array_equal(from_meshio.positions, from_arrays.positions)
    sagged, _ = tissue.phantom_breast_sagged()
    moved, shuffled = _renumbered(sagged, triangles, 9)
    expected = model.deformer(backend="cpu")
    expected.solve(sagged)
    for mesh in [
        trimesh.Trimesh(moved, shuffled, process=False),
        meshio.Mesh(moved, [("triangle", shuffled)]),
    ]:
        deformer = model.deformer(backend="cpu")
        assert deformer.solve(mesh)["converged"]
        np.testing.assert_allclose(deformer.positions, expected.positions, atol=1e-5)


def test_a_pyvista_like_mesh_is_read_through_its_regular_faces(model):
    # pyvista's PolyData exposes `points` and, for triangles, `regular_faces`.
    class PolyData:
        def __init__(self, points, faces):
            self.points, self.regular_faces = points, faces

    vertices, triangles = tissue.phantom_breast()
    from_pyvista = tissue.sample(PolyData(vertices, triangles), particles=300)
    from_arrays = tissue.sample((vertices, triangles), particles=300)
    np.testing.assert_array_equal(from_pyvista.positions, from_arrays.positions)


def test_every_surface_vtk_writes_is_sampled_from_its_path():
    # tests/fixtures/vtk: one surface as VTK writes it in each layout,
    # 3D Slicer's and pyvista's default save among them.
    fixtures = Path(__file__).resolve().parents[3] / "tests" / "fixtures" / "vtk"
    files = sorted(fixtures.glob("*.vt[kp]"))
    assert len(files) >= 20, files
    for path in files:
        model = tissue.sample(str(path), particles=300, backend="cpu")
        assert len(model) == 300, path.name


def test_results_are_written_as_the_command_line_writes_them(model, tmp_path):
    deformer = model.deformer(backend="cpu")
    with pytest.raises(tissue.TissueError, match="solve"):
        deformer.save_particles(tmp_path / "early.vtp")
    deformer.solve(tissue.phantom_breast_sagged()[0])
    # particles.vtp, tagged for 3D Slicer.
    deformer.save_particles(tmp_path / "particles.vtp", space="ras")
    text = (tmp_path / "particles.vtp").read_text()
    assert 'Name="displacement"' in text and 'Name="SPACE"' in text
    assert "82 65 83 0" in text  # "RAS"
    # The displacement field, a grid transform for Slicer.
    deformer.save_displacement_field(tmp_path / "field.nrrd")
    header = (tmp_path / "field.nrrd").read_bytes().split(b"\n\n")[0].decode()
    assert "intent_code:=1006" in header and "kinds: vector domain domain domain" in header
    # Landmarks from a markups file and a CSV, moved and written alike.
    inside = model.positions[~model.on_surface][:3]
    expected = deformer.carry(inside)
    markups = {
        "@schema": "https://raw.githubusercontent.com/slicer/slicer/main/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#",
        "markups": [
            {
                "type": "Fiducial",
                "coordinateSystem": "LPS",
                "controlPoints": [
                    {"id": str(k), "label": f"P{k}", "position": list(map(float, p))}
                    for k, p in enumerate(inside)
                ],
            }
        ],
    }
    import json

    (tmp_path / "in.mrk.json").write_text(json.dumps(markups))
    moved = deformer.carry_file(tmp_path / "in.mrk.json", tmp_path / "out.mrk.json")
    np.testing.assert_allclose(moved, expected, atol=1e-6)
    out = json.loads((tmp_path / "out.mrk.json").read_text())
    points = out["markups"][0]["controlPoints"]
    assert [p["label"] for p in points] == ["P0", "P1", "P2"]
    np.testing.assert_allclose([p["position"] for p in points], expected, atol=1e-4)
    np.savetxt(tmp_path / "in.csv", inside, delimiter=",", header="x,y,z", comments="")
    moved = deformer.carry_file(tmp_path / "in.csv", tmp_path / "out.csv")
    np.testing.assert_allclose(moved, expected, atol=1e-6)
    with pytest.raises(tissue.TissueError, match="overwrite"):
        deformer.carry_file(tmp_path / "in.csv", tmp_path / "in.csv")
    # A rigid structure's motion as an ITK transform.
    _, motion = deformer.carry_rigid(inside)
    tissue.save_motion(motion, tmp_path / "tumour.tfm")
    tfm = (tmp_path / "tumour.tfm").read_text()
    assert "AffineTransform_double_3_3" in tfm
    with pytest.raises(tissue.TissueError, match="4x4"):
        tissue.save_motion(np.eye(3), tmp_path / "bad.tfm")


def test_part_of_the_skin_may_be_observed(model):
    sagged, _ = tissue.phantom_breast_sagged()
    rest, _ = model.surface
    full = model.deformer(backend="cpu", force="elastic")
    full.solve(sagged)
    everything = model.deformer(backend="cpu", force="elastic", observed=np.ones(len(rest), bool))
    everything.solve(sagged)
    np.testing.assert_array_equal(everything.positions, full.positions)
    # The front half of the skin seen (the half nearer the apex, z large).
    seen = np.flatnonzero(rest[:, 2] > np.median(rest[:, 2]))
    half = model.deformer(backend="cpu", force="elastic", observed=seen)
    assert half.solve(sagged)["converged"]
    apart = np.linalg.norm(half.positions - full.positions, axis=1).max()
    assert apart > 1e-3, apart
    with pytest.raises(tissue.TissueError, match="observed: 3 flags"):
        model.deformer(backend="cpu", observed=[True, False, True])
    with pytest.raises(tissue.TissueError, match="observed: vertex"):
        model.deformer(backend="cpu", observed=[len(rest) + 5])


def test_a_turned_and_shifted_scan_is_fitted_back_onto_the_skin(tmp_path):
    vertices, triangles = tissue.phantom_breast()
    seen = vertices[vertices[:, 2] > vertices[:, 2].mean()]
    angle = np.radians(15.0)
    turn = np.array(
        [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]]
    )
    axis_turn = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.3), -np.sin(0.3)], [0.0, np.sin(0.3), np.cos(0.3)]])
    turn = axis_turn @ turn @ axis_turn.T
    centre = seen.mean(axis=0)
    moved = (seen - centre) @ turn.T + centre + [12.0, -16.0, 0.0]
    path = tmp_path / "scan.csv"
    np.savetxt(path, moved, delimiter=",", header="x,y,z", comments="")
    scan = tissue.load_cloud(path)
    assert scan.shape == moved.shape and np.allclose(scan, moved, atol=1e-4)

    fit = tissue.rigid_fit(scan, (vertices, triangles))
    assert fit["converged"] and abs(fit["angle_degrees"] - 15.0) < 0.1
    back = scan @ fit["rotation"].T + fit["translation"]
    assert np.abs(back - seen).max() < 0.05
    with pytest.raises(tissue.TissueError, match="reach"):
        tissue.rigid_fit(scan, (vertices, triangles), reach=-1.0)
    with pytest.raises(tissue.TissueError, match="unsupported file type"):
        tissue.load_cloud(tmp_path / "scan.xyz")


def test_fiducials_in_a_scans_frame_give_the_motion_that_puts_them_on_the_models():
    vertices, _ = tissue.phantom_breast()
    wall = vertices[np.abs(vertices[:, 2]) < 1e-6]
    fiducials = wall[np.linspace(0, len(wall) - 1, 5).astype(int)]
    angle = np.radians(15.0)
    turn = np.array(
        [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]]
    )
    shift = np.array([20.0, -5.0, 3.0])
    # The scan's frame: a model point p is seen at turn @ p + shift.
    seen = fiducials @ turn.T + shift

    fit = tissue.fiducial_fit(seen, fiducials)
    assert abs(fit["angle_degrees"] - 15.0) < 1e-3, fit
    assert fit["fiducials"] == 5 and fit["residual_max"] < 1e-3, fit
    assert np.allclose(fit["rotation"], turn.T, atol=1e-5)
    scan = vertices[vertices[:, 2] > vertices[:, 2].mean()] @ turn.T + shift
    back = scan @ fit["rotation"].T + fit["translation"]
    assert np.abs(back - vertices[vertices[:, 2] > vertices[:, 2].mean()]).max() < 1e-3

    with pytest.raises(tissue.TissueError, match="in the same order"):
        tissue.fiducial_fit(seen[:4], fiducials)
    with pytest.raises(tissue.TissueError, match="other units"):
        tissue.fiducial_fit(seen * 1000.0, fiducials)
    # Two fiducials swapped: they no longer correspond.
    with pytest.raises(tissue.TissueError, match="same order"):
        tissue.fiducial_fit(seen[[1, 0, 2, 3, 4]], fiducials)


def _cut_in_four(vertices, triangles):
    """The same surface with every triangle cut into four at its edges' midpoints."""
    vertices = [tuple(v) for v in vertices]
    middles = {}

    def middle(a, b):
        key = (min(a, b), max(a, b))
        if key not in middles:
            vertices.append(tuple((np.asarray(vertices[a]) + np.asarray(vertices[b])) / 2))
            middles[key] = len(vertices) - 1
        return middles[key]

    cut = []
    for a, b, c in triangles:
        ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
        cut += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)]
    return np.array(vertices), np.array(cut)


def test_the_skin_is_matched_to_a_surface_and_a_scan_without_correspondence():
    # The scan's points 1.7 mm apart, the skin particles about 5 mm.
    model = tissue.sample(tissue.phantom_breast(), particles=3000, seed=3)
    rest, triangles = model.surface
    sagged, _ = tissue.phantom_breast_sagged()
    wall = np.abs(sagged - rest).max(axis=1) < 1e-4
    assert 0 < wall.sum() < len(rest)
    other = _cut_in_four(sagged, triangles)
    deformer = model.deformer(backend="cpu", force="elastic", observed=wall)
    report = deformer.match_observation(surface=other)
    assert report["converged"] and report["pulled"] == report["skin"] > 0
    size = np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))
    assert report["residual_rms"] < 2e-3 * size
    # How sure: re-solved with the skin paired as the match paired it; the deformer
    # is left at its answer.
    answer = deformer.positions.copy()
    spread = deformer.uncertainty(samples=4)
    assert spread["converged"] and spread["radius"].max() > 0.05
    assert spread["radius"].min() == 0.0
    np.testing.assert_array_equal(deformer.positions, answer)
    # The front half as a scan: the skin it does not see is set aside.
    front = other[0][other[0][:, 2] > np.median(other[0][:, 2])]
    scan = deformer.match_observation(cloud=front)
    assert scan["converged"] and 0 < scan["pulled"] < scan["skin"]
    assert scan["residual_rms"] < 2e-3 * size
    # The same scan again from the last answer: one solve, already there.
    again = deformer.match_observation(cloud=front, from_last=True)
    assert again["converged"] and again["stages"] == 1
    assert again["iterations"] < scan["iterations"]
    assert again["residual_rms"] < 2e-3 * size
    # Nothing moved since: started at the last answer, predicted or not.
    plain = deformer.match_observation(cloud=front, from_last=True, predict=False)
    assert plain["converged"] and plain["stages"] == 1
    assert plain["iterations"] < scan["iterations"]
    with pytest.raises(tissue.TissueError, match="one of the two"):
        deformer.match_observation()
    # Paired with the nearest point instead of the smoothed plane.
    nearest = deformer.match_observation(surface=other, surface_smoothing=0.0)
    assert nearest["converged"] and nearest["residual_rms"] < 2e-3 * size
    assert nearest["iterations"] != report["iterations"]
    with pytest.raises(tissue.TissueError, match="surface_smoothing"):
        deformer.match_observation(surface=other, surface_smoothing=-1.0)
    with pytest.raises(tissue.TissueError, match="a quarter of the model's size"):
        deformer.match_observation(cloud=front + [0.0, 0.0, 1000.0])


def test_a_posture_is_fitted_to_an_observation_without_correspondence():
    # The phantom's sag (made by a map, not by gravity) in another
    # triangulation, and its front half as a scan: the skin matched without
    # gravity, the stiffness fitted to that, then matched with the deformed
    # posture's gravity inside, from the fit's guess.
    model = tissue.sample(tissue.phantom_breast(), particles=3000, seed=3)
    rest, triangles = model.surface
    sagged, _ = tissue.phantom_breast_sagged()
    wall = np.abs(sagged - rest).max(axis=1) < 1e-4
    other = _cut_in_four(sagged, triangles)
    size = np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))
    framed = model.deformer_in_posture(
        (sagged, triangles), (0, 0, -1), (0, -1, 0), held=wall, backend="cpu"
    )
    matched = model.deformer_in_posture(
        other, (0, 0, -1), (0, -1, 0), held=wall, backend="cpu"
    )
    a = framed.posture["stiffness_kpa"]
    b = matched.posture["stiffness_kpa"]
    assert matched.posture["stiffness_fitted"] and abs(np.log(a / b)) < np.log(2), (a, b)
    # The match without gravity converged; a frame of the rest surface has none.
    assert matched.posture["first_match_converged"] is True
    assert framed.posture["first_match_converged"] is None
    report = matched.match_observation(surface=other)
    assert report["converged"] and report["pulled"] == report["skin"] > 0
    assert report["residual_rms"] < 2e-3 * size
    front = other[0][other[0][:, 2] > np.median(other[0][:, 2])]
    scanned = model.deformer_in_posture(
        front, (0, 0, -1), (0, -1, 0), held=wall, backend="cpu", scan=True
    )
    assert scanned.posture["stiffness_fitted"]
    assert scanned.posture["first_match_converged"] is True
    scan = scanned.match_observation(cloud=front)
    assert scan["converged"] and 0 < scan["pulled"] < scan["skin"]
    assert scan["residual_rms"] < 2e-3 * size
    with pytest.raises(tissue.TissueError, match="held="):
        model.deformer_in_posture(front, (0, 0, -1), (0, -1, 0), scan=True, backend="cpu")
    with pytest.raises(tissue.TissueError, match="noise= is for an observation"):
        model.deformer_in_posture(
            (sagged, triangles), (0, 0, -1), (0, -1, 0), held=wall, noise=0.5, backend="cpu"
        )


def test_the_uncertainty_gives_every_particle_and_point_a_region(model):
    deformer = model.deformer(backend="cpu")
    with pytest.raises(tissue.TissueError, match="nothing solved"):
        deformer.uncertainty()
    sagged, _ = tissue.phantom_breast_sagged()
    assert deformer.solve(sagged)["converged"]
    answer = deformer.positions.copy()
    inside = model.positions[~model.on_surface][:5]
    spread = deformer.uncertainty(points=inside, samples=4)
    n = len(model)
    assert spread["converged"] and spread["solves"] > 4
    assert spread["radius"].shape == (n,) and spread["covariance"].shape == (n, 6)
    assert len(spread["dominant"]) == n
    assert spread["radius"].max() > 0.05
    # The chest wall did not move: the particles held on it are sure.
    assert spread["radius"].min() == 0.0
    assert spread["points_radius"].shape == (5,) and (spread["points_radius"] > 0).all()
    assert set(spread["dominant"]) <= {None, "poisson", "surface", "posture"}
    # The deformer is left at its answer.
    np.testing.assert_array_equal(deformer.positions, answer)
    # The same priors again start from the last call's re-solves: fewer
    # iterations, the same radii within the solves' tolerance.
    again = deformer.uncertainty(points=inside, samples=4)
    assert again["iterations"] < spread["iterations"]
    size = np.linalg.norm(answer.max(axis=0) - answer.min(axis=0))
    assert np.abs(again["radius"] - spread["radius"]).max() < 1e-3 * size
    assert again["carried"] == 0
    # Refreshing two re-solves a call: the first call makes them all, the
    # next two and carries the others from the call before.
    first = deformer.uncertainty(points=inside, samples=4, refresh=2)
    assert first["carried"] == 0 and first["solves"] == spread["solves"]
    later = deformer.uncertainty(points=inside, samples=4, refresh=2)
    assert later["solves"] == 2 and later["carried"] == spread["solves"] - 2
    assert np.abs(later["radius"] - spread["radius"]).max() < 1e-3 * size
    with pytest.raises(ValueError, match="refresh"):
        deformer.uncertainty(samples=4, refresh=0)
    # Nothing unknown: no spread.
    none = deformer.uncertainty(
        samples=4, surface_noise=0.0, poisson_range=(0.49, 0.49), posture_spread=0.0
    )
    assert none["solves"] == 0 and none["radius"].max() == 0.0
    with pytest.raises(tissue.TissueError, match="poisson"):
        deformer.uncertainty(poisson_range=(0.49, 0.45))
