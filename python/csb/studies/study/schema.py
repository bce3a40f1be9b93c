"""A study file's schema: its scenes, methods, grids, reference and metrics, read with the scene
files' machinery (every error names the file, the line and the key), and expanded into cells."""


from __future__ import annotations

import hashlib
import importlib
import importlib.util
import itertools
import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ... import _core
from ...model import ModelBuilder
from ...scene import find_scene, load_scene
from ...scene_file import SceneError, _Source, _Table, read_toml
from .. import hanging_chain, pendulum_model, spinning_cloth, swinging_chain
from ..literature import SETUPS as LITERATURE_SETUPS
from ..soft_bodies import hanging_tet_cube

__all__ = ["StudyError", "Study", "Cell", "load_study", "cell_key", "METRICS", "SETUPS"]


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
                  bending_compliance: float = 1.0, bending: bool = True) -> _core.Model:
    """An n x n cloth of ``size`` (m) side, ``density`` (kg/m²), stretch compliance (m/N) and
    bending compliance (1/(N m)), hanging from its two corners at z = -size/2. ``bending = false``:
    distance constraints only (the cloth a method that projects nothing else can step)."""
    if not isinstance(bending, bool):
        raise _core.ParameterError(f"bending must be true or false, got {bending!r}")
    b = ModelBuilder()
    inst = b.add_mesh(_core.cloth_grid(size, size, n, n), density=density, stretch_compliance=stretch_compliance,
                      bending_stiffness=1.0 if bending else None, bending_compliance=bending_compliance)
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
    # the literature's scenes with their published parameters (csb.studies.literature)
    **{name: _with_rest_state(make) for name, make in LITERATURE_SETUPS.items()},
}

# What each metric is; all are measured at the study's output times (the start included).
METRICS = {
    "position_error": "largest distance of any particle from the reference at any output time (m)",
    "energy_drift": "|E(end) - E(start)| of kinetic + gravitational + elastic (Σ C²/(2α)) energy, relative to "
                    "the larger of |E(start)| and the largest kinetic energy",
    "max_strain": "largest |C| / rest length of the distance constraints at any output time",
    "max_violation": "largest |C| of the distance constraints at any output time (m)",
    "volume_error": "largest |V - V0| / V0 of the total tet volume at any output time",
    "residual": "largest backward-Euler residual |∇E| (N, 2-norm; csb.backward_euler_residual) of the step of dt "
                "ending at each output time: zero for a converged backward Euler step, an iterative method's "
                "solver error (a method's sub-steps are measured as one step of dt)",
    "same_step_error": "largest distance (m) of the step of dt ending at each output time from the backward Euler "
                       "step from the same state solved to convergence (csb.BackwardEuler): the solver error alone, "
                       "where position_error is the total error",
    # (max_strain, max_violation, volume_error, residual and same_step_error are null, with a note, for a scene
    # without such constraints or with hard ones)
    "stability": "'stable', or 'blew-up' (csb.SimulationError, a non-finite position, or a particle farther "
                 "than 100 model sizes from its start)",
}
_NEEDS_REFERENCE = {"position_error"}
# A study's table has these columns besides the metrics: a scene grid may not name one.
_RESERVED = {"study", "scene", "method", "dt", "substeps", "iterations", "rtol", "dt_used", "steps", "status",
             "error", "error_type", "notes", "key", "repeats", "cpu_per_simulated_s", "cpu_spread", "cpu_low",
             "cpu_high", "csb_version", "build", "platform", "cpu_count", "load_average"}
_PARAMS = ("dt", "substeps", "iterations", "rtol")
REFERENCE_METHOD = "cvode"  # the reference's own integrator as a method, swept over rtol


# ------------------------------------------------------------------------------------ the schema


