"""Self-collision torture scenes and an independent intersection checker run at every sub-step.

The scenes (SI units; XPBD; every cloth self-colliding through ModelBuilder.enable_self_collision):

* ``twist``: a square cloth held by two opposite edges, the edges turned in opposite directions
  about the cloth's axis at π/3 rad/s each for 10 s (NVIDIA Newton's cloth-twist example), by the
  stepper's kinematic grabs, one per held particle;
* ``rotating_sphere``: a cloth dropped onto a sphere turning about the vertical axis, with
  friction, turned by the stepper's ``move_collider``;
* ``stack``: ten cloth layers a few cm apart, in one self-colliding group, dropped on the ground;
* ``funnel``: a cloth dragged by its centre through a funnel (a triangle-mesh frustum) whose hole
  is narrower than the cloth;
* ``soft_drape``: the bundled cloth_sphere scene (the soft bending of a drapier cloth,
  compliance 1000 1/(N m)), with the coloured sweep and the sequential one.

:func:`run` steps a scene one sub-step at a time (a PbdStepper of ``substeps=1`` whose dt is the
scene's sub-step: without grabs, the same positions to the bit as the scene's stepper of
``substeps`` sub-steps a frame, tests/test_torture.py checks it; the hands of grabs are put on
their path at the end of every sub-step, where that stepper would move them along the chord of
a frame), and after every sub-step asks the IPC Toolkit (``ipctk.has_intersections``, Ferguson
et al.'s, independent of csb's geometry) whether any edge of the cloth meets one of its
triangles; where it does, csb's exact count of crossing edge-triangle pairs (that of
:func:`csb.studies.collisions.self_intersections`) says how many. It also keeps the deepest
contact violation the stepper reports (``contacts()["max_penetration"]``: colliders and
self-contacts, thickness included), the self-collision fail-safe activations
(``contacts().get("self_failsafe", 0)``: 0 where the stepper has no fail-safe), and the wall time
of the stepping alone per frame of 1/60 s, beside the same scene's without self-collision.

    python -m csb.studies.torture [scene ...] [--quick]
"""

from __future__ import annotations

import math
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .. import _core
from ..model import ModelBuilder
from .collisions import segments_cross_triangles, self_intersections

G = (0.0, -9.81, 0.0)   # m/s²
FRAME = 1 / 60          # s, one frame at 60 Hz: the scenes' time step dt and the video's frame
SCENES = ("twist", "rotating_sphere", "stack", "funnel", "soft_drape", "soft_drape_sequential")


@dataclass
class TortureScene:
    """A scene to torture self-collision with: the model with self-collision and the same model
    without (the control), the stepper's settings, and the prescribed motion of the grabbed
    particles, if any."""

    name: str
    description: str
    model: _core.Model                  # self-collision on
    control: _core.Model                # the same model, self-collision off
    seconds: float                      # s, simulated
    substeps: int                       # sub-steps per frame of FRAME s
    settings: dict[str, Any] = field(default_factory=dict)   # PbdStepper keywords but dt and substeps
    held: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))   # grabbed particles
    hands: Callable[[float], np.ndarray] | None = None       # t (s) -> (len(held), 3) targets, m
    colliders: Callable[[Any, _core.Model, float], None] | None = None   # (stepper, model, t (s)): poses at t

    @property
    def num_particles(self) -> int:
        return int(self.model.num_particles)

    @property
    def frames(self) -> int:
        return int(round(self.seconds / FRAME))

    @property
    def substep(self) -> float:
        """h = FRAME / substeps, s"""
        return FRAME / self.substeps


