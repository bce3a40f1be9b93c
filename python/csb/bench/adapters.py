"""The peers as csb methods: a peer's solver wrapped in a :class:`csb.Integrator`, so that the scene
runner, the viewer and every study step it on a csb Model beside csb's own methods, and a
conformance check that says whether the peer really simulates the same thing.

An adapter maps a csb Model (particles, masses, pins, constraints, material, gravity) onto the
peer's model once per Model and says, by name, what it cannot map (a :class:`csb.ParameterError`).
``conformance`` then checks the mapping before anything is plotted: the same particle and
constraint counts, the same rest state, the same pins and gravity, and a quiet first step (from
rest) that agrees with csb's own method of the same family. A peer that fails it is reported,
not plotted.

The peers are the optional ``bench`` extra (``pip install csb[bench]``); without one, making its
adapter raises ImportError naming the extra.

* ``PypbdIntegrator``: Bender's PositionBasedDynamics (``pypbd``), PBD Gauss-Seidel. Maps a
  triangle-mesh model: a DistanceConstraint per csb distance constraint (in csb's order, with
  csb's per-iteration stiffness 1 - (1 - k)^(1/iterations)), pypbd's own dihedral bending on the
  same triangles (one stiffness for all), pins as mass 0; gravity -9.81 m/s² along y (pypbd's
  default, the only one it is given here).
* ``MujocoFlexIntegrator``: MuJoCo's flex (``mujoco``), a one-dimensional flex whose edges are
  csb's distance constraints as springs of stiffness 1/α (N/m), each particle a body on three
  slide joints with its own mass (a pin: a body with none), stepped by MuJoCo's semi-implicit
  Euler (or its implicit-in-velocity and RK4 integrators). A cloth's bending is a two-dimensional
  flex per hinge with MuJoCo's hinge bending, its Young's modulus chosen so that the hinge's
  stiffness is 1/α (exact to second order in the fold about a flat rest state).
* ``NewtonXpbdIntegrator``, ``NewtonVbdIntegrator``, ``NewtonStyle3dIntegrator``: NVIDIA Newton's
  cloth solvers (``newton`` on ``warp``, device "cpu"), SolverXPBD, SolverVBD and SolverStyle3D.
  The mapping of each is in its class's docstring (:class:`NewtonIntegrator` has what they share).
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import _core

__all__ = ["PypbdIntegrator", "MujocoFlexIntegrator", "mujoco_flex_model", "mujoco_flex_counts", "NewtonIntegrator",
           "NewtonXpbdIntegrator", "NewtonVbdIntegrator", "NewtonStyle3dIntegrator", "Conformance", "conformance"]

PYPBD_GRAVITY = (0.0, -9.81, 0.0)
_MUJOCO_WARNINGS: list[str] = []  # MuJoCo's warnings of this process, in order
_PYPBD_OWNER: list[Any] = [None]  # the PypbdIntegrator whose model pypbd's one simulation holds


def _require(module: str, extra: str = "bench") -> None:
    if importlib.util.find_spec(module) is None:
        raise ImportError(f"the peer '{module}' is not installed: it is part of csb's optional '{extra}' extra "
                          f"(pip install 'csb[{extra}]')")


def _num(x: float) -> str:
    """A number for MJCF, to the bit (repr of a Python float round-trips)."""
    return repr(float(x))


def _check_steps(dt: Any, substeps: Any) -> None:
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise _core.ParameterError(f"dt must be a finite time step > 0 s, got {dt!r}")
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise _core.ParameterError(f"substeps must be an integer >= 1, got {substeps!r}")


def _check_iterations(iterations: Any) -> None:
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise _core.ParameterError(f"iterations must be an integer >= 1, got {iterations!r}")


def _check_gravity(gravity: Any) -> np.ndarray:
    g = np.asarray(gravity, dtype=float)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise _core.ParameterError(f"gravity must be 3 finite numbers (m/s²), got {gravity!r}")
    return g


def _unmappable(model: _core.Model, peer: str, *, takes: tuple[str, ...]) -> list[str]:
    """What of `model` no adapter here maps: constraint kinds beyond `takes` (of "distance",
    "bending"), colliders, self-collision, one-sided distance constraints, and rest lengths other
    than the rest positions' (a peer takes them from the positions)."""
    why = []
    counts = {"bending": len(np.asarray(model.bending["stiffness"])),
              "volume": len(np.asarray(model.volume["stiffness"])),
              "attachment": len(np.asarray(model.attachments["stiffness"])),
              "balloon": len(np.asarray(model.balloons["rest_volume"]))}
    counts.update({name: len(np.asarray(arrays["particles"])) for name, arrays in model.families.items()})
    why += [f"{count} {kind} constraints" for kind, count in counts.items() if count and kind not in takes]
    if len(model.colliders):
        why.append("colliders")
    if np.any(np.asarray(model.self_collision_thickness) > 0):
        why.append("self-collision")
    d = model.distance
    if np.any(np.asarray(d["sense"]) != 0):
        why.append("one-sided distance constraints")
    x = np.asarray(model.rest_positions)
    pairs = np.asarray(d["particles"])
    if len(pairs):
        length = np.linalg.norm(x[pairs[:, 1]] - x[pairs[:, 0]], axis=1)
        if np.max(np.abs(length - np.asarray(d["rest_length"]))) > 1e-12 * max(1.0, float(np.max(length))):
            why.append(f"distance rest lengths other than the rest positions' ({peer} takes them from the positions)")
    return why


class _Peer(_core.Integrator):
    """What every adapter has beyond csb.Integrator: ``unmappable(model)``, ``counterpart()`` (csb's
    method of the same family) and ``conformance(model)``, which a study runs before it measures
    a peer (it finds the method by that name; csb.studies does not import this module); and the
    settings every adapter checks and keeps, with its per-Model state."""

    def __init__(self, dt: float, substeps: int, iterations: int):
        super().__init__()
        _check_steps(dt, substeps)
        _check_iterations(iterations)
        self._dt, self.substeps, self.iterations = float(dt), substeps, iterations
        self._model: _core.Model | None = None  # the csb Model the peer's model was built from
        self.counts: dict[str, int] = {}
        self.pinned: list[int] = []

    def dt(self) -> float:
        return self._dt

    def conformance(self, model: _core.Model, *, tolerance: float = 0.2) -> "Conformance":
        return conformance(self, model, tolerance=tolerance)

    def for_check(self) -> "_Peer":
        """The peer as the conformance check steps it: the same mapping, solved to convergence."""
        return self


