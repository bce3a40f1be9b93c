"""csb against its peers: the same square cloth in csb, Bender's PositionBasedDynamics
(``pypbd``), NVIDIA's Newton XPBD solver on the CPU and Jolt Physics' soft bodies, in one run,
and MuJoCo's flex springs, a different method, beside them.

The cloth is the bundled scene ``cloth_grid`` at N x N particles (1 m x 1 m in the xz plane, two
pinned corners, density 0.2 kg/m², gravity -9.81 m/s² along y, dt = 1/60 s per frame): a
distance constraint on every unique triangle edge (structural and diagonal shear) and a dihedral
bending constraint on every interior edge. The peers are built from csb's own arrays (positions,
triangles, masses, pins, the distance pairs and the bending quadruples), so every side has the
same particles and constraints; the counts in the table are read back from each peer's objects.

Each side runs in its own process (``python -m csb.bench.peers --serve SIDE ...``), so that
OMP_NUM_THREADS reaches pypbd's OpenMP runtime before it starts and Warp's kernel cache can be
a fresh directory. For each cloth and case the driver builds every side, each in a fresh
process, one after the other, and then lets them take turns: PASSES passes, in each of which
every side times one turn while the others wait, SETTLE_S seconds apart (so that one side's
spinning threads are asleep before the next side starts). A slow spell of the shared machine,
which lasts a second or more, then falls on every side's rounds alike instead of on the one
side that happened to be timed during it. A missing peer is reported and skipped. The peers are
the optional ``bench`` extra (``pip install csb[bench]``), never a core dependency.

Jolt is not a Python package: its side drives ``jolt_cloth`` (src/bench/jolt, built against the
user's own Jolt tree by ``scripts/jolt_cloth.py --jolt <Jolt tree> --build <dir>``; csb never
ships or downloads Jolt) in its serve mode, given by ``csb bench --peers --jolt PATH`` or the
environment variable CSB_JOLT_CLOTH. The Python process times it as it times the others; each
``frames K`` is one line to the program and one back. A Jolt iteration is a whole XPBD sub-step,
so Jolt runs the 10 x 1 case only and is skipped, with that reason, at 1 x 10. Jolt runs with 1
and with 2 threads (PhysicsSystem::Update and its job system), as pypbd runs with both.

MuJoCo's flex (``mujoco``, :class:`MujocoSide`) is a different method: force-based springs
stepped by MuJoCo's semi-implicit Euler, not PBD. It is the study adapter's mapping of the same
arrays, csb's hard edges as springs of MUJOCO_EDGE_STIFFNESS, with as many sub-steps a frame as
its stability needs (hundreds), so its figure is what a stable frame of the same cloth costs
MuJoCo, not equal work with csb. It runs on one thread, in the rows of one iteration only, and
says after its timed run whether it stayed stable (finite, largest edge strain below 10 %).

Timing: every turn begins with ``warmup`` untimed frames (the side sat idle while the others
had their turns); then each round starts again from the cloth at rest and times the same first
``frames`` frames of the motion on every side (so no side is timed on a cloth that has drifted
into a different state). A turn is at least ceil(rounds / PASSES) rounds and min_time / PASSES
seconds of timed frames, so a side ends with at least max(rounds, PASSES) rounds and
``min_time`` seconds. The figure is the median over all of a side's rounds, in ms
per frame. After the last turn each side's cloth is checked: finite, pins where they were,
fallen under gravity no faster than free fall, mean edge strain below 10 % (the largest strain
is printed).

What each side projects, and the parameter mapping, is in ``papers/benchmarks.md`` ("Against the
peers") and in :data:`MAPPING`.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import queue
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

CASES: tuple[tuple[int, int], ...] = ((10, 1), (1, 10))  # (substeps, iterations) per frame
SIZES: tuple[int, ...] = (32, 64, 128, 256)
FRAME_DT = 1.0 / 60.0
GRAVITY = 9.81

# Newton's XPBD sums the corrections of all constraints of a particle (Jacobi, no averaging) and
# cannot take compliance 0 (a spring with ke = 0 is skipped). Its springs are given
# ke_ij = 1 / (r (w_i + w_j) h²), i.e. α̃ = α/h² = r (w_i + w_j): each projection moves its two
# particles by 1/(1 + r) of the full correction, the stiffest setting whose summed Jacobi stays
# bounded on this cloth (r = 1 diverges at 32 x 32).
NEWTON_SPRING_RELAXATION = 4.0

# Timed rounds per side and row: at least `rounds`, and as many more as fill MIN_TIME seconds of
# timed frames (at most MAX_ROUNDS), so that each median rests on about a second of stepping.
MIN_TIME = 1.0
MAX_ROUNDS = 2000
# The sides of a row take turns: PASSES turns each, SETTLE_S seconds apart (module docstring).
PASSES = 10
SETTLE_S = 0.05

MAPPING = {
    "csb": "method 'pbd' (the bundled scene): stretch k = 1, bending k = 0.1, corrected per iteration "
           "to 1 - (1 - k)^(1/iterations); coloured Gauss-Seidel on the free cores (threads = 0: one or two here, "
           "printed per timed round), each bending element projecting its edge's distance constraint just "
           "before itself",
    "pypbd": "DistanceConstraint (PBD, stiffness 1) on every unique edge and DihedralConstraint (PBD) on "
             "every interior edge, from addClothConstraints(method 1) and addBendingConstraints(method 1) "
             "on the same triangles; dihedral stiffness = csb's corrected per-projection k; "
             "NUM_SUB_STEPS, MAX_ITERATIONS as the case, MAX_ITERATIONS_V = 0 (csb has no velocity pass)",
    "newton": "SolverXPBD(iterations) on device 'cpu', one solver.step per substep of dt/substeps; "
              "springs on csb's distance pairs with ke = 1/(r (w_i + w_j) h²), r = 4 (no compliance 0: "
              "see NEWTON_SPRING_RELAXATION), kd = 0; bending edges on csb's interior edges with "
              "ke = 1/(bending compliance) = 1e-3 N m, kd = 0; particle radius 0 (no particle contacts)",
    "jolt": "one soft body (XPBD) of csb's particles (inverse mass as csb's, 0 = pinned), an Edge per distance "
            "pair with csb's rest length and compliance (0: hard) and a DihedralBend per bending quadruple "
            "with csb's compliance (1e3 1/(N m)), rest angles from the flat rest state; no faces, volume, LRA "
            "or skinning constraints (checked after Optimize, every constraint unchanged); mNumIterations = "
            "substeps (each Jolt iteration is one sub-step projecting every constraint once with alpha/h²), "
            "so 10 x 1 only; linear damping 0, gravity -9.81 m/s², no sleeping, vertex radius 0; "
            "PhysicsSystem::Update(1/60 s, 1 collision step), the body alone in the system, with T - 1 "
            "job-system workers plus the calling thread",
    "mujoco": "csb.bench.adapters.mujoco_flex_model, the study adapter's mapping (a body on three "
              "slide joints per particle with csb's mass, a pin a body without joints; csb's distance pairs one 1-D "
              "flex of springs, damping 0; each bending quadruple a 2-D flex of hinge stiffness 1/α = 1e-3 N m), "
              "collision detection off, gravity -9.81 m/s², MuJoCo's semi-implicit Euler with the sub-steps a frame "
              "of its explicit stability limit (h ω̂ = 2.5), one thread",
}


# ---------------------------------------------------------------------------------------------
# The cloth, from csb


def cloth_arrays(n: int) -> dict[str, Any]:
    """csb's cloth_grid at n x n as plain arrays, the single source every side is built from."""
    from . import cloth_simulation

    sim = cloth_simulation(n)
    m = sim.model
    inv_mass = np.asarray(m.inv_mass, dtype=float)
    return dict(
        n=n,
        positions=np.asarray(m.rest_positions, dtype=float).copy(),
        triangles=np.asarray(m.triangles, dtype=np.int64).copy(),
        mass=np.asarray(m.mass, dtype=float).copy(),
        inv_mass=inv_mass.copy(),
        pinned=np.flatnonzero(inv_mass == 0),
        distance=np.asarray(m.distance["particles"], dtype=np.int64).copy(),
        rest_length=np.asarray(m.distance["rest_length"], dtype=float).copy(),
        stretch_stiffness=float(np.asarray(m.distance["stiffness"])[0]),
        stretch_compliance=float(np.asarray(m.distance["compliance"])[0]),
        # (a, b, c, d): the edge (a, b), c and d the opposite vertices of its two triangles
        bending=np.asarray(m.bending["particles"], dtype=np.int64).copy(),
        bending_stiffness=float(np.asarray(m.bending["stiffness"])[0]),
        bending_compliance=float(np.asarray(m.bending["compliance"])[0]),
    )


