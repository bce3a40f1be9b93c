"""One cell of a study: its scene built, its method made and stepped, its metrics measured
against the reference, its cost timed; and the cells' storage (one JSON file a cell, written
atomically)."""

from __future__ import annotations

import contextlib
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
                      duration: float, outputs: int) -> np.ndarray:
    """The reference's positions (T, N, 3) at the output times of a scene (m)."""
    model, start = _build_scene(scene, context)
    times = np.linspace(0.0, duration, outputs + 1)
    r = _core_reference(model, start, times, scene["gravity"], reference)
    return r.x


def _core_reference(model, start, times, gravity, reference):
    from ...reference import integrate_reference

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
    from .. import make_stepper

    module, _, cls = method["python"].partition(":")
    made = getattr(_import_user_module(module, context["method"].get("folder"), method.get("sha256")), cls)
    return make_stepper(made, dt=dt, gravity=gravity, **{k: params[k] for k in ("substeps", "iterations")
                                                        if k in params})


def _machine() -> dict[str, Any]:
    return dict(platform=platform.platform(), machine=platform.machine(), python=platform.python_version(),
                cpu_count=os.cpu_count(), node=platform.node())


class PeerDoesNotConform(Exception):
    """A peer's adapter failed its conformance check: the cell is reported, not plotted."""


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
        check = getattr(_make_stepper(definition, context, params, dt_used, gravity), "conformance", None)
        if check is not None:  # a peer's adapter (csb.bench.adapters): checked before it is measured
            outcome = check(model)
            if not outcome.ok:
                raise PeerDoesNotConform(str(outcome))
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