def _edges(triangles: np.ndarray) -> np.ndarray:
    """The unique edges of a triangle mesh, each as (low, high) particle index, sorted."""
    t = np.asarray(triangles, np.int64)
    return np.unique(np.sort(t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)


def _pair(build: Callable[[bool], _core.Model]) -> tuple[_core.Model, _core.Model]:
    return build(True), build(False)


# ------------------------------------------------------------------------------------ the scenes


def twist(*, n: int = 50, size: float = 1.0, seconds: float = 10.0, omega: float = math.pi / 3,
          substeps: int = 20, iterations: int = 1, thickness: float | None = None) -> TortureScene:
    """An ``n`` x ``n`` cloth of ``size`` m side (0.2 kg/m², stretch compliance 1e-6 m/N and
    bending 10 1/(N m), cloth_sphere's cloth) in the x-z plane at y = 0, held by its two edges at
    x = ±size/2, which turn about the x axis in opposite directions at ``omega`` rad/s each (π/3,
    NVIDIA Newton's cloth-twist example) for ``seconds`` s (10: 3.3 turns of one edge against the
    other), under gravity. Each held particle is a kinematic grab whose hand is on its rotating
    edge. Self-collision thickness ``thickness`` m (default a quarter of the edge length, as
    cloth_sphere's 1 cm against its 4.1 cm edges: under the edge length, so that neighbours are no
    contacts). ``substeps`` (20) sub-steps of ``iterations`` (1) XPBD sweeps per 1/60 s:
    cloth_sphere's small steps, fewer of them (its 30 are for a 30 x 30 cloth stopped by a sphere
    at 3 m/s; here the held edges move the cloth at most omega size/2 = 0.52 m/s)."""
    edge = size / (n - 1)
    h_self = edge / 4 if thickness is None else thickness
    mesh = _core.cloth_grid(size, size, n, n, "xz", [0.0, 0.0, 0.0])
    x = np.asarray(mesh.vertices, float)
    held = np.where(np.isclose(np.abs(x[:, 0]), size / 2, rtol=0, atol=1e-9 * size))[0]
    sense = np.sign(x[held, 0])     # +1: the edge at +size/2 turns by -omega t, the other by +omega t
    rest = x[held]

    def build(self_collision: bool) -> _core.Model:
        b = ModelBuilder()
        inst = b.add_mesh(mesh, density=0.2, stretch_compliance=1e-6, bending_stiffness=1.0, bending_compliance=10.0)
        if self_collision:
            b.enable_self_collision(inst.group, h_self)
        return b.build()

    def hands(t: float) -> np.ndarray:
        a = -sense * omega * min(t, seconds)   # rad, each edge's turn about +x
        c, s = np.cos(a), np.sin(a)
        return np.column_stack([rest[:, 0], rest[:, 1] * c - rest[:, 2] * s, rest[:, 1] * s + rest[:, 2] * c])

    model, control = _pair(build)
    return TortureScene("twist", f"{n} x {n} cloth, edges turned ±{omega:.3g} rad/s for {seconds:g} s", model, control,
                        seconds, substeps, dict(method="xpbd", iterations=iterations), held.astype(np.int64), hands)


def rotating_sphere(*, n: int = 30, size: float = 1.2, seconds: float = 3.0, spin: float = math.pi,
                    substeps: int = 30, iterations: int = 1) -> TortureScene:
    """cloth_sphere's cloth (``n`` x ``n``, ``size`` m, 0.5 m above the centre of a 0.3 m sphere,
    friction 0.4 / 0.3, and the ground at y = -0.6 m) dropped onto the sphere, which turns about
    the vertical axis at ``spin`` rad/s (π: a turn in 2 s), so that friction winds the cloth
    round it, for ``seconds`` s. The sphere turns through the stepper's moving colliders: before
    each sub-step, ``PbdStepper.move_collider(model, 0, R_y(spin t), 0)`` gives the pose it
    reaches at the sub-step's end t (a turn about its own centre, the origin, so it stays where
    it is and only its surface moves). Sub-steps and iterations are cloth_sphere's (30 x 1 per
    1/60 s)."""
    def build(self_collision: bool) -> _core.Model:
        b = ModelBuilder()
        inst = b.add_mesh(_core.cloth_grid(size, size, n, n, "xz", [0.0, 0.5, 0.0]), density=0.2,
                          stretch_compliance=1e-6, bending_stiffness=1.0, bending_compliance=10.0, thickness=0.005)
        if self_collision:
            b.enable_self_collision(inst.group, 0.01)
        b.add_sphere(center=[0.0, 0.0, 0.0], radius=0.3, friction_static=0.4, friction_kinetic=0.3, name="ball")
        b.add_plane(point=[0.0, -0.6, 0.0], normal=[0.0, 1.0, 0.0], friction_static=0.6, name="ground")
        return b.build()

    def colliders(stepper, model: _core.Model, t: float) -> None:
        a = spin * t   # rad about +y
        rotation = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
        stepper.move_collider(model, 0, rotation, (0.0, 0.0, 0.0))

    model, control = _pair(build)
    return TortureScene("rotating_sphere", f"{n} x {n} cloth on a sphere turning at {spin:.3g} rad/s", model, control,
                        seconds, substeps, dict(method="xpbd", iterations=iterations), colliders=colliders)


def stack(*, layers: int = 10, n: int = 20, size: float = 0.5, gap: float = 0.03, height: float = 0.1,
          seconds: float = 3.0, substeps: int = 20, iterations: int = 1) -> TortureScene:
    """``layers`` (10) cloths of ``n`` x ``n`` (20) particles and ``size`` m (0.5) side, ``gap`` m
    (3 cm) apart, the lowest ``height`` m (0.1) above the ground, each turned 9° further about the
    vertical than the one below (so that no two grids lie vertex on vertex), dropped on the ground
    (friction 0.5) for ``seconds`` s: the layers land one on another at up to 1.7 m/s. All the
    layers are one group, because self-collision is between a group's particles and its own
    triangles (csb has no contacts between groups). Cloth as cloth_sphere's (0.2 kg/m², 1e-6 m/N,
    10 1/(N m)), 5 mm thick against the ground; self-collision thickness 5 mm, a fifth of the
    2.6 cm edges and a sixth of the gap. ``substeps`` (20) of ``iterations`` (1) per 1/60 s: at
    1.7 m/s a particle moves 1.4 mm a sub-step, under the thickness."""
    grid = _core.cloth_grid(size, size, n, n, "xz", [0.0, 0.0, 0.0])
    v0 = np.asarray(grid.vertices, float)
    tris = np.asarray(grid.triangles, np.int64)

    def build(self_collision: bool) -> _core.Model:
        b = ModelBuilder()
        group = b.add_group("layers")
        for k in range(layers):
            a = math.radians(9.0 * k)
            rot = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
            v = v0 @ rot.T + (0.0, height + gap * k, 0.0)
            b.add_mesh(_core.Mesh(v, tris, name=f"layer {k}"), group=group, density=0.2, stretch_compliance=1e-6,
                       bending_stiffness=1.0, bending_compliance=10.0, thickness=0.005)
        if self_collision:
            b.enable_self_collision(group, 0.005)
        b.add_plane(point=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], friction_static=0.5, friction_kinetic=0.5,
                    name="ground")
        return b.build()

    model, control = _pair(build)
    return TortureScene("stack", f"{layers} layers of {n} x {n}, one group, dropped on the ground", model, control,
                        seconds, substeps, dict(method="xpbd", iterations=iterations))


