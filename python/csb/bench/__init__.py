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
         front_end_sizes: Sequence[int] = (32, 128, 512)) -> dict:
    """Prints the tables named in `parts` (default: all of them)."""
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
        out.update(cost_tables(cost_parts, rounds=rounds))
    return out


# ------------------------------------------------------------------------------------------------
# Colouring, SIMD, threads, scaling, memory, the reference's cost. Functions other code can
# call (e.g. a peer comparison) return plain numbers; the format_* ones print tables.

# What the coloured sweep and the reference cost: ms per frame and frames per second of 128x128 and
# 256x256 cloths, projections per second by constraint type, one against two threads (also beside a
# busy core), cost per particle from 1k to 1M particles, memory, a 1024x1024 cloth, the reference's KLU cost.
COST_PARTS = ("fps", "xpbd", "types", "threads", "busy", "particles", "memory", "big", "klu", "methods",
              "self-collision")


def make_stepper(sim: Simulation, *, substeps: int, iterations: int, threads: int = 0, ordering: str = "coloured",
                 method: str | None = None) -> _core.PbdStepper:
    """The scene's stepper with sub-steps, iterations, threads, ordering (and method) replaced."""
    solver = dataclasses.replace(sim.scene.solver, substeps=substeps, iterations=iterations, threads=threads,
                                 ordering=ordering, **({"method": method} if method else {}))
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


def xpbd_table(sizes: Sequence[int] = (64, 128, 256), *, rounds: int = 7, threads: int = 2) -> list[dict]:
    """XPBD's cost against PBD's at equal work: the bundled cloth_grid at n x n, dt = 1/60 s, the same
    constraints, sub-steps and iterations, `threads` threads. The two steppers take turns within
    each round (the order alternating), on their own cloths, so that a slow spell of the machine
    falls on both; ms per frame, medians and min-max of the rounds."""
    rows = []
    for n in sizes:
        frames = max(2, 20 * 128 * 128 // (n * n))
        for substeps, iterations in ((10, 1), (1, 10)):
            sides = {}
            for method in ("pbd", "xpbd"):
                sim = cloth_simulation(n, iterations=iterations, substeps=substeps)
                stepper = make_stepper(sim, substeps=substeps, iterations=iterations, threads=threads, method=method)
                stepper.step(sim.model, sim.state, 2)
                sides[method] = (stepper, sim.model, sim.state, [])
            for r in range(rounds):
                for method in (("pbd", "xpbd") if r % 2 == 0 else ("xpbd", "pbd")):
                    stepper, model, state, times = sides[method]
                    times += time_steps(stepper, model, state, steps=frames, rounds=1, warmup=1)
            row = dict(n=n, substeps=substeps, iterations=iterations, threads_used=sides["xpbd"][0].threads_used)
            for method, (_, _, _, times) in sides.items():
                row[method] = statistics.median(times)
                row[method + "_spread"] = (min(times), max(times))
            row["ratio"] = row["xpbd"] / row["pbd"]
            rows.append(row)
    return rows


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


def cost_tables(parts: Sequence[str] = COST_PARTS, *, rounds: int = 5) -> dict:
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
                model = cape(self_collision=0.006 if on else None)
                state = model.initial_state()
                stepper = _core.PbdStepper(method="xpbd", dt=1 / 60, substeps=substeps, iterations=iterations, threads=1)
                times, continuous, failsafe = [], 0, 0
                for f in range(frames):
                    t0 = time.perf_counter()
                    stepper.step(model, state)
                    times.append(time.perf_counter() - t0)
                    c = stepper.contacts()
                    continuous += c["self_continuous"]
                    failsafe += c["self_failsafe"]
                runs[on].append(1e3 * statistics.median(times[first:]))
                if on:
                    extra = dict(searches_per_step=stepper.contacts()["self_searches"] / frames,
                                 continuous=continuous, failsafe=failsafe)
        on, off = statistics.median(runs[True]), statistics.median(runs[False])
        rows.append(dict(substeps=substeps, iterations=iterations, ms_self=on, spread_self=(min(runs[True]), max(runs[True])),
                         ms_none=off, spread_none=(min(runs[False]), max(runs[False])), ratio=on / off, **extra))
    return rows


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
