"""Declarative studies: a TOML file of scenes, methods with their parameter grids, a reference,
metrics and repeats, expanded into cells (the Cartesian product), each cell run by one pure
function of its definition and stored under a key made from everything that determines it.

A study file::

    [study]
    name = "pareto"                  # the output folder's name (default: the file's stem)
    description = "..."
    duration = 0.3                   # s of simulated time per cell
    outputs = 10                     # output intervals: metrics are measured at these 11 times
    repeats = 2                      # timed runs per cell: the cost is their median and spread
    metrics = ["position_error", "energy_drift", "max_strain", "residual", "stability"]

    [reference]                      # the continuous CVODE reference (csb.integrate_reference)
    rtol = 1e-11                     # or "auto" (with energy_tolerance); atol default rtol/100

    [[scene]]                        # one of: scene = a bundled scene's name, file = a scene file,
    setup = "swinging_chain"         # setup = a study set-up (SETUPS) with its args
    args = { links = 5 }
    grid = { compliance = [1e-6, 1e-4] }   # a set-up's arguments swept: one scene per value

    [[method]]
    name = "xpbd"                    # a built-in (csb.methods()) or "cvode"; or
    dt = [0.0333, 0.00833]           # python = "module:Class" for a user's csb.Integrator
    iterations = [1, 20]             # grids: dt (s), substeps, iterations; rtol for "cvode"

Every error names the study file, the line and the key (:class:`StudyError`). The cells' results
are files ``<out>/cells/<key>.json``, written atomically, so a run killed at any point keeps every
cell it finished, and a re-run computes only the missing ones. Cells run on Dask (a
``distributed.LocalCluster`` by default, or a scheduler by address) or, with ``workers=0``, in
this process; either way through :func:`run_cell`.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import importlib
import importlib.util
import io
import itertools
import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
import tomllib
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .. import _core
from ..model import ModelBuilder
from ..scene import find_scene, load_scene
from ..scene_file import SceneError, _Source, _Table
from . import hanging_chain, pendulum_model, relative_energy_drift, spinning_cloth, swinging_chain
from .soft_bodies import hanging_tet_cube, total_volume

__all__ = ["StudyError", "Study", "Cell", "StudyResult", "load_study", "run_study", "run_cell", "cell_key",
           "METRICS", "SETUPS"]


class StudyError(SceneError):
    """A study file that cannot be used; the message names the file, the line and the key."""


class _StudyTable(_Table):
    def error(self, key: str | None, message: str) -> StudyError:
        e = super().error(key, message)
        return StudyError(str(e))

    def table(self, key: str, label: str | None = None) -> "_StudyTable | None":
        v = self.raw(key, None)
        if v is None:
            return None
        if not isinstance(v, dict):
            raise self.error(key, f"must be a table, got {v!r}")
        return _StudyTable(self.source, v, self.path + (key,), label or f"{self.label}.{key}")


# ------------------------------------------------------------------------------------ set-ups


def hanging_cloth(*, n: int = 12, size: float = 0.5, density: float = 0.2, stretch_compliance: float = 1e-4,
                  bending_compliance: float = 1.0) -> _core.Model:
    """An n x n cloth of ``size`` (m) side, ``density`` (kg/m²), stretch compliance (m/N) and
    bending compliance (1/(N m)), hanging from its two corners at z = -size/2."""
    b = ModelBuilder()
    inst = b.add_mesh(_core.cloth_grid(size, size, n, n), density=density, stretch_compliance=stretch_compliance,
                      bending_stiffness=1.0, bending_compliance=bending_compliance)
    b.pin(inst.nearest([-size / 2, 0, -size / 2]))
    b.pin(inst.nearest([size / 2, 0, -size / 2]))
    return b.build()


def _with_rest_state(make: Callable[..., Any]) -> Callable[..., tuple[_core.Model, _core.State]]:
    def setup(**args: Any) -> tuple[_core.Model, _core.State]:
        made = make(**args)
        if isinstance(made, tuple):
            if isinstance(made[1], _core.State):
                return made[0], made[1]
            made = made[0]
        return made, made.initial_state()

    setup.__doc__ = make.__doc__
    return setup


# The study set-ups a [[scene]] may name with `setup`, each returning (model, start state).
SETUPS: dict[str, Callable[..., tuple[_core.Model, _core.State]]] = {
    "swinging_chain": _with_rest_state(swinging_chain),
    "hanging_chain": _with_rest_state(hanging_chain),
    "pendulum": _with_rest_state(pendulum_model),
    "spinning_cloth": _with_rest_state(spinning_cloth),
    "hanging_cloth": _with_rest_state(hanging_cloth),
    "hanging_tet_cube": _with_rest_state(hanging_tet_cube),
}

# What each metric is; all are measured at the study's output times (the start included).
METRICS = {
    "position_error": "largest distance of any particle from the reference at any output time (m)",
    "energy_drift": "|E(end) - E(start)| of kinetic + gravitational + elastic (Σ C²/(2α)) energy, relative to "
                    "the larger of |E(start)| and the largest kinetic energy",
    "max_strain": "largest |C| / rest length of the distance constraints at any output time",
    "residual": "largest |C| of the distance constraints at any output time (m)",
    "volume_error": "largest |V - V0| / V0 of the total tet volume at any output time",
    # (max_strain, residual and volume_error are null, with a note, for a scene without such constraints)
    "stability": "'stable', or 'blew-up' (csb.SimulationError, a non-finite position, or a particle farther "
                 "than 100 model sizes from its start)",
}
_NEEDS_REFERENCE = {"position_error"}
_PARAMS = ("dt", "substeps", "iterations", "rtol")
REFERENCE_METHOD = "cvode"  # the reference's own integrator as a method, swept over rtol


# ------------------------------------------------------------------------------------ the schema


@dataclass(frozen=True)
class SceneDef:
    label: str
    definition: dict[str, Any]   # what determines the scene (file bytes' hash, set-up and args, gravity)
    context: dict[str, Any]      # how to find it (the file's path): not part of the key
    index: int = 0               # its [[scene]] table, for messages


@dataclass(frozen=True)
class MethodDef:
    label: str
    definition: dict[str, Any]   # name, or python "module:Class" with its source's hash
    context: dict[str, Any]      # the folder to import a user's module from
    grid: dict[str, tuple[Any, ...]]


@dataclass(frozen=True)
class Cell:
    """One scene x method x parameter set. ``definition`` is everything that determines its result
    (the key is its hash); ``context`` says where to find files and modules."""

    scene: str
    method: str
    params: dict[str, Any]
    definition: dict[str, Any]
    context: dict[str, Any]

    @property
    def key(self) -> str:
        return cell_key(self.definition)


@dataclass(frozen=True)
class Study:
    path: Path
    name: str
    description: str
    duration: float
    outputs: int
    repeats: int
    metrics: tuple[str, ...]
    reference: dict[str, Any] | None
    scenes: tuple[SceneDef, ...]
    methods: tuple[MethodDef, ...]

    def cells(self) -> list[Cell]:
        """The Cartesian product: every scene with every method at every point of its grid."""
        build = _core.build_info()
        out = []
        for s in self.scenes:
            for m in self.methods:
                names = list(m.grid)
                for values in itertools.product(*(m.grid[n] for n in names)):
                    params = dict(zip(names, values))
                    definition = dict(
                        scene=s.definition, method=m.definition, params=params, metrics=list(self.metrics),
                        reference=self.reference, duration=s.definition.get("duration", self.duration),
                        outputs=self.outputs, repeats=self.repeats, csb=dict(version=build["csb"], build=build))
                    out.append(Cell(s.label, m.label, params, definition, dict(scene=s.context, method=m.context)))
        return out


def cell_key(definition: dict[str, Any]) -> str:
    """SHA-256 of the canonical JSON (sorted keys, no spaces) of a cell's definition."""
    text = json.dumps(definition, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def _sha256_file(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _grid(t: _StudyTable, key: str, kind: str) -> tuple[Any, ...] | None:
    if not t.has(key):
        return None
    v = t.raw(key)
    values = v if isinstance(v, list) else [v]
    if not values:
        raise t.error(key, "must be a value or a non-empty list of values")
    for x in values:
        if kind == "time":
            ok = not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x) and x > 0
            expect = "time steps > 0 s"
        elif kind == "tolerance":
            ok = not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x) and 0 < x < 1
            expect = "tolerances in (0, 1)"
        else:
            ok = not isinstance(x, bool) and isinstance(x, int) and 1 <= x <= _core.MAX_SUBSTEPS
            expect = f"integers in [1, {_core.MAX_SUBSTEPS}]"
        if not ok:
            raise t.error(key, f"must be one of, or a list of, {expect}; got {x!r}")
    if len(set(values)) != len(values):
        raise t.error(key, f"lists a value twice: {values!r}")
    return tuple(float(x) if kind != "count" else int(x) for x in values)