def funnel_mesh(*, top: float = 0.35, hole: float = 0.06, depth: float = 0.4, y: float = 0.0,
                segments: int = 32) -> _core.Mesh:
    """The side of a frustum about the y axis, open at both ends: radius ``top`` m at
    y = ``y``, ``hole`` m at y = ``y`` - ``depth``; ``segments`` quads of two triangles round it."""
    a = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    ring = np.column_stack([np.cos(a), np.zeros_like(a), np.sin(a)])
    v = np.concatenate([ring * top + (0.0, y, 0.0), ring * hole + (0.0, y - depth, 0.0)])
    k = np.arange(segments)
    k1 = (k + 1) % segments
    tris = np.concatenate([np.column_stack([k, k1, segments + k]), np.column_stack([k1, segments + k1, segments + k])])
    return _core.Mesh(v, tris, name="funnel")


def funnel(*, n: int = 30, size: float = 0.8, seconds: float = 4.0, speed: float = 0.4, substeps: int = 20,
           iterations: int = 1) -> TortureScene:
    """An ``n`` x ``n`` (30) cloth of ``size`` m (0.8) side, 0.2 m above a funnel (funnel_mesh: a
    triangle-mesh collider, 0.7 m across at the top, a hole 0.12 m across 0.4 m lower, friction
    0.2), its centre particle grabbed and drawn straight down the funnel's axis at ``speed`` m/s
    (0.4) under gravity for ``seconds`` s (4: the centre ends 1.4 m lower, 1 m below the hole):
    the cloth, 6.7 times wider than the hole, is dragged through it in folds. Cloth as
    cloth_sphere's, 5 mm thick against the funnel; self-collision thickness 6 mm, a quarter of
    the 2.8 cm edges. ``substeps`` (20) of ``iterations`` (1) per 1/60 s."""
    mesh = _core.cloth_grid(size, size, n, n, "xz", [0.0, 0.2, 0.0])
    x = np.asarray(mesh.vertices, float)
    centre = int(np.argmin(np.sum((x - (0.0, 0.2, 0.0)) ** 2, axis=1)))

    def build(self_collision: bool) -> _core.Model:
        b = ModelBuilder()
        inst = b.add_mesh(mesh, density=0.2, stretch_compliance=1e-6, bending_stiffness=1.0, bending_compliance=10.0,
                          thickness=0.005)
        if self_collision:
            b.enable_self_collision(inst.group, 0.006)
        b.add_collider_mesh(funnel_mesh(), friction_static=0.2, friction_kinetic=0.2, name="funnel")
        return b.build()

    start = x[centre]

    def hands(t: float) -> np.ndarray:
        return (start - (0.0, speed * min(t, seconds), 0.0))[None, :]

    model, control = _pair(build)
    return TortureScene("funnel", f"{n} x {n} cloth drawn through a funnel at {speed:g} m/s", model, control, seconds,
                        substeps, dict(method="xpbd", iterations=iterations), np.array([centre], np.int64), hands)


