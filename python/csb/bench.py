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

import numpy as np

from . import _core
from .model import ModelBuilder
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


def front_ends(sizes: Sequence[int] = (32, 128, 512), *, iterations: int = 10, rounds: int = 7) -> list[dict]:
    """Euler (velocity) against Verlet (previous position) prediction inside the same PBD
    pipeline: the front end alone (the particles without constraints) in ns per particle per
    step, and the whole step of the cloth_grid scene at `iterations`."""
    rows = []
    for n in sizes:
        row: dict = {"n": n, "particles": n * n}
        for label, constraints in (("alone", False), ("step", True)):
            sim = cloth_simulation(n, iterations=iterations)
            model = sim.model
            if not constraints:  # the same particles, no constraints
                b = ModelBuilder()
                g = b.add_group("particles")
                for x, m in zip(np.asarray(model.rest_positions), np.asarray(model.mass)):
                    b.add_particle(x, float(m), g)
                model = b.build()
            steps = max(3, int(2e6 / (n * n * (iterations if constraints else 1))))
            for front in ("euler", "verlet"):
                stepper = _core.PbdStepper(dt=1 / 60, iterations=iterations, front_end=front)
                state = model.initial_state()
                stepper.step(model, state, 2)
                times = []
                for _ in range(rounds):
                    t0 = time.perf_counter()
                    stepper.step(model, state, steps)
                    times.append((time.perf_counter() - t0) / steps)
                med = statistics.median(times)
                row[f"{label}_{front}_ms"] = 1e3 * med
                row[f"{label}_{front}_ns_per_particle"] = 1e9 * med / (n * n)
        rows.append(row)
    return rows


def format_front_ends(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'particles':>9} | {'front end alone: ns/particle/step':^36} | "
            f"{'whole step (10 it): ms':^30}")
    sub = f"{'':>9} {'':>9} | {'Euler':>10} {'Verlet':>10} {'Euler/Verlet':>13} | {'Euler':>9} {'Verlet':>9} {'Euler/Verlet':>13}"
    lines = [head, sub, "-" * len(sub)]
    for r in rows:
        lines.append(
            f"{r['n']:>4}x{r['n']:<4} {r['particles']:>9} | {r['alone_euler_ns_per_particle']:>10.2f} "
            f"{r['alone_verlet_ns_per_particle']:>10.2f} "
            f"{r['alone_euler_ns_per_particle'] / r['alone_verlet_ns_per_particle']:>13.2f} | "
            f"{r['step_euler_ms']:>9.3f} {r['step_verlet_ms']:>9.3f} {r['step_euler_ms'] / r['step_verlet_ms']:>13.3f}")
    return "\n".join(lines)


def dispatch(sizes: Sequence[int] = (64, 128), *, sweeps: int = 10, repeats: int = 7) -> list[dict]:
    """The proposal's virtual Constraint::project against the batched kernels: the same
    constraints in the same order, checked bit for bit."""
    rows = []
    for n in sizes:
        for kind in KINDS:
            sim = cloth_simulation(n, constraints=kind)
            sim.stepper.step(sim.model, sim.state, 5)  # a deformed cloth, so that every projection moves something
            t = _core.benchmark_dispatch(sim.model, sim.state.x, sweeps, repeats)
            batched, virtual = statistics.median(t["batched_ns"]), statistics.median(t["virtual_ns"])
            rows.append(dict(n=n, kind=kind, constraints=sim.model.num_constraints, projections=t["projections"],
                             batched_ns=batched, virtual_ns=virtual, ratio=virtual / batched, identical=t["identical"]))
    return rows


def format_dispatch(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'kind':>15} {'constraints':>11} {'batched ns/proj':>16} {'virtual ns/proj':>16} "
            f"{'virtual/batched':>16} {'same bits':>10}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['kind']:>15} {r['constraints']:>11} {r['batched_ns']:>16.2f} "
                     f"{r['virtual_ns']:>16.2f} {r['ratio']:>16.3f} {'yes' if r['identical'] else 'NO':>10}")
    return "\n".join(lines)


def main(sizes: Sequence[int] = (64, 128), iterations: int = 10, substeps: int = 1, steps: int = 10,
         rounds: int = 7, parts: Sequence[str] = ("step", "front-ends", "dispatch", "viewer"),
         front_end_sizes: Sequence[int] = (32, 128, 512)) -> dict:
    info = _core.build_info()
    out: dict = {}
    if "step" in parts:
        print(f"csb {info['csb']} PBD step benchmark ({info['compiler']}, one thread): bundled scene cloth_grid "
              f"(stretch + bending, 2 pinned corners) at n x n particles, dt = 1/60 s; median of {rounds} rounds "
              f"of {steps} steps after 5 warm-up steps")
        out["step"] = [bench_cloth(n, iterations=iterations, substeps=substeps, steps=steps, rounds=rounds,
                                   constraints=kind) for n in sizes for kind in KINDS]
        print(format_table(out["step"]))
    if "front-ends" in parts:
        print(f"\nEuler against Verlet front end in the same PBD pipeline (cloth_grid, {iterations} iterations; "
              f"median of {rounds} rounds)")
        out["front-ends"] = front_ends(front_end_sizes, iterations=iterations, rounds=rounds)
        print(format_front_ends(out["front-ends"]))
    if "dispatch" in parts:
        print(f"\nVirtual Constraint::project against the batched kernels ({iterations} Gauss-Seidel sweeps of a "
              f"deformed cloth_grid; median of {rounds} repeats)")
        out["dispatch"] = dispatch(sizes, sweeps=iterations, repeats=rounds)
        print(format_dispatch(out["dispatch"]))
    if "viewer" in parts:
        from .view import format_frame_times, frame_times, viewer_available, viewer_missing

        if viewer_available():
            print("\nViewer frame time, offscreen (EGL), overlay on, 4x multisampling: cloth_grid 64 x 64, one "
                  "step of 1 x 10 iterations per frame; median of 60 frames (software rendering: a figure, not a "
                  "GPU measurement)")
            out["viewer"] = frame_times(64)
            print(format_frame_times(out["viewer"]))
        else:
            print(f"\nViewer frame time: not measured, the viewer was not built ({viewer_missing()})")
    return out