@dataclass(frozen=True)
class SceneDef:
    label: str
    definition: dict[str, Any]   # what determines the scene (file bytes' hash, set-up and args, gravity)
    context: dict[str, Any]      # how to find it (the file's path): not part of the key
    index: int = 0               # its [[scene]] table, for messages
    point: dict[str, Any] = field(default_factory=dict)  # its point of the scene's grid
    metrics: tuple[str, ...] | None = None  # the study's metrics measured on it (None: all of them)

    def measures(self, metric: str, study_metrics: tuple[str, ...]) -> bool:
        return metric in (study_metrics if self.metrics is None else self.metrics)


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
    scene_params: dict[str, Any] = field(default_factory=dict)  # the scene's grid point

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
    repeats: int | str          # timed runs per cell, or "auto" (from the spread: cells.AUTO_*)
    metrics: tuple[str, ...]
    reference: dict[str, Any] | None
    scenes: tuple[SceneDef, ...]
    methods: tuple[MethodDef, ...]
    # m: the accuracy of the report's performance profile (None: no profile). It reads the cells'
    # results and does not change them, so it is no part of their keys.
    profile_accuracy: float | None = None
    tier: str = "full"                      # "quick" or "full": which run of the main job includes it
    charts: tuple[dict[str, Any], ...] = ()  # [[chart]] tables, checked
    budget: int | None = None               # cells per method and scene every method gets, when given

    def scene_parameters(self) -> list[str]:
        """The names of the scene grids' arguments, in the order first declared."""
        names: list[str] = []
        for s in self.scenes:
            names += [n for n in s.point if n not in names]
        return names

    def cells(self) -> list[Cell]:
        """The Cartesian product: every scene with every method at every point of its grid."""
        build = _core.build_info()
        out = []
        for s in self.scenes:
            for m in self.methods:
                names = list(m.grid)
                for values in itertools.product(*(m.grid[n] for n in names)):
                    params = dict(zip(names, values))
                    # The reference is no part of a cell: the cell keeps its positions, and the
                    # errors against the reference are measured when the table is made.
                    definition = dict(
                        scene=s.definition, method=m.definition, params=params,
                        metrics=list(self.metrics if s.metrics is None else s.metrics),
                        duration=s.definition.get("duration", self.duration),
                        outputs=self.outputs, repeats=self.repeats, csb=dict(version=build["csb"], build=build))
                    out.append(Cell(s.label, m.label, params, definition, dict(scene=s.context, method=m.context),
                                    dict(s.point)))
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


def _read_scene(source: _Source, data: Any, k: int, base: Path, study_metrics: tuple[str, ...]) -> list[SceneDef]:
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
            if name in _RESERVED or name in METRICS:
                raise t.error("grid", f"{name} is a column of the study's table already: the set-up cannot sweep it")
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
            variants.append((name, dict(kind="setup", setup=setup, args=full), point))
    if given[0] in ("scene", "file"):
        variants = [(label, definition, {})]
    for _, d, _ in variants:
        d["gravity"] = list(gravity)
    if t.has("duration"):
        duration = t.number("duration", check=lambda x: x > 0, expect="a duration > 0 s")
        for _, d, _ in variants:
            d["duration"] = duration
    # The study's metrics measured on this scene, when not all of them (a scene with no converged
    # continuous reference leaves out position_error, and the reference is not run for it).
    metrics = None
    if t.has("metrics"):
        chosen = t.raw("metrics")
        if (not isinstance(chosen, list) or not chosen or not all(isinstance(m, str) for m in chosen)
                or len(set(chosen)) != len(chosen)):
            raise t.error("metrics", f"must be a non-empty list of distinct metric names, got {chosen!r}")
        unknown = [m for m in chosen if m not in study_metrics]
        if unknown:
            raise t.error("metrics", f"{unknown[0]!r} is not one of the study's metrics: {', '.join(study_metrics)}")
        metrics = tuple(m for m in study_metrics if m in chosen)
    t.finish()
    return [SceneDef(name, d, context, k, point, metrics) for name, d, point in variants]


def _stepping_grid(t: _StudyTable) -> dict[str, tuple[Any, ...]]:
    """The grid of a user's method or a plug-in: dt (required), and substeps and iterations
    where given (the method's own defaults otherwise)."""
    grid = {"dt": _grid(t, "dt", "time") or t.raw("dt")}
    for key in ("substeps", "iterations"):
        g = _grid(t, key, "count")
        if g is not None:
            grid[key] = g
    return grid