def soft_drape(*, ordering: str = "coloured", seconds: float = 3.0, bending_compliance: float = 1000.0) -> TortureScene:
    """The bundled cloth_sphere scene (30 x 30 XPBD cloth, 30 sub-steps of one iteration, 1 cm
    self-collision thickness) with the bending compliance ``bending_compliance`` 1/(N m) (1000: a
    drapier cloth) and the ``ordering`` sweep ('coloured', the default, or 'sequential': the
    constraints in build order), for ``seconds`` s (3, the scene's duration). The sequential
    sweep is tests/test_self_collision.py's expected failure (the hem whipping at 60 % strain)."""
    from ..scene import bundled_scenes, load_scene

    if ordering not in ("coloured", "sequential"):
        raise _core.ParameterError(f"ordering must be 'coloured' or 'sequential', got {ordering!r}")
    text = bundled_scenes()["cloth_sphere"].read_text(encoding="utf-8")
    text = re.sub(r"bending = \{ compliance = [0-9.e+-]+ \}", f"bending = {{ compliance = {bending_compliance!r} }}",
                  text)
    text = re.sub(r"\[solver\]", f'[solver]\nordering = "{ordering}"', text)
    control_text = re.sub(r"(?m)^self_collision = .*$", "", text)
    sims = []
    with tempfile.TemporaryDirectory() as d:
        for k, t in enumerate((text, control_text)):
            path = Path(d) / f"soft_drape_{k}.toml"
            path.write_text(t, encoding="utf-8")
            sims.append(load_scene(path).build())
    sim, ctl = sims
    if not np.asarray(sim.model.self_collision_thickness).any() or np.asarray(ctl.model.self_collision_thickness).any():
        raise _core.Error("cloth_sphere's self-collision line was not where soft_drape expects it")
    s = sim.stepper.settings
    settings = dict(method=s.method, iterations=s.iterations, ordering=s.ordering, xpbd_damping=s.xpbd_damping,
                    damping=s.damping, solver=s.solver, gravity=tuple(float(g) for g in s.gravity))
    name = "soft_drape" if ordering == "coloured" else f"soft_drape_{ordering}"
    return TortureScene(name, f"cloth_sphere, bending 1000 1/(N m), {ordering} sweep", sim.model, ctl.model, seconds,
                        s.substeps, settings)


def build(name: str, *, quick: bool = False) -> TortureScene:
    """A scene by name (SCENES), at full size or, ``quick``, small and short (tests and the main
    job's quick tier: about a second of simulated time on cloths of a few hundred particles)."""
    if name == "twist":
        return twist(n=16, seconds=1.5) if quick else twist()
    if name == "rotating_sphere":
        return rotating_sphere(n=16, seconds=1.0) if quick else rotating_sphere()
    if name == "stack":
        return stack(layers=4, n=10, seconds=1.0) if quick else stack()
    if name == "funnel":
        return funnel(n=16, seconds=1.5) if quick else funnel()
    if name == "soft_drape":
        return soft_drape(seconds=0.75) if quick else soft_drape()
    if name == "soft_drape_sequential":
        return soft_drape(ordering="sequential", seconds=0.75) if quick else soft_drape(ordering="sequential")
    raise _core.ParameterError(f"no torture scene {name!r}; the scenes are {', '.join(SCENES)}")


