"""Scenes: a small TOML file declares meshes, constraints, pins, the solver and the outputs.

Only what a scene declares is built and stepped. The same scene files serve the command line
(``csb run``), the tests, the benchmarks and the validation studies. Every error names the file,
the key and, where it can be found, the line.

See ``python/csb/scenes/*.toml`` for annotated examples and the README for the full schema.

A constraint's material (``stretch``, ``bending``, ``volume``, ``balloon``, ``attach``) has two
forms: ``stiffness`` in [0, 1], which the ``pbd`` and ``jakobsen`` methods read, and
``compliance`` (SI units), which ``xpbd`` and the force-based and implicit methods read (the
latter need compliance > 0: a hard constraint has no potential). A scene meant for every method
declares both;
stepped with a method that cannot read the form declared (compliance only under ``pbd`` or
``jakobsen``, stiffness below 1 only under ``xpbd``), the constraints are rigid and the first
step says so with a :class:`csb.MaterialWarning`.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from . import _core
from .mesh import AnimationWarning, Mesh, _rotation, icosphere, load_mesh, transformed
from .model import MeshInstance, ModelBuilder
from .select import Box, HalfSpace, Material, NearLine, Region, Sphere, select_vertices
from .scene_file import SceneError, Vec3, _Source, _Table, read_toml
from .tetmesh import load_tet_mesh

if TYPE_CHECKING:
    from .runner import RunResult

__all__ = [
    "Scene",
    "SceneError",
    "Simulation",
    "SolverSpec",
    "MeshSpec",
    "OutputSpec",
    "load_scene",
    "bundled_scenes",
    "find_scene",
]

# ---------------------------------------------------------------------------------------------
# The scene description


@dataclass(frozen=True)
class SolverSpec:
    method: str = "pbd"             # any method of csb.methods(): "pbd", "xpbd", "jakobsen", "vbd", "implicit-euler", ...
    dt: float = 1.0 / 60.0          # s
    substeps: int = 1
    iterations: int = 10            # small steps (Macklin 2019): "xpbd" with many substeps, iterations = 1
    gravity: Vec3 = (0.0, -9.81, 0.0)  # m/s²
    # The position-based pipeline's own settings (PbdStepper); a method outside it refuses them.
    damping: float = 0.0            # Müller 2007 §3.5 k_damping, per substep
    stiffness_correction: bool = True
    front_end: str = "auto"         # "euler", "verlet" or "auto" (Verlet for Jakobsen)
    solver: str = "gauss-seidel"    # or "jacobi" (averaged), "jacobi-summed"
    xpbd_damping: float = 0.0       # N s/m, XPBD only
    verlet_drag: float = 0.0        # Jakobsen's drag in [0, 1)
    sqrt_approximation: bool = False  # Jakobsen's stick relaxation without square roots
    ordering: str = "coloured"      # or "sequential" (the batches as built, one thread)
    threads: int = 0                # threads per colour; 0: the free cores (the result does not depend on it)
    max_speed: float = 0.0          # m/s, the divergence guard; 0: automatic (the model's size per sub-step, ...), inf: off
    precision: str = "float64"      # the solver's scalar; "float32": distance and bending with pins and kinematic grabs, no contacts
    # Any other method's own settings ([solver.settings]; csb.method_info(method).settings lists them).
    settings: tuple[tuple[str, Any], ...] = ()

    @property
    def position_based(self) -> bool:
        """Whether the method is a variant of the position-based pipeline (PbdStepper)."""
        return self.method in _core.pbd_variant_names(aliases=True)

    def stepper(self) -> _core.Integrator:
        """The scene's method: a PbdStepper for the position-based variants, else the registered
        method made with the scene's dt, substeps, iterations, gravity and settings."""
        if self.position_based:
            if self.settings:
                raise _core.ParameterError(
                    f"[solver.settings] are the settings of methods outside the position-based pipeline; "
                    f"'{self.method}' takes its settings as keys of [solver]")
            return _core.PbdStepper(
                method=self.method, dt=self.dt, substeps=self.substeps, iterations=self.iterations,
                gravity=self.gravity, damping=self.damping, stiffness_correction=self.stiffness_correction,
                front_end=self.front_end, solver=self.solver, xpbd_damping=self.xpbd_damping,
                verlet_drag=self.verlet_drag, sqrt_approximation=self.sqrt_approximation, ordering=self.ordering,
                threads=self.threads, max_speed=self.max_speed, precision=self.precision,
            )
        defaults = SolverSpec()
        for key in _PBD_KEYS:
            if getattr(self, key) != getattr(defaults, key):
                raise _core.ParameterError(
                    f"{key} is a setting of the position-based methods; '{self.method}' does not read it "
                    f"(its own settings go in [solver.settings])")
        return _core.make_integrator(self.method, self.dt, substeps=self.substeps, iterations=self.iterations,
                                     gravity=self.gravity, **dict(self.settings))


_PBD_KEYS = ("damping", "stiffness_correction", "front_end", "solver", "xpbd_damping", "verlet_drag",
             "sqrt_approximation", "ordering", "threads", "max_speed", "precision")


@dataclass(frozen=True)
class Selection:
    """Particles of one mesh chosen by vertex index, by the vertex nearest to points (m), and by
    regions of space (every vertex inside: a box, a sphere, a half-space, a distance to a line);
    the union of what each chose."""

    indices: tuple[int, ...] = ()
    near: tuple[Vec3, ...] = ()
    max_distance: float | None = None   # m; None: 2 % of the mesh's bounding-box diagonal
    regions: tuple[tuple[str, Region], ...] = ()   # (the key that gave it, the region)
    material: str | None = None                    # the file's meshes of this material


@dataclass(frozen=True)
class AttachSpec:
    selection: Selection
    targets: tuple[Vec3, ...] | None = None   # m; None: where the particles start
    stiffness: float = 1.0
    compliance: float = 0.0                   # m/N
    collider: str | None = None               # attached to this collider, kinematic, following its pose


@dataclass(frozen=True)
class BalloonSpec:
    """Müller 2007 §4.5 overpressure over the mesh's closed surface."""

    pressure: float = 1.0       # k_pressure: the target volume is pressure x the rest volume
    stiffness: float = 1.0      # PBD, in [0, 1]
    compliance: float = 0.0     # m⁶/J


