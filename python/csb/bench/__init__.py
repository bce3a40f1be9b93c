"""csb.bench: the benchmarks (this module) and the peers' adapters (csb.bench.peers). They use the
library (csb) and nothing uses them.

Benchmark of the PBD step on square cloths: ms per step and constraint projections per second.

The cloth is the bundled scene ``cloth_grid`` (stretch and bending, two pinned corners) at the
requested resolution. A benchmark prints figures; it asserts nothing about speed (the machines
it runs on are shared and noisy). Each figure is the median over several timed rounds, after a
warm-up.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .. import _core
from ..model import ModelBuilder
from ..scene import Simulation, load_scene


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
         rounds: int = 7, parts: Sequence[str] | None = None,
         front_end_sizes: Sequence[int] = (32, 128, 512), self_collision_sizes: Sequence[int] | None = None) -> dict:
    """Prints the tables named in `parts` (default: all of them); `self_collision_sizes`: the
    cape sizes of the self-collision sweep (default `SELF_COLLISION_SIZES`)."""
    if parts is None:
        parts = ("step", "front-ends", "dispatch", "viewer") + COST_PARTS
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
        from ..view import viewer_available, viewer_missing

        if viewer_available():
            print("\nViewer frame time, offscreen (EGL), overlay on, 4x multisampling: cloth_grid 64 x 64, one "
                  "step of 1 x 10 iterations per frame; median of 60 frames (software rendering: a figure, not a "
                  "GPU measurement)")
            out["viewer"] = frame_times(64)
            print(format_frame_times(out["viewer"]))
        else:
            print(f"\nViewer frame time: not measured, the viewer was not built ({viewer_missing()})")
    cost_parts = [p for p in parts if p in COST_PARTS]
    if cost_parts:
        out.update(cost_tables(cost_parts, rounds=rounds, self_collision_sizes=self_collision_sizes))
    return out


# ------------------------------------------------------------------------------------------------
# Colouring, SIMD, threads, scaling, memory, the reference's cost. Functions other code can
# call (e.g. a peer comparison) return plain numbers; the format_* ones print tables.

# What the coloured sweep and the reference cost: ms per frame and frames per second of 128x128 and
# 256x256 cloths, XPBD against PBD, float64 against float32, projections per second by constraint type,
# one against two threads (also beside a busy core), cost per particle from 1k to 1M particles, memory, a
# 1024x1024 cloth, the reference's KLU cost.
COST_PARTS = ("fps", "xpbd", "precision", "types", "threads", "busy", "particles", "memory", "big", "klu", "methods",
              "self-collision")


def make_stepper(sim: Simulation, *, substeps: int, iterations: int, threads: int = 0, ordering: str = "coloured",
                 method: str | None = None, precision: str = "float64") -> _core.PbdStepper:
    """The scene's stepper with sub-steps, iterations, threads, ordering, precision (and method) replaced."""
    solver = dataclasses.replace(sim.scene.solver, substeps=substeps, iterations=iterations, threads=threads,
                                 ordering=ordering, precision=precision, **({"method": method} if method else {}))
    return solver.stepper()


def time_steps(stepper: _core.PbdStepper, model, state, *, steps: int, rounds: int, warmup: int = 2) -> list[float]:
    """ms per step of each timed round of `steps` steps, after `warmup` steps."""
    if warmup:
        stepper.step(model, state, warmup)
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        stepper.step(model, state, steps)
        times.append((time.perf_counter() - t0) / steps * 1e3)
    return times


def cloth_ms_per_frame(n: int, *, substeps: int = 10, iterations: int = 1, threads: int = 0,
                       ordering: str = "coloured", method: str = "pbd", frames: int = 10, rounds: int = 5,
                       constraints: str = KINDS[0]) -> dict:
    """csb on the bundled cloth_grid at n x n particles (stretch and shear edges, dihedral bending,
    two pinned corners), dt = 1/60 s: median ms per frame (one step of dt) at (substeps,
    iterations) with the given threads (0: automatic) and ordering; also its min-max, the fps and
    the threads the stepper used."""
    sim = cloth_simulation(n, iterations=iterations, substeps=substeps, constraints=constraints)
    stepper = make_stepper(sim, substeps=substeps, iterations=iterations, threads=threads, ordering=ordering,
                           method=method)
    times = time_steps(stepper, sim.model, sim.state, steps=frames, rounds=rounds)
    ms = statistics.median(times)
    return dict(n=n, particles=sim.model.num_particles, substeps=substeps, iterations=iterations, threads=threads,
                threads_used=stepper.threads_used, ordering=ordering, method=method, ms=ms,
                spread=(min(times), max(times)), fps=1e3 / ms)