def _read_scene(source: _Source, data: Any, k: int, base: Path) -> list[SceneDef]:
    if not isinstance(data, dict):
        raise StudyError(f"{source.path}: scene {k + 1}: declare scenes as [[scene]] tables")
    t = _StudyTable(source, data, ("scene", k), f"scene[{k}]")
    given = [key for key in ("scene", "file", "setup") if t.has(key)]
    if len(given) != 1:
        raise t.error(given[1] if len(given) > 1 else None,
                      "give exactly one of scene (a bundled scene's name), file (a scene file) or setup "
                      f"(one of {', '.join(SETUPS)})")
    definition: dict[str, Any] = {}
    context: dict[str, Any] = {}
    if given[0] in ("scene", "file"):
        what = given[0]
        name = t.string(what)
        p = (base / name) if what == "file" and not Path(name).is_absolute() else Path(name)
        try:
            path = find_scene(p if what == "file" else name)
            if what == "file" and not p.is_file():
                raise FileNotFoundError(f"{p}: no such scene file")
            scene = load_scene(path)
        except (FileNotFoundError, SceneError) as e:
            raise t.error(what, str(e)) from None
        # The scene file's bytes and those of the mesh files it reads determine the model.
        meshes = {str(m.file.relative_to(path.parent) if m.file.is_relative_to(path.parent) else m.file):
                  _sha256_file(m.file) for m in scene.meshes if m.file is not None and m.file.is_file()}
        definition = dict(kind="file", sha256=_sha256_file(path), meshes=meshes)
        context = dict(path=str(path.resolve()))
        label = t.string("name", scene.name)
        gravity = tuple(scene.solver.gravity)
        if t.has("gravity"):
            raise t.error("gravity", "a scene file's gravity is its [solver] gravity")
    else:
        setup = t.string("setup", choices=tuple(SETUPS))
        args = t.raw("args", {})
        if not isinstance(args, dict):
            raise t.error("args", f"must be a table of the set-up's arguments, got {args!r}")
        try:
            cell_key(args)
        except ValueError:
            raise t.error("args", f"must hold finite numbers, got {args!r}") from None
        # A grid of set-up arguments (a material swept, say): one scene per point of it.
        grid = t.raw("grid", {})
        if not isinstance(grid, dict):
            raise t.error("grid", f"must be a table of argument = [values], got {grid!r}")
        for name, values in grid.items():
            if not isinstance(values, list) or not values:
                raise t.error("grid", f"{name} must be a non-empty list of values, got {values!r}")
            if name in args:
                raise t.error("grid", f"{name} is given in args too")
        try:
            cell_key(grid)
        except ValueError:
            raise t.error("grid", f"must hold finite numbers, got {grid!r}") from None
        label = t.string("name", setup)
        gravity = t.vector("gravity", (0.0, -9.81, 0.0))
        variants = []
        for values in itertools.product(*grid.values()):
            point = dict(zip(grid, values))
            full = {**args, **point}
            key = "grid" if point else "args"
            try:
                SETUPS[setup](**full)  # made once here, so that a wrong argument is named now
            except TypeError as e:
                raise t.error(key, f"{setup}: {e}") from None
            except (_core.Error, ValueError) as e:
                raise t.error(key, f"{setup}({', '.join(f'{n}={v!r}' for n, v in point.items())}): {e}") from None
            name = " ".join([label] + [f"{n}={v:g}" if isinstance(v, float) else f"{n}={v}" for n, v in point.items()])
            variants.append((name, dict(kind="setup", setup=setup, args=full)))
    if given[0] in ("scene", "file"):
        variants = [(label, definition)]
    for _, d in variants:
        d["gravity"] = list(gravity)
    if t.has("duration"):
        duration = t.number("duration", check=lambda x: x > 0, expect="a duration > 0 s")
        for _, d in variants:
            d["duration"] = duration
    t.finish()
    return [SceneDef(name, d, context, k) for name, d in variants]