@dataclass(frozen=True)
class MeshSpec:
    name: str
    kind: str = "surface"             # "surface" (Assimp, shapes) or "volume" (tetrahedra: meshio, tet_box)
    file: Path | None = None
    shape: str | None = None
    shape_args: dict[str, Any] = field(default_factory=dict)
    group: str | None = None
    mass_kind: str = "mass"          # "mass" (kg), "density" (kg/m² or kg/m), "particle_mass" (kg)
    mass_value: float = 1.0
    weld: bool = True
    weld_tolerance: float = 1e-6
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    rotate: Vec3 = (0.0, 0.0, 0.0)   # rad, XYZ Euler
    translate: Vec3 = (0.0, 0.0, 0.0)  # m
    stretch: float | None = None      # PBD stiffness of the edges, None: no stretch constraints
    stretch_compliance: float = 0.0   # m/N
    bending: float | None = None      # PBD stiffness of the bending pairs, None: no bending constraints
    bending_compliance: float = 0.0   # 1/(N m)
    volume: float | None = None       # PBD stiffness of the tet volume constraints (volume meshes)
    volume_compliance: float = 0.0    # m⁶/J
    balloon: BalloonSpec | None = None
    thickness: float = 0.0            # m, collision radius of its particles against the colliders
    self_collision: float | None = None  # m, point-triangle thickness h; None: off
    pin: Selection | None = None
    attach: AttachSpec | None = None


@dataclass(frozen=True)
class MotionSpec:
    """Keyframed rigid motion of a collider: at time t (s) its shape, as declared, is moved to
    x_world = R(t) x + translation(t). Rotations are rotation vectors (rad: the axis times the
    angle). Between keyframes the translation is linear and the rotation the slerp of the two
    keyframes' quaternions (the shorter arc: consecutive rotation vectors differ by less than π); before
    the first keyframe and after the last the pose is held."""

    times: tuple[float, ...]              # s, strictly increasing
    translation: tuple[Vec3, ...]         # m, one per time
    rotation: tuple[Vec3, ...]            # rad, rotation vectors, one per time

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(R, translation in m) at time t (s)."""
        times = self.times
        if t <= times[0] or len(times) == 1:
            k, f = 0, 0.0
        elif t >= times[-1]:
            k, f = len(times) - 2, 1.0
        else:
            k = int(np.searchsorted(times, t, side="right")) - 1
            f = (t - times[k]) / (times[k + 1] - times[k])
        a = np.asarray(self.translation[k])
        if f == 0.0:
            return _quat_matrix(_quat(self.rotation[k])), a.copy()
        b = np.asarray(self.translation[k + 1])
        q = _slerp(_quat(self.rotation[k]), _quat(self.rotation[k + 1]), f)
        return _quat_matrix(q), (b.copy() if f == 1.0 else a + f * (b - a))


def _quat(rotvec: Vec3) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation vector (rad)."""
    v = np.asarray(rotvec, dtype=float)
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate(([math.cos(angle / 2)], math.sin(angle / 2) * v / angle))


