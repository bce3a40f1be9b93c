"""Scenes (TOML), the run loop, its outputs (XDMF, VTU/PVD, CSV, PNG) and the csb command."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import meshio
import numpy as np
import pytest

import csb

GOOD = """\
[scene]
name = "tiny"
duration = 0.5

[solver]
dt = 0.01
substeps = 2
iterations = 5

[[mesh]]
name = "cloth"
shape = "cloth"
size = [1.0, 1.0]
resolution = [6, 6]
density = 0.2
stretch = { stiffness = 1.0 }
bending = { stiffness = 0.2 }
pin = { near = [[-0.5, 0.0, -0.5], [0.5, 0.0, -0.5]] }

[output]
fps = 20
"""


def scene_file(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_bundled_scenes_load_and_declare_only_what_they_use():
    names = csb.bundled_scenes()
    assert {"cloth_drop", "pendulum", "chain", "cloth_grid"} <= set(names)
    for name in names:
        assert csb.load_scene(name).name == name
    sim = csb.load_scene("pendulum").build()
    assert sim.model.num_particles == 2 and sim.model.num_constraints == 1  # one rod, nothing else
    sim = csb.load_scene("cloth_drop").build()
    assert sim.model.num_particles == 33 * 33
    assert np.count_nonzero(sim.model.inv_mass == 0) == 2
    pinned = sim.model.rest_positions[sim.model.inv_mass == 0]
    np.testing.assert_allclose(sorted(pinned[:, 0]), [-0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(pinned[:, 1:], [[1.0, -0.5], [1.0, -0.5]], atol=1e-6)


def test_run_writes_readable_outputs(tmp_path):
    scene = csb.load_scene(scene_file(tmp_path, GOOD))
    result = scene.run(tmp_path / "out")
    out = tmp_path / "out"
    frames = 11  # t = 0, 0.05, ..., 0.5 s
    assert result.steps == 50 and len(result.rows) == frames
    assert "tiny: 50 steps of 10 ms (pbd, 2 substeps x 5 iterations), 36 particles" in result.summary()

    # XDMF + HDF5 through meshio's reader: one topology, a time series of point data.
    with meshio.xdmf.TimeSeriesReader(str(out / "tiny.xdmf")) as reader:
        points, cells = reader.read_points_cells()
        assert points.shape == (36, 3) and cells[0].type == "triangle" and len(cells[0].data) == 50
        assert reader.num_steps == frames
        t, point_data, _ = reader.read_data(frames - 1)
        assert t == pytest.approx(0.5)
        final = points + point_data["displacement"]
        np.testing.assert_allclose(final, result.simulation.state.x, atol=1e-12)

    # The ParaView collection lists one VTU per frame, and each VTU holds the moved points.
    pvd = ET.parse(out / "tiny.pvd").getroot()
    sets = pvd.findall("./Collection/DataSet")
    assert len(sets) == frames
    last = meshio.read(out / sets[-1].get("file"))
    np.testing.assert_allclose(last.points, result.simulation.state.x, atol=1e-12)
    assert set(last.point_data) == {"velocity", "strain", "group", "pinned"}
    assert last.point_data["pinned"].sum() == 2

    with open(out / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == frames and float(rows[-1]["t"]) == pytest.approx(0.5)
    energy = [float(r["mechanical_energy"]) for r in rows]
    assert energy[-1] < energy[0]  # PBD dissipates; the pinned cloth has fallen and swung
    png = (out / "summary.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


@pytest.mark.parametrize("method, solver, label", [
    ("pbd", "gauss-seidel", "PBD Gauss-Seidel"),
    ("xpbd", "jacobi", "XPBD Jacobi"),
    ("jakobsen", "gauss-seidel", "Jakobsen (Verlet) Gauss-Seidel"),
])
def test_summary_png_is_titled_with_the_method_that_ran(tmp_path, monkeypatch, method, solver, label):
    import csb.runner

    titles = []
    real = csb.runner.plot_summary

    def spy(path, rows, title):
        titles.append(title)
        return real(path, rows, title)

    monkeypatch.setattr(csb.runner, "plot_summary", spy)
    text = GOOD.replace("[solver]\n", f'[solver]\nmethod = "{method}"\nsolver = "{solver}"\n')
    text = text.replace("fps = 20\n", "fps = 20\nxdmf = false\nvtu = false\n")
    text = text.replace("bending = { stiffness = 0.2 }", "bending = { stiffness = 0.2, compliance = 1.0 }")  # 1/(N m), for XPBD
    result = csb.load_scene(scene_file(tmp_path, text)).run(tmp_path / "out")
    assert titles == [f"tiny: 36 particles, {label}, dt = 10 ms, 2 substeps x 5 iterations"]
    assert tmp_path / "out" / "summary.png" in result.files


def test_two_runs_of_a_scene_give_identical_bits(tmp_path):
    path = scene_file(tmp_path, GOOD)
    a = csb.load_scene(path).run(None)
    b = csb.load_scene(path).run(None)
    assert np.array_equal(a.simulation.state.x, b.simulation.state.x)
    assert [r["mechanical_energy"] for r in a.rows] == [r["mechanical_energy"] for r in b.rows]


def bad(tmp_path, text):
    return scene_file(tmp_path, text, "bad.toml")


@pytest.mark.parametrize(
    "edit, message",
    [
        (("duration = 0.5", "duration = -1"), r"bad\.toml:3: scene\.duration: must be a duration > 0 s, got -1"),
        (("iterations = 5", "iteration = 5"), r"bad\.toml:8: solver\.iteration: unknown key; expected one of: .*iterations"),
        (("substeps = 2", "substeps = 0"), r"bad\.toml:7: solver\.substeps: must be an integer in \[1, 1000000\], got 0"),
        (("dt = 0.01", "dt = \"fast\""), r"bad\.toml:6: solver\.dt: must be a time step > 0 s, got 'fast'"),
        (("dt = 0.01", "dt = 1.0"), r"solver\.dt: the time step 1\.0 s is longer than the scene's duration 0\.5 s"),
        (("stretch = { stiffness = 1.0 }", "stretch = { stiffness = 1.5 }"),
         r"bad\.toml:16: mesh\[0\] \(cloth\)\.stretch\.stiffness: must be a stiffness in \[0, 1\], got 1\.5"),
        (("bending = { stiffness = 0.2 }", "bending = { stifness = 0.2 }"),
         r"bad\.toml:17: mesh\[0\] \(cloth\)\.bending\.stifness: unknown key; expected one of: compliance, stiffness"),
        (("stretch = { stiffness = 1.0 }", "stretch = { stiffness = 1.0, compliance = -1e-4 }"),
         r"bad\.toml:16: mesh\[0\] \(cloth\)\.stretch\.compliance: must be a compliance >= 0 \(m/N\)"),
        (("density = 0.2", "density = 0.0"), r"bad\.toml:15: mesh\[0\] \(cloth\)\.density: must be > 0 \(kg/m²\)"),
        (("density = 0.2", "# no mass"), r"mesh\[0\] \(cloth\): give exactly one of 'mass' \(kg\), 'density'"),
        (("resolution = [6, 6]", "resolution = [6, 1]"), r"bad\.toml:14: .*resolution: must be \[nx, ny\] with at least 2"),
        (("shape = \"cloth\"", "shape = \"cube\""), r"bad\.toml:12: .*shape: must be one of 'cloth', 'chain', 'pendulum'"),
        (("[solver]", "[solver]\nmethod = \"xpb\""), r"solver\.method: must be one of 'pbd', 'xpbd', 'small-steps', 'jakobsen', .*'backward-euler'.*, got 'xpb'"),
        (("[solver]", "[solver]\nmethod = \"jakobsen\"\ndamping = 0.1"),
         r"bad\.toml:5: solver: damping \(Müller 2007 §3\.5\) acts on stored velocities"),
        (("fps = 20", "fps = 20\nmovie = true"), r"bad\.toml:22: output\.movie: unknown key"),
        (("size = [1.0, 1.0]", "size = [1.0, 1.0\n"), r"bad\.toml: not valid TOML: Unclosed array \(at line 15"),
        (("pin = { near = [[-0.5, 0.0, -0.5], [0.5, 0.0, -0.5]] }", "pin = { near = [[-0.5, 0.3, -0.5]] }"),
         r"mesh 'cloth' pin\.near: the vertex nearest to \[-0\.5, 0\.3, -0\.5\] is 0\.3 m away"),
        (("pin = { near = [[-0.5, 0.0, -0.5], [0.5, 0.0, -0.5]] }", "pin = { indices = [36] }"),
         r"mesh 'cloth' pin\.indices: vertex 36 is out of range \(the mesh has 36 vertices"),
        (("pin = { near = [[-0.5, 0.0, -0.5], [0.5, 0.0, -0.5]] }", "pin = { }"),
         r"bad\.toml:18: mesh\[0\] \(cloth\)\.pin: give 'indices'"),
    ],
)
def test_scene_errors_name_file_key_and_line(tmp_path, edit, message):
    old, new = edit
    assert old in GOOD
    path = bad(tmp_path, GOOD.replace(old, new))
    with pytest.raises(csb.SceneError, match=message):
        csb.load_scene(path).build()


@pytest.mark.parametrize("method", ["xpbd", "jakobsen"])
def test_scene_method_reaches_the_stepper(tmp_path, method):
    text = GOOD.replace("[solver]", f'[solver]\nmethod = "{method}"\nsolver = "jacobi"')
    sim = csb.load_scene(scene_file(tmp_path, text)).build()
    s = sim.stepper.settings
    assert s.method == method and s.solver == "jacobi"
    assert s.front_end == ("verlet" if method == "jakobsen" else "euler")


COMPLIANT = GOOD.replace("stretch = { stiffness = 1.0 }", "stretch = { stiffness = 1.0, compliance = 1e-5 }").replace(
    "bending = { stiffness = 0.2 }", "bending = { stiffness = 0.2, compliance = 0.5 }")


EXPLICIT = {"explicit-euler", "symplectic-euler", "velocity-verlet"}


@pytest.mark.parametrize("method", [m.name for m in csb.methods() if not m.pbd_variant])
def test_every_method_steps_a_scene(tmp_path, method):
    """Every registered method outside the position-based pipeline runs a scene that declares its
    compliances, made with the scene's dt, substeps and iterations (an explicit method at a time
    step it can take: 1e-4 s). Small steps is XPBD's stepper set up with one iteration."""
    text = COMPLIANT.replace("[solver]", f'[solver]\nmethod = "{method}"')
    if method in EXPLICIT:
        text = text.replace("dt = 0.01", "dt = 0.0001").replace("duration = 0.5", "duration = 0.01")
    sim = csb.load_scene(scene_file(tmp_path, text)).build()
    assert sim.stepper.name() == ("xpbd" if method == "small-steps" else method)
    sim.stepper.step(sim.model, sim.state, 3)
    assert np.all(np.isfinite(sim.state.x)) and sim.state.step == 3