def _read_method(source: _Source, data: Any, k: int, base: Path) -> MethodDef:
    if not isinstance(data, dict):
        raise StudyError(f"{source.path}: method {k + 1}: declare methods as [[method]] tables")
    t = _StudyTable(source, data, ("method", k), f"method[{k}]")
    if t.has("name") == t.has("python"):
        raise t.error("python" if t.has("name") else None,
                      "give exactly one of name (a built-in method, csb.methods(), or 'cvode') or "
                      "python ('module:Class', a csb.Integrator subclass)")
    grid: dict[str, tuple[Any, ...]] = {}
    context: dict[str, Any] = {}
    if t.has("name"):
        infos = {m.name: m for m in _core.methods()}
        name = t.string("name", choices=(*infos, REFERENCE_METHOD))
        definition: dict[str, Any] = dict(name=name)
        label = t.string("label", name)
        if name == REFERENCE_METHOD:
            grid["rtol"] = _grid(t, "rtol", "tolerance") or (1e-6,)
        else:
            grid["dt"] = _grid(t, "dt", "time") or t.raw("dt")  # required
            grid["substeps"] = _grid(t, "substeps", "count") or (1,)
            its = _grid(t, "iterations", "count")
            if its is not None and not infos[name].iterates:
                raise t.error("iterations", f"{name} does not iterate: give substeps (or dt) instead")
            if infos[name].iterates:
                grid["iterations"] = its or (10,)
    else:
        spec = t.string("python")
        module, _, cls = spec.partition(":")
        if not module or not cls or not all(p.isidentifier() for p in module.split(".") + [cls]):
            raise t.error("python", f"must be 'module:Class', got {spec!r}")
        folder = str(base.resolve())
        added = folder not in sys.path
        if added:
            sys.path.insert(0, folder)
        try:
            found = importlib.util.find_spec(module)
            if found is None:
                raise ImportError(f"no module named {module!r}")
        except ImportError as e:
            raise t.error("python", f"cannot import {module!r} (from the study's folder or sys.path): {e}") from None
        finally:
            if added:
                sys.path.remove(folder)
        origin = Path(found.origin) if found.origin and found.origin not in ("built-in", "frozen") else None
        sha256 = _sha256_file(origin) if origin and origin.is_file() else None
        try:
            obj = getattr(_import_user_module(module, folder, sha256), cls, None)
        except ImportError as e:
            raise t.error("python", f"cannot import {module!r} (from the study's folder or sys.path): {e}") from None
        if not (isinstance(obj, type) and issubclass(obj, _core.Integrator)):
            raise t.error("python", f"{spec}: {cls!r} is not a csb.Integrator subclass in {module!r}")
        definition = dict(python=spec, sha256=sha256)
        context = dict(folder=folder)
        label = t.string("label", cls)
        grid["dt"] = _grid(t, "dt", "time") or t.raw("dt")
        for key in ("substeps", "iterations"):
            g = _grid(t, key, "count")
            if g is not None:
                grid[key] = g
    t.finish()
    return MethodDef(label, definition, context, grid)