def _read_method(source: _Source, data: Any, k: int, base: Path) -> MethodDef:
    if not isinstance(data, dict):
        raise StudyError(f"{source.path}: method {k + 1}: declare methods as [[method]] tables")
    t = _StudyTable(source, data, ("method", k), f"method[{k}]")
    given = [key for key in ("name", "python", "plugin") if t.has(key)]
    if len(given) != 1:
        raise t.error(given[1] if len(given) > 1 else None,
                      "give exactly one of name (a built-in method, csb.methods(), or 'cvode'), "
                      "python ('module:Class', a csb.Integrator subclass) or plugin (a C/C++ plug-in's shared "
                      "library, csb.load_plugin)")
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
            settings = t.raw("settings", {})
            if not isinstance(settings, dict) or not all(isinstance(v, (bool, int, float, str))
                                                         for v in settings.values()):
                raise t.error("settings", f"must be a table of the method's own settings (booleans, numbers, "
                                          f"strings; csb.method_info({name!r}).settings), got {settings!r}")
            if settings:
                try:
                    _core.make_integrator(name, float(grid["dt"][0]), **settings)
                except _core.ParameterError as e:
                    raise t.error("settings", str(e)) from None
                definition["settings"] = dict(settings)
    elif t.has("plugin"):
        lib = Path(t.string("plugin"))
        path = lib if lib.is_absolute() else base / lib
        try:
            made = _core.load_plugin(path)
        except (OSError, _core.Error, ValueError) as e:
            raise t.error("plugin", str(e)) from None
        definition = dict(plugin=str(lib), sha256=_sha256_file(path))
        context = dict(path=str(path.resolve()))
        label = t.string("label", made.name)
        grid.update(_stepping_grid(t))
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
        args = t.raw("args", {})
        if not isinstance(args, dict):
            raise t.error("args", f"must be a table of the class's keyword arguments, got {args!r}")
        try:
            cell_key(args)
        except ValueError:
            raise t.error("args", f"must hold finite numbers, got {args!r}") from None
        definition = dict(python=spec, sha256=sha256, args=args)
        context = dict(folder=folder)
        label = t.string("label", cls)
        grid.update(_stepping_grid(t))
    t.finish()
    return MethodDef(label, definition, context, grid)


def load_study(path: str | os.PathLike[str], *, extra_methods: tuple[str, ...] | list[str] = (),
               like: str | None = None) -> Study:
    """Read and check a study file; every error is a StudyError naming the file, line and key.

    ``extra_methods`` adds methods the file does not name, each a user's class ("module:Class",
    imported from the working directory or sys.path) or a plug-in (a path to a shared library),
    over the grid (dt, substeps, iterations) of the file's method labelled ``like`` (default: its
    first method that takes a time step): a researcher's method run through any study unedited."""
    p = Path(path)
    data, source = read_toml(p, "study file", StudyError)
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
    repeats: int | str = "auto" if st.raw("repeats", None) == "auto" else st.integer("repeats", 1, minimum=1,
                                                                                      maximum=1000)
    tier = st.string("tier", "full", choices=("quick", "full"))
    budget = st.integer("budget", None, minimum=1, maximum=100_000) if st.has("budget") else None
    metrics = st.raw("metrics", ["position_error", "stability"])
    if not isinstance(metrics, list) or not all(isinstance(m, str) for m in metrics):
        raise st.error("metrics", f"must be a list of metric names, got {metrics!r}")
    for m in metrics:
        if m not in METRICS:
            raise st.error("metrics", f"unknown metric {m!r}; known: {', '.join(METRICS)}")
    if len(set(metrics)) != len(metrics):
        raise st.error("metrics", f"lists a metric twice: {metrics!r}")
    profile_accuracy = st.number("profile_accuracy", None, check=lambda x: x > 0,
                                 expect="a largest distance to the reference > 0 m")
    if profile_accuracy is not None and "position_error" not in metrics:
        raise st.error("profile_accuracy", "a performance profile needs the position_error metric")
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
        fraction = rt.number("fraction", 0.01, check=lambda x: 0 < x < 1, expect="a fraction in (0, 1)")
        if rt.has("fraction") and rtol != "auto":
            raise rt.error("fraction", 'bounds the reference\'s own error when rtol = "auto" chooses it: '
                                       "give rtol = \"auto\" or leave fraction out")
        rt.finish()
        reference = dict(rtol=rtol, atol=atol, energy_tolerance=energy_tolerance, fraction=fraction)
    needs = [m for m in metrics if m in _NEEDS_REFERENCE]
    if needs and reference is None:
        raise st.error("metrics", f"{needs[0]} is measured against the reference: add a [reference] table (rtol)")

    raw_scenes = top.raw("scene", [])
    if not isinstance(raw_scenes, list) or not raw_scenes:
        raise top.error(None, "declare at least one [[scene]]")
    scenes = tuple(d for k, s in enumerate(raw_scenes) for d in _read_scene(source, s, k, p.parent, tuple(metrics)))
    raw_methods = top.raw("method", [])
    if not isinstance(raw_methods, list) or not raw_methods:
        raise top.error(None, "declare at least one [[method]]")
    methods = tuple(_read_method(source, m, k, p.parent) for k, m in enumerate(raw_methods))
    if extra_methods:
        stepping = [m for m in methods if "dt" in m.grid]
        template = next((m for m in stepping if m.label == like), None) if like else (stepping or [None])[0]
        if template is None:
            known = ", ".join(m.label for m in stepping) or "none"
            raise StudyError(f"{p}: the study has no method {like!r} that takes a time step whose grid an added "
                             f"method could take (its methods with one: {known})" if like else
                             f"{p}: the study has no method that takes a time step whose grid an added method could take")
        for k, spec in enumerate(extra_methods):
            kind = "plugin" if spec.endswith((".so", ".dylib", ".dll")) or os.sep in spec else "python"
            data = {kind: spec, **{key: list(v) for key, v in template.grid.items()
                                   if key in ("dt", "substeps", "iterations")}}
            methods += (_read_method(source, data, len(raw_methods) + k, Path.cwd()),)
    for what, items in (("scene", scenes), ("method", methods)):
        labels = [x.label for x in items]
        for k, label in enumerate(labels):
            if labels.index(label) != k:
                index = items[k].index if what == "scene" else k
                raise _StudyTable(source, {}, (what, index), f"{what}[{index}]").error(
                    "name" if what == "scene" else "label", f"two {what}s are called {label!r}: give one a name")
    if budget is not None:
        for k, m in enumerate(methods):
            n = math.prod(len(v) for v in m.grid.values())
            if n != budget:
                raise _StudyTable(source, {}, ("method", k), f"method[{k}]").error(
                    None, f"{m.label} has {n} parameter settings, and the study's budget is {budget} for every "
                          "method: give each method the same number of settings")
    charts = tuple(_read_chart(source, c, k, metrics, scenes, methods)
                   for k, c in enumerate(_list_of_tables(top, "chart")))
    top.finish()
    return Study(p, name, description, duration, outputs, repeats, tuple(metrics), reference, scenes, methods,
                 profile_accuracy, tier, charts, budget)


