"""One cell of a study: its scene built, its method made and stepped, its metrics measured
against the reference, its cost timed; and the cells' storage (one JSON file a cell, written
atomically)."""

from __future__ import annotations

import contextlib
import functools
import json
import os
import platform
import statistics
import tempfile
import time
import traceback
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ... import _core
from ...scene import load_scene
from .. import relative_energy_drift
from ..soft_bodies import total_volume
from .schema import REFERENCE_METHOD, SETUPS, _import_user_module, cell_key


# ------------------------------------------------------------------------------------ one cell


def _build_scene(definition: dict[str, Any], context: dict[str, Any]) -> tuple[_core.Model, _core.State]:
    if definition["kind"] == "file":
        sim = load_scene(context["path"]).build()
        return sim.model, sim.state
    return SETUPS[definition["setup"]](**definition["args"])


def _output_times(definition: dict[str, Any]) -> np.ndarray:
    return np.linspace(0.0, definition["duration"], definition["outputs"] + 1)


def compute_reference(scene: dict[str, Any], context: dict[str, Any], reference: dict[str, Any],
                      duration: float, outputs: int) -> tuple[np.ndarray, dict[str, Any]]:
    """The reference's positions (T, N, 3) at the output times of a scene (m), and what it used and
    kept: its rtol and atol, its relative energy drift (the study's energy_drift measure of its
    own trajectory), its CPU time (s)."""
    model, start = _build_scene(scene, context)
    times = np.linspace(0.0, duration, outputs + 1)
    c0 = time.process_time()
    r = _core_reference(model, start, times, scene["gravity"], reference)
    cpu = time.process_time() - c0
    drift = float(relative_energy_drift(model, list(r.states(model)), tuple(scene["gravity"])))
    return r.x, dict(rtol=float(r.stats["rtol"]), atol=float(r.stats["atol"]), energy_drift=drift, cpu_s=cpu)


def _core_reference(model, start, times, gravity, reference):
    from ...reference import integrate_reference

    return integrate_reference(model, start, times, gravity=gravity, rtol=reference["rtol"], atol=reference["atol"],
                               energy_tolerance=reference["energy_tolerance"])


def one_thread_integrator(name: str, dt: float, *, substeps: int = 1, iterations: int = 10, gravity=(0.0, -9.81, 0.0),
                          settings: dict[str, Any] | None = None) -> _core.Integrator:
    """The built-in method `name` as csb.make_integrator makes it, on one thread (a method with a
    `threads` setting, and the position-based pipeline), so that its cost is one core's: how the
    studies and the benchmarks time the methods against each other."""
    settings = dict(settings or {})
    if "threads" not in settings and any(k.name == "threads" for k in _core.method_info(name).settings):
        settings["threads"] = 1
    s = _core.make_integrator(name, dt, substeps=substeps, iterations=iterations, gravity=gravity, **settings)
    if isinstance(s, _core.PbdStepper):
        st = s.settings
        kept = {n: getattr(st, n) for n in ("method", "dt", "substeps", "iterations", "gravity", "damping",
                                            "stiffness_correction", "front_end", "solver", "xpbd_damping",
                                            "verlet_drag", "sqrt_approximation", "ordering", "max_speed")}
        s = _core.PbdStepper(**kept, threads=1)
    return s


def _make_stepper(definition: dict[str, Any], context: dict[str, Any], params: dict[str, Any], dt: float,
                  gravity) -> _core.Integrator:
    method = definition["method"]
    if "name" in method:
        return one_thread_integrator(method["name"], dt, substeps=params.get("substeps", 1),
                                     iterations=params.get("iterations", 10), gravity=gravity,
                                     settings=method.get("settings"))
    from .. import make_stepper

    if "plugin" in method:
        made = _core.load_plugin(context["method"]["path"])
    else:
        module, _, cls = method["python"].partition(":")
        made = getattr(_import_user_module(module, context["method"].get("folder"), method.get("sha256")), cls)
        if method.get("args"):
            made = functools.partial(made, **method["args"])
    return make_stepper(made, dt=dt, gravity=gravity, **{k: params[k] for k in ("substeps", "iterations")
                                                        if k in params})