# ------------------------------------------------------------------------------------ the checker


class IntersectionChecker:
    """The independent checker: ipctk's (Ferguson et al., the IPC Toolkit) has_intersections on
    the model's triangles and their edges, and csb's exact count of crossing edge-triangle pairs
    where it says yes. Edges and triangles are read once (the topology does not change)."""

    def __init__(self, model: _core.Model):
        import ipctk

        self._ipctk = ipctk
        self.triangles = np.asarray(model.triangles, np.int64)
        self.edges = _edges(self.triangles)
        x = np.asfortranarray(np.asarray(model.initial_state().x, float))
        self._edges32 = np.asfortranarray(self.edges, np.int32)
        self._triangles32 = np.asfortranarray(self.triangles, np.int32)
        self._mesh = ipctk.CollisionMesh(x, self._edges32, self._triangles32)

    def any(self, x: np.ndarray) -> bool:
        """Whether some edge crosses some triangle (ipctk.has_intersections)."""
        return bool(self._ipctk.has_intersections(self._mesh, np.asfortranarray(np.asarray(x, float))))

    def count(self, x: np.ndarray) -> int:
        """The crossing edge-triangle pairs: csb.studies.collisions.self_intersections's count,
        its exact test (segments_cross_triangles) on the pairs with overlapping boxes and no
        shared vertex, those pairs found by ipctk's hash grid (C++) instead of candidate_pairs'
        numpy grid, which takes seconds on the stacked layers (ten layers share every cell);
        a crossing pair's boxes overlap, so any such broad phase gives the same count
        (tests/test_torture.py checks it against self_intersections)."""
        x = np.asarray(x, float)
        broad = self._ipctk.HashGrid()
        broad.build(np.asfortranarray(x), self._edges32, self._triangles32, 0.0)
        found = broad.detect_edge_face_candidates()
        if not found:
            return 0
        pairs = np.array([(c.edge_id, c.face_id) for c in found], np.int64)
        e, t = self.edges[pairs[:, 0]], self.triangles[pairs[:, 1]]
        apart = np.all(e[:, :, None] != t[:, None, :], axis=(1, 2))
        e, t = e[apart], t[apart]
        return int(segments_cross_triangles(x[e[:, 0]], x[e[:, 1]], x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]).sum())

    def count_by_grid(self, x: np.ndarray) -> int:
        """The same count by csb.studies.collisions.self_intersections (numpy broad phase)."""
        return self_intersections(np.asarray(x, float), self.edges, self.triangles)


# ------------------------------------------------------------------------------------ the runner


def _stepper(scene: TortureScene, model: _core.Model, state: _core.State):
    """A PbdStepper stepping one sub-step a call, with a kinematic grab on each held particle."""
    settings = dict(scene.settings)
    settings.setdefault("gravity", G)
    stepper = _core.PbdStepper(dt=scene.substep, substeps=1, **settings)
    handles = []
    if len(scene.held):
        assert scene.hands is not None
        for p, target in zip(scene.held, scene.hands(0.0)):
            handles.append(stepper.grab(model, state, int(p), target))
    return stepper, handles