def fps_table(sizes: Sequence[int] = (128, 256), *, rounds: int = 5) -> list[dict]:
    rows = []
    for n in sizes:
        for substeps, iterations in ((10, 1), (1, 10)):
            for threads in (1, 2):
                rows.append(cloth_ms_per_frame(n, substeps=substeps, iterations=iterations, threads=threads,
                                               rounds=rounds, frames=max(2, 20 * 128 * 128 // (n * n))))
            try:  # a sweep that diverges is reported in its row (in index order this one did at 10 x 1)
                rows.append(cloth_ms_per_frame(n, substeps=substeps, iterations=iterations, threads=1,
                                               ordering="sequential", rounds=rounds,
                                               frames=max(2, 20 * 128 * 128 // (n * n))))
            except _core.SimulationError as e:
                rows.append(dict(n=n, particles=n * n, substeps=substeps, iterations=iterations, threads=1,
                                 threads_used=1, ordering="sequential", method="pbd", ms=float("nan"),
                                 spread=(float("nan"), float("nan")), fps=float("nan"),
                                 diverged=str(e).split(":")[0]))
    return rows


def _taking_turns(sizes: Sequence[int], sides: dict[str, dict], *, rounds: int, threads: int,
                  settings: Sequence[tuple[int, int]] = ((10, 1), (1, 10))) -> list[dict]:
    """ms per frame of the bundled cloth_grid at n x n, dt = 1/60 s, for each side (a label and the
    stepper's method and precision) at each (sub-steps, iterations), `threads` threads. The sides
    take turns within each round (the order alternating), on their own cloths, so that a slow spell
    of the machine falls on all; medians and min-max of the rounds."""
    rows = []
    for n in sizes:
        frames = max(2, 20 * 128 * 128 // (n * n))
        for substeps, iterations in settings:
            runs = {}
            for label, side in sides.items():
                sim = cloth_simulation(n, iterations=iterations, substeps=substeps)
                stepper = make_stepper(sim, substeps=substeps, iterations=iterations, threads=threads, **side)
                stepper.step(sim.model, sim.state, 2)
                runs[label] = (stepper, sim.model, sim.state, [])
            order = list(runs)
            for r in range(rounds):
                for label in (order if r % 2 == 0 else order[::-1]):
                    stepper, model, state, times = runs[label]
                    times += time_steps(stepper, model, state, steps=frames, rounds=1, warmup=1)
            row = dict(n=n, substeps=substeps, iterations=iterations, threads_used=runs[order[-1]][0].threads_used)
            for label, (_, _, _, times) in runs.items():
                row[label] = statistics.median(times)
                row[label + "_spread"] = (min(times), max(times))
            rows.append(row)
    return rows


def xpbd_table(sizes: Sequence[int] = (64, 128, 256), *, rounds: int = 7, threads: int = 2) -> list[dict]:
    """XPBD's cost against PBD's at equal work: the same constraints, sub-steps and iterations, the
    two steppers taking turns (_taking_turns); ms per frame, medians and min-max of the rounds."""
    rows = _taking_turns(sizes, {"pbd": dict(method="pbd"), "xpbd": dict(method="xpbd")}, rounds=rounds,
                         threads=threads)
    for row in rows:
        row["ratio"] = row["xpbd"] / row["pbd"]
    return rows


PRECISION_SIDES = {f"{m}_{p}": dict(method=m, precision=p) for m in ("pbd", "xpbd") for p in ("float64", "float32")}


def precision_table(sizes: Sequence[int] = (64, 128, 256), *, rounds: int = 7, threads: int = 2) -> list[dict]:
    """Whole frames in double and single precision: PBD and XPBD, each in float64 and float32, on the
    same cloths at equal work, taking turns (_taking_turns); ms per frame, and per method the
    speed-up float64 / float32."""
    rows = _taking_turns(sizes, PRECISION_SIDES, rounds=rounds, threads=threads)
    for row in rows:
        for m in ("pbd", "xpbd"):
            row[m + "_speedup"] = row[m + "_float64"] / row[m + "_float32"]
    return rows


def format_precision_table(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'sub x it':>8} {'threads':>7} " +
            " ".join(f"{m.upper() + ' ' + p[-2:]:>9} {'(min-max)':>13}" for m in ("pbd", "xpbd") for p in ("float64", "float32")) +
            f" {'PBD 64/32':>9} {'XPBD 64/32':>10} {'fps PBD/XPBD 32':>15}")
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = " ".join(f"{r[k]:>9.3f} {'({:.2f}-{:.2f})'.format(*r[k + '_spread']):>13}" for k in PRECISION_SIDES)
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['substeps']:>3} x {r['iterations']:<2} {r['threads_used']:>7} {cells} "
                     f"{r['pbd_speedup']:>9.2f} {r['xpbd_speedup']:>10.2f} "
                     f"{'{:.0f} / {:.0f}'.format(1e3 / r['pbd_float32'], 1e3 / r['xpbd_float32']):>15}")
    return "\n".join(lines)


def precision_rates(sizes: Sequence[int] = (128, 256), *, sweeps: int = 10, rounds: int = 7,
                    threads: int = 1) -> list[dict]:
    """The distance and bending kernels in double and single precision: ns per projection of each
    type (an n x n cloth of that type only, one sub-step of `sweeps` coloured Gauss-Seidel sweeps, so
    that predict and update are a few per cent), PBD and XPBD, float64 and float32 taking turns
    within each round; medians, min-max and the speed-up float64 / float32. At 128 x 128 the
    positions fit a core's L2 cache in either precision (384 and 256 KiB); at 256 x 256 the double
    ones (1.5 MiB) do not, the float ones (1 MiB) nearly."""
    rows = []
    for n in sizes:
        for kind in ("distance", "bending"):
            model = cloth_simulation(n, iterations=sweeps,
                                     constraints="stretch" if kind == "distance" else "bending").model
            for method in ("pbd", "xpbd"):
                runs = {}
                for precision in ("float64", "float32"):
                    stepper = _core.PbdStepper(method=method, dt=1 / 60, iterations=sweeps, threads=threads,
                                               precision=precision)
                    state = model.initial_state()
                    stepper.step(model, state, 2)
                    runs[precision] = (stepper, state, [])
                for r in range(rounds):
                    for precision in (("float64", "float32") if r % 2 == 0 else ("float32", "float64")):
                        stepper, state, times = runs[precision]
                        times += time_steps(stepper, model, state, steps=3, rounds=1, warmup=0)
                per_step = runs["float64"][0].projections_per_step(model)
                row = dict(n=n, kind=kind, method=method, constraints=model.num_constraints,
                           threads=runs["float64"][0].threads_used)
                for precision, (_, _, times) in runs.items():
                    row[precision] = 1e6 * statistics.median(times) / per_step
                    row[precision + "_spread"] = (1e6 * min(times) / per_step, 1e6 * max(times) / per_step)
                row["speedup"] = row["float64"] / row["float32"]
                rows.append(row)
    return rows


def format_precision_rates(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'type':>9} {'method':>6} {'threads':>7} {'constraints':>11} {'f64 ns':>7} "
            f"{'(min-max)':>13} {'f32 ns':>7} {'(min-max)':>13} {'64/32':>6}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['kind']:>9} {r['method']:>6} {r['threads']:>7} "
                     f"{r['constraints']:>11} {r['float64']:>7.2f} "
                     f"{'({:.2f}-{:.2f})'.format(*r['float64_spread']):>13} {r['float32']:>7.2f} "
                     f"{'({:.2f}-{:.2f})'.format(*r['float32_spread']):>13} {r['speedup']:>6.2f}")
    return "\n".join(lines)


def format_xpbd_table(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'sub x it':>8} {'threads':>7} {'PBD ms':>8} {'(min-max)':>13} {'XPBD ms':>8} "
            f"{'(min-max)':>13} {'XPBD/PBD':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['substeps']:>3} x {r['iterations']:<2} {r['threads_used']:>7} "
                     f"{r['pbd']:>8.3f} {'({:.2f}-{:.2f})'.format(*r['pbd_spread']):>13} {r['xpbd']:>8.3f} "
                     f"{'({:.2f}-{:.2f})'.format(*r['xpbd_spread']):>13} {r['ratio']:>8.2f}")
    return "\n".join(lines)


def format_fps(rows: Sequence[dict]) -> str:
    head = f"{'cloth':>9} {'sub x it':>8} {'ordering':>10} {'threads':>7} {'ms/frame':>9} {'(min-max)':>15} {'fps':>7}"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['substeps']:>3} x {r['iterations']:<2} {r['ordering']:>10} "
                     f"{r['threads_used']:>7} {r['ms']:>9.2f} {'({:.2f}-{:.2f})'.format(*r['spread']):>15} "
                     f"{r['fps']:>7.1f}" + (f"  diverged ({r['diverged']})" if "diverged" in r else ""))
    return "\n".join(lines)