class PypbdIntegrator(_Peer):
    """pypbd's PBD stepping a csb Model: dt (s) a step, `substeps` sub-steps of `iterations`
    Gauss-Seidel sweeps each. The peer's model is built at the first step of each csb Model;
    pypbd holds one simulation per process, so stepping another Model rebuilds it."""

    def __init__(self, dt: float, *, substeps: int = 1, iterations: int = 10,
                 gravity: tuple[float, float, float] = PYPBD_GRAVITY):
        _require("pypbd")
        super().__init__(dt, substeps, iterations)
        if tuple(float(g) for g in gravity) != PYPBD_GRAVITY:
            raise _core.ParameterError(f"gravity: pypbd is given {PYPBD_GRAVITY} m/s² only, got {tuple(gravity)!r}")

    def name(self) -> str:
        return "pypbd"

    # -- the mapping
    def unmappable(self, model: _core.Model) -> list[str]:
        """What of `model` this adapter cannot give pypbd (empty: all of it)."""
        why = []
        n = model.num_particles
        tris = np.asarray(model.triangles)
        if len(tris) == 0:
            why.append("no triangles: pypbd's particles come from a triangle mesh")
        elif len(np.unique(tris)) != n:
            why.append(f"{n - len(np.unique(tris))} particles in no triangle")
        why += _unmappable(model, "pypbd", takes=("distance", "bending"))
        k_bend = np.unique(np.asarray(model.bending["stiffness"]))
        if len(k_bend) > 1:
            why.append("bending stiffnesses that differ (pypbd's bending takes one)")
        return why

    def _build(self, model: _core.Model) -> None:
        import pypbd as pbd

        why = self.unmappable(model)
        if why:
            raise _core.ParameterError("pypbd cannot simulate this model: " + "; ".join(why))
        sim = pbd.Simulation.getCurrent()
        if sim.getModel() is not None and len(sim.getModel().getTriangleModels()):
            sim.getModel().cleanup()
        sim.initDefault()
        pbd.TimeManager.getCurrent().setTime(0.0)
        pbd.TimeManager.getCurrent().setTimeStepSize(self._dt)
        pm = sim.getModel()
        x = np.asarray(model.rest_positions, dtype=float)
        tri_model = pm.addTriangleModel(list(x), np.asarray(model.triangles).ravel().astype(np.uint32).tolist())
        pd = pm.getParticles()
        w, mass = np.asarray(model.inv_mass), np.asarray(model.mass)
        for i in range(len(x)):
            pd.setMass(i, 0.0 if w[i] == 0 else float(mass[i]))
        d = model.distance
        for (i, j), k in zip(np.asarray(d["particles"]).tolist(), np.asarray(d["stiffness"]).tolist()):
            pm.addDistanceConstraint(int(i), int(j), _core.corrected_stiffness(float(k), self.iterations))
        k_bend = np.asarray(model.bending["stiffness"])
        if len(k_bend):
            pm.addBendingConstraints(tri_model, 1, _core.corrected_stiffness(float(k_bend[0]), self.iterations))
        ts = sim.getTimeStep()
        c = pbd.TimeStepController
        ts.setValueUInt(c.NUM_SUB_STEPS, self.substeps)
        ts.setValueUInt(c.MAX_ITERATIONS, self.iterations)
        ts.setValueUInt(c.MAX_ITERATIONS_V, 0)  # csb has no velocity pass
        kinds: dict[str, int] = {}
        for con in pm.getConstraints():
            kinds[type(con).__name__] = kinds.get(type(con).__name__, 0) + 1
        self.counts = dict(particles=int(pd.size()), distance=kinds.pop("DistanceConstraint", 0),
                           bending=kinds.pop("DihedralConstraint", 0), other=sum(kinds.values()))
        self._pbd, self._pm, self._pd, self._ts = pbd, pm, pd, ts
        self._model = model  # held: the peer is built for this one
        _PYPBD_OWNER[0] = self
        self.pinned = [i for i in range(pd.size()) if pd.getInvMass(i) == 0]

    # Iterations of the check's step: Gauss-Seidel sweeps in pypbd's order and csb's converge to
    # the same positions, so the check sees the mapping, not the order (one sweep of each differs
    # by 15 % of a fall on a cloth at 1/30 s).
    CHECK_ITERATIONS = 200

    def for_check(self) -> "PypbdIntegrator":
        return type(self)(self._dt, substeps=self.substeps, iterations=max(self.iterations, self.CHECK_ITERATIONS))

    def counterpart(self) -> _core.Integrator:
        """csb's method of the same family, which the quiet first step is checked against."""
        return _core.PbdStepper(method="pbd", dt=self._dt, substeps=self.substeps, iterations=self.iterations,
                                ordering="sequential", gravity=PYPBD_GRAVITY)

    def step(self, model: _core.Model, state: _core.State, steps: int = 1, interrupt=None) -> None:
        if self._model is not model or _PYPBD_OWNER[0] is not self:  # another peer took pypbd's simulation
            self._build(model)
        pd = self._pd
        x, v = np.asarray(state.x, dtype=float), np.asarray(state.v, dtype=float)
        for i in range(len(x)):
            pd.setPosition(i, x[i])
            pd.setVelocity(i, v[i])
        for s in range(steps):
            self._ts.step(self._pm)
            state.t += self._dt
            state.step += 1
            if interrupt is not None and s + 1 < steps and interrupt():
                break
        n = pd.size()
        state.x = np.array([pd.getPosition(i) for i in range(n)])
        state.v = np.array([pd.getVelocity(i) for i in range(n)])