def load_study(path: str | os.PathLike[str]) -> Study:
    """Read and check a study file; every error is a StudyError naming the file, line and key."""
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except OSError as e:
        raise StudyError(f"{p}: cannot read the study file: {e.strerror}") from None
    except UnicodeDecodeError:
        raise StudyError(f"{p}: not UTF-8 text; TOML files are UTF-8") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise StudyError(f"{p}: not valid TOML: {e}") from None
    source = _Source(p, text)
    top = _StudyTable(source, data, (), "study file")
    st = top.table("study", "study")
    if st is None:
        raise top.error(None, "missing [study] table (name, duration, metrics, ...)")
    name = st.string("name", p.stem)
    if not name or any(c in name for c in "/\\") or name in (".", ".."):
        raise st.error("name", f"must be a name usable as a folder, got {name!r}")
    description = st.string("description", "")
    duration = st.number("duration", check=lambda x: x > 0, expect="a duration > 0 s")
    outputs = st.integer("outputs", 10, minimum=1, maximum=100_000)
    repeats = st.integer("repeats", 1, minimum=1, maximum=1000)
    metrics = st.raw("metrics", ["position_error", "stability"])
    if not isinstance(metrics, list) or not all(isinstance(m, str) for m in metrics):
        raise st.error("metrics", f"must be a list of metric names, got {metrics!r}")
    for m in metrics:
        if m not in METRICS:
            raise st.error("metrics", f"unknown metric {m!r}; known: {', '.join(METRICS)}")
    if len(set(metrics)) != len(metrics):
        raise st.error("metrics", f"lists a metric twice: {metrics!r}")
    st.finish()

    reference = None
    rt = top.table("reference", "reference")
    if rt is not None:
        rtol: Any = rt.raw("rtol", "auto")
        if rtol != "auto":
            rtol = rt.number("rtol", check=lambda x: 0 < x < 1, expect="'auto' or a tolerance in (0, 1)")
        atol: Any = rt.raw("atol", "auto")
        if atol != "auto":
            atol = rt.number("atol", check=lambda x: x > 0, expect="'auto' or a tolerance > 0")
        energy_tolerance = rt.number("energy_tolerance", 1e-6, check=lambda x: 0 < x < 1,
                                     expect="a relative tolerance in (0, 1)")
        rt.finish()
        reference = dict(rtol=rtol, atol=atol, energy_tolerance=energy_tolerance)
    needs = [m for m in metrics if m in _NEEDS_REFERENCE]
    if needs and reference is None:
        raise st.error("metrics", f"{needs[0]} is measured against the reference: add a [reference] table (rtol)")

    raw_scenes = top.raw("scene", [])
    if not isinstance(raw_scenes, list) or not raw_scenes:
        raise top.error(None, "declare at least one [[scene]]")
    scenes = tuple(d for k, s in enumerate(raw_scenes) for d in _read_scene(source, s, k, p.parent))
    raw_methods = top.raw("method", [])
    if not isinstance(raw_methods, list) or not raw_methods:
        raise top.error(None, "declare at least one [[method]]")
    methods = tuple(_read_method(source, m, k, p.parent) for k, m in enumerate(raw_methods))
    for what, items in (("scene", scenes), ("method", methods)):
        labels = [x.label for x in items]
        for k, label in enumerate(labels):
            if labels.index(label) != k:
                index = items[k].index if what == "scene" else k
                raise _StudyTable(source, {}, (what, index), f"{what}[{index}]").error(
                    "name" if what == "scene" else "label", f"two {what}s are called {label!r}: give one a name")
    top.finish()
    return Study(p, name, description, duration, outputs, repeats, tuple(metrics), reference, scenes, methods)


# ------------------------------------------------------------------------------------ one cell


def _build_scene(definition: dict[str, Any], context: dict[str, Any]) -> tuple[_core.Model, _core.State]:
    if definition["kind"] == "file":
        sim = load_scene(context["path"]).build()
        return sim.model, sim.state
    return SETUPS[definition["setup"]](**definition["args"])


def _output_times(definition: dict[str, Any]) -> np.ndarray:
    return np.linspace(0.0, definition["duration"], definition["outputs"] + 1)


def compute_reference(scene: dict[str, Any], context: dict[str, Any], reference: dict[str, Any],
                      duration: float, outputs: int) -> np.ndarray:
    """The reference's positions (T, N, 3) at the output times of a scene (m)."""
    model, start = _build_scene(scene, context)
    times = np.linspace(0.0, duration, outputs + 1)
    r = _core_reference(model, start, times, scene["gravity"], reference)
    return r.x


