"""Stepping a scene for its duration, recording metrics and writing its outputs."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from . import _core
from .output import FrameWriter, metrics_row, plot_snapshot, plot_summary, volume_errors, write_csv

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

    @property
    def final(self) -> dict[str, float]:
        return self.rows[-1]

    def summary(self) -> str:
        sim = self.simulation
        s = sim.scene.solver
        f = self.final
        return (
            f"{sim.scene.name}: {self.steps} steps of {1e3 * s.dt:.3g} ms ({s.substeps} substeps x "
            f"{s.iterations} iterations), {sim.model.num_particles} particles, {sim.model.num_constraints} "
            f"constraints, {self.wall_time:.3f} s wall ({self.steps / max(self.wall_time, 1e-12):.0f} steps/s); "
            f"t = {f['t']:.3f} s, kinetic + gravitational energy {f['mechanical_energy']:.6g} J, "
            f"max strain {100 * f['max_strain']:.3g} %"
            + (f", volume error {100 * f['volume_error']:+.3g} %" if sim.model.volume["rest_volume"].size else "")
            + (f", balloon volume error {100 * f['balloon_volume_error']:+.3g} %"
               if sim.model.balloons["rest_volume"].size else "")
            + (f", {self.tears} vertices torn" if sim.scene.tearing is not None else "")
        )


_METHODS = {"pbd": "PBD", "xpbd": "XPBD", "jakobsen": "Jakobsen (Verlet)"}
_SOLVERS = {"gauss-seidel": "Gauss-Seidel", "jacobi": "Jacobi", "jacobi-summed": "Jacobi (summed)"}


def summary_title(scene: "Scene", num_particles: int) -> str:
    """The title of a run's ``summary.png``: the scene, its size and how it was stepped (the
    method, the sweep, dt in ms, sub-steps x iterations)."""
    s = scene.solver
    return (f"{scene.name}: {num_particles} particles, {_METHODS.get(s.method, s.method)} "
            f"{_SOLVERS.get(s.solver, s.solver)}, dt = {1e3 * s.dt:.3g} ms, "
            f"{s.substeps} substeps x {s.iterations} iterations")


def run_scene(scene: "Scene", out_dir: str | os.PathLike[str] | None, *, progress: bool = False) -> RunResult:
    sim = scene.build()
    steps = scene.steps
    steps_per_frame = max(1, round(1.0 / (scene.output.fps * scene.solver.dt)))
    writer = None
    out = Path(out_dir) if out_dir is not None else None
    if out is not None and (scene.output.xdmf or scene.output.vtu):
        writer = FrameWriter(out, scene.name, sim.model, xdmf=scene.output.xdmf, vtu=scene.output.vtu)

    result = RunResult(sim, steps, 0.0)

    def record() -> None:
        result.rows.append(metrics_row(sim.measure(), sim.state.step, volume_errors(sim.model, sim.state)))
        if writer is not None:
            writer.write(sim.state)

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
                sim.stepper.step(sim.model, sim.state, n)
            else:
                for _ in range(n):
                    sim.stepper.step(sim.model, sim.state)
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
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if scene.output.csv:
            result.files.append(write_csv(out / "metrics.csv", result.rows))
        if scene.output.plot:
            title = summary_title(scene, sim.model.num_particles)
            result.files.append(plot_summary(out / "summary.png", result.rows, title))
            result.files.append(plot_snapshot(out / "snapshot.png", sim.model, sim.state,
                                              f"{scene.name} at t = {sim.state.t:.2f} s"))
    return result