def _machine() -> dict[str, Any]:
    return dict(platform=platform.platform(), machine=platform.machine(), python=platform.python_version(),
                cpu_count=os.cpu_count(), node=platform.node())


class PeerDoesNotConform(Exception):
    """A peer's adapter failed its conformance check: the cell is reported, not plotted."""


def run_cell(definition: dict[str, Any], context: dict[str, Any]) -> dict:
    """Run one cell: a pure function of its definition (with ``context`` to find its files).
    Returns its record, with the positions at the output times under "positions" (T, N, 3), from
    which the metrics against the reference are measured when the table is made. Never raises for
    the cell's own failure: an exception becomes status "failed" with its type and message."""
    caught: list[str] = []
    record: dict[str, Any] = dict(key=cell_key(definition), machine=_machine())
    try:
        load0 = os.getloadavg()
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            warnings.filterwarnings("ignore", message=r"(PBD|Jakobsen) reads stiffness, not compliance",
                                    category=_core.MaterialWarning)
            record.update(_measure(definition, context))
            caught = sorted({f"{w.category.__name__}: {w.message}" for w in seen})
        record.update(status="ok", error_type=None, error=None)
        record["load_average"] = [max(a, b) for a, b in zip(load0, os.getloadavg())]
    except Exception as e:  # a failed cell is a result: recorded, the others go on
        record.update(status="failed", error_type=type(e).__name__, error=str(e),
                      traceback="".join(traceback.format_exception(e))[-4000:])
    record["warnings"] = caught
    return record


# Repeats = "auto": timed runs until the spread of the cost (its range, from four runs on its
# interquartile range, which one run slowed by another process does not stretch) is within
# AUTO_SPREAD of the median, at least AUTO_MIN and at most AUTO_MAX of them, and no more once
# the runs have taken AUTO_BUDGET s of CPU time (the spread is then reported as it is).
AUTO_MIN, AUTO_MAX, AUTO_SPREAD, AUTO_BUDGET = 3, 15, 0.1, 10.0


def cost_range(costs: list[float]) -> tuple[float, float]:
    """The spread of a cell's costs: their range, or from four runs their first and third
    quartiles."""
    if len(costs) < 4:
        return min(costs), max(costs)
    q1, _, q3 = statistics.quantiles(costs, n=4, method="inclusive")
    return q1, q3


def _enough(costs: list[float], repeats: int | str) -> bool:
    if repeats != "auto":
        return len(costs) >= int(repeats)
    if len(costs) < AUTO_MIN:
        return False
    low, high = cost_range(costs)
    return (len(costs) >= AUTO_MAX or sum(costs) >= AUTO_BUDGET
            or high - low <= AUTO_SPREAD * statistics.median(costs))