def _tet_simulation(cells: int, *, iterations: int) -> tuple:
    """A tet box of cells³ x 6 tets with volume constraints only, pinned nowhere, no gravity."""
    b = ModelBuilder()
    b.add_tet_mesh(_core.tet_box((1.0, 1.0, 1.0), (cells, cells, cells)), mass=1.0, stretch_stiffness=None)
    return b.build()


def _attachment_model(n: int):
    b = ModelBuilder()
    g = b.add_group("particles")
    rng = np.random.default_rng(0)
    for k in range(n):
        x = rng.normal(size=3)
        i = b.add_particle(x, 1.0, g)
        b.attach(i, x + 0.01, stiffness=0.5)
    return b.build()


def projection_rates(n: int = 128, *, sweeps: int = 10, rounds: int = 5, threads: int = 1) -> list[dict]:
    """Constraint projections per second of each type in the stepper (one sub-step of `sweeps`
    Gauss-Seidel iterations, so predict and commit are under 1 % of the time), coloured and
    sequential, against the plain sequential C++ loop over the same distance constraints
    (benchmark_plain_distance) timed in the same run."""
    rows = []
    models = {
        "distance": cloth_simulation(n, iterations=sweeps, constraints="stretch").model,
        "bending": cloth_simulation(n, iterations=sweeps, constraints="bending").model,
        "volume": _tet_simulation(max(4, n // 6), iterations=sweeps),
        "attachment": _attachment_model(n * n),
    }
    for kind, model in models.items():
        for ordering in ("coloured", "sequential"):
            stepper = _core.PbdStepper(dt=1 / 60, iterations=sweeps, gravity=(0, -9.81, 0), ordering=ordering,
                                       threads=threads)
            state = model.initial_state()
            times = time_steps(stepper, model, state, steps=3, rounds=rounds, warmup=2)
            ms = statistics.median(times)
            per_step = stepper.projections_per_step(model)
            rows.append(dict(kind=kind, ordering=ordering, threads=stepper.threads_used, constraints=model.num_constraints,
                             mproj_s=per_step / (ms * 1e-3) / 1e6, ns=1e6 * ms / per_step))
        if kind == "distance":
            sim = cloth_simulation(n, iterations=sweeps, constraints="stretch")
            sim.stepper.step(sim.model, sim.state, 5)
            ns = statistics.median(_core.benchmark_plain_distance(sim.model, sim.state.x, sweeps, rounds))
            rows.append(dict(kind="distance", ordering="plain loop", threads=1, constraints=sim.model.num_constraints,
                             mproj_s=1e3 / ns, ns=ns))
    return rows


def format_projection_rates(rows: Sequence[dict]) -> str:
    plain = next(r for r in rows if r["ordering"] == "plain loop")
    head = f"{'type':>10} {'ordering':>11} {'threads':>7} {'constraints':>11} {'Mproj/s':>8} {'ns/proj':>8} {'vs plain loop':>13}"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['kind']:>10} {r['ordering']:>11} {r['threads']:>7} {r['constraints']:>11} {r['mproj_s']:>8.1f} "
                     f"{r['ns']:>8.2f} {r['mproj_s'] / plain['mproj_s']:>13.2f}")
    return "\n".join(lines)


def _busy_loop(core: int):
    """A process that keeps one core busy (pinned to it) until killed."""
    import os
    import subprocess
    import sys

    return subprocess.Popen([sys.executable, "-c", "while True: pass"],
                            preexec_fn=(lambda: os.sched_setaffinity(0, {core})) if hasattr(os, "sched_setaffinity") else None)


def thread_scaling(n: int = 128, *, substeps: int = 10, iterations: int = 1, rounds: int = 5, busy: bool = False,
                   wait: str = "adaptive") -> dict:
    """ms per frame of the n x n cloth with 1, 2 and automatic threads, measured in one run
    (interleaved rounds, so that the machine's load affects all alike), optionally with another
    process keeping core 1 busy; in a fresh interpreter. wait: how the team's threads wait at a
    barrier (CSB_WAIT): 'adaptive' (csb's default: spin briefly while every thread has a free
    core, else sleep at once), 'spin' or 'sleep'."""
    import json
    import os
    import subprocess
    import sys

    code = (
        "import json, statistics, time, sys\n"
        "from csb.bench import cloth_simulation, make_stepper\n"
        f"n, sub, it, rounds = {n}, {substeps}, {iterations}, {rounds}\n"
        "frames = max(2, 20 * 128 * 128 // (n * n))\n"
        "runs = {}\n"
        "for t in (1, 2, 0):\n"
        "    sim = cloth_simulation(n, iterations=it, substeps=sub)\n"
        "    st = make_stepper(sim, substeps=sub, iterations=it, threads=t)\n"
        "    st.step(sim.model, sim.state, 2)\n"
        "    runs[t] = [sim, st, []]\n"
        "for _ in range(rounds):\n"
        "    for t, (sim, st, times) in runs.items():\n"
        "        t0 = time.perf_counter(); st.step(sim.model, sim.state, frames)\n"
        "        times.append((time.perf_counter() - t0) / frames * 1e3)\n"
        "print(json.dumps({str(t): [statistics.median(v[2]), v[1].threads_used] for t, v in runs.items()}))\n"
    )
    env = dict(os.environ)
    env.pop("CSB_WAIT", None)
    if wait != "adaptive":
        env["CSB_WAIT"] = wait
    busy_proc = _busy_loop(1) if busy else None
    try:
        time.sleep(0.2 if busy else 0)
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    finally:
        if busy_proc:
            busy_proc.kill()
            busy_proc.wait()
    res = json.loads(r.stdout.strip().splitlines()[-1])
    with open("/proc/loadavg") if os.path.exists("/proc/loadavg") else open(os.devnull) as f:
        load = f.read().split()[:1]
    return dict(n=n, substeps=substeps, iterations=iterations, busy=busy,
                wait=wait,
                ms1=res["1"][0], ms2=res["2"][0], ms_auto=res["0"][0], auto_threads=res["0"][1],
                load=float(load[0]) if load else float("nan"))


def format_thread_scaling(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'sub x it':>8} {'busy core':>9} {'waiting':>9} {'1 thread':>9} {'2 threads':>9} "
            f"{'2 vs 1':>7} {'auto':>9} {'(threads)':>9} {'load':>5}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['substeps']:>3} x {r['iterations']:<2} {'yes' if r['busy'] else 'no':>9} "
                     f"{r['wait']:>9} {r['ms1']:>9.2f} {r['ms2']:>9.2f} {r['ms2'] / r['ms1']:>7.2f} "
                     f"{r['ms_auto']:>9.2f} {r['auto_threads']:>9} {r['load']:>5.2f}")
    return "\n".join(lines)