def mujoco_flex_model(positions: np.ndarray, inv_mass: np.ndarray, mass: np.ndarray, distance: np.ndarray,
                      edge_stiffness: float, bending: np.ndarray, bending_compliance: np.ndarray, *,
                      timestep: float, gravity: np.ndarray, integrator: str) -> tuple[Any, np.ndarray]:
    """A particle cloth as MuJoCo's flex (the mapping of :class:`MujocoFlexIntegrator`): each
    particle a body at its rest position (m) on three slide joints with its own mass (kg; a pin,
    inverse mass 0, a body with no joint), one 1-D flex whose elements are the `distance` pairs,
    edges of `edge_stiffness` (N/m) and damping 0, and a 2-D flex per `bending` quadruple (a, b,
    c, d: the hinge edge a-b, c and d opposite) of stiffness 1/α, α its `bending_compliance`
    (1/(N m)). Returns the MjModel (sub-step `timestep` s, `gravity` m/s², MuJoCo's `integrator`)
    and the qpos address of each particle's first slide joint (-1: pinned). Collision detection is
    off: no flex here collides (contype 0), and MuJoCo's collision pass would still size itself for
    every pair of flexes, one per hinge (it asked for 504 MB at 64², beyond its default arena).
    MuJoCo's warnings go to this module's list, not to MUJOCO_LOG.TXT in the working directory."""
    import mujoco

    x0, w = np.asarray(positions, dtype=float), np.asarray(inv_mass)
    slide = '<joint type="slide" axis="1 0 0"/><joint type="slide" axis="0 1 0"/><joint type="slide" axis="0 0 1"/>'
    bodies = []
    for i, p in enumerate(x0):
        m_i = float(mass[i]) if w[i] > 0 else 1.0  # a pin's mass is never used (it has no joint)
        bodies.append(f'<body name="p{i}" pos="{_num(p[0])} {_num(p[1])} {_num(p[2])}"><inertial pos="0 0 0" mass="{_num(m_i)}" '
                      f'diaginertia="1e-12 1e-12 1e-12"/>{slide if w[i] > 0 else ""}</body>')
    hinges = []
    for (a, b, c, d), alpha_b in zip(np.asarray(bending).tolist(), np.asarray(bending_compliance).tolist()):
        e2 = float(np.sum((x0[b] - x0[a]) ** 2))
        area = 0.5 * (np.linalg.norm(np.cross(x0[c] - x0[a], x0[c] - x0[b]))
                      + np.linalg.norm(np.cross(x0[d] - x0[b], x0[d] - x0[a])))
        young = 12.0 * area / (e2 * alpha_b)  # thickness 1 m, Poisson 0: D |e|²/A = 1/α
        hinges.append(f'<flex name="hinge{len(hinges)}" dim="2" body="p{a} p{b} p{c} p{d}" '
                      f'vertex="{" ".join(["0 0 0"] * 4)}" element="2 0 1 3 1 0" radius="1e-4">'
                      f'<elasticity young="{_num(young)}" poisson="0" thickness="1" elastic2d="bend"/>'
                      f'<contact contype="0" conaffinity="0" selfcollide="none"/></flex>')
    g = np.asarray(gravity, dtype=float)
    xml = f"""<mujoco>
  <option timestep="{_num(timestep)}" gravity="{_num(g[0])} {_num(g[1])} {_num(g[2])}"
          integrator="{integrator}"><flag contact="disable"/></option>
  <worldbody>{''.join(bodies)}</worldbody>
  <deformable>
    <flex name="springs" dim="1" body="{' '.join(f'p{i}' for i in range(len(x0)))}"
      vertex="{' '.join('0 0 0' for _ in range(len(x0)))}" element="{' '.join(f'{a} {b}' for a, b in np.asarray(distance).tolist())}"
      radius="1e-4">
      <edge stiffness="{_num(edge_stiffness)}" damping="0"/>
      <contact contype="0" conaffinity="0" selfcollide="none"/>
    </flex>{''.join(hinges)}
  </deformable>
</mujoco>"""
    mujoco.set_mju_user_warning(_MUJOCO_WARNINGS.append)
    m = mujoco.MjModel.from_xml_string(xml)
    # bodies 1.. are the particles
    adr = np.array([m.jnt_qposadr[m.body_jntadr[i + 1]] if m.body_jntnum[i + 1] else -1 for i in range(len(x0))])
    return m, adr


def mujoco_flex_counts(m: Any) -> dict[str, int]:
    """What a :func:`mujoco_flex_model` holds, read back from MuJoCo's model: the springs' flex's
    vertices and edges, the 2-D (hinge) flexes, and any 3-D flex (none)."""
    dims = np.asarray(m.flex_dim)
    return dict(particles=int(m.flex_vertnum[0]), distance=int(m.flex_edgenum[0]),
                bending=int(np.sum(dims == 2)), other=int(np.sum(dims == 3)))


