"""A method brought as a plug-in: examples/plugin (XPBD over distance constraints, built here with
CMake against the csb_plugin.h the package installs) is loaded with csb.load_plugin and stepped
like a built-in. It performs csb's XPBD operations in csb's sequential order, so it gives
PbdStepper(method="xpbd", ordering="sequential")'s bits; small C plug-ins compiled here check what
csb does with a plug-in that is missing, not a library, incomplete, of another interface version,
failing, refusing its settings or writing NaN."""

from __future__ import annotations

import os
import pickle
import shutil
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

import csb
from csb.studies import make_stepper, swinging_chain

ROOT = Path(__file__).resolve().parents[1]
CXX = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")
CC = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
pytestmark = pytest.mark.skipif(CXX is None, reason="no C++ compiler on PATH (c++, g++, clang++ or $CXX) to build a plug-in")


def run(*cmd) -> None:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"


@pytest.fixture(scope="module")
def example(tmp_path_factory) -> Path:
    """examples/plugin built as a user would, against the installed header (warnings are errors)."""
    build = tmp_path_factory.mktemp("plugin")
    if shutil.which("cmake"):
        run("cmake", "-S", ROOT / "examples" / "plugin", "-B", build, f"-DCMAKE_CXX_COMPILER={CXX}",
            f"-DCSB_PLUGIN_INCLUDE_DIR={csb.plugin_include_dir()}", "-DCMAKE_CXX_FLAGS=-Werror")
        run("cmake", "--build", build)
    else:
        run(CXX, "-std=c++17", "-O2", "-shared", "-fPIC", "-fvisibility=hidden", "-ffp-contract=off", "-Wall", "-Wextra",
            "-Werror", f"-I{csb.plugin_include_dir()}", ROOT / "examples" / "plugin" / "my_xpbd.cpp", "-o",
            build / "libmy_xpbd.so")
    (library,) = build.glob("libmy_xpbd.so")
    return library


# A plug-in in plain C (the header is C), whose step moves every coordinate by 1 m and then
# misbehaves as compiled: -DFAIL_AT=k fails at step k, -DNAN_AT=k writes a NaN there, -DCODE_AT=k
# returns an unknown code without a message, -DABI=v reports version v, -DNO_STEP exports no step.
TEST_PLUGIN = r"""
#include "csb_plugin.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#ifndef ABI
#define ABI CSB_PLUGIN_ABI_VERSION
#endif
int csb_plugin_abi_version(void) { return ABI; }
const char* csb_plugin_name(void) { return "test-plugin"; }
void* csb_plugin_create(const csb_settings* s, char* error, size_t size) {
  if (s->iterations > 100) {
    snprintf(error, size, "at most 100 iterations, got %d", (int)s->iterations);
    return NULL;
  }
  return malloc(1);
}
#ifndef NO_STEP
int csb_plugin_step(void* handle, const csb_model_view* m, csb_state_view* st, int64_t steps, char* error,
                    size_t size) {
  int64_t k;
  (void)handle, (void)steps, (void)error, (void)size;
  for (k = 0; k < 3 * m->num_particles; ++k) st->positions[k] += 1.0;
#ifdef FAIL_AT
  if (st->step == FAIL_AT) {
    snprintf(error, size, "the solver did not converge");
    return CSB_PLUGIN_FAILED;
  }
#endif
#ifdef NAN_AT
  if (st->step == NAN_AT) st->velocities[3 * 2 + 1] = NAN;
#endif
#ifdef CODE_AT
  if (st->step == CODE_AT) return 7;
#endif
  return CSB_PLUGIN_OK;
}
#endif
void csb_plugin_destroy(void* handle) { free(handle); }
"""


@pytest.fixture(scope="module")
def build_c(tmp_path_factory):
    """Compiles TEST_PLUGIN with the given -D flags as C99 (warnings are errors); returns its path."""
    folder = tmp_path_factory.mktemp("c-plugins")
    source = folder / "test_plugin.c"
    source.write_text(TEST_PLUGIN)
    compiler = CC or CXX

    def build(name: str, *defines: str) -> Path:
        out = folder / f"lib{name}.so"
        lang = ["-std=c99"] if compiler == CC else ["-x", "c++", "-std=c++17"]
        run(compiler, *lang, "-shared", "-fPIC", "-Wall", "-Wextra", "-pedantic", "-Werror",
            f"-I{csb.plugin_include_dir()}", *defines, source, "-o", out)
        return out

    return build


def chain_xpbd(**kw):
    return csb.PbdStepper(method="xpbd", ordering="sequential", **kw)