def memory_report(model, stepper: _core.PbdStepper) -> dict:
    """Bytes of the Model (its arrays' capacities) and of the stepper's per-model workspace (step
    the stepper once on the model first), per particle and per constraint."""
    mem = model.memory
    ws = stepper.workspace_bytes
    n, c = model.num_particles, model.num_constraints
    return dict(particles=n, constraints=c, model_bytes=mem["total"], workspace_bytes=ws,
                bytes_per_particle=(mem["total"] + ws) / n,
                model_per_particle=mem["particles"] / n,
                model_per_constraint=(mem["total"] - mem["particles"]) / max(c, 1),
                total_per_constraint=(mem["total"] + ws) / max(c, 1))


def memory_table(sizes: Sequence[int] = (64, 256)) -> list[dict]:
    rows = []
    for n in sizes:
        for method in ("pbd", "xpbd"):
            sim = cloth_simulation(n, iterations=1, substeps=1)
            stepper = make_stepper(sim, substeps=1, iterations=1, method=method)
            stepper.step(sim.model, sim.state)
            rows.append(dict(n=n, method=method, **memory_report(sim.model, stepper)))
    return rows


def format_memory(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'method':>6} {'particles':>9} {'constraints':>11} {'model MB':>9} {'stepper MB':>10} "
            f"{'B/particle':>10} {'model B/constraint':>18} {'all B/constraint':>16}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['method']:>6} {r['particles']:>9} {r['constraints']:>11} "
                     f"{r['model_bytes'] / 2**20:>9.1f} {r['workspace_bytes'] / 2**20:>10.1f} "
                     f"{r['bytes_per_particle']:>10.0f} {r['model_per_constraint']:>18.1f} {r['total_per_constraint']:>16.1f}")
    return "\n".join(lines)


def particle_scaling(sizes: Sequence[int] = (32, 64, 128, 256, 512, 1024), *, substeps: int = 1,
                     iterations: int = 10, threads: int = 1, rounds: int = 3) -> list[dict]:
    """Cost per particle per step from 1k to 1M particles (cloth_grid, stretch + shear + bending)."""
    rows = []
    for n in sizes:
        sim = cloth_simulation(n, iterations=iterations, substeps=substeps)
        stepper = make_stepper(sim, substeps=substeps, iterations=iterations, threads=threads)
        steps = max(1, int(2e6 / (n * n * iterations * substeps)))
        times = time_steps(stepper, sim.model, sim.state, steps=steps, rounds=rounds, warmup=1)
        ms = statistics.median(times)
        rows.append(dict(n=n, particles=n * n, constraints=sim.model.num_constraints, threads=stepper.threads_used,
                         ms=ms, ns_per_particle=1e6 * ms / (n * n),
                         ns_per_projection=1e6 * ms / stepper.projections_per_step(sim.model)))
    return rows


def format_particle_scaling(rows: Sequence[dict]) -> str:
    base = rows[0]["ns_per_particle"]
    head = f"{'cloth':>11} {'particles':>9} {'constraints':>11} {'threads':>7} {'ms/step':>9} {'ns/particle':>11} {'ns/proj':>8} {'vs first':>8}"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>5}x{r['n']:<5} {r['particles']:>9} {r['constraints']:>11} {r['threads']:>7} {r['ms']:>9.2f} "
                     f"{r['ns_per_particle']:>11.1f} {r['ns_per_projection']:>8.2f} {r['ns_per_particle'] / base:>8.2f}")
    return "\n".join(lines)


def big_cloth(n: int = 1024, *, substeps: int = 1, iterations: int = 10, steps: int = 3, threads: int = 0) -> dict:
    """Builds and steps an n x n cloth_grid in a fresh interpreter: build time, ms per step, peak
    resident memory (VmHWM of /proc/self/status), and the memory report."""
    import json
    import subprocess
    import sys

    # VmHWM, not getrusage: ru_maxrss keeps the parent's peak across fork and exec.
    code = (
        "import json, statistics, time\n"
        "from csb.bench import cloth_simulation, make_stepper, memory_report, time_steps\n"
        "def hwm():\n"
        "    return next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM'))\n"
        "r0 = hwm()\n"
        f"t0 = time.perf_counter(); sim = cloth_simulation({n}, iterations={iterations}, substeps={substeps})\n"
        "build = time.perf_counter() - t0\n"
        "r1 = hwm()\n"
        f"st = make_stepper(sim, substeps={substeps}, iterations={iterations}, threads={threads})\n"
        f"times = time_steps(st, sim.model, sim.state, steps=1, rounds={steps}, warmup=1)\n"
        "r2 = hwm()\n"
        "print(json.dumps(dict(build_s=build, ms=statistics.median(times), threads=st.threads_used, rss_start_mb=r0 / 1024,"
        " rss_built_mb=r1 / 1024, rss_peak_mb=r2 / 1024, **memory_report(sim.model, st))))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return dict(n=n, substeps=substeps, iterations=iterations, **json.loads(r.stdout.strip().splitlines()[-1]))


def format_big_cloth(r: dict) -> str:
    return (f"{r['n']}x{r['n']} cloth: {r['particles']} particles, {r['constraints']} constraints; build "
            f"{r['build_s']:.1f} s; {r['substeps']} x {r['iterations']}: {r['ms']:.0f} ms per step on {r['threads']} "
            f"thread(s); peak RSS {r['rss_peak_mb']:.0f} MB (interpreter and numpy alone {r['rss_start_mb']:.0f} MB, "
            f"after the build {r['rss_built_mb']:.0f} MB); reported: model {r['model_bytes'] / 2**20:.0f} MB + stepper "
            f"{r['workspace_bytes'] / 2**20:.0f} MB = {r['bytes_per_particle']:.0f} B per particle, "
            f"{r['total_per_constraint']:.1f} B per constraint")


def klu_scaling(sizes: Sequence[int] = (16, 32, 64), *, duration: float = 0.02, repeats: int = 5) -> list[dict]:
    """The reference integrator (CVODE BDF + KLU with the analytic sparse Jacobian) on cloth_grid
    with compliant stretch and shear edges (no bending: the KLU path needs the analytic Jacobian):
    ms per Jacobian assembly (the values into the fixed CSC pattern), and a run over `duration` s
    of simulated time: wall time per simulated second, steps, Jacobian evaluations."""
    from ..reference import integrate_reference

    rows = []
    for n in sizes:
        b = ModelBuilder()
        inst = b.add_mesh(_core.cloth_grid(1.0, 1.0, n, n), mass=0.1, stretch_stiffness=1.0, stretch_compliance=1e-3)
        b.pin(inst.first_particle)
        b.pin(inst.first_particle + n - 1)
        model = b.build()
        state = model.initial_state()
        net = _core.SpringNetwork(model, state)
        jac = statistics.median(_core.benchmark_jacobian(net, state, repeats))
        t0 = time.perf_counter()
        res = integrate_reference(model, state, [duration], rtol=1e-8, atol=1e-10, linear_solver="klu")
        wall = time.perf_counter() - t0
        rows.append(dict(n=n, particles=n * n, unknowns=net.size, nnz=len(net.jacobian(net.pack(state))[1]),
                         jacobian_ms=jac, wall_s=wall, per_simulated_s=wall / duration, steps=res.stats["steps"],
                         jacobian_evals=res.stats["jacobian_evals"], ms_per_step=1e3 * wall / max(res.stats["steps"], 1)))
    return rows


def format_klu(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'unknowns':>8} {'nnz(J)':>9} {'ms/Jacobian':>11} {'ns/nnz':>7} {'wall s/sim s':>12} "
            f"{'steps':>6} {'J evals':>7} {'ms/step':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['unknowns']:>8} {r['nnz']:>9} {r['jacobian_ms']:>11.3f} "
                     f"{1e6 * r['jacobian_ms'] / r['nnz']:>7.1f} {r['per_simulated_s']:>12.1f} {r['steps']:>6} "
                     f"{r['jacobian_evals']:>7} {r['ms_per_step']:>8.2f}")
    return "\n".join(lines)