def corrected_stiffness(k: float, iterations: int) -> float:
    """csb's per-projection PBD stiffness (Müller 2007 §3.3), as src/csb/pbd.cpp applies it."""
    return 1.0 if k >= 1 else 1.0 - (1.0 - k) ** (1.0 / iterations)


# ---------------------------------------------------------------------------------------------
# The sides. Each builds the cloth for one (substeps, iterations) case, counts what it built
# from its own objects, steps whole frames, and resets to rest.


class CsbSide:
    name = "csb"

    def __init__(self, arrays: dict[str, Any], substeps: int, iterations: int):
        from . import cloth_simulation, make_stepper

        self.sim = cloth_simulation(arrays["n"], substeps=substeps, iterations=iterations)
        # The scene's method (PBD) in double precision, or the variant the driver asks for.
        method, precision = os.environ.get(CSB_METHOD_ENV, "pbd"), os.environ.get(CSB_PRECISION_ENV, "float64")
        self.model = self.sim.model
        self.stepper = make_stepper(self.sim, substeps=substeps, iterations=iterations, method=method,
                                    precision=precision)
        self.state = self.model.initial_state()
        m = self.model
        self.counts = dict(particles=m.num_particles, distance=len(m.distance["rest_length"]),
                           bending=len(m.bending["rest_angle"]), constraints=m.num_constraints,
                           projections_per_frame=int(self.stepper.projections_per_step(m)))
        s = self.stepper.settings
        # (not "method": that key marks a different method's row, see run_row)
        self.verified = dict(substeps=s.substeps, iterations=s.iterations, dt=s.dt, csb_method=s.method,
                             precision=s.precision)

    def reset(self) -> None:
        self.state = self.model.initial_state()

    def frames(self, k: int) -> None:
        self.stepper.step(self.model, self.state, k)

    def threads_used(self) -> int | None:
        """Threads of the last step (csb picks them per step from the free cores)."""
        return int(self.stepper.threads_used)

    def positions(self) -> np.ndarray:
        x = np.asarray(self.state.x)
        return x.T if x.shape[0] == 3 and x.shape[1] != 3 else x


class PypbdSide:
    name = "pypbd"

    def __init__(self, arrays: dict[str, Any], substeps: int, iterations: int):
        import pypbd as pbd

        self.pbd = pbd
        sim = pbd.Simulation.getCurrent()
        if sim.getModel() is not None and len(sim.getModel().getTriangleModels()):
            sim.getModel().cleanup()  # one cloth at a time in this process
        sim.initDefault()
        pbd.TimeManager.getCurrent().setTime(0.0)
        pbd.TimeManager.getCurrent().setTimeStepSize(FRAME_DT)
        model = sim.getModel()
        tri_model = model.addTriangleModel(arrays["positions"], arrays["triangles"].ravel().astype(np.uint32))
        pd = model.getParticles()
        for i, m in enumerate(arrays["mass"]):
            pd.setMass(i, 0.0 if arrays["inv_mass"][i] == 0 else float(m))
        # clothMethod 1: a PBD distance constraint per unique edge (the stiffness arguments after
        # the first belong to the FEM/strain methods and are unused here)
        model.addClothConstraints(tri_model, 1, arrays["stretch_stiffness"], 1.0, 1.0, 1.0, 0.3, 0.3, False, False)
        # bendingMethod 1: a PBD dihedral constraint per interior edge, with csb's per-projection k
        model.addBendingConstraints(tri_model, 1, corrected_stiffness(arrays["bending_stiffness"], iterations))
        ts = sim.getTimeStep()
        C = pbd.TimeStepController
        ts.setValueUInt(C.NUM_SUB_STEPS, substeps)
        ts.setValueUInt(C.MAX_ITERATIONS, iterations)
        ts.setValueUInt(C.MAX_ITERATIONS_V, 0)
        self.sim, self.model, self.pd, self.ts = sim, model, pd, ts
        self.x0 = arrays["positions"]
        kinds: dict[str, int] = {}
        for c in model.getConstraints():
            kinds[type(c).__name__] = kinds.get(type(c).__name__, 0) + 1
        n_constraints = sum(kinds.values())
        self.kinds = kinds
        self.counts = dict(particles=int(pd.size()), distance=kinds.get("DistanceConstraint", 0),
                           bending=kinds.get("DihedralConstraint", 0), constraints=n_constraints,
                           projections_per_frame=substeps * iterations * n_constraints)
        self.verified = dict(substeps=ts.getValueUInt(C.NUM_SUB_STEPS), iterations=ts.getValueUInt(C.MAX_ITERATIONS),
                             velocity_iterations=ts.getValueUInt(C.MAX_ITERATIONS_V),
                             dt=pbd.TimeManager.getCurrent().getTimeStepSize(),
                             other_constraints={k: v for k, v in kinds.items()
                                                if k not in ("DistanceConstraint", "DihedralConstraint")})

    def reset(self) -> None:
        zero = np.zeros(3)
        for i, x in enumerate(self.x0):
            self.pd.setPosition(i, x)
            self.pd.setVelocity(i, zero)
        self.pbd.TimeManager.getCurrent().setTime(0.0)

    def frames(self, k: int) -> None:
        for _ in range(k):
            self.ts.step(self.model)

    def positions(self) -> np.ndarray:
        return np.array([self.pd.getPosition(i) for i in range(self.pd.size())])

    def threads_used(self) -> int | None:
        return None  # OMP_NUM_THREADS of the run


