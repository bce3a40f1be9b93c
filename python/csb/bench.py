"""Benchmark of the PBD step on square cloths: ms per step and constraint projections per second.

The cloth is the bundled scene ``cloth_grid`` (stretch and bending, two pinned corners) at the
requested resolution. A benchmark prints figures; it asserts nothing about speed (the machines
it runs on are shared and noisy). Each figure is the median over several timed rounds, after a
warm-up.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from dataclasses import dataclass
from typing import Sequence

from . import _core
from .scene import Simulation, load_scene


@dataclass(frozen=True)
class BenchRow:
    n: int                    # particles per side
    constraints: str          # which constraint types the cloth has
    particles: int
    distance: int
    bending: int
    substeps: int
    iterations: int
    ms_per_step: float        # median
    ms_spread: tuple[float, float]   # min, max over rounds
    projections_per_step: int

    @property
    def projections_per_second(self) -> float:
        return self.projections_per_step / (self.ms_per_step * 1e-3)

    @property
    def ns_per_projection(self) -> float:
        return 1e6 * self.ms_per_step / self.projections_per_step


KINDS = ("stretch+bending", "stretch", "bending")


def cloth_simulation(n: int, *, iterations: int = 10, substeps: int = 1, constraints: str = KINDS[0]) -> Simulation:
    """The bundled ``cloth_grid`` scene with n x n particles, at dt = 1/60 s, with all its
    constraints or only one type of them."""
    scene = load_scene("cloth_grid")
    mesh = scene.meshes[0]
    mesh = dataclasses.replace(
        mesh, shape_args={**mesh.shape_args, "resolution": (n, n)},
        stretch=mesh.stretch if "stretch" in constraints else None,
        bending=mesh.bending if "bending" in constraints else None,
    )
    solver = dataclasses.replace(scene.solver, dt=1 / 60, iterations=iterations, substeps=substeps)
    return dataclasses.replace(scene, meshes=(mesh,), solver=solver).build()


def bench_cloth(n: int, *, iterations: int = 10, substeps: int = 1, steps: int = 10, rounds: int = 7,
                warmup: int = 5, constraints: str = KINDS[0]) -> BenchRow:
    sim = cloth_simulation(n, iterations=iterations, substeps=substeps, constraints=constraints)
    model, state, stepper = sim.model, sim.state, sim.stepper
    stepper.step(model, state, warmup)
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        stepper.step(model, state, steps)
        times.append((time.perf_counter() - t0) / steps * 1e3)
    return BenchRow(
        n=n, constraints=constraints, particles=model.num_particles, distance=len(model.distance["rest_length"]),
        bending=len(model.bending["rest_angle"]), substeps=substeps, iterations=iterations,
        ms_per_step=statistics.median(times), ms_spread=(min(times), max(times)),
        projections_per_step=stepper.projections_per_step(model),
    )


def format_table(rows: Sequence[BenchRow]) -> str:
    head = (f"{'cloth':>9} {'constraints':>15} {'particles':>9} {'distance':>8} {'bending':>8} {'sub x it':>8} "
            f"{'ms/step':>9} {'(min-max)':>15} {'proj/step':>10} {'Mproj/s':>8} {'ns/proj':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r.n:>4}x{r.n:<4} {r.constraints:>15} {r.particles:>9} {r.distance:>8} {r.bending:>8} "
            f"{r.substeps:>3} x {r.iterations:<3} {r.ms_per_step:>9.3f} "
            f"{f'({r.ms_spread[0]:.3f}-{r.ms_spread[1]:.3f})':>15} {r.projections_per_step:>10} "
            f"{r.projections_per_second / 1e6:>8.1f} {r.ns_per_projection:>8.2f}")
    return "\n".join(lines)


def main(sizes: Sequence[int] = (64, 128), iterations: int = 10, substeps: int = 1, steps: int = 10,
         rounds: int = 7) -> list[BenchRow]:
    info = _core.build_info()
    print(f"csb {info['csb']} PBD step benchmark ({info['compiler']}, one thread): bundled scene cloth_grid "
          f"(stretch + bending, 2 pinned corners) at n x n particles, dt = 1/60 s; median of {rounds} rounds "
          f"of {steps} steps after 5 warm-up steps")
    rows = [bench_cloth(n, iterations=iterations, substeps=substeps, steps=steps, rounds=rounds, constraints=kind)
            for n in sizes for kind in KINDS]
    print(format_table(rows))
    return rows