def _list_of_tables(top: _StudyTable, key: str) -> list[Any]:
    v = top.raw(key, [])
    if not isinstance(v, list):
        raise top.error(key, f"declare them as [[{key}]] tables")
    return v


CHART_KINDS = {
    "line": "a metric (y) against a parameter (x), one panel per scene, one line per method and setting of "
            "the other parameters",
    "map": "a stability map: one panel per method and scene, a cell per (x, y) setting, coloured stable, "
           "blew up, or (with wrong) stable but farther than `wrong` m from the reference",
}


def _read_chart(source: _Source, data: Any, k: int, metrics: list[str], scenes, methods) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise StudyError(f"{source.path}: chart {k + 1}: declare charts as [[chart]] tables")
    t = _StudyTable(source, data, ("chart", k), f"chart[{k}]")
    kind = t.string("kind", choices=tuple(CHART_KINDS))
    axes = list(_PARAMS) + [n for s in scenes for n in s.point]
    cost = "cpu_per_simulated_s"
    x = t.string("x", choices=tuple(dict.fromkeys(axes)) + ((cost,) if kind == "line" else ()))
    chart: dict[str, Any] = dict(kind=kind, x=x, title=t.string("title", ""))
    if kind == "line":
        # The parameter a line runs along: x itself, or, against the cost, the one whose settings
        # it joins (iterations: the residual against CPU time as the iterations grow).
        along = t.string("along", None if x == cost else x, choices=tuple(dict.fromkeys(axes)))
        if along is None:
            raise t.error("along", f"a line against {cost} joins the settings of one parameter: give along "
                                   "(iterations, say)")
        chart["along"] = along
    # Optional: the scenes (by name, or by set-up for a grid's scenes) and methods it draws.
    for key, items in (("scenes", scenes), ("methods", methods)):
        names = {s.label for s in items} | ({s.definition.get("setup") for s in items} - {None}
                                             if key == "scenes" else set())
        chosen = t.raw(key, None)
        if chosen is not None:
            if not isinstance(chosen, list) or not chosen or not all(isinstance(c, str) for c in chosen):
                raise t.error(key, f"must be a non-empty list of names, got {chosen!r}")
            for c in chosen:
                if c not in names:
                    raise t.error(key, f"{c!r} is not one of the study's {key}: {', '.join(sorted(names))}")
        chart[key] = chosen
    if kind == "line":
        chart["y"] = t.string("y", choices=tuple(m for m in metrics if m != "stability") + ("cpu_per_simulated_s",))
    else:
        chart["y"] = t.string("y", choices=tuple(dict.fromkeys(axes)))
        if chart["y"] == x:
            raise t.error("y", "must differ from x")
        chart["wrong"] = t.number("wrong", None, check=lambda v: v > 0, expect="a distance > 0 m")
        if chart["wrong"] is not None and "position_error" not in metrics:
            raise t.error("wrong", "a stable-but-wrong class needs the position_error metric")
        if "stability" not in metrics:
            raise t.error("kind", "a stability map needs the stability metric")
    t.finish()
    return chart


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