def _core_reference(model, start, times, gravity, reference):
    from ..reference import integrate_reference

    return integrate_reference(model, start, times, gravity=gravity, rtol=reference["rtol"], atol=reference["atol"],
                               energy_tolerance=reference["energy_tolerance"])


def _make_stepper(definition: dict[str, Any], context: dict[str, Any], params: dict[str, Any], dt: float,
                  gravity) -> _core.Integrator:
    method = definition["method"]
    if "name" in method:
        s = _core.make_integrator(method["name"], dt, substeps=params.get("substeps", 1),
                                  iterations=params.get("iterations", 10), gravity=gravity)
        if isinstance(s, _core.PbdStepper):  # one thread: the cost is one core's
            st = s.settings
            settings = {n: getattr(st, n) for n in ("method", "dt", "substeps", "iterations", "gravity", "damping",
                                                    "stiffness_correction", "front_end", "solver", "xpbd_damping",
                                                    "verlet_drag", "sqrt_approximation", "ordering", "max_speed")}
            s = _core.PbdStepper(**settings, threads=1)
        return s
    from . import make_stepper

    module, _, cls = method["python"].partition(":")
    made = getattr(_import_user_module(module, context["method"].get("folder"), method.get("sha256")), cls)
    return make_stepper(made, dt=dt, gravity=gravity, **{k: params[k] for k in ("substeps", "iterations")
                                                        if k in params})


def _import_user_module(module: str, folder: str | None, sha256: str | None):
    """A user's module, imported with ``folder`` first on sys.path. The cell's key holds the
    module's source as the study read it, so a module imported earlier in this process from
    another source (edited since) is read again."""
    added = bool(folder) and folder not in sys.path
    if added:
        sys.path.insert(0, folder)
    try:
        fresh = module not in sys.modules
        mod = importlib.import_module(module)
        if sha256 is not None and getattr(mod, "__csb_source_sha256__", None) != sha256:
            if not fresh:
                mod = importlib.reload(mod)
            mod.__csb_source_sha256__ = sha256
    finally:
        if added:
            sys.path.remove(folder)
    return mod


def _machine() -> dict[str, Any]:
    return dict(platform=platform.platform(), machine=platform.machine(), python=platform.python_version(),
                cpu_count=os.cpu_count(), node=platform.node())


def run_cell(definition: dict[str, Any], context: dict[str, Any], reference_x: np.ndarray | None = None) -> dict:
    """Run one cell: a pure function of its definition (with ``context`` to find its files and
    the reference's positions when a metric needs them). Never raises for the cell's own failure:
    an exception becomes status "failed" with its type and message."""
    caught: list[str] = []
    record: dict[str, Any] = dict(key=cell_key(definition), machine=_machine())
    try:
        load0 = os.getloadavg()
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            warnings.filterwarnings("ignore", message=r"(PBD|Jakobsen) reads stiffness, not compliance",
                                    category=_core.MaterialWarning)
            record.update(_measure(definition, context, reference_x))
            caught = sorted({f"{w.category.__name__}: {w.message}" for w in seen})
        record.update(status="ok", error_type=None, error=None)
        record["load_average"] = [max(a, b) for a, b in zip(load0, os.getloadavg())]
    except Exception as e:  # a failed cell is a result: recorded, the others go on
        record.update(status="failed", error_type=type(e).__name__, error=str(e),
                      traceback="".join(traceback.format_exception(e))[-4000:])
    record["warnings"] = caught
    return record