def _slerp(a: np.ndarray, b: np.ndarray, f: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions along the shorter arc (Shoemake 1985)."""
    d = float(np.dot(a, b))
    if d < 0:
        b, d = -b, -d
    if d > 1 - 1e-12:  # the same rotation to round-off: nothing to interpolate
        q = a + f * (b - a)
        return q / np.linalg.norm(q)
    theta = math.acos(d)
    return (math.sin((1 - f) * theta) * a + math.sin(f * theta) * b) / math.sin(theta)


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


@dataclass(frozen=True, eq=False)
class DeformationSpec:
    """The vertices of a mesh collider over time, from its file's skinned animation: at
    ``times[k]`` (s) vertex v of the shape as declared (scale, rotation, translation applied) is at
    ``vertices[k, v]`` (m; the file's vertices, every mesh of it in order, not welded). Between
    samples each vertex moves linearly; before the first and after the last the pose is held."""

    times: np.ndarray        # (T,) s, increasing
    vertices: np.ndarray     # (T, V, 3) m
    triangles: np.ndarray    # (F, 3) indices into the V vertices

    def at(self, t: float) -> np.ndarray:
        """The (V, 3) vertices (m) at time t (s)."""
        times = self.times
        if t <= times[0] or len(times) == 1:
            return self.vertices[0].copy()
        if t >= times[-1]:
            return self.vertices[-1].copy()
        k = int(np.searchsorted(times, t, side="right")) - 1
        f = (t - times[k]) / (times[k + 1] - times[k])
        return self.vertices[k] + f * (self.vertices[k + 1] - self.vertices[k])


@dataclass(frozen=True)
class ColliderSpec:
    """A collider (Müller 2007 §4.3): its shape's parameters (m), its material, and optionally its
    keyframed motion or, for a mesh with a skinned animation, its deformation (the
    position-based methods only)."""

    name: str
    type: str                         # "plane", "sphere", "capsule", "box", "mesh"
    params: dict[str, Any]
    friction_static: float = 0.0      # Coulomb μs
    friction_kinetic: float = 0.0     # Coulomb μk <= μs
    restitution: float = 0.0          # e in [0, 1]
    motion: MotionSpec | None = None
    deformation: DeformationSpec | None = None


_COLLIDERS = ("plane", "sphere", "capsule", "box", "mesh")


@dataclass(frozen=True)
class TearingSpec:
    """Müller 2007 §4.6: after every step, split vertices of edges strained past max_strain."""

    max_strain: float              # |l - l0|/l0
    max_per_step: int = 10         # vertices split per step at most


@dataclass(frozen=True)
class TetherSpec:
    """Long range attachments (Kim, Chentanez and Müller 2012): every free particle tethered to its
    nearest pinned particles, at most max_stretch x its rest distance from them."""

    mode: str = "geodesic"          # "geodesic" (through the distance constraints) or "euclidean"
    max_stretch: float = 1.0        # >= 1
    stiffness: float = 1.0          # PBD, in [0, 1]
    compliance: float = 0.0         # m/N
    anchors: int = 1                # nearest pinned particles per free particle


@dataclass(frozen=True)
class OutputSpec:
    fps: float = 30.0     # frames per simulated second
    xdmf: bool = True
    vtu: bool = True
    csv: bool = True
    plot: bool = True
    usd: bool = False     # <name>.usd: the meshes as the files have them, and the colliders, animated (the usd extra)
    gltf: bool = False    # <name>.glb: the meshes animated by morph targets, for game engines
    obj: bool = False     # obj/<name>_<frame>.obj: one OBJ per frame
    ply: bool = False     # ply/<mesh>_<frame>.ply: one PLY per mesh per frame


@dataclass
class Simulation:
    """A scene made ready to step: the model, its state, the stepper and where each mesh landed.

    Colliders move by the scene's keyframes (``motion`` of a ``[[collider]]``) or, overriding
    them, by ``collider_motion[name] = f`` where ``f(t)`` returns ``(R, translation)`` at time t (s):
    a 3 x 3 rotation matrix and a translation in m applied to the collider as declared. step()
    asks for the pose at the end of each step (the stepper interpolates over its sub-steps).
    A mesh collider deforms by its file's skinned animation (``animation = true``) or by
    ``collider_deformation[name] = f``, ``f(t)`` the (V, 3) vertices (m) of the collider as
    ``model.colliders[i]["vertices"]`` numbers them, at time t (s) (PbdStepper.deform_collider)."""

    scene: "Scene"
    model: _core.Model
    state: _core.State
    stepper: _core.Integrator      # the scene's solver (a PbdStepper), or the method given to build()
    meshes: dict[str, MeshInstance]
    colliders: dict[str, int] = field(default_factory=dict)   # name -> index in the model
    collider_motion: dict[str, Callable[[float], tuple[Any, Any]]] = field(default_factory=dict)
    collider_deformation: dict[str, Callable[[float], Any]] = field(default_factory=dict)

    @property
    def gravity(self) -> Vec3:
        return self.scene.solver.gravity

    def _motions(self) -> list[tuple[int, Callable[[float], tuple[Any, Any]]]]:
        motions: dict[int, Callable[[float], tuple[Any, Any]]] = {}
        for c in self.scene.colliders:
            if c.motion is not None:
                motions[self.colliders[c.name]] = c.motion.pose
        for name, f in self.collider_motion.items():
            if name not in self.colliders:
                raise _core.ParameterError(
                    f"collider_motion: no collider named {name!r} (the scene has: {', '.join(self.colliders) or 'none'})")
            if not callable(f):
                raise _core.ParameterError(f"collider_motion[{name!r}] must be a function of t (s) returning (R, translation)")
            motions[self.colliders[name]] = f
        if motions and not isinstance(self.stepper, _core.PbdStepper):
            raise _core.ParameterError(
                f"method '{self.stepper.name()}' cannot move colliders: moving colliders are part of the "
                "position-based methods (pbd, xpbd, jakobsen); its colliders would be static")
        return sorted(motions.items())

    def _deformations(self) -> list[tuple[int, Callable[[float], Any]]]:
        deformations: dict[int, Callable[[float], Any]] = {}
        for name, f in self.collider_deformation.items():
            if name not in self.colliders:
                raise _core.ParameterError(
                    f"collider_deformation: no collider named {name!r} (the scene has: {', '.join(self.colliders) or 'none'})")
            if not callable(f):
                raise _core.ParameterError(f"collider_deformation[{name!r}] must be a function of t (s) returning "
                                           "the (V, 3) vertices (m)")
            deformations[self.colliders[name]] = f
        if deformations and not isinstance(self.stepper, _core.PbdStepper):
            raise _core.ParameterError(
                f"method '{self.stepper.name()}' cannot deform colliders: deforming colliders, like moving ones, are "
                "part of the position-based methods (pbd, xpbd, jakobsen); its colliders would be static")
        return sorted(deformations.items())

    def step(self, steps: int = 1) -> None:
        """Advance `steps` steps, each after putting every moving collider at its pose for the
        step's end (t + dt)."""
        motions = self._motions()
        deformations = self._deformations()
        if not motions and not deformations:
            self.stepper.step(self.model, self.state, steps)
            return
        stepper: _core.PbdStepper = self.stepper  # type: ignore[assignment]
        names = {i: n for n, i in self.colliders.items()}
        for _ in range(steps):
            t = self.state.t + stepper.dt()
            for index, pose in motions:
                try:
                    R, tr = pose(t)
                    stepper.move_collider(self.model, index, R, tr)
                except _core.ParameterError as e:
                    raise _core.ParameterError(f"collider '{names[index]}' at t = {t:.6g} s: {e}") from None
            for index, vertices in deformations:
                try:
                    stepper.deform_collider(self.model, index, vertices(t))
                except _core.ParameterError as e:
                    raise _core.ParameterError(f"collider '{names[index]}' at t = {t:.6g} s: {e}") from None
            stepper.step(self.model, self.state, 1)

    def measure(self) -> dict[str, Any]:
        return _core.measure(self.model, self.state, self.gravity)


_SHAPES = ("cloth", "chain", "pendulum", "sphere", "tet_box")
# Files read as tetrahedral meshes (meshio) unless the mesh says kind = "surface".
_VOLUME_SUFFIXES = (".msh", ".mesh", ".inp", ".vtu", ".vtk", ".xdmf", ".med")


@dataclass(frozen=True)
class Scene:
    path: Path
    name: str
    duration: float               # s
    solver: SolverSpec
    meshes: tuple[MeshSpec, ...]
    output: OutputSpec
    description: str = ""
    colliders: tuple[ColliderSpec, ...] = ()
    tearing: TearingSpec | None = None
    tethers: TetherSpec | None = None

    @property
    def steps(self) -> int:
        """Steps of solver.dt that cover the duration (the last one may end past it)."""
        return max(1, math.ceil(self.duration / self.solver.dt - 1e-9))

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "Scene":
        return load_scene(path)

    def build(self, stepper: _core.Integrator | None = None) -> Simulation:
        """Read the meshes and build the model, the initial state and the stepper: the solver's,
        or `stepper`, any csb.Integrator (a built-in, or a user's own method)."""
        if stepper is not None and not isinstance(stepper, _core.Integrator):
            raise _core.ParameterError(
                f"stepper must be a csb.Integrator (a built-in stepper, csb.make_integrator's, or a subclass "
                f"implementing name(), dt() and step()), got {type(stepper).__name__}")
        builder = ModelBuilder()
        groups: dict[str, int] = {}
        instances: dict[str, MeshInstance] = {}
        to_collider: list[tuple[str, str, list[int]]] = []   # (mesh, collider, particles) attached
        for spec in self.meshes:
            mesh = _make_mesh(spec)
            group_name = spec.group or spec.name
            if group_name not in groups:
                groups[group_name] = builder.add_group(group_name)
            if spec.kind == "volume":
                inst = builder.add_tet_mesh(
                    mesh, group=groups[group_name], stretch_stiffness=spec.stretch,
                    stretch_compliance=spec.stretch_compliance, volume_stiffness=spec.volume,
                    volume_compliance=spec.volume_compliance, **{spec.mass_kind: spec.mass_value},
                )
            else:
                inst = builder.add_mesh(
                    mesh, group=groups[group_name], stretch_stiffness=spec.stretch,
                    bending_stiffness=spec.bending, stretch_compliance=spec.stretch_compliance,
                    bending_compliance=spec.bending_compliance, **{spec.mass_kind: spec.mass_value},
                )
            instances[spec.name] = inst
            if spec.balloon is not None:
                try:
                    builder.add_balloon(inst, pressure=spec.balloon.pressure, stiffness=spec.balloon.stiffness,
                                        compliance=spec.balloon.compliance)
                except _core.ParameterError as e:
                    raise SceneError(f"{self.path}: mesh '{spec.name}' balloon: {e}") from None
            if spec.thickness > 0:
                builder.set_thickness(inst.group, spec.thickness)
            if spec.self_collision is not None:
                builder.enable_self_collision(inst.group, spec.self_collision)
            if spec.pin is not None:
                for i in _select(self, spec, spec.pin, inst, "pin"):
                    builder.pin(i)
            if spec.attach is not None and spec.attach.collider is not None:
                chosen = _select(self, spec, spec.attach.selection, inst, "attach")
                to_collider.append((spec.name, spec.attach.collider, chosen))
            elif spec.attach is not None:
                chosen = _select(self, spec, spec.attach.selection, inst, "attach")
                targets = spec.attach.targets
                if targets is not None and len(targets) != len(chosen):
                    raise SceneError(
                        f"{self.path}: mesh '{spec.name}' attach: {len(chosen)} particles selected but "
                        f"{len(targets)} targets given")
                for k, i in enumerate(chosen):
                    target = targets[k] if targets is not None else inst.vertices[i - inst.first_particle]
                    builder.attach(i, target, stiffness=spec.attach.stiffness, compliance=spec.attach.compliance)
        if self.tethers is not None:  # after every mesh's pins and stretch constraints
            t = self.tethers
            try:
                builder.add_tethers(mode=t.mode, max_stretch=t.max_stretch, stiffness=t.stiffness,
                                    compliance=t.compliance, anchors=t.anchors)
            except _core.ParameterError as e:
                raise SceneError(f"{self.path}: tethers: {e}") from None
        colliders = {c.name: _add_collider(self, builder, c) for c in self.colliders}
        try:
            model = builder.build()
        except _core.ParameterError as e:  # e.g. a particle that starts inside a collider
            raise SceneError(f"{self.path}: {e}") from None
        stepper = stepper if stepper is not None else self.solver.stepper()
        moving = [c.name for c in self.colliders if c.motion is not None or c.deformation is not None]
        if (moving or to_collider) and not isinstance(stepper, _core.PbdStepper):
            what = f"collider '{moving[0]}' has a motion" if moving else f"mesh '{to_collider[0][0]}' is attached to a collider"
            raise SceneError(
                f"{self.path}: {what}, but method '{stepper.name()}' cannot move or deform colliders or attach "
                "particles to them (the position-based methods pbd, xpbd and jakobsen can)")
        sim = Simulation(self, model, model.initial_state(), stepper, instances, colliders)
        for c in self.colliders:
            if c.deformation is not None:
                index = colliders[c.name]
                sim.collider_deformation[c.name] = _follow(c.deformation, model.colliders[index]["vertices"])
        for mesh_name, collider, chosen in to_collider:
            if collider not in colliders:
                raise SceneError(f"{self.path}: mesh '{mesh_name}' attach.collider: no collider named {collider!r} "
                                 f"(the scene has: {', '.join(colliders) or 'none'})")
            stepper.attach(model, sim.state, colliders[collider], chosen)  # type: ignore[attr-defined]
        return sim

    def run(self, out_dir: str | os.PathLike[str] | None = None, *, progress: bool = False,
            stepper: _core.Integrator | None = None) -> "RunResult":
        """Step the scene for its duration, recording metrics (and writing outputs if out_dir);
        with `stepper` (any csb.Integrator) instead of the scene's solver."""
        from .runner import run_scene

        return run_scene(self, out_dir, progress=progress, stepper=stepper)


def _add_collider(scene: Scene, builder: ModelBuilder, c: ColliderSpec) -> int:
    material = dict(friction_static=c.friction_static, friction_kinetic=c.friction_kinetic,
                    restitution=c.restitution, name=c.name)
    a = c.params
    try:
        if c.type == "plane":
            return builder.add_plane(point=a["point"], normal=a["normal"], **material)
        elif c.type == "sphere":
            return builder.add_sphere(center=a["center"], radius=a["radius"], **material)
        elif c.type == "capsule":
            return builder.add_capsule(a=a["a"], b=a["b"], radius=a["radius"], **material)
        elif c.type == "box":
            return builder.add_box(center=a["center"], half_extents=a["half_extents"],
                                   rotation=_rotation(a["rotate"]), **material)
        elif c.deformation is not None:  # its shape at t = 0, declared frame applied already
            d = c.deformation
            return builder.add_collider_mesh(Mesh(d.at(0.0), d.triangles, name=c.name), **material)
        else:
            with warnings.catch_warnings():
                if a["animation"] is not False:  # asked for: the collider follows the animation
                    warnings.simplefilter("ignore", AnimationWarning)
                mesh = load_mesh(a["file"])
            mesh = transformed(mesh, scale=a["scale"], rotate=a["rotate"], translate=a["translate"])
            return builder.add_collider_mesh(mesh, **material)
    except _core.ParameterError as e:
        raise SceneError(f"{scene.path}: collider '{c.name}': {e}") from None


def _follow(d: DeformationSpec, collider_vertices: np.ndarray) -> Callable[[float], np.ndarray]:
    """f(t): the collider's vertices at t from the file's: the model welded the file's vertices
    (seams split them), so each of its vertices takes the file's vertex at the same place at t = 0
    (exactly, else the nearest: the weld's tolerance)."""
    rest = d.at(0.0)
    first: dict[tuple[float, ...], int] = {}
    for j, v in enumerate(map(tuple, rest)):
        first.setdefault(v, j)
    source = np.empty(len(collider_vertices), dtype=np.int64)
    for k, v in enumerate(collider_vertices):
        j = first.get(tuple(v))
        source[k] = j if j is not None else int(np.argmin(np.sum((rest - v) ** 2, axis=1)))
    return lambda t: d.at(t)[source]


def _make_mesh(spec: MeshSpec) -> Mesh | _core.TetMesh:
    if spec.file is not None:
        if spec.kind == "volume":
            mesh = load_tet_mesh(spec.file)
        else:
            mesh = load_mesh(spec.file, weld=spec.weld, weld_tolerance=spec.weld_tolerance)
    else:
        a = spec.shape_args
        if spec.shape == "tet_box":
            mesh = _core.tet_box(a["size"], a["divisions"])
        elif spec.shape == "sphere":
            mesh = icosphere(a["radius"], a["subdivisions"])
        elif spec.shape == "cloth":
            mesh = _core.cloth_grid(a["size"][0], a["size"][1], a["resolution"][0], a["resolution"][1],
                                    plane=a["plane"])
        elif spec.shape == "chain":
            mesh = _core.chain(a["links"], a["link_length"], direction=a["direction"])
        else:
            mesh = _core.pendulum(a["length"], a["angle"])
    return transformed(mesh, scale=spec.scale, rotate=spec.rotate, translate=spec.translate)


def _select(scene: Scene, spec: MeshSpec, sel: Selection, inst: MeshInstance, what: str) -> list[int]:
    chosen: list[int] = []
    for i in sel.indices:
        if not 0 <= i < inst.num_particles:
            raise SceneError(
                f"{scene.path}: mesh '{spec.name}' {what}.indices: vertex {i} is out of range "
                f"(the mesh has {inst.num_particles} vertices after welding)")
        chosen.append(inst.first_particle + i)
    if sel.near:
        v = inst.vertices
        diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
        limit = sel.max_distance if sel.max_distance is not None else 0.02 * diag
        for p in sel.near:
            i = inst.nearest(p)
            d = float(np.linalg.norm(v[i - inst.first_particle] - np.asarray(p)))
            if d > limit:
                raise SceneError(
                    f"{scene.path}: mesh '{spec.name}' {what}.near: the vertex nearest to {list(p)} is "
                    f"{d:.4g} m away, more than max_distance = {limit:.4g} m (is the point in world "
                    f"coordinates, after scale/rotate/translate?)")
            chosen.append(i)
    if sel.material is not None:
        try:
            found = inst.select(Material(sel.material))
        except _core.ParameterError as e:
            raise SceneError(f"{scene.path}: mesh '{spec.name}' {what}.material: {e}") from None
        have = set(chosen)
        chosen.extend(int(i) for i in found if int(i) not in have)
    for key, region in sel.regions:
        try:
            inside = select_vertices(inst.vertices, region, label=f"mesh '{spec.name}'")
        except _core.ParameterError as e:
            raise SceneError(f"{scene.path}: mesh '{spec.name}' {what}.{key}: {e}") from None
        have = set(chosen)
        chosen.extend(int(inst.first_particle + i) for i in inside if inst.first_particle + i not in have)
    return chosen


# ---------------------------------------------------------------------------------------------
# Reading the TOML


def _relative_to(base: Path, file: str) -> Path:
    """A file named in a scene: relative to the scene's folder unless absolute."""
    return Path(file) if os.path.isabs(file) else base / file


def _read_region(t: _Table, key: str) -> Region | None:
    """A region table of a selection: box = {min, max}, sphere = {center, radius}, half_space =
    {point, normal}, near_line = {a, b, distance, segment}, in m."""
    r = t.table(key)
    if r is None:
        return None
    try:
        if key == "box":
            region: Region = Box(r.vector("min"), r.vector("max"))
        elif key == "sphere":
            region = Sphere(r.vector("center"), r.number("radius"))
        elif key == "half_space":
            region = HalfSpace(r.vector("point"), r.vector("normal"))
        else:
            region = NearLine(r.vector("a"), r.vector("b"), r.number("distance"), segment=r.boolean("segment", False))
    except _core.ParameterError as e:
        raise r.error(None, str(e)) from None
    r.finish()
    return region


_REGIONS = ("box", "sphere", "half_space", "near_line")


def _read_selection(t: _Table) -> Selection:
    regions = tuple((key, region) for key in _REGIONS if (region := _read_region(t, key)) is not None)
    sel = Selection(
        indices=t.integers("indices", ()),
        near=t.vectors("near", ()),
        max_distance=t.number("max_distance", None, check=lambda x: x > 0, expect="a distance > 0 m"),
        regions=regions,
        material=t.string("material", None),
    )
    if not sel.indices and not sel.near and not sel.regions and sel.material is None:
        raise t.error(None, "give 'indices' (vertex numbers), 'near' (points in m), 'material' (a material's name "
                            "in the file) or a region: 'box', 'sphere', 'half_space' or 'near_line'")
    return sel


def _read_mesh(source: _Source, data: Any, k: int, base: Path) -> MeshSpec:
    if not isinstance(data, dict):
        raise SceneError(f"{source.path}: mesh[{k}] must be a table")
    t = _Table(source, data, ("mesh", k), f"mesh[{k}]")
    name = t.string("name", f"mesh{k}")
    t.label = f"mesh[{k}] ({name})"
    file = t.string("file", None)
    shape = t.string("shape", None, choices=_SHAPES)
    if (file is None) == (shape is None):
        raise t.error(None, "give exactly one of 'file' (a mesh file) or 'shape' (" + ", ".join(_SHAPES) + ")")
    guessed = "volume" if shape == "tet_box" or (file is not None and Path(file).suffix.lower() in _VOLUME_SUFFIXES) \
        else "surface"
    kind = t.string("kind", guessed, choices=("surface", "volume"))
    if shape is not None and kind != guessed:
        raise t.error("kind", f"shape '{shape}' is a {guessed} mesh")
    shape_args: dict[str, Any] = {}
    path: Path | None = None
    if file is not None:
        path = _relative_to(base, file)
    elif shape == "cloth":
        shape_args["size"] = t.vector("size", size=2)
        if min(shape_args["size"]) <= 0:
            raise t.error("size", f"must be two lengths > 0 m, got {list(shape_args['size'])}")
        res = t.integers("resolution")
        if len(res) != 2 or min(res) < 2:
            raise t.error("resolution", f"must be [nx, ny] with at least 2 particles each, got {list(res)}")
        shape_args["resolution"] = res
        shape_args["plane"] = t.string("plane", "xz", choices=("xy", "xz", "yz"))
    elif shape == "chain":
        shape_args["links"] = t.integer("links", minimum=1)
        shape_args["link_length"] = t.number("link_length", check=lambda x: x > 0, expect="a length > 0 m")
        shape_args["direction"] = t.vector("direction", (1.0, 0.0, 0.0))
    elif shape == "tet_box":
        shape_args["size"] = t.vector("size")
        if min(shape_args["size"]) <= 0:
            raise t.error("size", f"must be three lengths > 0 m, got {list(shape_args['size'])}")
        div = t.integers("divisions")
        if len(div) != 3 or min(div) < 1:
            raise t.error("divisions", f"must be [nx, ny, nz] cells, at least 1 each, got {list(div)}")
        shape_args["divisions"] = div
    elif shape == "sphere":
        shape_args["radius"] = t.number("radius", check=lambda x: x > 0, expect="a radius > 0 m")
        shape_args["subdivisions"] = t.integer("subdivisions", 2, minimum=0, maximum=13)  # as icosphere
    else:
        shape_args["length"] = t.number("length", check=lambda x: x > 0, expect="a length > 0 m")
        shape_args["angle"] = t.number("angle", 0.0, expect="an angle in rad")

    masses = [key for key in ("mass", "density", "particle_mass") if t.has(key)]
    if len(masses) != 1:
        raise t.error(None, "give exactly one of 'mass' (kg), 'density' (kg/m²) or 'particle_mass' (kg)")
    mass_kind = masses[0]
    mass_value = t.number(mass_kind, check=lambda x: x > 0, expect="> 0 (" + {
        "mass": "kg", "density": "kg/m³" if kind == "volume" else "kg/m²", "particle_mass": "kg"}[mass_kind] + ")")

    scale = t.scale()

    def material(key: str, unit: str) -> tuple[float | None, float]:
        """(PBD stiffness or None if the table is absent, compliance)."""
        sub = t.table(key)
        if sub is None:
            return None, 0.0
        k_ = sub.number("stiffness", 1.0, check=lambda x: 0 <= x <= 1, expect="a stiffness in [0, 1]")
        alpha = sub.number("compliance", 0.0, check=lambda x: x >= 0, expect=f"a compliance >= 0 ({unit})")
        sub.finish()
        return k_, alpha

    pin = None
    pin_t = t.table("pin")
    if pin_t is not None:
        pin = _read_selection(pin_t)
        pin_t.finish()
    attach = None
    att_t = t.table("attach")
    if att_t is not None:
        sel = _read_selection(att_t)
        collider = att_t.string("collider", None)
        if collider is not None:
            for key in ("targets", "stiffness", "compliance"):
                if att_t.has(key):
                    raise att_t.error(key, "an attachment to a collider follows the collider's pose exactly "
                                           "(kinematic): no targets, stiffness or compliance")
        targets = att_t.vectors("targets", None)
        stiffness = att_t.number("stiffness", 1.0, check=lambda x: 0 <= x <= 1, expect="a stiffness in [0, 1]")
        compliance = att_t.number("compliance", 0.0, check=lambda x: x >= 0, expect="a compliance >= 0 (m/N)")
        att_t.finish()
        attach = AttachSpec(sel, targets, stiffness, compliance, collider)

    stretch, stretch_compliance = material("stretch", "m/N")
    bending, bending_compliance = (None, 0.0)
    volume, volume_compliance = (None, 0.0)
    if kind == "volume":
        volume, volume_compliance = material("volume", "m⁶/J")
        if t.has("bending"):
            raise t.error("bending", "a volume mesh has no dihedral bending; its tets hold its shape (use 'volume')")
    else:
        bending, bending_compliance = material("bending", "1/(N m)")
        if t.has("volume"):
            raise t.error("volume", "tet volume constraints need a volume mesh (a tet file or shape = 'tet_box'); "
                                    "a closed surface can be a 'balloon'")
    thickness = t.number("thickness", 0.0, check=lambda x: x >= 0, expect="a collision radius >= 0 m")
    self_collision = None
    sc_t = t.table("self_collision")
    if sc_t is not None:
        if kind != "surface":
            raise t.error("self_collision", "self-collision is point-triangle contact of a cloth (a surface mesh)")
        self_collision = sc_t.number("thickness", check=lambda x: x > 0, expect="a thickness > 0 m")
        sc_t.finish()
    balloon = None
    bal_t = t.table("balloon")
    if bal_t is not None:
        balloon = BalloonSpec(
            pressure=bal_t.number("pressure", 1.0, check=lambda x: x >= 0, expect="a pressure factor >= 0"),
            stiffness=bal_t.number("stiffness", 1.0, check=lambda x: 0 <= x <= 1, expect="a stiffness in [0, 1]"),
            compliance=bal_t.number("compliance", 0.0, check=lambda x: x >= 0, expect="a compliance >= 0 (m⁶/J)"),
        )
        bal_t.finish()
    spec = MeshSpec(
        name=name, kind=kind, file=path, shape=shape, shape_args=shape_args, group=t.string("group", None),
        mass_kind=mass_kind, mass_value=mass_value, weld=t.boolean("weld", True),
        weld_tolerance=t.number("weld_tolerance", 1e-6, check=lambda x: x >= 0, expect="a relative tolerance >= 0"),
        scale=scale, rotate=t.vector("rotate", (0.0, 0.0, 0.0)), translate=t.vector("translate", (0.0, 0.0, 0.0)),
        stretch=stretch, stretch_compliance=stretch_compliance, bending=bending,
        bending_compliance=bending_compliance, volume=volume, volume_compliance=volume_compliance, balloon=balloon,
        thickness=thickness, self_collision=self_collision, pin=pin, attach=attach,
    )
    t.finish()
    return spec


def _read_collider(source: _Source, data: Any, k: int, base: Path) -> ColliderSpec:
    if not isinstance(data, dict):
        raise SceneError(f"{source.path}: collider[{k}] must be a table")
    t = _Table(source, data, ("collider", k), f"collider[{k}]")
    kind = t.string("type", choices=_COLLIDERS)
    name = t.string("name", f"{kind}{k}")
    t.label = f"collider[{k}] ({name})"
    length = dict(check=lambda x: x > 0, expect="a length > 0 m")
    params: dict[str, Any] = {}
    if kind == "plane":
        params["point"] = t.vector("point", (0.0, 0.0, 0.0))
        params["normal"] = t.vector("normal", (0.0, 1.0, 0.0))
    elif kind == "sphere":
        params["center"] = t.vector("center")
        params["radius"] = t.number("radius", **length)
    elif kind == "capsule":
        params["a"] = t.vector("a")
        params["b"] = t.vector("b")
        params["radius"] = t.number("radius", **length)
    elif kind == "box":
        params["center"] = t.vector("center")
        params["half_extents"] = t.vector("half_extents")
        if min(params["half_extents"]) <= 0:
            raise t.error("half_extents", f"must be three lengths > 0 m, got {list(params['half_extents'])}")
        params["rotate"] = t.vector("rotate", (0.0, 0.0, 0.0))
    else:
        file = t.string("file")
        params["file"] = _relative_to(base, file)
        params["scale"] = t.scale()
        params["rotate"] = t.vector("rotate", (0.0, 0.0, 0.0))
        params["translate"] = t.vector("translate", (0.0, 0.0, 0.0))
        # animation = true (the file's first animation) or the animation's name: the collider
        # follows the file's rigid node animation as its motion, or deforms with its skinning.
        params["animation"] = t.raw("animation", False)
        if not (isinstance(params["animation"], bool) or (isinstance(params["animation"], str) and params["animation"])):
            raise t.error("animation", f"must be true, false or an animation's name, got {params['animation']!r}")
    mus = t.number("friction_static", 0.0, check=lambda x: x >= 0, expect="a friction coefficient >= 0")
    muk = t.number("friction_kinetic", mus, check=lambda x: x >= 0, expect="a friction coefficient >= 0")
    if muk > mus:
        raise t.error("friction_kinetic", f"must not exceed friction_static ({mus}), got {muk}")
    e = t.number("restitution", 0.0, check=lambda x: 0 <= x <= 1, expect="a restitution in [0, 1]")
    motion = None
    motion_t = t.table("motion")
    if motion_t is not None:
        motion = _read_motion(motion_t)
    deformation = None
    if kind == "mesh" and params["animation"] is not False:
        if motion is not None:
            raise t.error("animation", "a collider follows either its motion table or its file's animation, not both")
        motion, deformation = _animation_motion(t, params)
    t.finish()
    return ColliderSpec(name, kind, params, mus, muk, e, motion, deformation)


# Where a file's animation is sampled for a collider's keyframes besides its keys (Hz): between
# keyframes the motion interpolates linearly and by slerp, which is the file's own interpolation
# only for one node turning about its origin; at 30 Hz the difference is second order in 1/30 s.
_ANIMATION_RATE = 30.0


def _animation_motion(t: _Table, params: dict[str, Any]) -> tuple[MotionSpec | None, DeformationSpec | None]:
    """The keyframes of a mesh collider that follows its file's rigid node animation: the
    animation's motion of the mesh from its rest pose (:func:`csb.load_animation`), conjugated by
    the collider's declared scale, rotation and translation so that it moves the shape as
    declared. A file with a mesh that deforms (skinning, a scaling key) gives instead every mesh's
    vertices at the samples, as declared: the collider deforms."""
    from .animation import _rotation_vectors, load_animation

    which = params["animation"]
    choice: int | str = 0 if which is True else which
    try:
        keys = load_animation(params["file"], animation=choice)
        grid = np.arange(0.0, keys.duration, 1.0 / _ANIMATION_RATE)
        times = np.union1d(keys.times, np.append(grid, keys.duration))
        anim = keys if len(times) == len(keys.times) else load_animation(params["file"], times, animation=choice)
    except (_core.ParameterError, _core.MeshError, FileNotFoundError) as e:
        raise t.error("animation", str(e)) from None
    A = _rotation(params["rotate"]) @ np.diag(params["scale"])
    b = np.asarray(params["translate"], dtype=float)
    if any(m.keyframes is None for m in anim.meshes):
        vertices, triangles, offset = [], [], 0
        for m in anim.meshes:
            vertices.append(m.vertices @ A.T + b)
            triangles.append(np.asarray(m.triangles) + offset)
            offset += m.vertices.shape[1]
        tris = np.concatenate(triangles)
        if np.prod(np.sign(params["scale"])) < 0:  # a mirroring scale: outward stays outward (transformed())
            tris = tris[:, [0, 2, 1]]
        return None, DeformationSpec(np.asarray(anim.times, dtype=float), np.concatenate(vertices, axis=1), tris)
    first = anim.meshes[0].keyframes
    assert first is not None
    for m in anim.meshes[1:]:
        assert m.keyframes is not None
        # 1e-9 m and rad: far below any collider's thickness, far above the round-off (1e-15) of
        # the same node chain evaluated for two meshes.
        if (np.max(np.abs(m.keyframes.matrices - first.matrices)) > 1e-9
                or np.max(np.abs(m.keyframes.translation - first.translation)) > 1e-9):
            raise t.error("animation", f"meshes {anim.meshes[0].name!r} and {m.name!r} of the file move differently; "
                          "a collider follows one rigid motion (split the file, one collider per mesh)")
    # The declared shape is x_d = A x + b (A = rotation · diag(scale)); the file moves x to
    # R_k x + p_k, hence x_d to (A R_k A⁻¹) x_d + A p_k + b - A R_k A⁻¹ b.
    A_inv = np.linalg.inv(A)
    matrices = np.array([A @ R @ A_inv for R in first.matrices])
    for k, M in enumerate(matrices):
        if np.max(np.abs(M.T @ M - np.eye(3))) > 1e-6:  # move_collider's tolerance on a rotation
            raise t.error("scale", f"a non-uniform scale turns the file's rotation at t = {anim.times[k]:.6g} s into a "
                          "motion that is not rigid; scale the file uniformly")
    translation = [A @ p + b - M @ b for p, M in zip(first.translation, matrices)]
    return MotionSpec(tuple(float(x) for x in anim.times), tuple(tuple(float(c) for c in v) for v in translation),
                      tuple(tuple(float(c) for c in v) for v in _rotation_vectors(matrices))), None


def _read_motion(t: _Table) -> MotionSpec:
    """motion = { times = [...] (s), translation = [[x, y, z], ...] (m), rotation = [[rx, ry, rz], ...]
    (rad, rotation vectors) }, one keyframe per time; a missing translation or rotation is zero."""
    times = t.raw("times")
    if (not isinstance(times, list) or not times
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in times)):
        raise t.error("times", f"must be a non-empty list of finite times (s), got {times!r}")
    if any(b <= a for a, b in zip(times, times[1:])):
        raise t.error("times", f"must be strictly increasing, got {times!r}")
    zeros = tuple((0.0, 0.0, 0.0) for _ in times)
    translation = t.vectors("translation", zeros)
    rotation = t.vectors("rotation", zeros)
    for key, v in (("translation", translation), ("rotation", rotation)):
        if len(v) != len(times):
            raise t.error(key, f"must have one [x, y, z] per time ({len(times)}), got {len(v)}")
    for k in range(len(times) - 1):
        # Slerp takes the shorter arc: a turn of π or more between keyframes would go the other way.
        if float(np.linalg.norm(np.subtract(rotation[k + 1], rotation[k]))) >= math.pi:
            raise t.error("rotation", f"keyframes {k} and {k + 1} differ by π rad or more; add keyframes in "
                                      "between (the rotation is interpolated along the shorter arc)")
    t.finish()
    return MotionSpec(tuple(float(x) for x in times), translation, rotation)


def _method_settings(so) -> tuple[tuple[str, Any], ...]:
    """[solver.settings]: a method's own settings, booleans, numbers or strings; the method checks
    their names and ranges when the stepper is made."""
    st = so.table("settings", "solver.settings")
    if st is None:
        return ()
    out = []
    for key in list(st.data):
        v = st.raw(key)
        if not isinstance(v, (bool, int, float, str)):
            raise st.error(key, f"must be a boolean, a number or a string, got {v!r}")
        out.append((key, v))
    st.finish()
    return tuple(out)


def load_scene(path: str | os.PathLike[str]) -> Scene:
    """Read and check a scene file (or the name of a bundled scene, see :func:`bundled_scenes`)."""
    p = find_scene(path)
    data, source = read_toml(p, "scene file")
    top = _Table(source, data, (), "scene file")

    sc = top.table("scene", "scene")
    if sc is None:
        raise top.error(None, "missing [scene] table (name, duration)")
    name = sc.string("name", p.stem)
    duration = sc.number("duration", check=lambda x: x > 0, expect="a duration > 0 s")
    description = sc.string("description", "")
    sc.finish()

    so = top.table("solver", "solver")
    if so is None:
        raise top.error(None, "missing [solver] table (method, dt, substeps, iterations, ...)")
    solver = SolverSpec(
        method=so.string("method", "pbd", choices=[n for m in _core.methods() for n in (m.name, *m.aliases)]),
        dt=so.number("dt", check=lambda x: x > 0, expect="a time step > 0 s"),
        substeps=so.integer("substeps", 1, minimum=1, maximum=_core.MAX_SUBSTEPS),
        iterations=so.integer("iterations", 10, minimum=1, maximum=_core.MAX_ITERATIONS),
        gravity=so.vector("gravity", (0.0, -9.81, 0.0)),
        damping=so.number("damping", 0.0, check=lambda x: 0 <= x <= 1, expect="a damping factor in [0, 1]"),
        stiffness_correction=so.boolean("stiffness_correction", True),
        front_end=so.string("front_end", "auto", choices=("auto", "euler", "verlet")),
        solver=so.string("solver", "gauss-seidel", choices=("gauss-seidel", "jacobi", "jacobi-summed")),
        xpbd_damping=so.number("xpbd_damping", 0.0, check=lambda x: x >= 0, expect="a damping coefficient >= 0 (N s/m)"),
        verlet_drag=so.number("verlet_drag", 0.0, check=lambda x: 0 <= x < 1, expect="a drag factor in [0, 1)"),
        sqrt_approximation=so.boolean("sqrt_approximation", False),
        ordering=so.string("ordering", "coloured", choices=("coloured", "sequential")),
        threads=so.integer("threads", 0, minimum=0, maximum=_core.MAX_THREADS),
        max_speed=so.number("max_speed", 0.0, check=lambda x: x >= 0, allow_inf=True,
                            expect="a speed >= 0 m/s (0: automatic divergence guard, inf: off)"),
        precision=so.string("precision", "float64", choices=("float64", "float32")),
        settings=_method_settings(so),
    )
    so.finish()
    try:
        solver.stepper()  # combinations the stepper refuses (damping with Verlet, ...)
    except _core.ParameterError as e:
        raise so.error(None, str(e)) from None
    if solver.dt > duration:
        raise so.error("dt", f"the time step {solver.dt} s is longer than the scene's duration {duration} s")

    raw_meshes = top.raw("mesh", [])
    if not isinstance(raw_meshes, list) or not raw_meshes:
        raise top.error(None, "declare at least one [[mesh]]")
    meshes = tuple(_read_mesh(source, m, k, p.parent) for k, m in enumerate(raw_meshes))
    names = [m.name for m in meshes]
    for n in names:
        if names.count(n) > 1:
            raise SceneError(f"{p}: two meshes are named '{n}'; mesh names must be unique")

    raw_colliders = top.raw("collider", [])
    if not isinstance(raw_colliders, list):
        raise top.error("collider", "declare colliders as [[collider]] tables")
    colliders = tuple(_read_collider(source, c, k, p.parent) for k, c in enumerate(raw_colliders))

    tearing = None
    te = top.table("tearing", "tearing")
    if te is not None:
        tearing = TearingSpec(
            max_strain=te.number("max_strain", check=lambda x: x > 0, expect="a strain > 0"),
            max_per_step=te.integer("max_per_step", 10, minimum=1),
        )
        te.finish()

    tethers = None
    tt = top.table("tethers", "tethers")
    if tt is not None:
        tethers = TetherSpec(
            mode=tt.string("mode", "geodesic", choices=("geodesic", "euclidean")),
            max_stretch=tt.number("max_stretch", 1.0, check=lambda x: x >= 1, expect="a stretch factor >= 1"),
            stiffness=tt.number("stiffness", 1.0, check=lambda x: 0 <= x <= 1, expect="a stiffness in [0, 1]"),
            compliance=tt.number("compliance", 0.0, check=lambda x: x >= 0, expect="a compliance >= 0 (m/N)"),
            anchors=tt.integer("anchors", 1, minimum=1),
        )
        tt.finish()

    out = top.table("output", "output")
    # A torn model gains particles, which an XDMF series cannot follow: VTU only by default.
    output = OutputSpec(xdmf=tearing is None)
    if out is not None:
        output = OutputSpec(
            fps=out.number("fps", 30.0, check=lambda x: x > 0, expect="frames per second > 0"),
            xdmf=out.boolean("xdmf", tearing is None), vtu=out.boolean("vtu", True),
            csv=out.boolean("csv", True), plot=out.boolean("plot", True), usd=out.boolean("usd", False),
            gltf=out.boolean("gltf", False), obj=out.boolean("obj", False), ply=out.boolean("ply", False),
        )
        if tearing is not None and output.xdmf:
            raise out.error("xdmf", "an XDMF series cannot follow a model that tears (its particle count grows); "
                                    "use the VTU series")
        for key in ("usd", "gltf", "obj", "ply"):
            if tearing is not None and getattr(output, key):
                raise out.error(key, "the file's mesh cannot follow a model that tears (its particle count grows); "
                                     "use the VTU series")
        out.finish()
    top.finish()
    return Scene(p, name, duration, solver, meshes, output, description, colliders, tearing, tethers)


def bundled_scenes() -> dict[str, Path]:
    """Scenes shipped with csb, by name."""
    root = resources.files("csb") / "scenes"
    return {Path(str(f)).stem: Path(str(f)) for f in root.iterdir() if str(f).endswith(".toml")}


def find_scene(name_or_path: str | os.PathLike[str]) -> Path:
    """A path to a scene file as given, or the bundled scene of that name."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    bundled = bundled_scenes()
    if str(name_or_path) in bundled:
        return bundled[str(name_or_path)]
    raise FileNotFoundError(
        f"{name_or_path}: no such scene file, and no bundled scene of that name "
        f"(bundled: {', '.join(sorted(bundled))})")