class MujocoFlexIntegrator(_Peer):
    """MuJoCo's flex stepping a csb Model of distance springs and dihedral bending: dt (s) a step
    in `substeps` mj_step calls of dt/substeps. integrator: "Euler" (MuJoCo's semi-implicit Euler,
    the force-based counterpart of csb's symplectic Euler), "implicitfast" or "RK4".

    * distance constraints: one 1-D flex whose elements are csb's distance pairs, edges of
      stiffness 1/α (N/m), damping 0: exact (MuJoCo's edge stiffness is for 1-D flexes only; a
      2-D flex's stretching is a continuum St Venant-Kirchhoff membrane, not per-edge springs).
    * bending: a 2-D flex per hinge, its two triangles, elastic2d "bend" only, Poisson's ratio
      0, thickness t = 1 m and Young's modulus E = 12 A / (t³ |e|² α), A the two triangles' rest
      area and |e| the hinge's edge. MuJoCo's 2-D bending is a hinge model for flat references of
      stiffness D |e|²/A per hinge, D = E t³/(12 (1 - ν²)) one rigidity per flex (measured here
      to 1e-6: k/(D |e|²/A) = 0.9999998 at a fold of 1 mrad, on square and equilateral hinges), so
      a flex per hinge gives each hinge csb's 1/α, whatever its shape. It is quadratic in the
      positions about the flat rest state (a constant Hessian), csb's θ²/(2α) is not: the two
      agree to second order in the fold, and a fold of θ rad turns MuJoCo's force by about θ/2
      from csb's. Rest angles must be 0, and MuJoCo 4.0 or later (whose bending rigidity is the
      plate's D; earlier versions took 3/4 (1 - ν) D).
    """

    INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")

    def __init__(self, dt: float, *, substeps: int = 1, gravity: tuple[float, float, float] = (0.0, -9.81, 0.0),
                 integrator: str = "Euler"):
        _require("mujoco")
        super().__init__(dt, substeps, 1)  # no iterations: one force evaluation a sub-step
        self.gravity = _check_gravity(gravity)
        if integrator not in self.INTEGRATORS:
            raise _core.ParameterError(f"integrator must be one of {', '.join(self.INTEGRATORS)}, got {integrator!r}")
        self.integrator = integrator

    def name(self) -> str:
        return f"mujoco-flex ({self.integrator})"

    def unmappable(self, model: _core.Model) -> list[str]:
        why = _unmappable(model, "a flex", takes=("distance", "bending"))
        bending = model.bending
        if len(np.asarray(bending["rest_angle"])) and self._mujoco_major() < 4:
            why.append(f"bending with MuJoCo {self._mujoco_version()}: the hinge mapping needs MuJoCo 4.0 or later "
                       f"(earlier versions scale a 2-D flex's bending rigidity by 3/4 (1 - ν))")
        if np.any(np.abs(np.asarray(bending["rest_angle"])) > 1e-9):
            why.append("bending rest angles other than 0 (MuJoCo's 2-D flex bending is a hinge model for flat "
                       "rest states)")
        if np.any(np.asarray(bending["compliance"]) <= 0):
            why.append("hard bending constraints (compliance 0): a flex hinge is a stiffness 1/α")
        alpha = np.asarray(model.distance["compliance"])
        if len(alpha) == 0:
            why.append("no distance constraints")
        elif np.any(alpha <= 0):
            why.append("hard distance constraints (compliance 0): a flex edge is a spring of stiffness 1/α")
        elif np.ptp(alpha) > 0:
            why.append("distance compliances that differ (a flex's edges share one stiffness)")
        if np.any(np.asarray(model.mass)[np.asarray(model.inv_mass) > 0] <= 0):
            why.append("free particles without mass")
        return why

    @staticmethod
    def _mujoco_version() -> str:
        from importlib.metadata import version

        return version("mujoco")

    @classmethod
    def _mujoco_major(cls) -> int:
        head = cls._mujoco_version().split(".")[0]
        return int(head) if head.isdigit() else 0

    def _build(self, model: _core.Model) -> None:
        import mujoco

        why = self.unmappable(model)
        if why:
            raise _core.ParameterError("MuJoCo's flex cannot simulate this model: " + "; ".join(why))
        x0 = np.asarray(model.rest_positions, dtype=float)
        self._m, self._adr = mujoco_flex_model(
            x0, np.asarray(model.inv_mass), np.asarray(model.mass), np.asarray(model.distance["particles"]),
            1.0 / float(np.asarray(model.distance["compliance"])[0]), np.asarray(model.bending["particles"]),
            np.asarray(model.bending["compliance"]), timestep=self._dt / self.substeps, gravity=self.gravity,
            integrator=self.integrator)
        self._mj = mujoco
        self._d = mujoco.MjData(self._m)
        self._x0 = x0
        self.counts = mujoco_flex_counts(self._m)
        self.pinned = [i for i in range(len(x0)) if self._adr[i] < 0]
        self._model = model

    def counterpart(self) -> _core.Integrator:
        """csb's method of the same family, which the quiet first step is checked against."""
        return _core.ForceStepper(method="symplectic-euler", dt=self._dt, substeps=self.substeps,
                                  gravity=tuple(self.gravity))

    def step(self, model: _core.Model, state: _core.State, steps: int = 1, interrupt=None) -> None:
        if self._model is not model:
            self._build(model)
        m, d, mj = self._m, self._d, self._mj
        free = self._adr >= 0
        adr = self._adr[free][:, None] + np.arange(3)
        xn, vn = np.array(state.x, dtype=float), np.array(state.v, dtype=float)
        d.qpos[adr] = xn[free] - self._x0[free]
        d.qvel[adr] = vn[free]
        d.time = 0.0
        d.warning.number[:] = 0
        try:
            for s in range(steps):
                for _ in range(self.substeps):
                    mj.mj_step(m, d)
                # MuJoCo meets a diverging step by resetting its state after a warning: say so instead.
                if d.warning.number.any() or not np.all(np.isfinite(d.qpos)):
                    raise _core.SimulationError(
                        f"MuJoCo's flex diverged in step {state.step + 1} (t = {state.t:g} s to {state.t + self._dt:g} "
                        f"s): {'; '.join(_MUJOCO_WARNINGS[-1:]) or 'positions not finite'}; the state is left at the "
                        f"end of the step before")
                xn[free] = self._x0[free] + d.qpos[adr]
                vn[free] = d.qvel[adr]
                state.t += self._dt
                state.step += 1
                if interrupt is not None and s + 1 < steps and interrupt():
                    break
        finally:
            state.x, state.v = xn, vn