@pytest.mark.parametrize("dt,substeps,iterations", [(1 / 60, 1, 10), (0.005, 2, 20), (0.001, 1, 1)])
def test_example_is_csbs_sequential_xpbd_to_the_bit(example, dt, substeps, iterations):
    """The example does XPBD's operations in the constraints' order without fused multiply-adds,
    as csb's sequential XPBD does: 2 s of the swinging chain give the same bits."""
    model = swinging_chain()
    mine, theirs = model.initial_state(), model.initial_state()
    steps = round(2.0 / dt)
    csb.load_plugin(example)(dt=dt, substeps=substeps, iterations=iterations).step(model, mine, steps)
    chain_xpbd(dt=dt, substeps=substeps, iterations=iterations).step(model, theirs, steps)
    assert np.array_equal(mine.x, theirs.x) and np.array_equal(mine.v, theirs.v)
    assert mine.step == theirs.step == steps and mine.t == pytest.approx(2.0, rel=1e-12)


def test_example_against_csbs_default_xpbd(example):
    """csb's default XPBD sweeps the chain's links in colours (even links, then odd), another
    Gauss-Seidel order, so the two differ by rounding, not by method: 5.6e-14 m after 2 s here
    (measured); the tolerance, 1e-9 m, is 2e-8 of a 5 cm link."""
    model = swinging_chain()
    mine, theirs = model.initial_state(), model.initial_state()
    csb.load_plugin(example)(dt=0.005, substeps=2, iterations=20).step(model, mine, 400)
    csb.make_integrator("xpbd", 0.005, substeps=2, iterations=20).step(model, theirs, 400)
    assert np.abs(np.asarray(mine.x) - np.asarray(theirs.x)).max() < 1e-9
    assert np.abs(np.asarray(mine.x) - np.asarray(model.rest_positions)).max() > 0.05  # it swung


def test_free_fall_against_the_closed_form(example):
    """An unpinned chain at rest length falls as one body. The scheme's positions after N
    sub-steps of h are y0 - g h² N(N+1)/2 = y0 - g t²/2 - g h t/2: the closed form plus the
    first-order term of semi-implicit Euler; its velocity is -g t exactly."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(4, 0.1), density=0.1, stretch_compliance=1e-6)
    model = b.build()
    state = model.initial_state()
    dt, substeps, g = 0.01, 4, 9.81
    csb.load_plugin(example)(dt=dt, substeps=substeps, gravity=(0, -g, 0)).step(model, state, 100)
    h, t = dt / substeps, state.t
    x, x0 = np.asarray(state.x), np.asarray(model.rest_positions)
    assert t == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(x[:, 1], x0[:, 1] - g * t * t / 2 - g * h * t / 2, rtol=0, atol=1e-9)
    np.testing.assert_allclose(x[:, [0, 2]], x0[:, [0, 2]], rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(state.v), np.tile([0, -g * t, 0], (len(x), 1)), rtol=0, atol=1e-9)


def test_a_plugin_is_an_integrator_wherever_one_is_taken(example):
    """The Plugin is a callable making an Integrator from dt, iterations, substeps and gravity,
    as csb.studies.make_stepper takes one; two runs give the same bits; it pickles by its path."""
    plugin = csb.load_plugin(str(example))
    assert plugin.name == "my-xpbd" and plugin.abi_version == 1 and plugin.path == str(example)
    stepper = make_stepper(plugin, dt=0.01, iterations=5, substeps=2)
    assert isinstance(stepper, csb.Integrator) and isinstance(stepper, csb.PluginIntegrator)
    assert (stepper.name(), stepper.dt(), stepper.substeps, stepper.iterations) == ("my-xpbd", 0.01, 2, 5)
    assert stepper.plugin.path == plugin.path and list(stepper.gravity) == [0, -9.81, 0]
    assert repr(stepper) == "<PluginIntegrator 'my-xpbd', dt = 0.01 s>"
    model = swinging_chain()
    runs = []
    for again in (plugin, csb.load_plugin(example), pickle.loads(pickle.dumps(plugin))):
        state = model.initial_state()
        again(dt=0.01, iterations=5, substeps=2).step(model, state, 150)
        runs.append((np.array(state.x), np.array(state.v)))
    for x, v in runs[1:]:
        assert np.array_equal(x, runs[0][0]) and np.array_equal(v, runs[0][1])
    # An interrupt is asked between steps; the state is left at the end of a step.
    state = model.initial_state()
    with pytest.raises(csb.Error, match="interrupted after step 1 "):
        stepper.step(model, state, 5, interrupt=lambda: True)
    assert state.step == 1


def test_threads_each_with_their_own_integrator(example):
    """Two integrators of one plug-in step two states at once in two threads (the step releases
    the GIL), with the bits of one after the other."""
    plugin, model = csb.load_plugin(example), swinging_chain()
    states = [model.initial_state() for _ in range(2)]
    threads = [threading.Thread(target=plugin(dt=0.002, iterations=20).step, args=(model, s, 500)) for s in states]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    alone = model.initial_state()
    plugin(dt=0.002, iterations=20).step(model, alone, 500)
    assert all(np.array_equal(s.x, alone.x) for s in states)


def test_the_plugin_refuses_a_model_it_cannot_step(example):
    """The example projects distance constraints only, and says so (CSB_PLUGIN_BAD_INPUT): a
    csb.ParameterError naming the plug-in and its file, the state untouched."""
    model = csb.load_scene("cloth_drop").build().model
    state = model.initial_state()
    with pytest.raises(csb.ParameterError, match=r"plug-in 'my-xpbd' \(.*libmy_xpbd.so\) failed at step 0 .*distance "
                                                 r"constraints only"):
        csb.load_plugin(example)(dt=0.01).step(model, state)
    assert state.step == 0 and np.array_equal(state.x, model.rest_positions)


def test_bad_paths(tmp_path):
    with pytest.raises(FileNotFoundError, match="plug-in .*nothere.so does not exist"):
        csb.load_plugin(tmp_path / "nothere.so")
    text = tmp_path / "notes.so"
    text.write_text("not a library\n")
    with pytest.raises(csb.ParameterError, match=r"plug-in .*notes.so is not a shared library csb can load: "):
        csb.load_plugin(text)
    with pytest.raises(csb.ParameterError, match="is not a file"):
        csb.load_plugin(tmp_path)
    with pytest.raises(csb.ParameterError, match="path is empty"):
        csb.load_plugin("")
    with pytest.raises(csb.ParameterError, match="path must be a str or an os.PathLike"):
        csb.load_plugin(3)


def test_a_name_without_a_folder_is_the_working_directorys(example, tmp_path, monkeypatch):
    """dlopen would search the library path for a bare name; csb takes the file the user named."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError, match="libm.so.6 does not exist"):
        csb.load_plugin("libm.so.6")
    shutil.copy(example, tmp_path / "libmine.so")
    assert csb.load_plugin("libmine.so").name == "my-xpbd"