class NewtonSide:
    name = "newton"

    def __init__(self, arrays: dict[str, Any], substeps: int, iterations: int,
                 relaxation: float = NEWTON_SPRING_RELAXATION, graph: bool | None = None):
        import newton
        import warp as wp

        self.wp = wp
        x, w = arrays["positions"], arrays["inv_mass"]
        mass = np.where(w == 0, 0.0, arrays["mass"])  # mass 0: a kinematic (pinned) particle
        d, b = arrays["distance"], arrays["bending"]
        self.h = FRAME_DT / substeps
        ke = 1.0 / (relaxation * (w[d[:, 0]] + w[d[:, 1]]) * self.h * self.h)
        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -GRAVITY, 0.0))
        builder.add_particles(x.tolist(), [(0.0, 0.0, 0.0)] * len(x), mass.tolist(), radius=[0.0] * len(x))
        t = arrays["triangles"]
        builder.add_triangles(t[:, 0].tolist(), t[:, 1].tolist(), t[:, 2].tolist())
        for (i, j), k in zip(d.tolist(), ke.tolist()):
            builder.add_spring(i, j, k, 0.0, 0.0)
        # newton's edge is (i, j, k, l): k-l the shared edge, i and j the opposite vertices
        bend_ke = 1.0 / arrays["bending_compliance"] if arrays["bending_compliance"] > 0 else 1e-3
        builder.add_edges(b[:, 2].tolist(), b[:, 3].tolist(), b[:, 0].tolist(), b[:, 1].tolist(),
                          edge_ke=[bend_ke] * len(b), edge_kd=[0.0] * len(b))
        self.model = model = builder.finalize(device="cpu")
        self.solver = newton.solvers.SolverXPBD(model, iterations=iterations)
        self.s0, self.s1 = model.state(), model.state()
        self.substeps = substeps
        self.x0 = x.astype(np.float32)
        # A frame replayed as a CPU graph (wp.ScopedCapture, as Newton's own examples do), which
        # leaves out Python's cost of launching each kernel; CSB_NEWTON_GRAPH=0 launches them.
        self.use_graph = (os.environ.get("CSB_NEWTON_GRAPH", "1") != "0") if graph is None else graph
        self.graph = None
        n_constraints = int(model.spring_count + model.edge_count)
        self.counts = dict(particles=int(model.particle_count), distance=int(model.spring_count),
                           bending=int(model.edge_count), constraints=n_constraints,
                           projections_per_frame=substeps * iterations * n_constraints)
        self.verified = dict(substeps=substeps, iterations=self.solver.iterations, dt=self.h * substeps,
                             triangles_not_projected=int(model.tri_count),
                             particle_max_radius=float(model.particle_max_radius),
                             spring_ke=(float(ke.min()), float(ke.max())), bending_ke=bend_ke,
                             device=str(model.device), graph=self.use_graph)

    def reset(self) -> None:
        for s in (self.s0, self.s1):
            s.particle_q.assign(self.x0)
            s.particle_qd.zero_()

    def _frame(self) -> None:
        start = self.s0
        for _ in range(self.substeps):
            self.solver.step(self.s0, self.s1, None, None, self.h)
            self.s0, self.s1 = self.s1, self.s0
        if self.use_graph and self.s0 is not start:  # an odd number of steps: a graph must end where it began
            self.wp.copy(start.particle_q, self.s0.particle_q)
            self.wp.copy(start.particle_qd, self.s0.particle_qd)
            self.s0, self.s1 = start, self.s0

    def frames(self, k: int) -> None:
        wp = self.wp
        if self.use_graph and self.graph is None:
            with wp.ScopedCapture(device="cpu") as capture:
                self._frame()
            self.graph = capture.graph
        for _ in range(k):
            if self.graph is not None:
                wp.capture_launch(self.graph)
            else:
                self._frame()
        wp.synchronize()

    def positions(self) -> np.ndarray:
        return self.s0.particle_q.numpy().astype(float)

    def threads_used(self) -> int | None:
        return None  # Warp's CPU kernels run on one thread


JOLT_ENV = "CSB_JOLT_CLOTH"           # the path of a built jolt_cloth
JOLT_THREADS_ENV = "CSB_JOLT_THREADS"  # the side's thread count, set by the driver per run
JOLT_BUILD_HINT = "build it with: python scripts/jolt_cloth.py --jolt <Jolt tree> --build <dir>"


def jolt_binary(path: str | None = None) -> tuple[str | None, str]:
    """The jolt_cloth to run (`path`, else $CSB_JOLT_CLOTH) and, when there is none, why not."""
    given = path or os.environ.get(JOLT_ENV)
    if not given:
        return None, f"no jolt_cloth given (--jolt PATH or {JOLT_ENV}); {JOLT_BUILD_HINT}"
    if not (os.path.isfile(given) and os.access(given, os.X_OK)):
        return None, f"jolt_cloth {given!r} is not an executable file; {JOLT_BUILD_HINT}"
    return os.path.abspath(given), ""


def jolt_case_reason(substeps: int, iterations: int) -> str | None:
    """Why Jolt cannot run a case (None: it can)."""
    if iterations != 1:
        return (f"Jolt has no {substeps} x {iterations} case: each Jolt iteration is a whole XPBD sub-step, "
                f"so it cannot project {iterations} times within one")
    return None


def write_jolt_cloth(a: dict[str, Any], path: str | os.PathLike) -> None:
    """csb's arrays as jolt_cloth reads them (little endian; the format is at the top of
    src/bench/jolt/jolt_cloth.cpp)."""
    n, e, b = len(a["positions"]), len(a["rest_length"]), len(a["bending"])
    with open(path, "wb") as f:
        f.write(b"CSBCLTH1")
        np.array([n, e, b], "<i8").tofile(f)
        np.asarray(a["positions"], "<f8").tofile(f)
        np.asarray(a["inv_mass"], "<f8").tofile(f)
        np.asarray(a["distance"], "<i8").tofile(f)
        np.asarray(a["rest_length"], "<f8").tofile(f)
        np.array([a["stretch_compliance"]], "<f8").tofile(f)
        np.asarray(a["bending"], "<i8").tofile(f)
        np.array([a["bending_compliance"]], "<f8").tofile(f)