class NewtonIntegrator(_Peer):
    """NVIDIA Newton stepping a csb Model on the CPU (warp device "cpu"): dt (s) a step in
    `substeps` calls of the solver's step with dt/substeps, `iterations` of the solver each. A
    subclass names the solver (``SOLVER``) and maps the constraints; what they share:

    * particles: csb's rest positions and masses; a pin (inverse mass 0) is a particle of mass 0,
      which Newton keeps where it is; radius 0 (no particle contacts); no colliders, contacts
      None, control None.
    * gravity: as given (m/s², any direction).
    * state: each call of ``step`` copies csb's x and v into Newton's state and back at the end of
      each step. Newton computes in float32: positions are rounded to 6e-8 of their size.
    * Newton's model is built at the first step of each csb Model and kept for it.
    * cost: Newton's first use compiles its kernels for the CPU and keeps them in Warp's kernel
      cache (``~/.cache/warp``): 16 s for SolverXPBD's, 7 s for SolverVBD's, 4.6 s for the
      model's own on the development machine (papers/benchmarks.md). Every sub-step launches its
      kernels from Python, which dominates the cost on small models.

    Not mapped, and said so by ``unmappable``: volume, attachment, balloon and user constraint
    families, colliders, self-collision, one-sided distance constraints, rest lengths other than
    the rest positions', hard constraints (compliance 0: Newton's elastic terms are stiffnesses
    1/α), free particles without mass."""

    SOLVER = ""     # the solver's class in newton.solvers
    LABEL = ""
    TAKES: tuple[str, ...] = ("distance", "bending")

    def __init__(self, dt: float, *, substeps: int = 1, iterations: int = 10,
                 gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)):
        _require("newton")
        _require("warp")
        super().__init__(dt, substeps, iterations)
        self.gravity = _check_gravity(gravity)

    def name(self) -> str:
        return f"newton-{self.LABEL}"

    def unmappable(self, model: _core.Model) -> list[str]:
        """What of `model` this adapter cannot give Newton's solver (empty: all of it)."""
        why = _unmappable(model, "Newton", takes=self.TAKES)
        alpha = np.asarray(model.distance["compliance"])
        if np.any(alpha <= 0):
            why.append("hard distance constraints (compliance 0): Newton's elastic terms are stiffnesses 1/α")
        if "bending" in self.TAKES and np.any(np.asarray(model.bending["compliance"]) <= 0):
            why.append("hard bending constraints (compliance 0): Newton's bending is a stiffness 1/α")
        if np.any(np.asarray(model.mass)[np.asarray(model.inv_mass) > 0] <= 0):
            why.append("free particles without mass")
        return why

    def _particles(self, builder: Any, model: _core.Model) -> None:
        x = np.asarray(model.rest_positions, dtype=float)
        w, mass = np.asarray(model.inv_mass), np.asarray(model.mass)
        builder.add_particles(x.tolist(), [(0.0, 0.0, 0.0)] * len(x), np.where(w == 0, 0.0, mass).tolist(),
                              radius=[0.0] * len(x))

    def _springs(self, builder: Any, model: _core.Model) -> None:
        """A spring of stiffness 1/α (N/m) per distance constraint, damping 0; its rest length is
        the rest positions' (``unmappable`` checks csb's is the same)."""
        d = model.distance
        for (i, j), a in zip(np.asarray(d["particles"]).tolist(), np.asarray(d["compliance"]).tolist()):
            builder.add_spring(int(i), int(j), 1.0 / a, 0.0, 0.0)

    def _edges(self, builder: Any, model: _core.Model, ke: np.ndarray) -> None:
        """A bending edge per csb bending constraint, csb's rest angle, stiffness `ke`, damping 0.
        csb's (a, b, c, d) hinge on the edge (a, b) with triangles (c, a, b), (d, b, a) is Newton's
        (i, j, k, l) = (c, d, a, b) with triangles (i, k, l), (j, l, k): Newton's signed dihedral
        angle is then csb's (the same normals and edge direction), so csb's rest angle is passed."""
        q = np.asarray(model.bending["particles"])
        if len(q):
            builder.add_edges(q[:, 2].tolist(), q[:, 3].tolist(), q[:, 0].tolist(), q[:, 1].tolist(),
                              rest=np.asarray(model.bending["rest_angle"], dtype=float).tolist(),
                              edge_ke=np.asarray(ke, dtype=float).tolist(), edge_kd=[0.0] * len(q))

    def _add(self, builder: Any, model: _core.Model) -> None:
        raise NotImplementedError

    def _solver(self, newton: Any, nm: Any) -> Any:
        raise NotImplementedError

    def _count(self, nm: Any, model: _core.Model) -> dict[str, int]:
        return dict(particles=int(nm.particle_count), distance=int(nm.spring_count), bending=int(nm.edge_count),
                    other=int(nm.tri_count + nm.tet_count))

    def _build(self, model: _core.Model) -> None:
        why = self.unmappable(model)
        if why:
            raise _core.ParameterError(f"Newton's {self.SOLVER} cannot simulate this model: " + "; ".join(why))
        import warp as wp

        wp.config.quiet = True
        if hasattr(wp, "LOG_ERROR"):  # Warp 1.19+: the greeting and module loads are log messages
            wp.config.log_level = wp.LOG_ERROR
        import newton

        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=tuple(float(g) for g in self.gravity))
        self._add(builder, model)
        nm = builder.finalize(device="cpu")
        self._wp, self._nm = wp, nm
        self._solve = self._solver(newton, nm)
        self._s0, self._s1 = nm.state(), nm.state()
        self.counts = self._count(nm, model)
        self.pinned = np.flatnonzero(nm.particle_mass.numpy() == 0).tolist()
        self._free = np.asarray(model.inv_mass) > 0
        self._model = model

    def step(self, model: _core.Model, state: _core.State, steps: int = 1, interrupt=None) -> None:
        if self._model is not model:
            self._build(model)
        xn, vn = np.array(state.x, dtype=float), np.array(state.v, dtype=float)
        v_in = np.where(self._free[:, None], vn, 0.0)  # a pin stays (Newton moves a massless particle by its v)
        self._s0.particle_q.assign(xn.astype(np.float32))
        self._s0.particle_qd.assign(v_in.astype(np.float32))
        h = self._dt / self.substeps
        try:
            for s in range(steps):
                for _ in range(self.substeps):
                    self._solve.step(self._s0, self._s1, None, None, h)
                    self._s0, self._s1 = self._s1, self._s0
                x, v = self._s0.particle_q.numpy(), self._s0.particle_qd.numpy()
                if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
                    raise _core.SimulationError(
                        f"Newton's {self.SOLVER} diverged in step {state.step + 1} (t = {state.t:g} s to "
                        f"{state.t + self._dt:g} s): positions not finite; the state is left at the end of the step "
                        f"before")
                xn, vn = x.astype(float), v.astype(float)
                state.t += self._dt
                state.step += 1
                if interrupt is not None and s + 1 < steps and interrupt():
                    break
        finally:
            state.x, state.v = xn, vn