def run(scene: TortureScene, *, self_collision: bool = True, check: str = "substep", count: str = "substep",
        record: bool = False, progress: bool = False) -> dict[str, Any]:
    """Steps ``scene`` for its time, one sub-step a call, with self-collision (or its control
    without) and, ``check`` = 'substep', the checker after every sub-step ('frame': after every
    frame only; 'none': never). ``count`` = 'substep' counts the crossing pairs at every checked
    sub-step that intersects, 'frame' only at those that end a frame (ipctk's yes or no is still
    asked at every checked sub-step): on the full-size scenes a count takes 0.1 s, ipctk's
    verdict 0.01 s. ``progress`` prints a line every simulated second. Returns:

    - substeps, checked: sub-steps stepped and checked;
    - intersecting: checked sub-steps (or frames) where ipctk finds the cloth intersecting itself;
      first_intersection: the time (s) of the first (None: never); crossing: those of them where
      some edge properly crosses a triangle (csb's count > 0), max_crossings: the most crossing
      edge-triangle pairs at one of them. ipctk also counts an edge touching a triangle or lying
      in its plane across it (its test is conservative there), which proper crossings do not:
      two layers pressed into one plane (the stack without self-collision, every layer projected
      onto the ground's contact height) intersect for ipctk with 0 crossings;
    - max_penetration: m, the largest contacts()["max_penetration"] over the sub-steps (the
      deepest collider contact left at the end of a sub-step, thickness included);
    - failsafe: the sum over the sub-steps of contacts().get("self_failsafe", 0);
    - frame_seconds: wall time (s) of the stepping alone in each frame of 1/60 s (the checker, the
      hands and the contact queries not counted), and its median frame_cost;
    - history: at each checked sub-step, its end time t (s), ipctk's verdict and the crossings
      (-1: not counted);
    - frames: with ``record``, the positions at the end of every frame (and the start), (F+1, N, 3);
    - final: the positions at the end.
    """
    if check not in ("substep", "frame", "none"):
        raise _core.ParameterError(f"check must be 'substep', 'frame' or 'none', got {check!r}")
    if count not in ("substep", "frame"):
        raise _core.ParameterError(f"count must be 'substep' or 'frame', got {count!r}")
    model = scene.model if self_collision else scene.control
    state = model.initial_state()
    stepper, handles = _stepper(scene, model, state)
    checker = IntersectionChecker(model) if check != "none" else None
    h = scene.substep
    intersecting = crossing = checked = max_crossings = failsafe = 0
    first = None
    penetration = 0.0
    frame_seconds = []
    history = []   # (t, ipctk's verdict, crossings) at each checked sub-step
    frames = [np.array(state.x)] if record else []
    for f in range(scene.frames):
        spent = 0.0
        for k in range(scene.substeps):
            t = (f * scene.substeps + k + 1) * h   # s, at the end of this sub-step
            if handles:
                assert scene.hands is not None
                for handle, target in zip(handles, scene.hands(t)):
                    stepper.move_grab(handle, target)
            if scene.colliders is not None:
                scene.colliders(stepper, model, t)
            start = time.perf_counter()
            stepper.step(model, state)
            spent += time.perf_counter() - start
            c = stepper.contacts()
            penetration = max(penetration, float(c["max_penetration"]))
            failsafe += int(c.get("self_failsafe", 0))
            if checker is not None and (check == "substep" or k == scene.substeps - 1):
                checked += 1
                x = np.asarray(state.x)
                n = -1   # not counted
                hit = checker.any(x)
                if hit:
                    intersecting += 1
                    if count == "substep" or k == scene.substeps - 1:
                        n = checker.count(x)
                        crossing += n > 0
                        max_crossings = max(max_crossings, n)
                    if first is None:
                        first = t
                history.append((t, hit, n if hit else 0))
        frame_seconds.append(spent)
        if progress and (f + 1) % 60 == 0:
            which = scene.name + ("" if self_collision else " (control)")
            print(f"  {which}: {(f + 1) * FRAME:.0f} s of {scene.seconds:g}, {sum(frame_seconds):.0f} s stepping, "
                  f"{intersecting} intersecting sub-steps", flush=True)
        if record:
            frames.append(np.array(state.x))
    return dict(scene=scene.name, self_collision=self_collision, particles=scene.num_particles,
                substeps=scene.frames * scene.substeps, checked=checked, check=check, count=count,
                intersecting=intersecting,
                crossing=crossing, max_crossings=max_crossings, first_intersection=first, max_penetration=penetration,
                failsafe=failsafe, frame_seconds=frame_seconds,
                frame_cost=float(np.median(frame_seconds)) if frame_seconds else 0.0,
                history=np.array(history, dtype=[("t", float), ("intersecting", bool), ("crossings", np.int64)]),
                frames=np.array(frames) if record else None, final=np.array(state.x))