def _measure(definition: dict[str, Any], context: dict[str, Any], reference_x: np.ndarray | None) -> dict:
    scene, params, metrics = definition["scene"], definition["params"], definition["metrics"]
    gravity = tuple(scene["gravity"])
    times = _output_times(definition)
    interval = float(times[1] - times[0])
    duration = float(times[-1])
    model, start = _build_scene(scene, context["scene"])
    if "name" in definition["method"] and definition["method"]["name"] == REFERENCE_METHOD:
        costs, states = [], None
        for _ in range(definition["repeats"]):
            c0 = time.process_time()
            r = _core_reference(model, start, times, gravity,
                                dict(rtol=params["rtol"], atol=params["rtol"] / 100, energy_tolerance=1e-6))
            costs.append(time.process_time() - c0)
            states = list(r.states(model))
        blew, steps_per_interval, dt_used = False, None, None
    else:
        # Whole steps between output times: the dt asked for, rounded to divide the interval.
        steps_per_interval = max(1, round(interval / params["dt"]))
        dt_used = interval / steps_per_interval
        size = float(np.linalg.norm(np.asarray(start.x).max(axis=0) - np.asarray(start.x).min(axis=0)))
        costs, states, blew = [], None, False
        for _ in range(definition["repeats"]):
            stepper = _make_stepper(definition, context, params, dt_used, gravity)
            state, cpu, run_states, blew = start.copy(), 0.0, [start.copy()], False
            x0 = np.asarray(start.x).copy()
            for _k in range(1, len(times)):
                c0 = time.process_time()
                try:
                    stepper.step(model, state, steps_per_interval)
                except _core.SimulationError:
                    blew = True
                cpu += time.process_time() - c0
                x = np.asarray(state.x)
                if blew or not np.all(np.isfinite(x)) or np.abs(x - x0).max() > 100 * max(size, 1e-12):
                    blew = True
                    break
                run_states.append(state.copy())
            costs.append(cpu)
            states = run_states
    assert states is not None
    values: dict[str, Any] = {}
    notes: list[str] = []  # metrics that do not apply to the scene: null, and said why
    for m in metrics:
        if m == "stability":
            values[m] = "blew-up" if blew else "stable"
        elif blew:
            values[m] = None  # not measured past a blow-up; the stability says why
        elif m == "position_error":
            if reference_x is None:
                raise _core.ParameterError("position_error needs the reference's positions")
            values[m] = max(float(np.linalg.norm(np.asarray(s.x) - reference_x[k], axis=1).max())
                            for k, s in enumerate(states))
        elif m == "energy_drift":
            values[m] = float(relative_energy_drift(model, states, gravity))
        elif m in ("max_strain", "residual"):
            rest = np.asarray(model.distance["rest_length"])
            if len(rest) == 0:
                values[m] = None
                notes.append(f"{m}: the scene has no distance constraints")
                continue
            c = [np.abs(_core.distance_violations(model, s)) for s in states]
            values[m] = max(float((v / rest).max() if m == "max_strain" else v.max()) for v in c)
        elif m == "volume_error":
            v0 = float(np.sum(np.asarray(model.volume["rest_volume"])))
            if v0 == 0:
                values[m] = None
                notes.append(f"{m}: the scene has no tet volume constraints")
                continue
            values[m] = max(abs(total_volume(model, s) - v0) / abs(v0) for s in states)
    per_second = [c / duration for c in costs]
    return dict(metrics=values, notes=notes, dt_used=dt_used, steps=None if steps_per_interval is None
                else steps_per_interval * (len(times) - 1),
                cost=dict(cpu_per_simulated_s=statistics.median(per_second),
                          spread=max(per_second) - min(per_second), samples=per_second))


# ------------------------------------------------------------------------------------ storage


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that a kill at any moment leaves the old file or the new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _read_record(path: Path) -> dict | None:
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None  # absent, or not ours: computed again
    return record if isinstance(record, dict) and record.get("status") in ("ok", "failed") else None


# ------------------------------------------------------------------------------------ execution


def _executor(workers: int | None, scheduler: str | None, jobs: int):
    """A function running [(fn, args)] and yielding (index, result or exception) as each ends."""
    want_dask = scheduler is not None or (workers is not None and workers > 0)
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        if want_dask:
            raise _core.ParameterError(
                "running a study on Dask (--workers N > 0 or --scheduler) needs dask.distributed: "
                "pip install 'csb[study]'") from None
        Client = None
    if Client is None or workers == 0 or (scheduler is None and jobs <= 1 and workers is None):
        def serial(tasks):
            for i, (fn, args) in enumerate(tasks):
                try:
                    yield i, fn(*args)
                except Exception as e:
                    yield i, e
        return serial, None

    if scheduler is not None:
        client = Client(scheduler)
        cluster = None
    else:
        n = workers if workers is not None else max(1, min(os.cpu_count() or 1, jobs))
        # The dashboard on a free port: two studies (or a study and a notebook) at once do not collide.
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=40)
        client = Client(cluster)

    def on_dask(tasks):
        futures = {client.submit(fn, *args, pure=False): i for i, (fn, args) in enumerate(tasks)}
        for f in as_completed(futures):
            try:
                yield futures[f], f.result()
            except Exception as e:
                yield futures[f], e
            finally:
                f.release()

    def close():
        client.close()
        if cluster is not None:
            cluster.close()

    return on_dask, close