class NewtonXpbdIntegrator(NewtonIntegrator):
    """Newton's SolverXPBD: per sub-step, semi-implicit Euler prediction, then `iterations`
    sweeps in which every constraint's XPBD correction (Macklin et al. 2016, λ kept over the
    sweeps of a sub-step) is computed from the same positions and the corrections are summed
    (Jacobi, not averaged), then v = (x - x0)/h. csb's counterpart is therefore XPBD with
    solver "jacobi-summed": the two agree to float32 (the first step of the hanging cloth and of
    the chain to 2e-3 of a free fall). Summed Jacobi diverges on a stiff cloth at large steps, in
    both codes; that is the method, not the mapping.

    * distance constraint of compliance α (m/N): a spring of ke = 1/α (N/m). Newton's solve_springs
      uses α̃ = 1/(ke h²) = α/h²: exact.
    * bending constraint of compliance α (1/(N m)): a bending edge of ke = 1/(α s), s =
      (|N1| + |N2|)/2 at rest, N1 and N2 the hinge's two triangle normals unnormalised (twice their
      areas, m²). Newton's bending_constraint takes C = θ - θ0 (csb's angle) but the gradient with
      each triangle's N/|N|² replaced by N/|N|, i.e. |N| times csb's; converged, that is the
      potential s θ²/(2 α') with α' = 1/ke. Exact when the two triangles have equal areas (a
      regular grid), approximate otherwise; csb's bending stiffness (PBD's k) is not used.
    """

    SOLVER, LABEL = "SolverXPBD", "xpbd"

    def _add(self, builder: Any, model: _core.Model) -> None:
        self._particles(builder, model)
        self._springs(builder, model)
        q = np.asarray(model.bending["particles"])
        x = np.asarray(model.rest_positions, dtype=float)
        if len(q):
            a, b, c, d = (x[q[:, k]] for k in range(4))
            s = 0.5 * (np.linalg.norm(np.cross(c - a, c - b), axis=1) + np.linalg.norm(np.cross(d - b, d - a), axis=1))
            self._edges(builder, model, 1.0 / (np.asarray(model.bending["compliance"]) * s))

    def _solver(self, newton: Any, nm: Any) -> Any:
        return newton.solvers.SolverXPBD(nm, iterations=self.iterations)

    def counterpart(self) -> _core.Integrator:
        """csb's XPBD with summed Jacobi sweeps, Newton's XPBD's own scheme."""
        return _core.PbdStepper(method="xpbd", dt=self._dt, substeps=self.substeps, iterations=self.iterations,
                                gravity=tuple(self.gravity), solver="jacobi-summed", ordering="sequential", threads=1)


class NewtonVbdIntegrator(NewtonIntegrator):
    """Newton's SolverVBD (Chen et al. 2024, Vertex Block Descent): per sub-step the inertial
    prediction, then `iterations` coloured Gauss-Seidel sweeps, each particle moved by one Newton
    step of its own 3 x 3 block of the backward-Euler objective, then v = (x - x0)/h. Converged, it
    is backward Euler on the same potential, csb's counterpart "backward-euler" (the first step of
    the hanging cloth agrees to 4e-5 of a free fall at 1/120 s and 1000 iterations). Particles are
    coloured with the bending stencils (``ModelBuilder.color(include_bending=True)``): without
    them two particles of one hinge share a colour and the sweeps diverge.

    * distance constraint of compliance α (m/N): a spring of ke = 1/α (N/m), energy ke (l - L)²/2,
      csb's C²/(2α): exact.
    * bending constraint of compliance α (1/(N m)): a bending edge of ke = 1/(α L) (N), L the
      edge's rest length: Newton's dihedral energy is ke L (θ - θ0)²/2, csb's (θ - θ0)²/(2α):
      exact (Newton uses the Gauss-Newton block Hessian ke L ∇θ ∇θᵀ).

    VBD's sweeps converge slowly on stiff springs at long steps: on the 5-link chain (α = 1e-6
    m/N) at 1/30 s no number of iterations brings it to backward Euler (69 % of a fall apart at 10,
    116 % at 5000), at 1/120 s 1000 iterations do (2e-4)."""

    SOLVER, LABEL = "SolverVBD", "vbd"
    CHECK_ITERATIONS = 1000  # the check's sweeps: enough to converge where VBD converges (class docstring)

    def _add(self, builder: Any, model: _core.Model) -> None:
        self._particles(builder, model)
        self._springs(builder, model)
        q = np.asarray(model.bending["particles"])
        x = np.asarray(model.rest_positions, dtype=float)
        if len(q):
            length = np.linalg.norm(x[q[:, 1]] - x[q[:, 0]], axis=1)
            self._edges(builder, model, 1.0 / (np.asarray(model.bending["compliance"]) * length))
        builder.color(include_bending=True)

    def _solver(self, newton: Any, nm: Any) -> Any:
        return newton.solvers.SolverVBD(nm, iterations=self.iterations)

    def for_check(self) -> "NewtonVbdIntegrator":
        return type(self)(self._dt, substeps=self.substeps, iterations=max(self.iterations, self.CHECK_ITERATIONS),
                          gravity=tuple(self.gravity))

    def counterpart(self) -> _core.Integrator:
        """csb's backward Euler, which VBD converges to."""
        return _core.make_integrator("backward-euler", self._dt, substeps=self.substeps, gravity=tuple(self.gravity))