@pytest.mark.parametrize("edit, message", [
    ('method = "implicit-euler"\n[solver.settings]\ncg_iterations = 0',
     r"solver: setting 'cg_iterations' must be an integer in \[1, "),
    ('method = "implicit-euler"\n[solver.settings]\ncg_iteration = 5',
     r"solver: method 'implicit-euler' has no setting 'cg_iteration'; its settings are .*'cg_iterations'"),
    ('method = "implicit-euler"\n[solver.settings]\ncg_iterations = [5]',
     r"solver\.settings\.cg_iterations: must be a boolean, a number or a string"),
    ('method = "implicit-euler"\nsolver = "jacobi"',
     r"solver: solver is a setting of the position-based methods; 'implicit-euler' does not read it"),
    ('method = "pbd"\n[solver.settings]\ncg_iterations = 5',
     r"solver: \[solver\.settings\] are the settings of methods outside the position-based pipeline"),
])
def test_method_settings_errors_are_named(tmp_path, edit, message):
    text = COMPLIANT.replace("[solver]\n", "[solver]\n" + edit.split("\n[solver.settings]")[0] + "\n")
    if "[solver.settings]" in edit:
        text = text.replace("[[mesh]]", "[solver.settings]" + edit.split("[solver.settings]")[1] + "\n\n[[mesh]]")
    with pytest.raises(csb.SceneError, match=message):
        csb.load_scene(bad(tmp_path, text)).build()