@dataclass
class StudyResult:
    study: Study
    out: Path
    table: list[dict]                    # one row per cell, in the study's order
    computed: int = 0
    reused: int = 0
    failed: int = 0
    files: list[Path] = field(default_factory=list)

    def summary(self) -> str:
        lines = [f"{self.study.name}: {len(self.table)} cells, {self.computed} computed, {self.reused} reused, "
                 f"{self.failed} failed"]
        for r in self.table:
            if r["status"] == "failed":
                lines.append(f"  failed: {r['scene']} / {r['method']} {_param_text(r)}: {r['error_type']}: {r['error']}")
        return "\n".join(lines)

    def report(self) -> str:
        """The study as a report section (Markdown): what it is, its cells, per scene the cells on
        the accuracy-against-cost front (when position_error is measured), what blew up or failed."""
        st = self.study
        lines = [f"## Study: {st.name}", ""]
        if st.description:
            lines += [st.description, ""]
        lines += [f"`csb study run {st.path}`: {len(self.table)} cells ({len(st.scenes)} scenes, {len(st.methods)} "
                  f"methods), {st.duration:g} s each, metrics at {st.outputs + 1} times, cost the median CPU time "
                  f"per simulated second of {st.repeats} run(s) on one thread. Table: `results.csv`.", ""]
        if "position_error" in st.metrics:
            lines += ["![accuracy against cost](accuracy_cost.png)", ""]
            for scene in st.scenes:
                front = _front([r for r in self.table if r["scene"] == scene.label])
                lines += [f"{scene.label}: the cells no other cell beats in both error and cost", "",
                          "| method | parameters | largest distance to the reference (m) | CPU s per simulated s |",
                          "|---|---|---:|---:|"]
                lines += [f"| {r['method']} | {_param_text(r)} | {r['position_error']:.3g} | "
                          f"{r['cpu_per_simulated_s']:.3g} |" for r in front]
                lines.append("")
        blown = [r for r in self.table if r.get("stability") == "blew-up"]
        if blown:
            lines += ["Blew up: " + ", ".join(f"{r['scene']} / {r['method']} {_param_text(r)}" for r in blown), ""]
        failed = [r for r in self.table if r["status"] == "failed"]
        if failed:
            lines += ["Failed: " + "; ".join(f"{r['scene']} / {r['method']} {_param_text(r)}: {r['error_type']}: "
                                             f"{r['error']}" for r in failed), ""]
        return "\n".join(lines)


def _front(rows: list[dict]) -> list[dict]:
    """The rows no other row beats in both position_error and cost, cheapest first."""
    good = sorted((r for r in rows if r["status"] == "ok" and r.get("stability") != "blew-up"
                   and r.get("position_error") is not None and r.get("cpu_per_simulated_s") is not None),
                  key=lambda r: (r["cpu_per_simulated_s"], r["position_error"]))
    front, best = [], math.inf
    for r in good:
        if r["position_error"] < best:
            best = r["position_error"]
            front.append(r)
    return front


def _param_text(row: dict) -> str:
    return " ".join(f"{p}={row[p]:g}" for p in _PARAMS if row.get(p) is not None)


def run_study(path: str | os.PathLike[str], *, out: str | os.PathLike[str] | None = None, workers: int | None = None,
              scheduler: str | None = None, retry_failed: bool = False, progress: bool = False) -> StudyResult:
    """Run the study file at ``path``: the cells without a stored result are computed (on Dask:
    ``scheduler`` an address, else a LocalCluster of ``workers`` processes, default one per core
    up to the cells; ``workers=0`` in this process), each stored as ``<out>/cells/<key>.json`` as
    it ends; the table (``results.csv``, ``results.parquet`` with pyarrow) and the chart are written
    to ``out`` (default ``out/studies/<name>``). A stored failed cell is run again only with
    ``retry_failed``."""
    study = load_study(path)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise _core.ParameterError(f"workers must be an integer >= 0 (0: in this process), got {workers!r}")
    out_dir = Path(out) if out is not None else Path("out") / "studies" / study.name
    cells_dir = out_dir / "cells"
    cells = study.cells()
    records: dict[str, dict] = {}
    missing: list[Cell] = []
    seen: set[str] = set()
    for c in cells:
        if c.key in seen:
            continue
        seen.add(c.key)
        r = _read_record(cells_dir / f"{c.key}.json")
        if r is not None and (r["status"] == "ok" or not retry_failed):
            records[c.key] = r
        else:
            missing.append(c)
    reused = len(records)
    if missing:
        _compute(study, missing, out_dir, records, workers, scheduler, progress)
    table = [_row(study, c, records[c.key]) for c in cells]
    result = StudyResult(study, out_dir, table, computed=len(missing), reused=reused,
                         failed=sum(r["status"] == "failed" for r in table))
    result.files = _write_outputs(result)
    return result


def _compute(study: Study, missing: list[Cell], out_dir: Path, records: dict[str, dict], workers, scheduler,
             progress: bool) -> None:
    from tqdm import tqdm

    need_ref = any(m in _NEEDS_REFERENCE for m in study.metrics)
    # The references the missing cells need, each stored as its own file by its key.
    refs: dict[str, np.ndarray] = {}
    ref_tasks: list[tuple[str, Any]] = []
    ref_key = {}
    if need_ref:
        for c in missing:
            d = c.definition
            rdef = dict(scene=d["scene"], reference=d["reference"], duration=d["duration"], outputs=d["outputs"],
                        csb=d["csb"])
            k = cell_key(rdef)
            ref_key[c.key] = k
            if k in refs or any(k == t[0] for t in ref_tasks):
                continue
            f = out_dir / "references" / f"{k}.npy"
            try:
                refs[k] = np.load(f)
            except (OSError, ValueError):
                ref_tasks.append((k, (compute_reference, (d["scene"], c.context["scene"], d["reference"],
                                                          d["duration"], d["outputs"]))))
    run, close = _executor(workers, scheduler, len(missing))
    try:
        ref_errors: dict[str, BaseException] = {}
        if ref_tasks:
            for i, value in run([t[1] for t in ref_tasks]):
                k = ref_tasks[i][0]
                if isinstance(value, BaseException):
                    ref_errors[k] = value
                    continue
                buf = io.BytesIO()
                np.save(buf, value)
                _write_atomic(out_dir / "references" / f"{k}.npy", buf.getvalue())
                refs[k] = value
        tasks, todo = [], []
        for c in missing:
            k = ref_key.get(c.key)
            if k in ref_errors:
                e = ref_errors[k]
                record = dict(key=c.key, machine=_machine(), status="failed", error_type=type(e).__name__,
                              error=f"the reference failed: {e}", warnings=[])
                _store(out_dir, c, record, records)
                continue
            tasks.append((run_cell, (c.definition, c.context, refs.get(k) if k else None)))
            todo.append(c)
        bar = tqdm(total=len(todo), desc=study.name, unit="cell", disable=not progress)
        for i, value in run(tasks):
            c = todo[i]
            if isinstance(value, BaseException):  # the worker died, or the task could not run
                value = dict(key=c.key, machine={}, status="failed", error_type=type(value).__name__,
                             error=str(value), warnings=[])
            _store(out_dir, c, value, records)
            bar.update()
        bar.close()
    finally:
        if close is not None:
            close()