def test_a_library_that_is_not_a_plugin(build_c):
    with pytest.raises(csb.ParameterError, match=r"plug-in .*libnostep.so does not export csb_plugin_step"):
        csb.load_plugin(build_c("nostep", "-DNO_STEP"))
    with pytest.raises(csb.ParameterError, match=r"plug-in .*libabi.so was built for version 999 of csb's plug-in "
                                                 r"interface, and this csb speaks version 1: rebuild it"):
        csb.load_plugin(build_c("abi", "-DABI=999"))
    libm = "/lib/x86_64-linux-gnu/libm.so.6"
    if Path(libm).exists():  # a shared library, but no plug-in
        with pytest.raises(csb.ParameterError, match="does not export csb_plugin_abi_version"):
            csb.load_plugin(libm)


def test_settings(build_c):
    plugin = csb.load_plugin(build_c("plain"))
    with pytest.raises(csb.ParameterError, match=r"refused its settings .*: at most 100 iterations, got 200"):
        plugin(dt=0.01, iterations=200)
    with pytest.raises(csb.ParameterError, match="dt must be a finite time step > 0 s, got 0"):
        plugin(dt=0.0)
    with pytest.raises(csb.ParameterError, match="dt must be a finite time step > 0 s, got nan"):
        plugin(dt=float("nan"))
    with pytest.raises(csb.ParameterError, match="substeps"):
        plugin(dt=0.01, substeps=0)
    with pytest.raises(csb.ParameterError, match="iterations"):
        plugin(dt=0.01, iterations=-1)
    with pytest.raises(csb.ParameterError, match="gravity must be finite"):
        plugin(dt=0.01, gravity=(0, float("inf"), 0))
    with pytest.raises(csb.ParameterError, match="gravity must be a sequence of 3 numbers"):
        plugin(dt=0.01, gravity=(0, 1))
    model = swinging_chain()
    with pytest.raises(csb.ParameterError, match="the state has 3 positions and 3 velocities, the model 11 particles"):
        plugin(dt=0.01).step(model, _small_state())