def cost_tables(parts: Sequence[str] = COST_PARTS, *, rounds: int = 5,
                self_collision_sizes: Sequence[int] | None = None) -> dict:
    """Prints the cost tables (`COST_PARTS`) that `parts` names: time per frame, per projection and
    per particle of the coloured sweep, its memory, and the reference's cost; returns their rows."""
    import os

    info = _core.build_info()
    out: dict = {}
    print(f"\ncsb {info['csb']} benchmarks of the coloured sweep ({info['compiler']}, {info['simd']} build, "
          f"blocked kernels {_core.kernels.kernel_isa()}, "
          f"{os.cpu_count()} cores, CSB_WAIT={os.environ.get('CSB_WAIT', 'adaptive')}); medians of {rounds} rounds")
    if "fps" in parts:
        print("\ncloth_grid (stretch + shear + bending, 2 pinned corners), dt = 1/60 s: ms per frame and frames per second")
        out["fps"] = fps_table(rounds=rounds)
        print(format_fps(out["fps"]))
    if "xpbd" in parts:
        print("\nXPBD against PBD at equal work: cloth_grid (stretch + shear + bending, 2 pinned corners), dt = 1/60 s, "
              "the same constraints, sub-steps and iterations, two threads; the two take turns within each round")
        out["xpbd"] = xpbd_table(rounds=rounds)
        print(format_xpbd_table(out["xpbd"]))
    if "precision" in parts:
        print("\nDouble against single precision (PbdStepper(precision='float32')): cloth_grid (stretch + shear + "
              "bending, 2 pinned corners), dt = 1/60 s, PBD and XPBD each in float64 and float32, two threads, the "
              "four taking turns within each round")
        out["precision"] = precision_table(rounds=rounds)
        print(format_precision_table(out["precision"]))
        print("\nThe distance and bending kernels in each precision: 128 x 128 and 256 x 256 cloths of one constraint "
              "type, one sub-step of 10 coloured Gauss-Seidel sweeps, one thread, float64 and float32 taking turns")
        out["precision-kernels"] = precision_rates(rounds=rounds)
        print(format_precision_rates(out["precision-kernels"]))
    if "types" in parts:
        print("\nProjections per second by constraint type (1 sub-step x 10 Gauss-Seidel sweeps, 128x128 cloth, "
              "a 21^3 x 6 tet box, 16k attachments; one thread) against a plain sequential C++ loop over the "
              "distance constraints")
        out["types"] = projection_rates(rounds=rounds)
        print(format_projection_rates(out["types"]))
    if "threads" in parts or "busy" in parts:
        print("\nThreads: ms per frame of the 128x128 cloth at 10 x 1, with 1, 2 and automatic threads in one run "
              "(interleaved rounds); 'busy core': another process spins on core 1 meanwhile")
        rows = []
        if "threads" in parts:
            rows.append(thread_scaling(rounds=rounds))
            rows.append(thread_scaling(rounds=rounds, wait="sleep"))
        if "busy" in parts:
            rows.append(thread_scaling(rounds=rounds, busy=True))
            rows.append(thread_scaling(rounds=rounds, busy=True, wait="spin"))
        out["threads"] = rows
        print(format_thread_scaling(rows))
    if "particles" in parts:
        print("\nCost per particle from 1k to 1M particles (cloth_grid, 1 sub-step x 10 iterations, one thread)")
        out["particles"] = particle_scaling(rounds=3)
        print(format_particle_scaling(out["particles"]))
    if "memory" in parts:
        print("\nMemory (vector capacities): Model and the stepper's per-model workspace")
        out["memory"] = memory_table()
        print(format_memory(out["memory"]))
    if "big" in parts:
        print("\nA 1024x1024 cloth (about a million particles), built and stepped in a fresh interpreter")
        out["big"] = big_cloth()
        print(format_big_cloth(out["big"]))
    if "methods" in parts:
        print("\nEvery method on one compliant cloth (cloth_grid's n x n, 1 m, 0.2 kg/m², stretch 1e-4 m/N, bending "
              "1000 1/(N m), 2 pinned corners), dt = 1/60 s, one thread: ms per step at 10 iterations, and at the "
              f"fewest iterations (of {_LADDER[0]}, {_LADDER[1]}, {_LADDER[2]}, ... {_LADDER[-1]}) whose step's "
              f"backward-Euler residual is within {EQUAL_ERROR:g} of the step's force scale, from the same moving "
              "state (implicit Euler: Newton iterations of at most 100 PCG iterations; PBD reads stiffness 1, and has no "
              "residual of this material)")
        out["methods"] = method_table(rounds=rounds)
        print(format_method_table(out["methods"]))
    if "self-collision" in parts:
        print("\nSelf-collision's cost: a 40 x 40 cape (1,600 particles, 1 m, 0.2 kg/m², stretch 1e-6 m/N, bending 10 "
              "1/(N m)) held along one edge, falling and swinging from horizontal, XPBD, dt = 1/60 s, one thread: ms per "
              "step with self-collision (thickness 6 mm: the patches that cannot meet themselves certified, proximity "
              "contacts and continuous point-triangle and edge-edge tests elsewhere, fail-safe) and without, the two "
              "taking turns within each round, over frames 30-90")
        out["self-collision"] = self_collision_table(rounds=rounds)
        print(format_self_collision_table(out["self-collision"]))
        sizes = SELF_COLLISION_SIZES if self_collision_sizes is None else self_collision_sizes
        print("\nSelf-collision's cost against the number of particles: the same cape at n x n (1 m, 0.2 kg/m², the "
              "same material; thickness 6 mm, or half the triangles' smallest rest altitude when that is less), "
              "10 sub-steps x 1 iteration, one thread, with self-collision and without taking turns within each "
              "round; ms per step is each run's mean over frames 30-90 (the folds' steps included), the median of "
              "the rounds; 'median-step ratio' compares the runs' median steps; pairs: candidate pairs kept after "
              "a step")
        out["self-collision-sizes"] = self_collision_scaling(sizes, rounds=rounds)
        print(format_self_collision_scaling(out["self-collision-sizes"]))
    if "klu" in parts:
        print("\nReference integrator (CVODE BDF + KLU, analytic sparse Jacobian) against problem size: compliant "
              "stretch and shear (1e-3 m/N), 0.02 s simulated")
        out["klu"] = klu_scaling()
        print(format_klu(out["klu"]))
    return out