def _store(out_dir: Path, cell: Cell, record: dict, records: dict[str, dict]) -> None:
    record = dict(record, definition=cell.definition)
    text = json.dumps(record, sort_keys=True, indent=1, allow_nan=True)
    _write_atomic(out_dir / "cells" / f"{cell.key}.json", text.encode())
    records[cell.key] = record


def _row(study: Study, cell: Cell, record: dict) -> dict:
    row: dict[str, Any] = dict(study=study.name, scene=cell.scene, method=cell.method)
    for p in _PARAMS:
        row[p] = cell.params.get(p)
    row["dt_used"] = record.get("dt_used")
    row["steps"] = record.get("steps")
    values = record.get("metrics", {})
    for m in study.metrics:
        row[m] = values.get(m)
    cost = record.get("cost", {})
    row["cpu_per_simulated_s"] = cost.get("cpu_per_simulated_s")
    row["cpu_spread"] = cost.get("spread")
    row["repeats"] = study.repeats
    row["status"] = record["status"]
    row["error_type"] = record.get("error_type")
    row["error"] = record.get("error")
    row["notes"] = "; ".join(record.get("notes", []) + record.get("warnings", []))
    build = cell.definition["csb"]["build"]
    row["csb_version"] = build["csb"]
    row["build"] = f"{build.get('compiler')}, {build.get('simd')}, SUNDIALS {build.get('sundials')}"
    machine = record.get("machine", {})
    row["platform"] = machine.get("platform")
    row["cpu_count"] = machine.get("cpu_count")
    load = record.get("load_average")
    row["load_average"] = None if load is None else load[0]
    row["key"] = cell.key
    return row


def _write_outputs(result: StudyResult) -> list[Path]:
    out = result.out
    out.mkdir(parents=True, exist_ok=True)
    rows = result.table
    files = []
    columns = list(rows[0])
    s = io.StringIO()
    w = csv.DictWriter(s, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    text = s.getvalue().encode()
    unchanged = _same_bytes(out / "results.csv", text)
    if not unchanged:
        _write_atomic(out / "results.csv", text)
    files.append(out / "results.csv")
    chart = "position_error" in result.study.metrics
    wanted = [out / "report.md"] + [out / "results.parquet"] * _has_pyarrow() + [out / "accuracy_cost.png"] * chart
    if unchanged and all(f.is_file() for f in wanted):  # a re-run of an unchanged study: nothing to draw
        return files + wanted
    _write_atomic(out / "report.md", result.report().encode())
    files.append(out / "report.md")
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        pass
    else:
        table = pa.Table.from_pylist(rows)
        tmp = out / ".results.parquet.tmp"
        pq.write_table(table, tmp)
        os.replace(tmp, out / "results.parquet")
        files.append(out / "results.parquet")
    if chart:
        files.append(_chart(result))
    return files


def _same_bytes(path: Path, data: bytes) -> bool:
    try:
        return path.read_bytes() == data
    except OSError:
        return False


def _has_pyarrow() -> bool:
    return importlib.util.find_spec("pyarrow") is not None


def _chart(result: StudyResult) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = [s.label for s in result.study.scenes]
    fig, axes = plt.subplots(1, len(scenes), figsize=(6.5 * len(scenes), 5.5), constrained_layout=True, squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        for m in result.study.methods:
            pts = [r for r in result.table if r["scene"] == scene and r["method"] == m.label and r["status"] == "ok"
                   and r.get("position_error") and r["cpu_per_simulated_s"]]
            if pts:
                pts.sort(key=lambda r: r["cpu_per_simulated_s"])
                ax.loglog([r["cpu_per_simulated_s"] for r in pts], [r["position_error"] for r in pts], "o",
                          label=m.label, ms=6, alpha=0.85)
        ax.set_title(f"{scene}: error against cost", fontsize="medium")
        ax.set_xlabel("CPU time per simulated second (s), median of the repeats")
        ax.set_ylabel("largest distance to the reference (m)")
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="x-small", ncol=2)
    path = result.out / "accuracy_cost.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