def measure(scene: TortureScene, *, record: bool = False, count: str = "substep",
            progress: bool = False) -> dict[str, Any]:
    """The scene's figures: :func:`run` with self-collision, checked at every sub-step, and its
    control without self-collision, checked at frame ends (it shows whether the scene needs
    self-collision at all) and timed the same way (one sub-step a call on both sides, so that the
    ratio compares like with like). Keys: those of run()'s self-collision run, plus
    control_intersecting (frames), control_crossing, control_checked, control_max_crossings, control_frame_cost and
    cost_ratio (frame_cost / control_frame_cost)."""
    on = run(scene, record=record, count=count, progress=progress)
    off = run(scene, self_collision=False, check="frame", progress=progress)
    return dict(on, control_intersecting=off["intersecting"], control_crossing=off["crossing"],
                control_checked=off["checked"],
                control_max_crossings=off["max_crossings"], control_frame_cost=off["frame_cost"],
                cost_ratio=on["frame_cost"] / off["frame_cost"] if off["frame_cost"] > 0 else math.inf)


# ------------------------------------------------------------------------------------ video


class _Replay(_core.Integrator):
    """An Integrator that puts the recorded positions back, one frame a step: the viewer draws a
    recorded run with it."""

    def __init__(self, frames: np.ndarray):
        super().__init__()
        self._frames = frames
        self._next = 1

    def name(self) -> str:
        return "replay"

    def dt(self) -> float:
        return FRAME

    def step(self, model, state, steps=1, interrupt=None):
        for _ in range(steps):
            k = min(self._next, len(self._frames) - 1)
            state.x = self._frames[k]
            state.t += FRAME
            state.step += 1
            self._next += 1


def render_video(scene: TortureScene, frames: np.ndarray, out: str | Path, *, width: int = 640,
                 height: int = 400) -> dict[str, Any]:
    """Draws recorded positions (``frames``, (F+1, N, 3), one a frame of 1/60 s, as run(record=
    True) returns) offscreen with the viewer and writes ``<out>/<scene>.mp4`` (ffmpeg) and the
    last frame as ``<out>/<scene>_NNNNN.png``. Returns the viewer's capture record (video, its
    note, images). Needs the viewer in the build (csb.view's viewer_available)."""
    from ..view import viewer_module

    Viewer = viewer_module().Viewer
    frames = np.asarray(frames, float)
    state = scene.model.initial_state()
    state.x = frames[0]
    v = Viewer(scene.model, state, _Replay(frames), width=width, height=height, offscreen=True, overlay=False,
               title=f"csb - {scene.name}", gravity=G)
    try:
        return v.capture(frames=len(frames) - 1, directory=str(out), every=len(frames), prefix=scene.name, video=True)
    finally:
        v.close()


# ------------------------------------------------------------------------------------ the table


COLUMNS = ("scene", "particles", "sub-steps checked", "intersecting sub-steps (ipctk)", "with crossings",
           "max crossings", "first intersection (s)", "max penetration (m)", "fail-safe",
           "control: intersecting frames", "ms/frame with", "ms/frame without", "ratio")


def row(r: dict[str, Any]) -> dict[str, Any]:
    """One line of the table from measure()'s figures."""
    return {"scene": r["scene"], "particles": r["particles"], "sub-steps checked": r["checked"],
            "intersecting sub-steps (ipctk)": r["intersecting"],
            "with crossings": r["crossing"] if r["count"] == "substep" else f"{r['crossing']} of frame ends",
            "max crossings": r["max_crossings"] if r["count"] == "substep" else f"{r['max_crossings']} at frame ends",
            "first intersection (s)": r["first_intersection"], "max penetration (m)": r["max_penetration"],
            "fail-safe": r["failsafe"],
            "control: intersecting frames": f"{r['control_intersecting']}/{r['control_checked']}"
                                            f" ({r['control_crossing']} crossing)",
            "ms/frame with": 1e3 * r["frame_cost"], "ms/frame without": 1e3 * r["control_frame_cost"],
            "ratio": r["cost_ratio"]}


def _cell(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def markdown(rows: list[dict[str, Any]]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        lines.append("| " + " | ".join(_cell(r.get(c)) for c in COLUMNS) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m csb.studies.torture", description=__doc__.split("\n\n")[0])
    p.add_argument("scenes", nargs="*", default=list(SCENES), help=f"of {', '.join(SCENES)} (default: all)")
    p.add_argument("--quick", action="store_true", help="small cloths, short times")
    args = p.parse_args(argv)
    rows = []
    for name in args.scenes:
        rows.append(row(measure(build(name, quick=args.quick))))
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
