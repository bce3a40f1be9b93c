"""Stepping a scene for its duration, recording metrics and writing its outputs."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from . import _core
from .output import FrameWriter, metrics_row, plot_snapshot, plot_summary, volume_errors, write_csv
from .scene_file import SceneError

if TYPE_CHECKING:
    from .scene import Scene, Simulation

__all__ = ["RunResult", "run_scene"]


@dataclass
class RunResult:
    simulation: "Simulation"
    steps: int
    wall_time: float                     # s, stepping only (outputs excluded)
    rows: list[dict[str, float]] = field(default_factory=list)   # metrics per frame
    files: list[Path] = field(default_factory=list)
    tears: int = 0                       # vertices split by tearing
    memory: dict[str, int] = field(default_factory=dict)
    """Bytes at the end of the run: ``model`` (Model.memory's total), ``stepper``
    (PbdStepper.workspace_bytes), ``state`` (positions and velocities) and ``peak_resident``, the
    process's peak resident memory so far (what sizes a run: it includes building the model,
    about 5 times the model's own arrays for a cloth; absent where the platform does not say)."""
    stepper_given: bool = False
    """The scene was stepped by a method given to the run (``stepper=``) instead of its solver's."""

    @property
    def final(self) -> dict[str, float]:
        return self.rows[-1]

    @property
    def largest_strain(self) -> float:
        """The largest edge strain of any recorded frame."""
        return max(r["max_strain"] for r in self.rows)

    @property
    def energy_growth(self) -> float:
        """J: how far the kinetic + gravitational energy of any recorded frame rose above the
        first frame's (0 if it never did)."""
        e0 = self.rows[0]["mechanical_energy"]
        return max(0.0, max(r["mechanical_energy"] for r in self.rows) - e0)

    def checks(self) -> list[str]:
        """What the run did that its scene's materials do not allow; empty when nothing did.

        - Strain: an edge whose material the method reads as hard (PBD, Jakobsen: stiffness 1;
          XPBD and the other methods that read compliance: compliance 0) allows none; a compliant
          one at most what the whole body's
          weight would stretch it by, α m |g| / L; a soft PBD edge (k < 1) has no strain in SI
          units, so it allows any. Flagged past that plus 10 % (what a converged solver keeps
          well under), or past the tearing threshold in a tearing scene.
        - Energy: without drivers (grabs, moving colliders, particles attached to colliders) the
          kinetic + gravitational energy can only fall from the first frame, which starts at rest
          shape (no elastic energy to release); flagged when it rises by more than 1 % of m |g| D,
          D the body's rest bounding-box diagonal. A scene with drivers is not checked for it.

        A method given to the run is held to the strain of the built-in method of its name (what
        csb.methods() says it reads); one csb does not know is held to the energy alone."""
        sim = self.simulation
        model = sim.model
        out = []
        solver, method = sim.scene.solver, sim.scene.solver.method.upper()
        if self.stepper_given:
            method = sim.stepper.name()
            reads = {m.name: m.reads for m in _core.methods()}.get(method)
            solver = None if reads is None else dataclasses.replace(
                solver, method="xpbd" if reads == "compliance" else "pbd")
        allowed = strain_allowed(model, solver) if solver is not None else math.inf
        if sim.scene.tearing is not None:
            allowed = max(allowed, sim.scene.tearing.max_strain)
        limit = allowed + 0.10
        if self.largest_strain > limit:
            out.append(f"the largest strain, {100 * self.largest_strain:.3g} %, exceeds the {100 * limit:.3g} % its "
                       f"materials allow under {method} (converge further: more sub-steps "
                       f"or iterations)")
        mass = float(np.sum(np.asarray(model.mass)))
        rest = np.asarray(model.rest_positions)
        size = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))) if len(rest) else 0.0
        scale = 0.01 * mass * float(np.linalg.norm(sim.scene.solver.gravity)) * size
        driven = (bool(sim.collider_motion) or any(c.motion is not None for c in sim.scene.colliders)
                  or any(m.attach is not None and m.attach.collider is not None for m in sim.scene.meshes))
        if scale > 0 and not driven and self.energy_growth > scale:
            out.append(f"its kinetic + gravitational energy rose by {self.energy_growth:.3g} J, more than 1 % of "
                       f"m |g| D = {100 * scale:.3g} J, which a scene without drivers cannot gain (unstable: "
                       f"smaller sub-steps or more iterations)")
        return out

    def summary(self) -> str:
        sim = self.simulation
        s = sim.scene.solver
        f = self.final
        how = (f"{1e3 * sim.stepper.dt():.3g} ms ({sim.stepper.name()})" if self.stepper_given
               else f"{1e3 * s.dt:.3g} ms ({s.method}, {s.substeps} substeps x {s.iterations} iterations)")
        return (
            f"{sim.scene.name}: {self.steps} steps of {how}, {sim.model.num_particles} particles, {sim.model.num_constraints} "
            f"constraints, {self.wall_time:.3f} s wall ({self.steps / max(self.wall_time, 1e-12):.0f} steps/s); "
            f"t = {f['t']:.3f} s, kinetic + gravitational energy {f['mechanical_energy']:.6g} J, "
            f"max strain {100 * f['max_strain']:.3g} %"
            + (f", volume error {100 * f['volume_error']:+.3g} %" if sim.model.volume["rest_volume"].size else "")
            + (f", balloon volume error {100 * f['balloon_volume_error']:+.3g} %"
               if sim.model.balloons["rest_volume"].size else "")
            + (f", {self.tears} vertices torn" if sim.scene.tearing is not None else "")
            + f"; largest strain {100 * self.largest_strain:.3g} %, energy growth {self.energy_growth:.3g} J"
            + (f"\n  memory: model {self.memory['model'] / 1e6:.3g} MB + stepper {self.memory['stepper'] / 1e6:.3g} MB"
               f" + state {self.memory['state'] / 1e6:.3g} MB"
               + (f", process peak {self.memory['peak_resident'] / 1e6:.4g} MB resident" if "peak_resident" in self.memory
                  else "") if self.memory else "")
            + "".join(f"\n  CHECK: {c}" for c in self.checks())
        )