def frame_times(n: int = 64, sizes: tuple[tuple[int, int], ...] = ((640, 480), (1280, 720)), *, frames: int = 60,
                warmup: int = 10, samples: int = 4, offscreen: bool = True) -> list[dict[str, Any]]:
    """Wall time per frame of the viewer, offscreen, on the bundled cloth_grid scene at n x n
    particles (its solver: dt = 1/60 s, 1 sub-step x 10 iterations, one step per frame), with the
    overlay on. Per image size: the median ms of a whole frame (step, normals, upload, draw, read
    back), of a frame drawn while paused (everything but the step), and their difference, the
    step. offscreen=False times a window instead (vsync off; needs a display). A figure for the
    record: with Mesa's software renderer it measures the CPU."""
    from ..view import open_viewer

    rows = []
    for width, height in sizes:
        sim = cloth_simulation(n)
        extra = {} if offscreen else {"vsync": False}
        with open_viewer(sim, offscreen=offscreen, width=width, height=height, overlay=True, samples=samples,
                         **extra) as v:
            def timed(paused: bool) -> float:
                v.paused = paused
                t0 = time.perf_counter()
                v.frame()
                v.screenshot()  # waits for the renderer to finish
                return 1e3 * (time.perf_counter() - t0)

            for _ in range(warmup):
                timed(False)
            # Whole and paused frames alternate, so that both see the same load on a shared machine.
            whole, drawn = [], []
            for _ in range(frames):
                whole.append(timed(False))
                drawn.append(timed(True))
        w, d = statistics.median(whole), statistics.median(drawn)
        rows.append({"n": n, "particles": n * n, "triangles": len(sim.model.triangles), "width": width,
                     "height": height, "frame_ms": w, "draw_ms": d, "step_ms": w - d, "fps": 1e3 / w})
    return rows