def _small_state():
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(2, 0.1), density=0.1)
    return b.build().initial_state()


@pytest.mark.parametrize("flag,error,message", [
    ("-DFAIL_AT=3", csb.SimulationError, r"failed at step 3 \(t = 0.03 s\): the solver did not converge; the state is "
                                         r"left at the start of that step"),
    ("-DNAN_AT=3", csb.SimulationError, r"wrote a non-finite velocity \(0, nan, 0\) of particle 2 at step 3 \(t = 0.03 s\)"),
    ("-DCODE_AT=3", csb.SimulationError, r"failed at step 3 .*: \(the plug-in gave no message\).* \(it returned 7\)"),
])
def test_a_failing_step_leaves_the_state_at_the_last_good_step(build_c, flag, error, message):
    """The plug-in moves every coordinate by 1 m a step and goes wrong at step 3: csb raises,
    naming the plug-in and its file, and puts the state back where step 3 began."""
    plugin = csb.load_plugin(build_c(flag[2:].split("=")[0].lower(), flag))
    model = swinging_chain()
    state = model.initial_state()
    with pytest.raises(error, match=r"plug-in 'test-plugin' \(.*\) " + message):
        plugin(dt=0.01).step(model, state, 10)
    assert state.step == 3 and state.t == pytest.approx(0.03)
    np.testing.assert_allclose(np.asarray(state.x), np.asarray(model.rest_positions) + 3.0, rtol=0, atol=1e-12)
    assert np.all(np.isfinite(state.v))


def test_the_documented_use_runs(example, monkeypatch, tmp_path):
    """docs/your_own_method.md's plug-in block, run as printed with the example built here."""
    import re

    text = (ROOT / "docs" / "your_own_method.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "load_plugin" in b]
    (tmp_path / "build" / "plugin").mkdir(parents=True)
    shutil.copy(example, tmp_path / "build" / "plugin" / "libmy_xpbd.so")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(block, "your_own_method.md", "exec"), namespace)
    assert namespace["state"].step == 400 and isinstance(namespace["stepper"], csb.PluginIntegrator)


def test_one_integrator_is_one_threads_at_a_time(example):
    """A second thread stepping the integrator another thread is stepping is refused before it
    reaches the plug-in (a plug-in's handle is one thread's at a time). The first thread is held
    inside its step by its interrupt, which csb asks between steps."""
    stepper, model = csb.load_plugin(example)(dt=0.01), swinging_chain()
    inside, done = threading.Event(), threading.Event()

    def hold() -> bool:
        inside.set()
        done.wait(30)
        return False

    first = threading.Thread(target=stepper.step, args=(model, model.initial_state(), 3), kwargs={"interrupt": hold})
    first.start()
    assert inside.wait(30)
    try:
        with pytest.raises(csb.ConcurrentUseError, match="PluginIntegrator::step: this stepper is in use by another"):
            stepper.step(model, model.initial_state(), 1)
    finally:
        done.set()
        first.join()


def test_a_plugin_goes_through_a_study_file(example, tmp_path):
    from csb.studies.study import StudyError, load_study, run_study

    study = tmp_path / "study.toml"
    body = f"""\
[study]
duration = 0.3
metrics = ["position_error", "max_strain", "residual", "stability"]

[reference]
rtol = 1e-10

[[scene]]
setup = "swinging_chain"
args = {{ links = 5, compliance = 1e-6 }}

[[method]]
plugin = "{example}"
dt = [0.01, 0.005]
iterations = 10

[[method]]
name = "xpbd"
dt = [0.01, 0.005]
iterations = 10
"""
    study.write_text(body)
    r = run_study(study, out=tmp_path / "out", workers=0)
    assert r.failed == 0
    rows = {(row["method"], row["dt"]): row for row in r.table}
    name = csb.load_plugin(example).name
    for dt in (0.01, 0.005):
        mine, builtin = rows[(name, dt)], rows[("xpbd", dt)]
        # The example sweeps the links in order, csb's default XPBD in its own order: rounding apart.
        assert mine["position_error"] == pytest.approx(builtin["position_error"], abs=1e-9)
        assert mine["residual"] == pytest.approx(builtin["residual"], rel=1e-6)
    # The library's bytes are part of the cells' keys; a path that is no plug-in is named.
    assert all(row["key"] for row in r.table)
    study.write_text(body.replace(str(example), str(tmp_path / "missing.so")))
    with pytest.raises(StudyError, match=r"method\[0\]\.plugin: .*missing\.so"):
        load_study(study)