_SOLVERS = {"gauss-seidel": "Gauss-Seidel", "jacobi": "Jacobi", "jacobi-summed": "Jacobi (summed)"}


def strain_allowed(model: "_core.Model", solver) -> float:
    """The largest strain any distance constraint's material allows under the solver's method
    (see RunResult.checks): 0 for hard edges, α m |g| / L for compliant ones (XPBD), any (inf)
    for soft PBD edges (stiffness < 1)."""
    d = model.distance
    if len(d["rest_length"]) == 0:
        return 0.0
    if _core.method_info(solver.method).reads == "compliance":
        weight = float(np.sum(np.asarray(model.mass))) * float(np.linalg.norm(solver.gravity))
        return float(np.max(np.asarray(d["compliance"]) * weight / np.asarray(d["rest_length"])))
    return float("inf") if np.any(np.asarray(d["stiffness"]) < 1) else 0.0


def peak_resident_bytes() -> int | None:
    """The process's peak resident memory (bytes), or None where the platform does not report it."""
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)  # bytes on macOS, KiB elsewhere


def memory_used(sim: "Simulation") -> dict[str, int]:
    """The run's memory, as in RunResult.memory."""
    out = dict(model=int(sim.model.memory["total"]), stepper=int(getattr(sim.stepper, "workspace_bytes", 0)),
               state=int(2 * 3 * 8 * sim.model.num_particles))
    peak = peak_resident_bytes()
    if peak is not None:
        out["peak_resident"] = peak
    return out


def summary_title(scene: "Scene", num_particles: int, stepper: "_core.Integrator | None" = None) -> str:
    """The title of a run's ``summary.png``: the scene, its size and how it was stepped (the
    method, the sweep, dt in ms, sub-steps x iterations; a given stepper's name and dt)."""
    if stepper is not None:
        return f"{scene.name}: {num_particles} particles, {stepper.name()}, dt = {1e3 * stepper.dt():.3g} ms"
    s = scene.solver
    label = _core.method_info(s.method).label
    if not s.position_based:
        return (f"{scene.name}: {num_particles} particles, {label}, dt = {1e3 * s.dt:.3g} ms, "
                f"{s.substeps} substeps x {s.iterations} iterations")
    verlet = " (Verlet)" if s.stepper().settings.front_end == "verlet" else ""  # the front end in effect
    return (f"{scene.name}: {num_particles} particles, {label}{verlet} "
            f"{_SOLVERS.get(s.solver, s.solver)}, dt = {1e3 * s.dt:.3g} ms, "
            f"{s.substeps} substeps x {s.iterations} iterations")