class JoltSide:
    """Jolt's soft body, in a jolt_cloth process in its serve mode (one line in, one line out)."""

    name = "jolt"

    def __init__(self, arrays: dict[str, Any], substeps: int, iterations: int,
                 binary: str | None = None, threads: int | None = None):
        why = jolt_case_reason(substeps, iterations)
        if why:  # never 10 sub-steps in place of 1 x 10
            raise ValueError(why)
        exe, why = jolt_binary(binary)
        if exe is None:
            raise FileNotFoundError(why)
        threads = threads or int(os.environ.get(JOLT_THREADS_ENV, "1"))
        self._dir = tempfile.TemporaryDirectory(prefix="csb-jolt-")
        cloth = os.path.join(self._dir.name, "cloth.bin")
        self._x = os.path.join(self._dir.name, "x.bin")
        write_jolt_cloth(arrays, cloth)
        # stderr is this process's: jolt_cloth's own message reaches the driver's report
        self.proc = subprocess.Popen(
            [exe, cloth, "--serve", "--mode", "system", "--threads", str(threads), "--substeps", str(substeps),
             "--dt", repr(FRAME_DT)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        info = self._ask("info")
        self.info = info
        n_constraints = info["edge_constraints"] + info["bend_constraints"] + info["other_constraints"]
        self.counts = dict(particles=info["particles"], distance=info["edge_constraints"],
                           bending=info["bend_constraints"], constraints=n_constraints,
                           projections_per_frame=info["substeps_per_frame"] * info["iterations_per_substep"]
                           * n_constraints)
        self.verified = dict(substeps=info["substeps_per_frame"], iterations=info["iterations_per_substep"],
                             dt=info["dt"], threads=info["threads"], simd=info["simd"],
                             constraints_identical=info["constraints_identical"],
                             other_constraints=info["other_constraints"], linear_damping=info["linear_damping"],
                             gravity_y=info["gravity_y"])
        self.versions = dict(jolt=f"{info['jolt_version']} ({info['simd']})")
        if not info["constraints_identical"] or info["other_constraints"]:
            raise RuntimeError(f"jolt_cloth did not build csb's constraints unchanged: {info}")

    def _ask(self, line: str) -> dict[str, Any]:
        try:
            self.proc.stdin.write(line + "\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            pass  # it has ended: said below
        answer = self.proc.stdout.readline()
        if not answer:
            raise RuntimeError(f"jolt_cloth ended (exit {self.proc.wait()}) on {line.split()[0]!r}")
        out = json.loads(answer)
        if "error" in out:
            raise RuntimeError(f"jolt_cloth: {out['error']} ({line!r})")
        return out

    def reset(self) -> None:
        self._ask("reset")

    def frames(self, k: int) -> None:
        self._ask(f"frames {k}")

    def positions(self) -> np.ndarray:
        self._ask(f"positions {self._x}")
        return np.fromfile(self._x, "<f8").reshape(-1, 3)

    def threads_used(self) -> int | None:
        return None  # the run's thread count, in its label

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self._ask("quit")
                self.proc.wait(timeout=10)  # it answers, then tears Jolt down
            except (RuntimeError, OSError, ValueError, subprocess.TimeoutExpired):
                pass
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()
            except OSError:
                pass
        self._dir.cleanup()


# MuJoCo's flex, a different method: force-based springs stepped by MuJoCo's integrator, not PBD.
# The setting and how it was found are in MujocoSide's docstring.
MUJOCO_INTEGRATOR = "Euler"
MUJOCO_EDGE_STIFFNESS = 3000.0  # N/m: the edges' stiffness when csb's distance compliance is 0 (hard)
MUJOCO_COURANT = 2.5            # h ω̂ of a MuJoCo sub-step (mujoco_substeps)
MUJOCO_STRAIN_LIMIT = 0.10      # the largest edge strain a stable run stays below
MUJOCO_METHOD = f"MuJoCo flex (springs, {MUJOCO_INTEGRATOR}), a different method"


def mujoco_edge_stiffness(arrays: dict[str, Any]) -> tuple[float, str]:
    """The flex's edge stiffness (N/m) and why: 1/α of csb's distance compliance α when α > 0,
    else (α = 0, a hard constraint, as on csb's benchmark cloth) MUJOCO_EDGE_STIFFNESS."""
    alpha = arrays["stretch_compliance"]
    if alpha > 0:
        return 1.0 / alpha, f"1/α of csb's distance compliance α = {alpha:g} m/N"
    return MUJOCO_EDGE_STIFFNESS, (f"csb's edges are hard (compliance 0) and a spring cannot be; the softest "
                                   f"stiffness tried whose largest edge strain stays below "
                                   f"{100 * MUJOCO_STRAIN_LIMIT:g} % over 120 frames at 64²")


def mujoco_substeps(arrays: dict[str, Any], stiffness: float) -> int:
    """MuJoCo sub-steps per 1/60 s frame: the fewest with h ω̂ <= MUJOCO_COURANT, h the sub-step and
    ω̂² = max_i 2 k deg_i / m_i (rad/s)² over the free particles (deg_i springs of stiffness k on a
    particle of mass m_i), Gershgorin's bound on the largest eigenvalue of M⁻¹K for springs along
    the axes and diagonals of a plane, as on csb's flat grid. Semi-implicit Euler is stable for
    h ω < 2, ω the largest true frequency; the bending hinges (1/α = 1e-3 N m, about 16 N/m a
    particle at 128²) are left out of ω̂."""
    springs = np.bincount(arrays["distance"].ravel(), minlength=len(arrays["inv_mass"]))
    omega = math.sqrt(float(np.max(2.0 * stiffness * springs * arrays["inv_mass"])))
    return max(1, math.ceil(FRAME_DT * omega / MUJOCO_COURANT))


class MujocoSide:
    """MuJoCo's flex on csb's cloth: a different method, force-based springs stepped by MuJoCo's
    semi-implicit Euler, not PBD, so its ms per frame is not equal work with csb's.

    The model is :func:`csb.bench.adapters.mujoco_flex_model`, the mapping of the study adapter
    ``MujocoFlexIntegrator``: each particle a body on three slide joints with csb's mass (a pin: a
    body without joints), csb's distance pairs one 1-D flex of springs (damping 0), each bending
    quadruple a 2-D flex of hinge stiffness 1/α = 1e-3 N m; collision detection off (the cloth
    has no contacts on any side). The counts are read back from MuJoCo's model and must equal
    csb's: the flex's vertices, its edges (csb's distance pairs) and the 2-D flexes (csb's
    bending quadruples). MuJoCo steps one model on one thread.

    The setting. csb's edges are hard (compliance 0) and a spring cannot be: the edges get
    k = MUJOCO_EDGE_STIFFNESS = 3000 N/m, one material at every size (a finite compliance α of
    csb's would give 1/α instead). It is the softest of those tried whose largest edge strain
    stays below 10 % over 120 frames (2 s) from rest at 64² (Euler, h ω̂ = 2.5, MuJoCo 4.0.0):
    k = 300, 1000 and 3000 N/m gave 34 %, 14 % and 5 % at 32², and 3000 N/m 9.4 % at 64² (at a
    pin, frame 84, the bottom of the first swing; the mean 0.18 % at frame 120). Stiffer springs
    cost more: the sub-steps grow as √k. At one k the strain at a pin grows with the size (the
    pins carry the same weight, on shorter edges), so the side reports it at every size.

    The integrator. MuJoCo 4.0 refuses 2-D flex elasticity (the hinges) under "implicit" and
    "implicitfast" ("no longer integrated implicitly") and flex edge stiffness under "discrete",
    so the springs with hinges run under "Euler" (semi-implicit, explicit in the springs) or
    "RK4" (four force evaluations a step, for a sub-step about 1.4 times as long). The sub-steps
    come from the explicit limit (:func:`mujoco_substeps`), its margin tried on this cloth at
    k = 3000 N/m, 10 frames from rest: at 32², 96 sub-steps a frame (h ω̂ = 3.23) diverged in the
    first frame and 104 (2.98) held; at 64², 191 (3.30) diverged and 210 (3.00) held.
    MUJOCO_COURANT = 2.5 is a factor 1.2 below the longest sub-step that held: 125 sub-steps a
    frame at 32², 252 at 64² (which held the 120 frames above), 509 at 128², 1021 at 256². RK4
    held at 72 sub-steps at 32² (h ω̂ = 4.31; 64 diverged) but took 2.3 times Euler's time a
    frame at 104.

    A frame is MuJoCo's own loop of mj_step calls (``mj_step(m, d, nstep)``). MuJoCo meets a
    diverging step by resetting its state after a warning: ``frames`` raises instead. After the
    timed run, :meth:`stability` says whether the cloth is finite and its largest edge strain
    below MUJOCO_STRAIN_LIMIT. The benchmark's substeps x iterations do not apply: the side runs
    its own sub-steps, in the rows of one iteration (:func:`case_reason`).
    """

    name = "mujoco"

    def __init__(self, arrays: dict[str, Any], substeps: int, iterations: int):
        from .adapters import MujocoFlexIntegrator, _require, mujoco_flex_counts, mujoco_flex_model

        _require("mujoco")
        import mujoco

        if MujocoFlexIntegrator._mujoco_major() < 4:
            raise RuntimeError(f"MuJoCo {MujocoFlexIntegrator._mujoco_version()}: the hinge mapping needs MuJoCo 4.0 "
                               f"or later (earlier versions scale a 2-D flex's bending rigidity by 3/4 (1 - ν))")
        self.mj = mujoco
        stiffness, stiffness_why = mujoco_edge_stiffness(arrays)
        self.substeps = mujoco_substeps(arrays, stiffness)
        b = arrays["bending"]
        self.model, adr = mujoco_flex_model(
            arrays["positions"], arrays["inv_mass"], arrays["mass"], arrays["distance"], stiffness, b,
            np.full(len(b), arrays["bending_compliance"]), timestep=FRAME_DT / self.substeps,
            gravity=(0.0, -GRAVITY, 0.0), integrator=MUJOCO_INTEGRATOR)
        self.data = mujoco.MjData(self.model)
        self.free = adr >= 0
        self.qpos = adr[self.free][:, None] + np.arange(3)  # each free particle's x, y, z slide joints
        self.x0 = arrays["positions"]
        read = mujoco_flex_counts(self.model)
        expected = dict(particles=len(self.x0), distance=len(arrays["distance"]), bending=len(b), other=0)
        if read != expected:
            raise RuntimeError(f"MuJoCo's flex does not hold csb's cloth: read back {read}, csb's {expected}")
        m = self.model
        # springs and hinges are passive forces: no constraint rows, no projections
        self.counts = dict(particles=read["particles"], distance=read["distance"], bending=read["bending"],
                           constraints=int(m.neq), projections_per_frame=None)
        self.verified = dict(method=MUJOCO_METHOD, mujoco_substeps=self.substeps, timestep=float(m.opt.timestep),
                             dt=float(m.opt.timestep) * self.substeps,
                             integrator=mujoco.mjtIntegrator(m.opt.integrator).name,
                             edge_stiffness=float(m.flex_edgestiffness[0]), edge_stiffness_why=stiffness_why,
                             edge_damping=float(m.flex_edgedamping[0]),
                             hinge_stiffness=1.0 / arrays["bending_compliance"], gravity_y=float(m.opt.gravity[1]),
                             contacts=not bool(m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT), threads=1)

    def reset(self) -> None:
        self.mj.mj_resetData(self.model, self.data)

    def frames(self, k: int) -> None:
        d = self.data
        self.mj.mj_step(self.model, d, nstep=k * self.substeps)
        if d.warning.number.any():  # MuJoCo reset a diverging state and went on: say so
            raise RuntimeError(f"MuJoCo's flex diverged at {self.substeps} sub-steps a frame (warnings "
                               f"{d.warning.number.tolist()}); the cloth was reset to rest, not stepped")

    def positions(self) -> np.ndarray:
        x = self.x0.copy()
        x[self.free] += self.data.qpos[self.qpos]
        return x

    def threads_used(self) -> int | None:
        return 1  # mj_step runs one model on one thread

    def stability(self, check: dict[str, Any]) -> dict[str, Any]:
        """After the timed run (`check`, :func:`check_cloth`): stable if finite with its largest edge
        strain below MUJOCO_STRAIN_LIMIT."""
        stable = bool(check["finite"] and check["max_strain"] < MUJOCO_STRAIN_LIMIT)
        return dict(stable=stable, finite=check["finite"], max_strain=check["max_strain"],
                    strain_limit=MUJOCO_STRAIN_LIMIT)


# csb's side steps the scene's method in double precision unless these say otherwise (the
# driver's csb_variants: e.g. XPBD, single precision).
CSB_METHOD_ENV, CSB_PRECISION_ENV = "CSB_PEER_METHOD", "CSB_PEER_PRECISION"
SIDE_CLASSES = {"csb": CsbSide, "pypbd": PypbdSide, "newton": NewtonSide, "jolt": JoltSide, "mujoco": MujocoSide}
PEER_MODULES = {"pypbd": "pypbd", "newton": "newton", "mujoco": "mujoco"}


def peer_available(side: str) -> bool:
    if side == "jolt":  # a program, not a module
        return jolt_binary()[0] is not None
    mod = PEER_MODULES.get(side)
    if mod is None:
        return True
    try:
        return importlib.util.find_spec(mod) is not None
    except (ImportError, ValueError):
        return False


# ---------------------------------------------------------------------------------------------
# Check and timing


def check_cloth(arrays: dict[str, Any], x: np.ndarray, frames: int) -> dict[str, Any]:
    """After `frames` frames from rest: finite, pins in place, fallen but not faster than free
    fall, mean edge strain below 10 % (not diverging)."""
    x0, pinned = arrays["positions"], arrays["pinned"]
    free = np.setdiff1d(np.arange(len(x0)), pinned)
    finite = bool(np.isfinite(x).all())
    pin_moved = float(np.abs(x[pinned] - x0[pinned]).max()) if finite else float("inf")
    drop = x0[free, 1] - x[free, 1]
    d = arrays["distance"]
    strain = np.abs(np.linalg.norm(x[d[:, 0]] - x[d[:, 1]], axis=1) / arrays["rest_length"] - 1) if finite else [np.inf]
    # semi-implicit Euler with one substep falls g h² K(K+1)/2 in K frames; substeps fall less
    free_fall = GRAVITY * FRAME_DT**2 * frames * (frames + 1) / 2
    out = dict(frames=frames, finite=finite, pin_moved=pin_moved,
               mean_drop=float(drop.mean()) if finite else float("nan"),
               max_drop=float(drop.max()) if finite else float("nan"), free_fall=free_fall,
               max_strain=float(np.max(strain)), mean_strain=float(np.mean(strain)))
    # the strain of the few edges at the pins is printed, not judged: ten projections per frame
    # cannot carry the cloth's weight to the pins at 128² and more, on any side
    out["ok"] = bool(finite and pin_moved < 1e-5 and out["mean_drop"] > 0
                     and out["max_drop"] <= free_fall * 1.05 + 1e-3 and out["mean_strain"] < 0.1)
    return out


class Turns:
    """One side in this process, taking its turns: each turn starts with `warmup` untimed frames
    (the side has been idle while the others had theirs), then times rounds that each start
    from rest and step `frames` frames."""

    def __init__(self, side: Any, frames: int, warmup: int):
        self.side, self.frames, self.warmup = side, frames, warmup

    def turn(self, min_rounds: int, seconds: float, max_rounds: int) -> dict[str, list]:
        """At least `min_rounds` rounds, more until the timed frames add up to `seconds`, at most
        `max_rounds`: ms per frame of each round, and the threads of each (csb's, else None)."""
        side = self.side
        side.reset()
        side.frames(self.warmup)
        times: list[float] = []
        threads: list[int | None] = []
        timed = 0.0
        while len(times) < max_rounds and (len(times) < min_rounds or timed < seconds):
            side.reset()
            t0 = time.perf_counter()
            side.frames(self.frames)
            dt = time.perf_counter() - t0
            timed += dt
            times.append(dt / self.frames * 1e3)
            threads.append(side.threads_used())
        return dict(times=times, threads=threads)


def rounds_per_turn(rounds: int, passes: int) -> int:
    """The fewest rounds of a turn: `rounds` spread over `passes` turns, at least one."""
    return max(1, math.ceil(rounds / passes))


def alternate(sides: Sequence[Any], rounds: int, min_time: float, passes: int = PASSES,
              max_rounds: int = MAX_ROUNDS, settle: float = SETTLE_S) -> list[dict[str, Any]]:
    """Time every side of one row in `passes` passes; in each pass every side takes one turn, in
    order, with `settle` seconds between turns. A turn is at least ceil(rounds / passes) rounds
    and min_time / passes seconds of timed frames (at most ceil(max_rounds / passes) rounds), so
    each side ends with at least `rounds` rounds and `min_time` seconds, and a slow spell of the
    shared machine falls on every side's rounds alike, not on the one side timed during it.
    Returns, per side, the median ms per frame over all its rounds, min, max and the rounds."""
    per_turn = rounds_per_turn(rounds, passes)
    cap = max(per_turn, math.ceil(max_rounds / passes))
    got: list[dict[str, list]] = [dict(times=[], threads=[]) for _ in sides]
    failed: list[Exception | None] = [None] * len(sides)
    for _ in range(passes):
        for i, (side, acc) in enumerate(zip(sides, got)):
            if failed[i] is not None:
                continue
            try:
                part = side.turn(per_turn, min_time / passes, cap)
            except WorkerFailed as e:  # that side is out of the row; the others go on
                failed[i] = e
                continue
            acc["times"] += part["times"]
            acc["threads"] += part["threads"]
            if settle > 0:
                time.sleep(settle)  # the side's spinning threads (OpenMP's, csb's) go to sleep
    return [dict(failed=str(e)) if e is not None else
            dict(ms_per_frame=statistics.median(a["times"]), ms_min=min(a["times"]), ms_max=max(a["times"]),
                 rounds=len(a["times"]), threads=a["threads"]) for a, e in zip(got, failed)]


# ---------------------------------------------------------------------------------------------
# A side in its own process, taking its turns on the driver's word: one line in, one line out.


def _line_prefix(tag: str) -> str:
    """How a side's process starts its answer lines: READY, TURN, DONE and their JSON follow."""
    return f"CSB_PEERS_{tag} "


def _side_versions(side_name: str) -> dict[str, str]:
    if side_name == "newton":
        import warp as wp

        wp.config.quiet = True
        if hasattr(wp, "LOG_ERROR"):  # Warp 1.19+: the greeting and module loads are log messages
            wp.config.log_level = wp.LOG_ERROR
        import newton

        return dict(newton=newton.__version__, warp=wp.__version__)
    if side_name == "pypbd":
        from importlib.metadata import version

        import pypbd  # noqa: F401

        return dict(pypbd=version("pypbd"))
    if side_name == "jolt":
        return {}  # jolt_cloth says its version once it runs (JoltSide.versions)
    if side_name == "mujoco":
        import mujoco

        return dict(mujoco=mujoco.__version__)
    from .. import _core

    return dict(csb=_core.build_info()["csb"])


def serve(side_name: str, n: int, substeps: int, iterations: int, frames: int, warmup: int,
          stdin: Any = None, stdout: Any = None) -> int:
    """Build one side's cloth, say READY, then answer ``turn MIN_ROUNDS SECONDS MAX_ROUNDS`` and
    finally ``finish HOLD_FRAMES`` (check the cloth after the last timed round, then hold it)."""
    stdin, stdout = stdin or sys.stdin, stdout or sys.stdout

    def say(tag: str, payload: dict[str, Any]) -> None:
        stdout.write(_line_prefix(tag) + json.dumps(payload) + "\n")
        stdout.flush()

    t0 = time.perf_counter()
    versions = _side_versions(side_name)
    import_s = time.perf_counter() - t0
    arrays = cloth_arrays(n)
    t_build = time.perf_counter()
    side = SIDE_CLASSES[side_name](arrays, substeps, iterations)
    build_s = time.perf_counter() - t_build
    t_first = time.perf_counter()
    side.frames(1)  # the first frame: Newton compiles its kernels here
    first_frame_s = time.perf_counter() - t_first
    versions.update(getattr(side, "versions", {}))
    say("READY", dict(side=side_name, versions=versions, import_s=import_s, counts=side.counts,
                      verified=side.verified, build_s=build_s, first_frame_s=first_frame_s))
    turns = Turns(side, frames, warmup)
    for line in stdin:
        word, *args = line.split()
        if word == "turn":
            say("TURN", turns.turn(int(args[0]), float(args[1]), int(args[2])))
        elif word == "finish":
            check = check_cloth(arrays, side.positions(), frames)
            hold = None
            hold_frames = int(args[0])
            if hold_frames > 0:  # longer: does the cloth hang, or fall, or diverge?
                side.reset()
                side.frames(hold_frames)
                hold = check_cloth(arrays, side.positions(), hold_frames)
            if hasattr(side, "stability"):  # a force-based side: is its step stable at its setting?
                for c in (check, hold):
                    if c is not None:
                        c["stability"] = side.stability(c)
            if hasattr(side, "close"):  # a side with a process of its own (Jolt's) ends it
                side.close()
            say("DONE", dict(check=check, hold=hold))
            return 0
        else:
            raise ValueError(f"csb.bench.peers --serve: unknown command {line.strip()!r}")
    return 1  # the driver went away


def _worker_main(argv: Sequence[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m csb.bench.peers")
    p.add_argument("--serve", required=True, choices=sorted(SIDE_CLASSES))
    p.add_argument("--size", type=int, required=True)
    p.add_argument("--case", required=True, help="SUBSTEPSxITERATIONS")
    p.add_argument("--frames", type=int, default=5)
    p.add_argument("--warmup", type=int, default=2)
    a = p.parse_args(argv)
    substeps, iterations = (int(v) for v in a.case.split("x"))
    return serve(a.serve, a.size, substeps, iterations, a.frames, a.warmup)


# ---------------------------------------------------------------------------------------------
# The driver: for each row, one live process per side (and per thread count for pypbd)


@dataclass
class Run:
    label: str                      # "csb", "pypbd (1 thread)", ...
    side: str
    env: dict[str, str] = field(default_factory=dict)
    result: dict[str, Any] | None = None
    error: str | None = None
    skipped: list[tuple[int, tuple[int, int], str]] = field(default_factory=list)  # (n, case, why)


def case_reason(side: str, case: tuple[int, int]) -> str | None:
    """Why a side has no such (substeps, iterations) case (None: it has)."""
    if side == "jolt":
        return jolt_case_reason(*case)
    if side == "mujoco" and case[1] != 1:
        return (f"{MUJOCO_METHOD}: force-based, no iterations, its own sub-steps (from its stability limit), "
                f"so it is timed once per cloth, in the rows of 1 iteration")
    return None


class WorkerFailed(RuntimeError):
    pass


class Worker:
    """The driver's end of one side's process for one row (``python -m csb.bench.peers --serve``).
    Its turns go through the pipe; the process is built and ready before the row's first turn."""

    def __init__(self, run: Run, n: int, case: tuple[int, int], frames: int, warmup: int,
                 timeout: float = 3600):
        self.run, self.timeout = run, timeout
        self.stderr = tempfile.TemporaryFile(mode="w+")
        cmd = [sys.executable, "-m", "csb.bench.peers", "--serve", run.side, "--size", str(n),
               "--case", f"{case[0]}x{case[1]}", "--frames", str(frames), "--warmup", str(warmup)]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.stderr,
                                     text=True, env={**os.environ, **run.env})
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.pump = threading.Thread(target=self._pump, daemon=True)
        self.pump.start()
        self.ready = self._read("READY")

    def _pump(self) -> None:
        # The process's lines, read by a thread: a select() on the pipe would not see lines
        # already in the reader's buffer.
        for line in self.proc.stdout:
            self.lines.put(line)
        self.lines.put(None)

    def _read(self, tag: str) -> dict[str, Any]:
        deadline = time.monotonic() + self.timeout
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                self.close()
                raise WorkerFailed(f"no answer in {self.timeout:g} s") from None
            if line is None:  # the process ended
                self.proc.wait()
                self.stderr.seek(0)
                tail = self.stderr.read().strip().splitlines()[-5:]
                self.close()
                raise WorkerFailed(f"exit {self.proc.returncode}: " + " | ".join(tail))
            prefix = _line_prefix(tag)
            if line.startswith(prefix):
                return json.loads(line[len(prefix):])

    def _ask(self, line: str, tag: str) -> dict[str, Any]:
        try:
            self.proc.stdin.write(line + "\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            pass  # the process ended: _read says how
        return self._read(tag)

    def turn(self, min_rounds: int, seconds: float, max_rounds: int) -> dict[str, list]:
        return self._ask(f"turn {min_rounds} {seconds!r} {max_rounds}", "TURN")

    def finish(self, hold_frames: int) -> dict[str, Any]:
        done = self._ask(f"finish {hold_frames}", "DONE")
        self.close()
        return done

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        self.pump.join(timeout=10)  # it reads to the end of the pipe, then stops
        for f in (self.proc.stdin, self.proc.stdout, self.stderr):
            try:
                f.close()
            except OSError:  # stdin's last write to a process that has gone
                pass


def run_row(runs: Sequence[Run], n: int, case: tuple[int, int], frames: int, rounds: int, warmup: int,
            hold_frames: int = 0, min_time: float = MIN_TIME, passes: int = PASSES) -> None:
    """One cloth and case: every run's side in its own process, built one after the other, timed
    in alternating turns (:func:`alternate`), checked; results and errors go to the runs."""
    workers: list[Worker] = []
    for run in runs:
        why = case_reason(run.side, case)
        if why:
            run.skipped.append((n, case, why))
            continue
        print(f"building {run.label} {n}x{n} {case[0]}x{case[1]} ...", file=sys.stderr, flush=True)
        try:
            workers.append(Worker(run, n, case, frames, warmup))
        except WorkerFailed as e:
            run.error = (run.error + "; " if run.error else "") + f"{n} {case}: {e}"
    if not workers:
        return
    print(f"timing {n}x{n} {case[0]}x{case[1]}: {len(workers)} sides in {passes} alternating turns ...",
          file=sys.stderr, flush=True)
    timings = alternate(workers, rounds, min_time, passes)
    for w, timing in zip(workers, timings):
        try:
            if "failed" in timing:
                raise WorkerFailed(timing["failed"])
            done = w.finish(hold_frames)
        except WorkerFailed as e:
            w.close()
            w.run.error = (w.run.error + "; " if w.run.error else "") + f"{n} {case}: {e}"
            continue
        r = w.ready
        row = dict(n=n, substeps=case[0], iterations=case[1], counts=r["counts"], verified=r["verified"],
                   build_s=r["build_s"], first_frame_s=r["first_frame_s"], **done, **timing)
        if "method" in r["verified"]:  # a different method: its own setting, not the row's work
            row["method"] = r["verified"]["method"]
        if w.run.result is None:
            w.run.result = dict(side=w.run.side, versions=r["versions"], import_s=r["import_s"], rows=[])
        w.run.result["rows"].append(row)


def plan_runs(sides: Sequence[str], pypbd_threads: Sequence[int], newton_cold: bool,
              cache_dir: str | None = None, newton_launches: bool = False, jolt: str | None = None,
              jolt_threads: Sequence[int] = (1, 2),
              csb_variants: Sequence[tuple[str, str]] = (("pbd", "float64"),)) -> tuple[list[Run], list[str]]:
    """The runs of each side. csb_variants: csb's (method, precision) pairs, each a run of its own
    ("csb" for PBD in float64, the ratios' base, else "csb xpbd float32" and so on)."""
    runs, skipped = [], []
    for side in sides:
        if side == "jolt":  # a program given by path, not an installed module
            exe, why = jolt_binary(jolt)
            if exe is None:
                skipped.append(f"jolt: {why}; skipped")
                continue
            for t in jolt_threads:
                runs.append(Run(f"jolt {t}T", "jolt", {JOLT_ENV: exe, JOLT_THREADS_ENV: str(t)}))
            continue
        if not peer_available(side):
            skipped.append(f"{side}: not installed (pip install 'csb[bench]'), skipped")
            continue
        if side == "pypbd":
            for t in pypbd_threads:
                runs.append(Run(f"pypbd {t}T", "pypbd", {"OMP_NUM_THREADS": str(t)}))
        elif side == "newton":
            env = {"OMP_NUM_THREADS": "1"}
            if newton_cold and cache_dir is not None:
                env["WARP_CACHE_PATH"] = cache_dir  # a fresh kernel cache: first use compiles
            runs.append(Run("newton", "newton", env))
            if newton_launches:
                runs.append(Run("newton nograph", "newton", {**env, "CSB_NEWTON_GRAPH": "0"}))
        elif side == "mujoco":
            runs.append(Run("mujoco", "mujoco"))
        else:
            for method, precision in csb_variants:
                label = "csb" if (method, precision) == ("pbd", "float64") else f"csb {method} {precision}"
                runs.append(Run(label, "csb", {"OMP_NUM_THREADS": "1", CSB_METHOD_ENV: method,
                                               CSB_PRECISION_ENV: precision}))
    return runs, skipped


def format_peer_table(runs: Sequence[Run]) -> str:
    done = [r for r in runs if r.result is not None]
    csb = next((r for r in done if r.label == "csb"), next((r for r in done if r.side == "csb"), None))
    csb_ms = {(row["n"], row["substeps"], row["iterations"]): row["ms_per_frame"]
              for row in (csb.result["rows"] if csb else [])}
    head = (f"{'cloth':>9} {'sub x it':>8} {'side':>14} {'particles':>9} {'distance':>8} {'bending':>8} "
            f"{'proj/frame':>10} {'ms/frame':>9} {'(min-max)':>17} {'rounds':>6} {'Mproj/s':>8} {'/ csb':>7} "
            f"{'check after the timed frames':<40}")
    lines = [head, "-" * len(head)]
    keys = sorted({(row["n"], -row["substeps"], row["iterations"]) for r in done for row in r.result["rows"]})
    for n, msub, it in keys:
        for r in done:
            for row in r.result["rows"]:
                if (row["n"], -row["substeps"], row["iterations"]) != (n, msub, it):
                    continue
                c, ch = row["counts"], row["check"]
                ms = row["ms_per_frame"]
                ref = csb_ms.get((n, -msub, it))
                ratio = f"{ms / ref:7.1f}" if ref else f"{'-':>7}"
                proj = c["projections_per_frame"]  # None: a force-based side projects nothing
                mproj = f"{proj / (ms * 1e-3) / 1e6:8.1f}" if proj else f"{'-':>8}"
                spread = f"({row['ms_min']:.3f}-{row['ms_max']:.3f})"
                verdict = "ok" if ch["ok"] else "FAILED"
                note = (f"{verdict}: drop {1e3 * ch['mean_drop']:.0f} mm (free fall {1e3 * ch['free_fall']:.0f}), "
                        f"strain max {100 * ch['max_strain']:.0f}% mean {100 * ch['mean_strain']:.1f}%, "
                        f"pins {ch['pin_moved']:.0e} m" if ch["finite"] else f"{verdict}: not finite")
                if "method" in row:
                    note = f"{method_note(row)}; {stability_note(ch['stability'])}; {note}"
                used = [t for t in row.get("threads") or [] if t is not None]
                if used:  # csb: the threads of the timed rounds, and in how many rounds each count
                    counts = sorted(((used.count(t), t) for t in set(used)), reverse=True)
                    note += f"; threads {used[0]}" if len(counts) == 1 else "; threads " + ", ".join(
                        f"{t} in {k} rounds" for k, t in counts)
                lines.append(
                    f"{n:>4}x{n:<4} {-msub:>3} x {it:<3} {r.label:>14} {c['particles']:>9} {c['distance']:>8} "
                    f"{c['bending']:>8} {proj or '-':>10} {ms:>9.3f} "
                    f"{spread:>17} {row['rounds']:>6} {mproj} {ratio} {note}")
    return "\n".join(lines)


def method_note(row: dict[str, Any]) -> str:
    """What a different method's row times: its method and its own setting, not the row's."""
    v = row["verified"]
    return f"{v['method']}: {v['mujoco_substeps']} sub-steps/frame, edges {v['edge_stiffness']:g} N/m"


def stability_note(stability: dict[str, Any]) -> str:
    """A force-based side's verdict (MujocoSide.stability), as the table prints it."""
    if not stability["finite"]:
        return "NOT stable: not finite"
    return (f"{'stable' if stability['stable'] else 'NOT stable'}: max strain {100 * stability['max_strain']:.1f} % "
            f"{'<' if stability['stable'] else '>='} {100 * stability['strain_limit']:g} %")


def format_hold_table(runs: Sequence[Run]) -> str:
    """The longer check (--hold-frames): where each side's cloth is after that many frames."""
    lines = []
    for r in runs:
        for row in (r.result or {}).get("rows", []):
            h = row.get("hold")
            if not h:
                continue
            state = (f"{'ok' if h['ok'] else 'FAILED'}: drop mean {h['mean_drop']:.3g} m max {h['max_drop']:.3g} m "
                     f"(free fall {h['free_fall']:.3g} m), strain max {100 * h['max_strain']:.3g}% "
                     f"mean {100 * h['mean_strain']:.3g}%, pins {h['pin_moved']:.0e} m"
                     if h["finite"] else "FAILED: not finite")
            if "stability" in h:
                state = f"{stability_note(h['stability'])}; {state}"
            lines.append(f"{row['n']:>4}x{row['n']:<4} {row['substeps']:>3} x {row['iterations']:<3} {r.label:>14}  {state}")
    if not lines:
        return ""
    frames = next(row["hold"]["frames"] for r in runs for row in (r.result or {}).get("rows", []) if row.get("hold"))
    return f"\nAfter {frames} frames ({frames / 60:.2f} s) from rest, untimed:\n" + "\n".join(lines)


def format_header(runs: Sequence[Run], frames: int, rounds: int, warmup: int, min_time: float = 0.0,
                  passes: int = PASSES) -> str:
    versions: dict[str, str] = {}
    for r in runs:
        if r.result:
            versions.update(r.result.get("versions", {}))
    info = ", ".join(f"{k} {v}" for k, v in versions.items())
    per_turn = rounds_per_turn(rounds, passes)
    return (f"csb against its peers: cloth_grid at N x N, 2 pinned corners, dt = 1/60 s per frame. "
            f"The sides of a row take turns, {passes} each, one side at a time; a turn is {warmup} untimed "
            f"warm-up frames, then rounds that each start at rest and time frames 1-{frames}: at least "
            f"{per_turn} round{'s' if per_turn > 1 else ''}"
            + (f" and {min_time / passes:g} s of timed frames" if min_time > 0 else "")
            + f". ms/frame: the median over all of a side's rounds (column 'rounds'; at least {per_turn * passes}"
            + (f", filling at least {min_time:g} s" if min_time > 0 else "")
            + f"). '/ csb': ms/frame over csb's. {info}")


def format_notes(runs: Sequence[Run]) -> str:
    lines = []
    for r in runs:
        reasons: dict[str, list[str]] = {}
        for n, case, why in r.skipped:
            reasons.setdefault(why, []).append(f"{n}x{n} {case[0]}x{case[1]}")
        for why, rows in reasons.items():
            lines.append(f"{r.label}: skipped {', '.join(rows)}: {why}")
        if r.error:
            lines.append(f"{r.label}: FAILED to run: {r.error}")
            continue
        res = r.result
        if res is None:
            continue
        if r.side == "newton":
            firsts = [row["first_frame_s"] for row in res["rows"]]  # one process per row: [0] is the first use
            fresh = r.env.get("WARP_CACHE_PATH") and r.env.get("CSB_NEWTON_GRAPH") != "0"
            how = ("kernel compilation into a fresh cache" if fresh else
                   "kernels loaded from the cache" + (" the run above compiled" if r.env.get("WARP_CACHE_PATH") else ""))
            lines.append(f"{r.label}: import {res['import_s']:.1f} s; first frame of its first process ({how}) "
                         f"{firsts[0]:.1f} s, of the later processes (kernels from that cache) "
                         f"{min(firsts[1:], default=0):.2f}-{max(firsts[1:], default=0):.2f} s; "
                         f"none of it is in ms/frame")
        if "method" in res["rows"][0]:  # a different method, at its own setting
            v = res["rows"][0]["verified"]
            steps = ", ".join(f"{row['n']}² {row['verified']['mujoco_substeps']} of "
                              f"{1e6 * row['verified']['timestep']:.1f} µs" for row in res["rows"])
            lines.append(f"{r.label}: {v['method']}, not equal work with csb ('/ csb' is time per frame of the same "
                         f"cloth): {MAPPING[r.side]}; edge stiffness {v['edge_stiffness']:g} N/m: "
                         f"{v['edge_stiffness_why']}; sub-steps a frame from the explicit stability limit: {steps}")
            continue
        mismatched = []
        for row in res["rows"]:
            v = row["verified"]
            if v.get("substeps") != row["substeps"] or v.get("iterations") != row["iterations"]:
                mismatched.append(f"{row['n']} {row['substeps']}x{row['iterations']}: peer reports {v}")
        if mismatched:
            lines.append(f"{r.label}: substeps/iterations NOT as asked: " + "; ".join(mismatched))
        else:
            lines.append(f"{r.label}: substeps and iterations read back from the peer as asked "
                         f"({', '.join(f'{k}={v}' for k, v in res['rows'][0]['verified'].items() if k not in ('substeps', 'iterations'))})")
    return "\n".join(lines)


def main(sizes: Sequence[int] = SIZES, cases: Sequence[tuple[int, int]] = CASES, frames: int = 5, rounds: int = 7,
         warmup: int = 2, min_time: float = MIN_TIME, sides: Sequence[str] = ("csb", "pypbd", "newton", "jolt"),
         pypbd_threads: Sequence[int] = (1, 2), newton_cold: bool = True, hold_frames: int = 0,
         newton_launches: bool = True, passes: int = PASSES, jolt: str | None = None,
         jolt_threads: Sequence[int] = (1, 2),
         csb_variants: Sequence[tuple[str, str]] = (("pbd", "float64"),)) -> list[Run]:
    with tempfile.TemporaryDirectory(prefix="csb-warp-cache-") as cache:
        runs, skipped = plan_runs(sides, pypbd_threads, newton_cold, cache, newton_launches, jolt, jolt_threads,
                                  csb_variants)
        for s in skipped:
            print(s)
        for n in sizes:
            for case in cases:
                run_row(runs, n, case, frames, rounds, warmup, hold_frames, min_time, passes)
    print(format_header(runs, frames, rounds, warmup, min_time, passes))
    print(format_peer_table(runs))
    print(format_notes(runs))
    hold = format_hold_table(runs)
    if hold:
        print(hold)
    return runs


if __name__ == "__main__":
    sys.exit(_worker_main(sys.argv[1:]))