class NewtonStyle3dIntegrator(NewtonIntegrator):
    """Newton's SolverStyle3D: backward Euler by projective-dynamics iterations (`iterations`
    non-linear iterations a sub-step, each a preconditioned CG solve of 10 iterations with the
    constant PD matrix), on a cloth made of a membrane and Bergou's quadratic bending. csb's
    counterpart is backward Euler. Style3D has no springs: csb's cloth is mapped onto its
    continuum, which is an approximation of csb's material, exact only at rest.

    * the cloth: csb's triangles, flat at rest (Style3D measures the membrane against a flat
      panel: the rest positions in the plane of the cloth are the panel's coordinates). Every
      distance constraint must be a triangle edge and every triangle edge a distance constraint.
    * stretch: per triangle, Style3D's Baraff-Witkin membrane (energy A (ku (|F_u| - 1)² + kv (|F_v|
      - 1)² + ks (F_u·F_v)²)/2, N/m) with ku = kv = 1/α and ks = 1/(2α), α the mean compliance of
      the triangle's three edges: the moduli of a square grid of springs of stiffness 1/α along its
      axes (a structural spring per cell and axis; the diagonal's shear, its share of the stretch
      and the coupling it adds between the axes are not mapped).
    * bending of compliance α (1/(N m)) on a hinge: Bergou's energy ke (3/A) |Σ w_j x_j|²/2 (A the
      hinge's rest area, w its cotangent weights) with ke = A / (3 α (w h)²), h the distance of an
      opposite vertex from the edge: for a small fold θ of a flat hinge that is csb's θ²/(2α),
      exact to second order in θ. Rest angles must be 0 (Bergou's energy is zero flat only).
    * Style3D's collision handling is off (``solver.collision = None``).
    * not csb's: Style3D scales every velocity by 0.998 at the end of a step (a fixed damping in its
      update_velocity kernel), so a free fall of n steps is slower than backward Euler's.

    Its iterations converge slowly on a stiff cloth: the first step of the study's hanging cloth
    (6 x 6, α = 1e-4 m/N) is 0.13 of a free fall from backward Euler's at 1/120 s and 100
    iterations, 0.0097 at 1000, 0.00026 at 5000; at 1/30 s, 1.19, 0.51 and 0.030.
    """

    SOLVER, LABEL = "SolverStyle3D", "style3d"
    CHECK_ITERATIONS = 1000

    def unmappable(self, model: _core.Model) -> list[str]:
        why = []
        n = model.num_particles
        tris = np.asarray(model.triangles)
        if len(tris) == 0:
            why.append("no triangles: Style3D simulates a cloth, a membrane of triangles")
        else:
            if len(np.unique(tris)) != n:
                why.append(f"{n - len(np.unique(tris))} particles in no triangle")
            pairs = {tuple(sorted(p)) for p in np.asarray(model.distance["particles"]).tolist()}
            edges = {tuple(sorted(e)) for t in tris.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
            if pairs - edges:
                why.append(f"{len(pairs - edges)} distance constraints on no triangle edge (Style3D has no springs)")
            if edges - pairs:
                why.append(f"{len(edges - pairs)} triangle edges without a distance constraint (Style3D's membrane "
                           f"stretches every triangle)")
            if self._panel(model) is None:
                why.append("a cloth not flat at rest, or its triangles not wound alike (Style3D measures the "
                           "membrane against a flat panel)")
        if np.any(np.abs(np.asarray(model.bending["rest_angle"])) > 1e-9):
            why.append("bending rest angles other than 0 (Style3D's bending is zero only flat)")
        return why + super().unmappable(model)

    @staticmethod
    def _panel(model: _core.Model) -> np.ndarray | None:
        """The rest positions in the cloth's plane (m), the triangles' winding positive; None when
        the cloth is not flat or its triangles are not wound alike."""
        x = np.asarray(model.rest_positions, dtype=float)
        tris = np.asarray(model.triangles)
        c = x - x.mean(axis=0)
        _, sv, vt = np.linalg.svd(c, full_matrices=False)
        size = float(np.max(np.ptp(x, axis=0))) if len(x) else 0.0
        if len(sv) < 3 or sv[2] > 1e-9 * max(size, 1e-300) * math.sqrt(len(x)):
            return None
        p = c @ vt[:2].T
        e1, e2 = p[tris[:, 1]] - p[tris[:, 0]], p[tris[:, 2]] - p[tris[:, 0]]
        area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        if np.all(area < 0):
            p[:, 1] *= -1
        elif not np.all(area > 0):
            return None
        return p

    def _add(self, builder: Any, model: _core.Model) -> None:
        import warp as wp
        from newton.solvers import SolverStyle3D, style3d

        SolverStyle3D.register_custom_attributes(builder)
        x = np.asarray(model.rest_positions, dtype=float)
        tris = np.asarray(model.triangles)
        d = model.distance
        alpha = {tuple(sorted(p)): a for p, a in zip(np.asarray(d["particles"]).tolist(),
                                                     np.asarray(d["compliance"]).tolist())}
        a_tri = [np.mean([alpha[tuple(sorted(e))] for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))])
                 for t in tris.tolist()]
        style3d.add_cloth_mesh(builder, pos=(0.0, 0.0, 0.0), rot=wp.quat_identity(), vel=(0.0, 0.0, 0.0),
                               vertices=x.tolist(), indices=tris.ravel().tolist(), density=1.0,
                               panel_verts=self._panel(model).tolist(),
                               tri_aniso_ke=[(1.0 / a, 1.0 / a, 0.5 / a) for a in a_tri], edge_kd=0.0, tri_kd=0.0,
                               particle_radius=0.0)
        w, mass = np.asarray(model.inv_mass), np.asarray(model.mass)
        builder.particle_mass[:] = np.where(w == 0, 0.0, mass).tolist()

    def _solver(self, newton: Any, nm: Any) -> Any:
        # Bending stiffness per hinge (class docstring), set before the solver builds its PD matrix.
        model = self._mapping_model
        x = np.asarray(model.rest_positions, dtype=float)
        edges = nm.edge_indices.numpy()
        cot = nm.style3d.edge_bending_cot.numpy()
        area = nm.style3d.edge_rest_area.numpy()
        q = np.asarray(model.bending["particles"])
        alpha = {tuple(sorted(h[:2])): a for h, a in zip(q.tolist(), np.asarray(model.bending["compliance"]).tolist())}
        props = nm.edge_bending_properties.numpy()
        props[:] = 0.0
        self._hinges = 0
        for e, (o0, o1, v0, v1) in enumerate(edges.tolist()):
            a = alpha.get(tuple(sorted((v0, v1))))
            if a is None or o0 < 0 or o1 < 0:
                continue
            u = x[v1] - x[v0]
            h = np.linalg.norm(np.cross(x[o1] - x[v0], u)) / np.linalg.norm(u)
            w1 = -(cot[e][1] + cot[e][3])
            props[e, 0] = area[e] / (3.0 * a * (w1 * h) ** 2)
            self._hinges += 1
        nm.edge_bending_properties.assign(props)
        config = newton.solvers.SolverStyle3D.Config(iterations=self.iterations)
        solver = newton.solvers.SolverStyle3D(nm, config=config)
        solver.collision = None
        return solver

    def _build(self, model: _core.Model) -> None:
        self._mapping_model = model
        super()._build(model)

    def _count(self, nm: Any, model: _core.Model) -> dict[str, int]:
        """The distance constraints are counted as the membrane's triangle edges they lie on, the
        bending ones as the hinges given a stiffness."""
        edges = {tuple(sorted(e)) for t in nm.tri_indices.numpy().tolist()
                 for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
        pairs = [tuple(sorted(p)) for p in np.asarray(model.distance["particles"]).tolist()]
        return dict(particles=int(nm.particle_count), distance=sum(p in edges for p in pairs), bending=self._hinges,
                    other=int(nm.spring_count + nm.tet_count))

    def for_check(self) -> "NewtonStyle3dIntegrator":
        return type(self)(self._dt, substeps=self.substeps, iterations=max(self.iterations, self.CHECK_ITERATIONS),
                          gravity=tuple(self.gravity))

    def counterpart(self) -> _core.Integrator:
        """csb's backward Euler, which Style3D's iterations solve for."""
        return _core.make_integrator("backward-euler", self._dt, substeps=self.substeps, gravity=tuple(self.gravity))


@dataclass
class Conformance:
    """The outcome of :func:`conformance`: ``ok`` and, when not, the checks that failed."""

    peer: str
    ok: bool
    failures: list[str] = field(default_factory=list)
    figures: dict[str, Any] = field(default_factory=dict)

    def __str__(self) -> str:
        return f"{self.peer}: conforms" if self.ok else f"{self.peer}: does not conform: " + "; ".join(self.failures)


def conformance(peer: Any, model: _core.Model, *, tolerance: float = 0.2) -> Conformance:
    """Checks that `peer` (an adapter) simulates `model`: it maps all of it; the same particle and
    constraint counts; the same pins; and one quiet step from rest, dt and sub-steps as the peer's,
    iterations enough to converge (``peer.for_check()``), that agrees with csb's method of the same
    family (``peer.counterpart()``) to within `tolerance` times the step's free fall.

    What it is for are mapping errors: a wrong gravity, mass or pin moves a particle by a fall or
    more. Two codes' formulations of the same constraint differ by less, and the check lets that
    through and reports it (``figures``): pypbd's dihedral bending and csb's, converged, differ by
    up to 5.5 % of the fall on a cloth with rigid bending (the hanging cloth set-up at 1/30 to 1/480
    s), 0.1 to 4.9 % on the bundled cloth (bending k = 0.1, 8 to 32 squares). MuJoCo's
    semi-implicit Euler and csb's symplectic Euler agree to round-off, Newton's XPBD and csb's
    summed-Jacobi XPBD to float32. Hence 20 %."""
    name = peer.name()
    peer = peer.for_check()
    why = peer.unmappable(model)
    if why:
        return Conformance(name, False, [f"cannot map: {w}" for w in why])
    start = model.initial_state()
    state = model.initial_state()
    try:
        peer.step(model, state, 1)
    except Exception as e:  # noqa: BLE001 — a peer's failure is what the check reports
        return Conformance(name, False, [f"the first step raised {type(e).__name__}: {e}"])
    failures = []
    counts = peer.counts
    expect = dict(particles=model.num_particles, distance=len(np.asarray(model.distance["rest_length"])),
                  bending=len(np.asarray(model.bending["rest_angle"])), other=0)
    for key, want in expect.items():
        if counts.get(key) != want:
            failures.append(f"{key}: {counts.get(key)} in the peer, {want} in csb")
    pinned = np.flatnonzero(np.asarray(model.inv_mass) == 0).tolist()
    if list(peer.pinned) != pinned:
        failures.append(f"pins: {len(peer.pinned)} in the peer, {len(pinned)} in csb")
    ours = model.initial_state()
    diverged = ""
    try:
        peer.counterpart().step(model, ours, 1)
    except _core.SimulationError as e:  # csb's own method diverges at these settings
        diverged = f" ({e})"
        ours.x = np.full_like(np.asarray(ours.x), np.nan)
    h, n = peer.dt() / peer.substeps, peer.substeps
    fall = 9.81 * h * h * n * (n + 1) / 2  # from rest, n sub-steps of symplectic Euler: g h² (1 + 2 + ... + n)
    gap = float(np.max(np.abs(np.asarray(state.x) - np.asarray(ours.x))))
    moved = float(np.max(np.abs(np.asarray(state.x) - np.asarray(start.x))))
    figures = dict(first_step_gap_m=gap, fall_m=fall, moved_m=moved)
    ours_moved = float(np.max(np.abs(np.asarray(ours.x) - np.asarray(start.x))))
    if diverged:
        failures.append(f"cannot check the first step: csb's {peer.counterpart().name()} diverges in it{diverged[:200]}"
                        f"{'...' if len(diverged) > 200 else ''} (unstable at these settings: take a smaller dt)")
    elif not (np.all(np.isfinite(ours.x)) and ours_moved <= 10 * fall):
        failures.append(f"cannot check the first step: csb's {peer.counterpart().name()} moves the model "
                        f"{ours_moved:.3g} m in it, far beyond a fall of {fall:.3g} m (unstable at these settings: "
                        f"take a smaller dt)")
    elif not np.all(np.isfinite(state.x)):
        failures.append("the first step is not finite")
    elif gap > tolerance * fall:
        failures.append(f"the first step differs from csb's by {gap:.3g} m, more than {tolerance:g} of the "
                        f"step's free fall ({fall:.3g} m)")
    return Conformance(name, not failures, failures, figures)