def run_scene(scene: "Scene", out_dir: str | os.PathLike[str] | None, *, progress: bool = False,
              stepper: "_core.Integrator | None" = None) -> RunResult:
    """Steps `scene` for its duration with its solver, or with `stepper` (any csb.Integrator: a
    built-in, csb.make_integrator's, or a user's own) in steps of the stepper's dt()."""
    sim = scene.build(stepper)
    dt = scene.solver.dt
    if stepper is not None:
        dt = sim.stepper.dt()
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise _core.ParameterError(f"stepper {sim.stepper.name()!r}: dt() must be a time step > 0 s, got {dt!r}")
    steps = scene.steps if stepper is None else max(1, math.ceil(scene.duration / dt - 1e-9))
    try:  # a duration beyond the machine is refused before the first step (each call is a frame's steps)
        if hasattr(sim.stepper, "operations"):
            _core._require_time_for(f"duration {scene.duration:g} s = {steps} steps of {dt:g} s",
                                    float(steps) * sim.stepper.operations(sim.model, 1))
    except _core.ParameterError as e:
        raise SceneError(f"{scene.path}: {e}") from None
    steps_per_frame = max(1, round(1.0 / (scene.output.fps * dt)))
    writer = None
    out = Path(out_dir) if out_dir is not None else None
    if out is not None and (scene.output.xdmf or scene.output.vtu):
        writer = FrameWriter(out, scene.name, sim.model, xdmf=scene.output.xdmf, vtu=scene.output.vtu)
    usd = None
    exports: list = []   # the game-engine formats: glTF, OBJ and PLY sequences
    if out is not None and (scene.output.usd or scene.output.gltf or scene.output.obj or scene.output.ply):
        from .export import GltfWriter, SequenceWriter, collider_frame, simulation_usd_writer

        if scene.output.usd:  # time codes count the frames as written: one every steps_per_frame steps of dt
            usd = simulation_usd_writer(out / f"{scene.name}.usd", sim, fps=1.0 / (steps_per_frame * dt))
        if scene.output.gltf:
            exports.append(GltfWriter(out / f"{scene.name}.glb", sim.meshes))
        for fmt in ("obj", "ply"):
            if getattr(scene.output, fmt):
                exports.append(SequenceWriter(out / fmt, scene.name, sim.meshes, format=fmt))

    result = RunResult(sim, steps, 0.0, stepper_given=stepper is not None)

    def record() -> None:
        result.rows.append(metrics_row(sim.measure(), sim.state.step, volume_errors(sim.model, sim.state)))
        if writer is not None:
            writer.write(sim.state)
        if usd is not None:
            usd.write(sim.state, *collider_frame(sim))
        for e in exports:
            e.write(sim.state)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, unit="step", desc=scene.name, leave=False, dynamic_ncols=True)
    record()
    done = 0
    try:
        while done < steps:
            n = min(steps_per_frame, steps - done)
            t0 = time.perf_counter()
            if scene.tearing is None:
                sim.step(n)  # moving colliders put at each step's pose
            else:
                for _ in range(n):
                    sim.step()
                    torn = _core.tear(sim.model, sim.state, max_strain=scene.tearing.max_strain,
                                      max_tears=scene.tearing.max_per_step)
                    if torn["torn"]:
                        sim.model, sim.state = torn["model"], torn["state"]
                        result.tears += torn["torn"]
                        if writer is not None:
                            writer.set_model(sim.model)
            result.wall_time += time.perf_counter() - t0
            done += n
            record()
            if bar is not None:
                bar.update(n)
    finally:
        if bar is not None:
            bar.close()
        if writer is not None:
            result.files += writer.close()
        if usd is not None and usd.frames:
            result.files.append(usd.close())
        for e in exports:
            closed = e.close()
            result.files += closed if isinstance(closed, list) else [closed]
        result.memory = memory_used(sim)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if scene.output.csv:
            result.files.append(write_csv(out / "metrics.csv", result.rows))
        if scene.output.plot:
            title = summary_title(scene, sim.model.num_particles, stepper)
            result.files.append(plot_summary(out / "summary.png", result.rows, title))
            # The colliders where the last step left them: each at its pose, and a deforming mesh
            # (a skinned body) in its shape then, not as declared at t = 0.
            poses = vertices = None
            if isinstance(sim.stepper, _core.PbdStepper):
                colliders = sim.model.colliders
                poses = [sim.stepper.collider_pose(k) for k in range(len(colliders))]
                vertices = [sim.stepper.collider_vertices(sim.model, k) if c["kind"] == "mesh" else None
                            for k, c in enumerate(colliders)]
            result.files.append(plot_snapshot(out / "snapshot.png", sim.model, sim.state,
                                              f"{scene.name} at t = {sim.state.t:.2f} s", poses, vertices))
    return result