def format_frame_times(rows: list[dict[str, Any]]) -> str:
    head = (f"{'cloth':>9} {'triangles':>9} {'image':>10} {'frame ms':>9} {'fps':>6} {'draw+read ms':>13} "
            f"{'step ms':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['triangles']:>9} {r['width']:>4}x{r['height']:<5} "
                     f"{r['frame_ms']:>9.2f} {r['fps']:>6.1f} {r['draw_ms']:>13.2f} {r['step_ms']:>8.2f}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------
# Every method at equal iterations and at equal error

# The methods of the table: (label, registered name, its own settings).
METHOD_ROWS = (("PBD", "pbd", {}), ("XPBD", "xpbd", {}), ("VBD", "vbd", {}),
               ("Projective Dynamics", "projective-dynamics", {}),
               ("PD + Chebyshev", "projective-dynamics", {"chebyshev": True}),
               ("implicit Euler (Newton-PCG)", "implicit-euler", {}))
# Iteration counts tried for the equal-error column, about 1.4x apart, and the error all must
# reach: the largest backward-Euler residual component over the step's force scale (the largest
# of m|g|, the constraint forces and the inertia; csb.backward_euler_residual).
_LADDER = (1, 2, 3, 4, 5, 7, 10, 14, 20, 28, 40, 56, 80, 113, 160, 226, 320, 452, 640)
EQUAL_ERROR = 1e-2


def compliant_cloth(n: int) -> _core.Model:
    """cloth_grid's cloth at n x n with a compliant stretch (1e-4 m/N) that every method reads."""
    b = ModelBuilder()
    inst = b.add_mesh(_core.cloth_grid(1.0, 1.0, n, n), density=0.2, stretch_stiffness=1.0, stretch_compliance=1e-4,
                      bending_stiffness=0.1, bending_compliance=1000.0)
    b.pin(inst.nearest([-0.5, 0.0, -0.5]))
    b.pin(inst.nearest([0.5, 0.0, -0.5]))
    return b.build()


def method_table(sizes: Sequence[int] = (32, 64), *, rounds: int = 5, steps: int = 5) -> list[dict]:
    """Per cloth size and method: ms per step at 10 iterations, the backward-Euler residual of one
    step from a moving state (the cloth after 30 steps of XPBD from rest) over the step's force
    scale, and the fewest iterations of _LADDER whose step's is within EQUAL_ERROR, with its ms
    per step (None: not within 640). Median of `rounds` rounds of `steps` steps each, the methods
    taking turns within a round."""
    from ..studies import copy_state
    from ..studies.study.cells import one_thread_integrator

    rows = []
    g = (0.0, -9.81, 0.0)
    for n in sizes:
        model = compliant_cloth(n)
        moving = model.initial_state()
        _core.PbdStepper(method="xpbd", dt=1 / 60, iterations=10).step(model, moving, 30)

        def residual(name, iterations, settings):
            s = copy_state(model, moving)
            one_thread_integrator(name, 1 / 60, iterations=iterations, settings=settings).step(model, s)
            r = _core.backward_euler_residual(model, moving, s, 1 / 60, g)
            return r.max / r.scale

        target = EQUAL_ERROR
        plan = []
        for label, name, settings in METHOD_ROWS:
            at_ten = residual(name, 10, settings) if label != "PBD" else float("nan")
            needed = None
            if label != "PBD":
                for it in _LADDER:
                    if residual(name, it, settings) <= target:
                        needed = it
                        break
            plan.append(dict(label=label, name=name, settings=settings, residual_10=at_ten, iterations_equal=needed))
        # time the two settings of every method, taking turns within each round
        steppers = {}
        for p in plan:
            for key, it in (("ten", 10), ("equal", p["iterations_equal"])):
                if it is not None:
                    stepper = one_thread_integrator(p["name"], 1 / 60, iterations=it, settings=p["settings"])
                    state = copy_state(model, moving)
                    with warnings.catch_warnings():  # PBD makes the compliant stretch rigid, as the header says
                        warnings.simplefilter("ignore", _core.MaterialWarning)
                        stepper.step(model, state, 2)
                    steppers[(p["label"], key)] = (stepper, state, [])
        for _ in range(rounds):
            for stepper, state, times in steppers.values():
                t0 = time.perf_counter()
                stepper.step(model, state, steps)
                times.append((time.perf_counter() - t0) / steps * 1e3)
        for p in plan:
            ten = steppers[(p["label"], "ten")][2]
            eq = steppers.get((p["label"], "equal"), (None, None, []))[2]
            rows.append(dict(n=n, particles=model.num_particles, method=p["label"], ms_10=statistics.median(ten),
                             spread_10=(min(ten), max(ten)), residual_10=p["residual_10"], target=target,
                             iterations_equal=p["iterations_equal"],
                             ms_equal=statistics.median(eq) if eq else float("nan"),
                             spread_equal=(min(eq), max(eq)) if eq else (float("nan"), float("nan"))))
    return rows


def cape(n: int = 40, *, self_collision: float | None = 0.006) -> _core.Model:
    """An n x n cloth of 1 m (0.2 kg/m², stretch 1e-6 m/N, bending 10 1/(N m)) held along its edge at
    z = -0.5 m, flat at the start: it falls and swings, folding as it hangs (a cape on a bar)."""
    b = ModelBuilder()
    inst = b.add_mesh(_core.cloth_grid(1.0, 1.0, n, n), density=0.2, stretch_compliance=1e-6, bending_stiffness=1.0,
                      bending_compliance=10.0)
    x = inst.vertices
    for i in np.where(np.isclose(x[:, 2], x[:, 2].min()))[0]:
        b.pin(inst.first_particle + int(i))
    if self_collision:
        b.enable_self_collision(inst.group, self_collision)
    return b.build()


def _cape_run(n: int, thickness: float | None, *, substeps: int, iterations: int, frames: int,
              first: int) -> dict:
    """One run of the n x n cape (XPBD, dt = 1/60 s, one thread) over `frames` steps: the seconds of
    each step, the candidate pairs kept after each step, the continuous contacts and the
    fail-safe's particles (self_failsafe) summed over the run, the candidate searches, and the
    continuous tests run over steps first..frames."""
    model = cape(n, self_collision=thickness)
    state = model.initial_state()
    stepper = _core.PbdStepper(method="xpbd", dt=1 / 60, substeps=substeps, iterations=iterations, threads=1)
    times, pairs, continuous, failsafe, tests_before = [], [], 0, 0, 0
    for f in range(frames):
        if f == first:
            tests_before = stepper.contacts()["self_tests"] if f else 0
        t0 = time.perf_counter()
        stepper.step(model, state)
        times.append(time.perf_counter() - t0)
        c = stepper.contacts()
        continuous += c["self_continuous"]
        failsafe += c["self_failsafe"]
        pairs.append(c["self_candidates"])
    c = stepper.contacts()
    return dict(particles=model.num_particles, times=times, pairs=pairs, continuous=continuous, failsafe=failsafe,
                searches=c["self_searches"], tests=c["self_tests"] - tests_before)


def self_collision_table(settings: Sequence[tuple[int, int]] = ((2, 5), (10, 1), (1, 10)), *, rounds: int = 5,
                         frames: int = 90, first: int = 30) -> list[dict]:
    """Per (substeps, iterations): ms per step of the cape with and without self-collision over
    frames first..frames, the two runs taking turns `rounds` times; medians and spreads of the
    per-run medians, their ratio, and with self-collision the candidate searches per step, the
    continuous contacts and the fail-safe's stops over the run."""
    rows = []
    for substeps, iterations in settings:
        runs: dict[bool, list[float]] = {True: [], False: []}
        extra = {}
        for _ in range(rounds):
            for on in (True, False):
                run = _cape_run(40, 0.006 if on else None, substeps=substeps, iterations=iterations, frames=frames,
                                first=first)
                runs[on].append(1e3 * statistics.median(run["times"][first:]))
                if on:
                    extra = dict(searches_per_step=run["searches"] / frames, continuous=run["continuous"],
                                 failsafe=run["failsafe"])
        on, off = statistics.median(runs[True]), statistics.median(runs[False])
        rows.append(dict(substeps=substeps, iterations=iterations, ms_self=on, spread_self=(min(runs[True]), max(runs[True])),
                         ms_none=off, spread_none=(min(runs[False]), max(runs[False])), ratio=on / off, **extra))
    return rows


# The cape sizes (particles per side) of the self-collision sweep; 113 and 160 are optional
# (--self-collision-sizes): their runs take minutes.
SELF_COLLISION_SIZES = (20, 28, 40, 56, 80)


def cape_thickness(n: int) -> float:
    """The self-collision thickness of the n x n cape in the size sweep: the table's 6 mm, or half
    the smallest rest altitude of its triangles (edge / sqrt(2), the edge 1 m / (n - 1)) when that
    is less (n >= 60). A thickness above the altitude puts a particle within the contact distance
    of its own flat neighbourhood (the stepper warns of it); 6 mm at 160 x 160 (altitude 4.4 mm)
    diverges within 15 steps, and so does 6 mm at 113 x 113, 0.95 of its altitude."""
    return min(0.006, 0.5 / ((n - 1) * np.sqrt(2.0)))


def _slope(x: Sequence[float], y: Sequence[float]) -> float:
    """The least-squares slope of log y against log x over the points with y > 0 (nan if fewer than two)."""
    pts = [(a, b) for a, b in zip(x, y) if a > 0 and b > 0 and np.isfinite(b)]
    if len({a for a, _ in pts}) < 2:
        return float("nan")
    return float(np.polyfit(np.log([a for a, _ in pts]), np.log([b for _, b in pts]), 1)[0])


def self_collision_scaling(sizes: Sequence[int] = SELF_COLLISION_SIZES, *, substeps: int = 10, iterations: int = 1,
                           rounds: int = 5, frames: int = 90, first: int = 30) -> dict:
    """Self-collision's cost against the number of particles: the cape (1 m, 0.2 kg/m², the
    same material) at n x n for each n of `sizes`, thickness `cape_thickness(n)`, with and without
    self-collision, the two taking turns within each round (which goes first alternates between
    rounds). Per run: ms per step as the mean over frames first..frames (what the run cost; the
    folds' steps are a few of them and cost the most) and as their median (a typical step). Per
    size (medians over rounds): both, their ratios, the extra cost per particle per step (ns), the
    candidate searches per step, the frames of first..frames that kept candidate pairs, the pairs
    kept after a step per particle (mean and largest), the continuous tests per step and the
    continuous contacts and the fail-safe's particles over the run. Returns the rows and the
    least-squares slopes of log cost against log particles: without self-collision, of the extra
    cost (mean) and of the extra cost of a typical step (median)."""
    rows = []
    for n in sizes:
        h = cape_thickness(n)
        mean: dict[bool, list[float]] = {True: [], False: []}
        median: dict[bool, list[float]] = {True: [], False: []}
        counts: dict = {}
        for r in range(rounds):
            for on in ((True, False) if r % 2 == 0 else (False, True)):
                run = _cape_run(n, h if on else None, substeps=substeps, iterations=iterations, frames=frames,
                                first=first)
                timed = run["times"][first:]
                mean[on].append(1e3 * statistics.fmean(timed))
                median[on].append(1e3 * statistics.median(timed))
                if on:
                    pairs = run["pairs"][first:]
                    counts = dict(particles=run["particles"], searches_per_step=run["searches"] / frames,
                                  frames_with_pairs=sum(1 for k in pairs if k > 0), timed_frames=len(pairs),
                                  pairs_per_particle=statistics.fmean(pairs) / run["particles"],
                                  max_pairs_per_particle=max(pairs) / run["particles"],
                                  tests_per_step=run["tests"] / len(pairs), continuous=run["continuous"],
                                  failsafe=run["failsafe"])
        on, off = statistics.median(mean[True]), statistics.median(mean[False])
        on_med, off_med = statistics.median(median[True]), statistics.median(median[False])
        particles = counts["particles"]
        rows.append(dict(n=n, thickness=h, ms_none=off, spread_none=(min(mean[False]), max(mean[False])),
                         ms_self=on, spread_self=(min(mean[True]), max(mean[True])), ratio=on / off,
                         median_ms_none=off_med, median_ms_self=on_med, median_ratio=on_med / off_med,
                         extra_ns_per_particle=1e6 * (on - off) / particles,
                         median_extra_ns_per_particle=1e6 * (on_med - off_med) / particles, **counts))
    p = [r["particles"] for r in rows]
    return dict(substeps=substeps, iterations=iterations, rounds=rounds, frames=frames, first=first, rows=rows,
                slope_none=_slope(p, [r["ms_none"] for r in rows]),
                slope_extra=_slope(p, [r["ms_self"] - r["ms_none"] for r in rows]),
                slope_median_extra=_slope(p, [r["median_ms_self"] - r["median_ms_none"] for r in rows]))


def format_self_collision_scaling(result: dict) -> str:
    rows = result["rows"]
    head = (f"{'cape':>9} {'particles':>9} {'h mm':>5} {'ms/step none':>12} {'(min-max)':>15} {'ms/step self':>12} "
            f"{'(min-max)':>17} {'ratio':>6} {'extra ns/particle':>17} {'median-step ratio':>17} "
            f"{'searches/step':>13} {'frames w/ pairs':>15} {'pairs/particle':>14} {'(largest)':>9} "
            f"{'tests/step':>10} {'continuous':>10} {'fail-safe':>9}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['particles']:>9} {1e3 * r['thickness']:>5.2f} {r['ms_none']:>12.2f} "
                     f"{'(%.2f-%.2f)' % r['spread_none']:>15} {r['ms_self']:>12.2f} "
                     f"{'(%.2f-%.2f)' % r['spread_self']:>17} {r['ratio']:>6.2f} {r['extra_ns_per_particle']:>17.0f} "
                     f"{r['median_ratio']:>17.2f} {r['searches_per_step']:>13.2f} "
                     f"{str(r['frames_with_pairs']) + ' of ' + str(r['timed_frames']):>15} "
                     f"{r['pairs_per_particle']:>14.2f} {r['max_pairs_per_particle']:>9.1f} {r['tests_per_step']:>10.0f} "
                     f"{r['continuous']:>10} {r['failsafe']:>9}")
    extra = [r["extra_ns_per_particle"] for r in rows]
    positive = [e for e in extra if e > 0]
    factor = max(positive) / min(positive) if len(positive) == len(extra) and positive else float("nan")
    slope = result["slope_extra"]
    linear = 0.85 <= slope <= 1.2 and factor <= 2
    lines.append(f"cost against particles, least-squares slope of log ms against log particles: without "
                 f"self-collision {result['slope_none']:.2f}; self-collision's extra cost {slope:.2f} (a typical "
                 f"step's, the medians': {result['slope_median_extra']:.2f}); extra ns per particle from "
                 f"{min(extra):.0f} to {max(extra):.0f} ({factor:.1f}x) over the sizes: "
                 + ("linear (slope within 0.85-1.2, within 2x per particle)" if linear else
                    "not linear (linear would be a slope within 0.85-1.2 and within 2x per particle)"))
    return "\n".join(lines)


def format_self_collision_table(rows: Sequence[dict]) -> str:
    head = (f"{'sub-steps x its':>15} {'ms/step self':>13} {'(min-max)':>15} {'ms/step none':>13} {'(min-max)':>15} "
            f"{'ratio':>6} {'searches/step':>14} {'continuous':>11} {'fail-safe':>10}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{str(r['substeps']) + ' x ' + str(r['iterations']):>15} {r['ms_self']:>13.2f} "
                     f"{'(%.2f-%.2f)' % r['spread_self']:>15} {r['ms_none']:>13.2f} {'(%.2f-%.2f)' % r['spread_none']:>15} "
                     f"{r['ratio']:>6.2f} {r['searches_per_step']:>14.2f} {r['continuous']:>11} {r['failsafe']:>10}")
    return "\n".join(lines)


def format_method_table(rows: Sequence[dict]) -> str:
    head = (f"{'cloth':>9} {'method':>28} {'ms/step @10':>12} {'(min-max)':>15} {'residual/scale @10':>18} "
            f"{'its to ' + format(EQUAL_ERROR, 'g'):>12} {'ms/step':>9} {'(min-max)':>15}")
    lines = [head, "-" * len(head)]
    for r in rows:
        its = f"> {_LADDER[-1]}" if r["iterations_equal"] is None else str(r["iterations_equal"])
        if r["method"] == "PBD":
            its = "n/a"
        eq = "" if np.isnan(r["ms_equal"]) else f"{r['ms_equal']:.3f}"
        eqs = "" if np.isnan(r["ms_equal"]) else f"({r['spread_equal'][0]:.3f}-{r['spread_equal'][1]:.3f})"
        res = "" if np.isnan(r["residual_10"]) else f"{r['residual_10']:.3g}"
        ten = f"({r['spread_10'][0]:.3f}-{r['spread_10'][1]:.3f})"
        lines.append(f"{r['n']:>4}x{r['n']:<4} {r['method']:>28} {r['ms_10']:>12.3f} "
                     f"{ten:>15} {res:>18} {its:>12} {eq:>9} {eqs:>15}")
    return "\n".join(lines)