def test_scene_compliance_reaches_the_model(tmp_path):
    text = GOOD.replace("stretch = { stiffness = 1.0 }", "stretch = { compliance = 1e-5 }")
    model = csb.load_scene(scene_file(tmp_path, text)).build().model
    assert np.all(model.distance["compliance"] == 1e-5) and np.all(model.distance["stiffness"] == 1.0)
    assert np.all(model.bending["compliance"] == 0.0)


def test_scene_mesh_files_are_relative_to_the_scene(tmp_path):
    (tmp_path / "meshes").mkdir()
    meshio.write(tmp_path / "meshes" / "sheet.ply", meshio.Mesh(
        csb.cloth_grid(1, 1, 4, 4).vertices, [("triangle", csb.cloth_grid(1, 1, 4, 4).triangles)]))
    text = GOOD.replace('shape = "cloth"\nsize = [1.0, 1.0]\nresolution = [6, 6]\n', 'file = "meshes/sheet.ply"\n')
    sim = csb.load_scene(scene_file(tmp_path, text)).build()
    assert sim.model.num_particles == 16
    missing = text.replace("sheet.ply", "nothere.ply")
    with pytest.raises(FileNotFoundError, match=r"meshes/nothere\.ply: no such file"):
        csb.load_scene(scene_file(tmp_path, missing)).build()
    with pytest.raises(FileNotFoundError, match=r"no such scene file, and no bundled scene of that name"):
        csb.load_scene(tmp_path / "nothere.toml")


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "csb.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def test_cli_run_and_errors(tmp_path):
    path = scene_file(tmp_path, GOOD)
    r = run_cli("run", str(path), "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "tiny: 50 steps of 10 ms" in r.stdout and "max strain" in r.stdout
    assert (tmp_path / "out" / "tiny" / "summary.png").exists()
    r = run_cli("run", str(bad(tmp_path, GOOD.replace("duration = 0.5", "duration = 0"))), cwd=tmp_path)
    assert r.returncode == 2 and "csb: error:" in r.stderr and "scene.duration" in r.stderr
    r = run_cli("scenes", cwd=tmp_path)
    assert r.returncode == 0 and "cloth_drop" in r.stdout
    r = run_cli("info", cwd=tmp_path)
    assert r.returncode == 0 and "sundials" in r.stdout and ".fbx" in r.stdout


def test_cli_version_and_run_overrides(tmp_path):
    """`csb --version` prints the version build_info reports; `csb run` takes the method, the time
    step, sub-steps, iterations, duration and frame rate from the command line over the scene's,
    and refuses an impossible one by name."""
    r = run_cli("--version", cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.strip() == f"csb {csb.build_info()['csb']}"
    path = scene_file(tmp_path, GOOD)
    r = run_cli("run", str(path), "--quiet", "--method", "xpbd", "--dt", "0.02", "--substeps", "4", "--iterations", "1",
                "--duration", "0.2", "--fps", "10", "--format", "csv", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "tiny: 10 steps of 20 ms (xpbd, 4 substeps x 1 iterations)" in r.stdout, r.stdout
    rows = list(csv.DictReader((tmp_path / "out" / "tiny" / "metrics.csv").read_text().splitlines()))
    assert len(rows) == 3 and float(rows[-1]["t"]) == pytest.approx(0.2)  # t = 0, 0.1, 0.2 s at 10 frames per second
    r = run_cli("run", str(path), "--dt", "-1", cwd=tmp_path)
    assert r.returncode == 2 and "argument --dt: must be a finite number > 0, got -1" in r.stderr
    r = run_cli("run", str(path), "--method", "vbd", cwd=tmp_path)
    assert r.returncode == 2 and "csb: error:" in r.stderr and "damping" not in r.stderr.split("error:")[0]


def info_lines(capsys) -> dict[str, str]:
    from csb.cli import main

    assert main(["info"]) == 0
    return {line[:13].strip(): line[14:] for line in capsys.readouterr().out.splitlines()}


def test_cli_info_reports_the_kernels_in_use_beside_the_compiled_baseline(tmp_path, capsys):
    """`csb info` names the instruction set the build targets for all code (build_info's simd,
    SSE2 in the portable build) and, apart from it, the copy of the blocked kernels that runs:
    the one kernels.kernel_isa() reports, whichever is forced."""
    r = run_cli("info", cwd=tmp_path)
    lines = {line[:13].strip(): line[14:] for line in r.stdout.splitlines()}
    baseline = csb.build_info()["simd"]
    assert lines["simd baseline"] == f"{baseline} (compiled for all code)"
    assert "simd" not in lines  # no unlabelled line to mistake for the kernels'
    best = csb.kernels.kernel_isa("auto")  # what a fresh process picks, as `csb info` above did
    assert lines["simd kernels"].startswith(f"{best}: ")
    order = ("sse2", "avx2", "avx512")
    isas = order[:order.index(best) + 1] if best in order else ("native",)
    try:
        for isa in isas:
            if isa != "native":
                assert csb.kernels.kernel_isa(isa) == isa
            lines = info_lines(capsys)
            assert lines["simd baseline"] == f"{baseline} (compiled for all code)"
            assert lines["simd kernels"].startswith(f"{isa}: "), isa
    finally:
        csb.kernels.kernel_isa("auto")
    if best == "avx512":
        assert lines["simd kernels"].startswith("avx512: bending in AVX-512, distance in AVX2 (")


def test_the_readme_command_line_examples_run_as_written(tmp_path):
    """Each command of the README's command-line block (the one with csb --version) runs from a
    fresh folder and succeeds."""
    import re
    import shlex

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    (block,) = [b for b in re.findall(r"```sh\n(.*?)```", text, re.S) if "csb --version" in b]
    exe = Path(sys.executable).parent / "csb"
    commands = [shlex.split(line.split("#")[0]) for line in block.splitlines() if line.startswith("csb ")]
    assert len(commands) == 5
    # `csb render` needs the viewer: where it cannot load (a wheel without the system's display
    # libraries), that command says so, in one line, and the others run.
    viewer = csb.viewer_available() or os.environ.get("CSB_REQUIRE_VIEWER") == "1"
    for argv in commands:
        r = subprocess.run([exe, *argv[1:]], capture_output=True, text=True, cwd=tmp_path, timeout=300)
        if argv[1] == "render" and not viewer:
            assert r.returncode == 2 and r.stderr.count("\n") == 1 and "the viewer" in r.stderr, r.stderr
            continue
        assert r.returncode == 0, (argv, r.stderr)
    assert (tmp_path / "out" / "cloth_drop" / "cloth_drop.usd").exists()
    assert (tmp_path / "out" / "cloth_grid" / "metrics.csv").exists()  # the float32 run
    assert (tmp_path / "out" / "cloth_drop" / "frames" / "frame_00059.png").exists() or not viewer