def _measure(definition: dict[str, Any], context: dict[str, Any]) -> dict:
    scene, params, metrics = definition["scene"], definition["params"], definition["metrics"]
    gravity = tuple(scene["gravity"])
    times = _output_times(definition)
    interval = float(times[1] - times[0])
    duration = float(times[-1])
    model, start = _build_scene(scene, context["scene"])
    # The step ending at each output time, with the state it started from: for the metrics
    # measured on one step (the backward-Euler residual, the same-step error).
    per_step = [m for m in metrics if m in ("residual", "same_step_error")]
    last_steps: list[tuple[_core.State, _core.State]] = []
    if "name" in definition["method"] and definition["method"]["name"] == REFERENCE_METHOD:
        if per_step:
            raise _core.ParameterError(f"{per_step[0]} is measured on one step of a time-stepping method; "
                                       "the continuous reference takes no steps of its own")
        costs, states = [], None
        while not _enough(costs, definition["repeats"]):
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
        check = getattr(_make_stepper(definition, context, params, dt_used, gravity), "conformance", None)
        if check is not None:  # a peer's adapter (csb.bench.adapters): checked before it is measured
            outcome = check(model)
            if not outcome.ok:
                raise PeerDoesNotConform(str(outcome))
        # A warm-up: one step of another stepper on a copy, untimed (first-call costs: caches,
        # allocations, a peer's kernels), so that the timed runs measure the steady cost.
        with contextlib.suppress(_core.SimulationError):
            _make_stepper(definition, context, params, dt_used, gravity).step(model, start.copy(), 1)
        while not _enough(costs, definition["repeats"]):
            stepper = _make_stepper(definition, context, params, dt_used, gravity)
            state, cpu, run_states, blew = start.copy(), 0.0, [start.copy()], False
            x0 = np.asarray(start.x).copy()
            keep = per_step and not costs  # the first run keeps the last step of each interval
            steps_list: list[tuple[_core.State, _core.State]] = []
            for _k in range(1, len(times)):
                try:
                    if keep:
                        if steps_per_interval > 1:  # (an Integrator need not take 0 steps)
                            cpu += _timed(stepper, model, state, steps_per_interval - 1)
                        before = state.copy()
                        cpu += _timed(stepper, model, state, 1)
                        steps_list.append((before, state.copy()))
                    else:
                        cpu += _timed(stepper, model, state, steps_per_interval)
                except _core.SimulationError:
                    blew = True
                x = np.asarray(state.x)
                if blew or not np.all(np.isfinite(x)) or np.abs(x - x0).max() > 100 * max(size, 1e-12):
                    blew = True
                    break
                run_states.append(state.copy())
            costs.append(cpu)
            if keep:
                last_steps = steps_list
            states = run_states
            if blew:
                break  # a blow-up is not timed again
    assert states is not None
    values: dict[str, Any] = {}
    notes: list[str] = []  # metrics that do not apply to the scene: null, and said why
    for m in metrics:
        if m == "stability":
            values[m] = "blew-up" if blew else "stable"
        elif blew or m == "position_error":
            values[m] = None  # not measured past a blow-up (the stability says why); position_error: from
            #                   the positions, against the reference, when the table is made
        elif m == "energy_drift":
            values[m] = float(relative_energy_drift(model, states, gravity))
        elif m in ("max_strain", "max_violation"):
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
        elif m in ("residual", "same_step_error"):
            # One backward-Euler stepper for the cell: it keeps its matrices and their analysis
            # between solves, and gives a fresh stepper's bits (tests/test_implicit_euler.py).
            exact = _core.BackwardEuler(dt=dt_used, gravity=gravity) if m == "same_step_error" else None
            try:
                values[m] = max(_one_step_metric(m, model, before, after, dt_used, gravity, exact)
                                for before, after in last_steps)
            except _core.ParameterError as e:  # a hard constraint: no incremental potential
                values[m] = None
                notes.append(f"{m}: {e}")
            except _core.SimulationError as e:  # the converged backward-Euler step failed: no same step
                values[m] = None
                notes.append(f"{m}: the same-step reference failed: {e}")
    per_second = [c / duration for c in costs]
    low, high = cost_range(per_second)
    positions = np.stack([np.asarray(s.x, dtype=np.float64) for s in states]) if not blew else None
    return dict(metrics=values, notes=notes, dt_used=dt_used, positions=positions,
                steps=None if steps_per_interval is None else steps_per_interval * (len(times) - 1),
                cost=dict(cpu_per_simulated_s=statistics.median(per_second),
                          spread=high - low, low=low, high=high,
                          samples=per_second, repeats=len(costs)))


def _timed(stepper: _core.Integrator, model: _core.Model, state: _core.State, steps: int) -> float:
    """Steps ``state`` and returns the process CPU time it took (s)."""
    c0 = time.process_time()
    stepper.step(model, state, steps)
    return time.process_time() - c0


def _one_step_metric(metric: str, model: _core.Model, before: _core.State, after: _core.State, dt: float,
                     gravity, stepper: _core.Integrator | None = None) -> float:
    """The backward-Euler residual |∇E| (N, 2-norm) of the step from ``before`` to ``after``, or the
    largest distance (m) of ``after`` from the converged backward-Euler step from ``before``
    (taken by ``stepper``, a csb.BackwardEuler of step dt)."""
    if metric == "residual":
        return float(_core.backward_euler_residual(model, before, after, dt, gravity).norm)
    exact = before.copy()
    (stepper or _core.BackwardEuler(dt=dt, gravity=gravity)).step(model, exact, 1)
    return float(np.linalg.norm(np.asarray(after.x) - np.asarray(exact.x), axis=1).max())


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


