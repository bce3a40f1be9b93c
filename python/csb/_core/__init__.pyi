"""
csb compiled core: meshes, models, states and the PBD stepper
"""
from __future__ import annotations
import collections.abc
from csb import AccuracyWarning
from csb import ConcurrentUseError
from csb import Error
from csb import MaterialWarning
from csb import MeshError
from csb import ParameterError
from csb import SimulationError
import numpy
import numpy.typing
import typing
from . import kernels
__all__: list[str] = ['AccuracyWarning', 'BackwardEuler', 'BackwardEulerResidual', 'ConcurrentUseError', 'Error', 'ForceStepper', 'IncrementalPotential', 'Integrator', 'MAX_COLOURS', 'MAX_INDEX', 'MAX_ITERATIONS', 'MAX_SUBSTEPS', 'MAX_THREADS', 'MIN_COLOUR_SIZE', 'MIN_TASK_COLOUR_SIZE', 'MaterialWarning', 'Mesh', 'MeshError', 'MethodInfo', 'Model', 'ModelBuilder', 'ParameterError', 'PbdSettings', 'PbdStepper', 'Pick', 'Plugin', 'PluginIntegrator', 'ProjectiveDynamics', 'SettingInfo', 'SimulationError', 'SpringNetwork', 'State', 'TetMesh', 'VertexBlockDescent', 'backward_euler_residual', 'balloon_volumes', 'benchmark_dispatch', 'benchmark_jacobian', 'benchmark_plain_distance', 'bending_violations', 'build_info', 'chain', 'check_obj', 'cloth_grid', 'colour_constraints', 'corrected_stiffness', 'distance_violations', 'elastic_energy', 'kernels', 'load_plugin', 'lumped_measure', 'make_integrator', 'measure', 'method_info', 'methods', 'pbd_variant_names', 'pendulum', 'pick_particle', 'readable_extensions', 'save_mesh', 'tear', 'tet_box', 'topology', 'volume_violations']
class Mesh:
    """
    A triangle (and/or line) mesh before it enters the particle pool; metres.
    """
    def __init__(self, vertices: typing.Any, triangles: typing.Any = None, lines: typing.Any = None, name: str = 'mesh') -> None:
        """
        vertices: (N, 3) float, m. triangles: (T, 3) int. lines: (L, 2) int (ropes, chains).
        """
    def __repr__(self) -> str:
        ...
    @property
    def lines(self) -> numpy.typing.NDArray[numpy.int32]:
        """
        (L, 2) vertex indices of explicit segments (a copy)
        """
    @property
    def name(self) -> str:
        ...
    @property
    def num_vertices(self) -> int:
        ...
    @property
    def triangles(self) -> numpy.typing.NDArray[numpy.int32]:
        """
        (T, 3) vertex indices (a copy)
        """
    @property
    def vertices(self) -> numpy.typing.NDArray[numpy.float64]:
        """
        (N, 3) vertex positions, m (a copy)
        """
class TetMesh:
    """
    A tetrahedral volume mesh before it enters the particle pool; metres.
    """
    def __init__(self, points: typing.Any, tets: typing.Any, name: str = 'tet mesh') -> None:
        """
        points: (N, 3) float, m. tets: (M, 4) int point indices. Raises MeshError naming the mesh and the element for non-finite points, out-of-range or repeated indices, or no tets.
        """
    def __repr__(self) -> str:
        ...
    def surface(self) -> numpy.typing.NDArray[numpy.int32]:
        """
        (T, 3) the faces used by one tet, wound outwards for positively oriented tets
        """
    def volumes(self) -> numpy.typing.NDArray[numpy.float64]:
        """
        (M,) signed volume of every tet, m³ (positive: (p1 - p0) x (p2 - p0) points towards p3)
        """
    @property
    def name(self) -> str:
        ...
    @property
    def num_points(self) -> int:
        ...
    @property
    def num_tets(self) -> int:
        ...
    @property
    def points(self) -> numpy.typing.NDArray[numpy.float64]:
        """
        (N, 3) point positions, m (a copy)
        """
    @property
    def tets(self) -> numpy.typing.NDArray[numpy.int32]:
        """
        (M, 4) point indices (a copy)
        """
class State:
    """
    Positions (m), velocities (m/s) and time (s) of every particle.
    """
    def __repr__(self) -> str:
        ...
    def copy(self) -> State:
        """
        A deep copy (a checkpoint).
        """
    @property
    def num_particles(self) -> int:
        ...
    @property
    def step(self) -> int:
        """
        number of completed steps
        """
    @step.setter
    def step(self, arg1: int) -> None:
        ...
    @property
    def t(self) -> float:
        """
        time, s
        """
    @t.setter
    def t(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def v(self) -> numpy.ndarray:
        """
        (N, 3) velocities, m/s: a writable view, no copy
        """
    @v.setter
    def v(self, arg1: typing.Any) -> None:
        ...
    @property
    def x(self) -> numpy.ndarray:
        """
        (N, 3) positions, m: a writable view, no copy
        """
    @x.setter
    def x(self, arg1: typing.Any) -> None:
        ...
class Model:
    """
    Immutable: rest positions, masses, and one batch per constraint type. Arrays are read-only views.
    """
    def __repr__(self) -> str:
        ...
    def colouring(self, batch: str) -> dict:
        """
        The batch's graph colouring: order (constraint indices colour by colour), colour_offsets (colour k is order[offsets[k]:offsets[k+1]]), serial (per colour: its constraints may share particles and are projected in order), group_colours (group g owns colours group_colours[g]:group_colours[g+1]; with P = num_parts, groups 0..P-1 are the parts' interiors, P+i the interface of parts i and i+1, 2P-1 the rest)
        """
    def evaluate_family(self, family: str, x: typing.Any) -> dict:
        """
        A constraint family at positions x (N, 3) m, as the references see it: C (M,), grad (M, arity, 3) = ∂C/∂x, energy = Σ C₊²/(2α) J (C₊ = max(C, 0) for a unilateral family), forces (N, 3) = -∂energy/∂x N, jacobian (M, arity, arity, 3, 3): per constraint the blocks ∂f_i/∂x_j N/m (the Gauss-Newton term plus the curvature term where the family gives its Hessian). Hard constraints (α = 0) have no potential.
        """
    def initial_state(self) -> State:
        """
        A new State at the rest positions with zero velocities and t = 0.
        """
    @property
    def attachments(self) -> dict:
        """
        attachment batch: particle (M,), target (M, 3) m, stiffness, compliance (m/N)
        """
    @property
    def balloons(self) -> dict:
        """
        balloon batch: balloon b moves particles[particle_offsets[b]:particle_offsets[b+1]] and has triangles[triangle_offsets[b]:triangle_offsets[b+1]] (indices into its own particle list); rest_volume (m³), pressure (k_pressure: target volume pressure x rest_volume), stiffness, compliance (m⁶/J)
        """
    @property
    def bending(self) -> dict:
        """
        bending batch: particles (M, 4) = edge (a, b) and wings (c, d), rest_angle (rad), stiffness, compliance (1/(N m))
        """
    @property
    def colliders(self) -> list:
        """
        The static colliders, one dict each (copies): kind, name, material (friction_static, friction_kinetic, restitution) and the geometry of its kind, in m.
        """
    @property
    def distance(self) -> dict:
        """
        distance batch: particles (M, 2), rest_length (m), stiffness, compliance (m/N), sense (0: ==, +1: >=, -1: <=)
        """
    @property
    def families(self) -> dict:
        """
        Every constraint family's batch by name (see each family's own property, e.g. tethers)
        """
    @property
    def group(self) -> numpy.ndarray:
        """
        (N,) group index of each particle
        """
    @property
    def group_names(self) -> list[str]:
        ...
    @property
    def interface_phases(self) -> list[list[int]]:
        """
        The interfaces between parts (i: parts i and i+1) in phases whose interfaces share no particle
        """
    @property
    def inv_mass(self) -> numpy.ndarray:
        """
        (N,) inverse masses, 1/kg; 0 for pinned particles
        """
    @property
    def mass(self) -> numpy.ndarray:
        """
        (N,) masses, kg (kept for pinned particles)
        """
    @property
    def memory(self) -> dict:
        """
        Bytes the model's arrays hold (from their capacities), per part. Not counted: what stepping adds (PbdStepper.workspace_bytes, about as much again under PBD and twice under XPBD, and 48 B a particle per State) and the peak of building, when the builder's arrays, the mesh and the model coexist (about 5 x this total for a cloth). csb run reports the process's peak resident memory.
        """
    @property
    def num_constraints(self) -> int:
        ...
    @property
    def num_particles(self) -> int:
        ...
    @property
    def num_parts(self) -> int:
        """
        Parts of the particles (runs of indices or slabs along an axis) that group the colourings for the threads
        """
    @property
    def particle_parts(self) -> numpy.ndarray:
        """
        The part of each particle (see num_parts)
        """
    @property
    def rest_positions(self) -> numpy.ndarray:
        """
        (N, 3) rest positions, m
        """
    @property
    def self_collision_thickness(self) -> numpy.ndarray:
        """
        (G,) self-collision thickness h of each group, m (0: off)
        """
    @property
    def tethers(self) -> dict:
        """
        tethers batch: particles (M, 2), rest_length (m), stiffness, compliance (m/N); unilateral: C <= 0 is satisfied. A constraint family (constraints/family.hpp).
        """
    @property
    def thickness(self) -> numpy.ndarray:
        """
        (N,) collision radius of each particle against the colliders, m
        """
    @property
    def triangles(self) -> numpy.ndarray:
        """
        (T, 3) surface triangles (particle indices)
        """
    @property
    def volume(self) -> dict:
        """
        volume batch: particles (M, 4) of each tet, rest_volume (m³), stiffness, compliance (m⁶/J)
        """
class ModelBuilder:
    """
    Collects particles and constraints; build() returns the immutable Model.
    """
    def __init__(self) -> None:
        ...
    def _add_balloon(self, triangles: typing.Any, pressure: typing.SupportsFloat | typing.SupportsIndex = 1.0, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> int:
        ...
    def _add_mesh(self, mesh: Mesh, group: int = -1, mass: typing.Any = None, density: typing.Any = None, particle_mass: typing.Any = None, stretch_stiffness: typing.SupportsFloat | typing.SupportsIndex | None = 1.0, bending_stiffness: typing.SupportsFloat | typing.SupportsIndex | None = None, stretch_compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0, bending_compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0, thickness: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> dict:
        ...
    def _add_tet_mesh(self, mesh: TetMesh, group: int = -1, mass: typing.Any = None, density: typing.Any = None, particle_mass: typing.Any = None, stretch_stiffness: typing.SupportsFloat | typing.SupportsIndex | None = 1.0, stretch_compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0, volume_stiffness: typing.SupportsFloat | typing.SupportsIndex | None = 1.0, volume_compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> dict:
        ...
    def add_bending(self, a: int, b: int, c: int, d: int, stiffness: typing.SupportsFloat | typing.SupportsIndex, rest_angle: typing.SupportsFloat | typing.SupportsIndex | None = None, compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> int:
        """
        Dihedral bending across edge (a, b) with wings c, d: PBD stiffness in [0, 1], rest_angle in rad (default the current angle), compliance in 1/(N m) (0: hard).
        """
    def add_box(self, *, center: typing.Any, half_extents: typing.Any, rotation: typing.Any = None, friction_static: typing.SupportsFloat | typing.SupportsIndex = 0.0, friction_kinetic: typing.SupportsFloat | typing.SupportsIndex = 0.0, restitution: typing.SupportsFloat | typing.SupportsIndex = 0.0, name: str = '') -> int:
        """
        Static oriented box collider: center in m, half_extents > 0 m along the box's axes, rotation a 3 x 3 rotation matrix whose columns are those axes in the world (default identity); material as add_plane.
        """
    def add_capsule(self, *, a: typing.Any, b: typing.Any, radius: typing.SupportsFloat | typing.SupportsIndex, friction_static: typing.SupportsFloat | typing.SupportsIndex = 0.0, friction_kinetic: typing.SupportsFloat | typing.SupportsIndex = 0.0, restitution: typing.SupportsFloat | typing.SupportsIndex = 0.0, name: str = '') -> int:
        """
        Static capsule collider: the points within radius (> 0 m) of the segment a-b (m); material as add_plane.
        """
    def add_collider_mesh(self, mesh: Mesh, *, friction_static: typing.SupportsFloat | typing.SupportsIndex = 0.0, friction_kinetic: typing.SupportsFloat | typing.SupportsIndex = 0.0, restitution: typing.SupportsFloat | typing.SupportsIndex = 0.0, name: str = '') -> int:
        """
        Static triangle-mesh collider (any mesh csb.load_mesh reads), a two-sided sheet: a particle keeps the side it is on. Material as add_plane.
        """
    def add_constraint(self, family: str, particles: collections.abc.Sequence[int], params: collections.abc.Sequence[typing.SupportsFloat | typing.SupportsIndex], stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> int:
        """
        A constraint of a constraint family (Model.families): its particles (the family's arity), its parameters (the family's, in order and in their units), PBD stiffness in [0, 1], compliance in the family's unit (0: hard). Returns its index in the family's batch.
        """
    def add_distance(self, i: int, j: int, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, rest_length: typing.SupportsFloat | typing.SupportsIndex | None = None, sense: str = '==', compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> int:
        """
        Distance constraint: PBD stiffness in [0, 1], compliance in m/N (0: hard); rest_length in m, default the current distance; sense '==', '>=' (at least) or '<=' (at most, a tether). Returns its index.
        """
    def add_group(self, name: str) -> int:
        """
        Adds a particle group; returns its index.
        """
    def add_particle(self, x: typing.Any, mass: typing.SupportsFloat | typing.SupportsIndex, group: int) -> int:
        """
        One particle at x (m) of mass (kg) in a group; returns its index.
        """
    def add_plane(self, *, point: typing.Any = [0.0, 0.0, 0.0], normal: typing.Any = [0.0, 1.0, 0.0], friction_static: typing.SupportsFloat | typing.SupportsIndex = 0.0, friction_kinetic: typing.SupportsFloat | typing.SupportsIndex = 0.0, restitution: typing.SupportsFloat | typing.SupportsIndex = 0.0, name: str = '') -> int:
        """
        Static half-space collider: solid where (x - point)·normal < 0. point in m; normal any non-zero vector towards the free side. friction_static μs >= friction_kinetic μk >= 0 (Coulomb), restitution e in [0, 1]. Returns the collider's index.
        """
    def add_sphere(self, *, center: typing.Any, radius: typing.SupportsFloat | typing.SupportsIndex, friction_static: typing.SupportsFloat | typing.SupportsIndex = 0.0, friction_kinetic: typing.SupportsFloat | typing.SupportsIndex = 0.0, restitution: typing.SupportsFloat | typing.SupportsIndex = 0.0, name: str = '') -> int:
        """
        Static sphere collider: center in m, radius > 0 m; material as add_plane.
        """
    def add_tethers(self, *, mode: str = 'geodesic', max_stretch: typing.SupportsFloat | typing.SupportsIndex = 1.0, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0, anchors: int = 1) -> int:
        """
        Long range attachments (Kim, Chentanez and Müller 2012): tethers every free particle to its `anchors` nearest pinned particles (among those its distance constraints reach) with the unilateral constraint |x_i - x_a| <= L, L = max_stretch (>= 1) x the rest distance: 'euclidean' (the straight line in the rest positions) or 'geodesic' (the shortest path through the distance constraints, by rest length). Pin and add the meshes first. PBD stiffness in [0, 1], compliance in m/N (0: hard). Returns the tethers added; they are in Model.tethers.
        """
    def add_tetrahedron(self, a: int, b: int, c: int, d: int, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0, rest_volume: typing.SupportsFloat | typing.SupportsIndex | None = None) -> int:
        """
        Tetrahedral volume constraint C = V - V0: PBD stiffness in [0, 1], compliance in m⁶/J (0: hard), rest_volume in m³ (default the current signed volume, which must be > 0: d on the side of (b - a) x (c - a)). Returns its index.
        """
    def attach(self, i: int, target: typing.Any, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> int:
        """
        Holds particle i at a world point (m): PBD stiffness in [0, 1], compliance in m/N (0: hard).
        """
    def build(self) -> Model:
        ...
    def enable_self_collision(self, group: int, thickness: typing.SupportsFloat | typing.SupportsIndex) -> None:
        """
        Point-triangle self-collision of a group's cloth (Müller 2007 §4.4) with thickness h > 0 m; keep h below the cloth's edge length.
        """
    def pin(self, i: int) -> None:
        """
        Fixes particle i (inverse mass 0).
        """
    def position(self, i: int) -> numpy.ndarray:
        ...
    def set_thickness(self, group: int, thickness: typing.SupportsFloat | typing.SupportsIndex) -> None:
        """
        Collision radius (m, >= 0) of every particle of a group against the colliders.
        """
    @property
    def num_colliders(self) -> int:
        ...
    @property
    def num_particles(self) -> int:
        ...
class Integrator:
    """
    The step-level interface every method implements: name(), dt() (s) and step(model, state, steps=1, interrupt=None), which advances the state in place by `steps` steps of dt (positions, velocities, state.t and state.step). PbdStepper and ForceStepper are Integrators; so is a Python subclass that implements the three methods (calling Integrator.__init__ in its own __init__), and it is then accepted wherever a built-in is: the scene runner, csb.render and csb.view, the studies. `interrupt`, when not None, is a callable a long step may ask between steps whether to stop.
    """
    def __init__(self) -> None:
        ...
    def __repr__(self) -> str:
        ...
    def dt(self) -> float:
        """
        s, the time one step advances.
        """
    def name(self) -> str:
        """
        A short name of the method ('pbd', 'symplectic-euler', a user's own).
        """
    def step(self, model: Model, state: State, steps: int = 1, interrupt: typing.Any = None) -> None:
        """
        Advances state by `steps` steps of dt.
        """
class SettingInfo:
    """
    One of a method's own settings: make_integrator's keyword, a scene's [solver.settings] key.
    """
    def __repr__(self) -> str:
        ...
    @property
    def default(self) -> str:
        """
        as a scene file writes it
        """
    @property
    def description(self) -> str:
        """
        what it is, its unit and range
        """
    @property
    def name(self) -> str:
        ...
class MethodInfo:
    """
    A method csb can step with, as listed by csb.methods().
    """
    def __repr__(self) -> str:
        ...
    @property
    def aliases(self) -> list[str]:
        """
        other names it answers to
        """
    @property
    def iterates(self) -> bool:
        """
        whether `iterations` means anything to it
        """
    @property
    def label(self) -> str:
        """
        for tables and the viewer
        """
    @property
    def name(self) -> str:
        """
        how to ask for it: make_integrator(name, dt)
        """
    @property
    def pbd_variant(self) -> bool:
        """
        whether PbdStepper(method=name) and a scene's solver.method take this name (small steps is a set-up of XPBD, not a variant of its own)
        """
    @property
    def reads(self) -> str:
        """
        what it reads of a constraint's material: 'stiffness' or 'compliance'
        """
    @property
    def settings(self) -> list[SettingInfo]:
        """
        its own settings, beyond dt, substeps, iterations and gravity
        """
    @property
    def source(self) -> str:
        """
        where it comes from
        """
class PbdSettings:
    """
    Settings of a position-based stepper (SI units).
    """
    def __repr__(self) -> str:
        ...
    @property
    def damping(self) -> float:
        """
        Müller 2007 §3.5 k_damping per substep, [0, 1]
        """
    @property
    def dt(self) -> float:
        """
        s, time advanced by one step
        """
    @property
    def front_end(self) -> str:
        ...
    @property
    def gravity(self) -> numpy.ndarray:
        """
        m/s²
        """
    @property
    def iterations(self) -> int:
        ...
    @property
    def max_speed(self) -> float:
        """
        m/s, the divergence guard (0: automatic, inf: off)
        """
    @property
    def method(self) -> str:
        ...
    @property
    def ordering(self) -> str:
        ...
    @property
    def precision(self) -> str:
        """
        the solver's scalar: 'float64' or 'float32'
        """
    @property
    def solver(self) -> str:
        ...
    @property
    def sqrt_approximation(self) -> bool:
        ...
    @property
    def stiffness_correction(self) -> bool:
        ...
    @property
    def substeps(self) -> int:
        ...
    @property
    def threads(self) -> int:
        """
        threads that share a sweep (parts and interfaces as tasks); 0: automatic
        """
    @property
    def verlet_drag(self) -> float:
        """
        Jakobsen's drag d in [0, 1)
        """
    @property
    def xpbd_damping(self) -> float:
        """
        XPBD constraint damping β, N s/m
        """
class PbdStepper(Integrator):
    """
    Position-based stepper: Müller et al. 2007 PBD, Macklin et al. 2016 XPBD, or Jakobsen 2001 Verlet with relaxation.
    """
    def __init__(self, *, method: str = 'pbd', dt: typing.SupportsFloat | typing.SupportsIndex = 0.016666666666666666, substeps: int = 1, iterations: int = 10, gravity: typing.Any = [0.0, -9.81, 0.0], damping: typing.SupportsFloat | typing.SupportsIndex = 0.0, stiffness_correction: bool = True, front_end: str = 'auto', solver: str = 'gauss-seidel', xpbd_damping: typing.SupportsFloat | typing.SupportsIndex = 0.0, verlet_drag: typing.SupportsFloat | typing.SupportsIndex = 0.0, sqrt_approximation: bool = False, ordering: str = 'coloured', threads: int = 0, max_speed: typing.SupportsFloat | typing.SupportsIndex = 0.0, precision: str = 'float64') -> None:
        """
        method: 'pbd' (stiffness k), 'xpbd' (compliance α) or 'jakobsen'. dt: time step, s (> 0). substeps: sub-steps per step, in [1, 10^6]. iterations: constraint sweeps per sub-step, in [1, 10^6]. gravity: m/s². damping: Müller §3.5 k_damping in [0, 1] per sub-step (Euler front end). stiffness_correction: PBD's k' = 1 - (1 - k)^(1/iterations). front_end: 'euler' (velocity), 'verlet' (previous position) or 'auto' (Verlet for Jakobsen). solver: 'gauss-seidel', 'jacobi' (averaged) or 'jacobi-summed'. xpbd_damping: β, N s/m (XPBD). verlet_drag: Jakobsen's d in [0, 1). sqrt_approximation: Jakobsen's stick relaxation without square roots. ordering: 'coloured' (the model's parts and interfaces as the threads' tasks, each batch of a task colour by colour in SIMD lanes) or 'sequential' (as built, one thread). threads: threads that share a sweep, in [0, 1024] (0: the free cores, at most the model's parts; the result does not depend on it). max_speed: the divergence guard, m/s: a step after which a movable particle is faster raises SimulationError naming it (0: automatic, D/h + 2 (v0 + |g| t + sqrt(2 |g| D)) with D the model's size and v0 the fastest start speed; inf: off). precision: the solver's scalar, 'float64' or 'float32' (the state rounded to float during a step: twice the SIMD lanes, half the bytes; coloured Gauss-Seidel, distance and bending constraints and pins, without contacts or grabs).
        """
    def attach(self, model: Model, state: State, collider: int, particles: collections.abc.Iterable) -> None:
        """
        Attaches particles to collider `collider`: kinematic while attached (inverse mass 0 in the projections), each placed at the collider's pose, interpolated over the sub-steps, applied to where it is in the collider's frame now (a cape on a moving character's shoulders).
        """
    def collider_pose(self, collider: int) -> tuple[numpy.typing.NDArray[numpy.float64], numpy.ndarray]:
        """
        The pose (rotation, translation in m) of a collider at the end of the last step.
        """
    def collider_vertices(self, model: Model, collider: int) -> numpy.typing.NDArray[numpy.float64]:
        """
        A mesh collider's vertices (V x 3, m, model frame) at the end of the last step: the model's until deformed.
        """
    def contacts(self) -> dict:
        """
        The contacts of the last sub-step: count (particle-collider, speculative ones included), active (those that pushed their particle), self_count (self-contacts: proximity point-triangle, and continuous), self_continuous (found by the continuous test), self_failsafe (particles the fail-safe stopped), self_unresolved (impacts only prescribed particles drive), self_searches (candidate-pair searches since the stepper was made), self_skipped (triangles left out: spread over more than the cloth's size within a step), max_depth (m, deepest violation r - (p - q)·n at the prediction), max_penetration (m, deepest violation left at the end of the sub-step, thickness included; the larger of collider_penetration, the collider contacts', which they take last and so leave at round-off, and self_penetration, the self-contacts', which a collider's push after them may leave thinner than their thickness), and per contact: particle, collider, point q (m), normal n, normal_correction (m) and lambda (XPBD multiplier, kg m; force λ/h² N).
        """
    def deform_collider(self, model: Model, collider: int, vertices: typing.Any) -> None:
        """
        Sets the vertices (V x 3, m, the collider's model frame, in the order of model.colliders[collider]['vertices']) mesh collider `collider` reaches at the end of the next step: each moves there on a straight line over the step's sub-steps (then carried by its pose, if moved). Particles are tested against the moving triangles continuously; friction and restitution see the surface's velocity; attached particles follow their triangle. The first call deforms from the model's vertices.
        """
    def detach(self, collider: int, particles: collections.abc.Iterable | None = None) -> None:
        """
        Lets go of `particles` attached to collider `collider` (all of them if None); they keep their velocity.
        """
    def grab(self, model: Model, state: State, particle: int, target: typing.Any, *, compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> int:
        """
        Holds `particle` with the hand at `target` (m) and returns a handle (click and drag). compliance 0: the particle follows the hand exactly, moved along a straight line over the sub-steps of the next step; compliance > 0 (m/N): an XPBD spring to the hand. The hand starts where the particle is now.
        """
    def move_collider(self, model: Model, collider: int, rotation: typing.Any, translation: typing.Any) -> None:
        """
        Sets the pose collider `collider` reaches at the end of the next step: x_world = rotation x_model + translation (rotation a 3 x 3 rotation matrix, orthonormal with det +1 to 1e-6; translation in m). Over the step's sub-steps it moves there from its present pose (translation linearly, rotation by quaternion slerp, so less than π a step); contacts see the motion relative to it, friction and restitution the relative velocity. Every collider starts at the identity.
        """
    def move_grab(self, handle: int, target: typing.Any) -> None:
        """
        Moves the hand of a grab (m); the next step takes the particle there.
        """
    def multipliers(self) -> dict:
        """
        XPBD: the Lagrange multipliers λ of the last sub-step per batch and per constraint family (tethers: λ <= 0) (empty otherwise); the constraint force is λ/h² along ∇C (N for distance constraints and tethers; for volume and balloon λ/h² is a pressure, Pa).
        """
    def operations(self, model: Model, steps: int) -> float:
        """
        Constraint projections and particle updates of `steps` steps of the model: step() refuses (csb.ParameterError, with the estimate) a request that would take more than a year at 1e9 a second
        """
    def projections_per_step(self, model: Model) -> int:
        ...
    def release(self, handle: int) -> None:
        """
        Lets go of a grab; the particle keeps the velocity it had.
        """
    def step(self, model: Model, state: State, steps: int = 1, interrupt: typing.Any = None) -> None:
        """
        Advances state by `steps` steps of dt (the GIL is released meanwhile; Ctrl-C, or `interrupt` (a callable asked between sub-steps) returning True, stops it between sub-steps, the state left at the end of the last completed one; a second thread stepping the same stepper meanwhile gets csb.ConcurrentUseError). The first time this stepper steps a model, a csb.MaterialWarning per constraint family whose declared material the method cannot read: PBD and Jakobsen read the stiffness k, XPBD the compliance α, so constraints with only α > 0 (k = 1) are rigid under PBD and Jakobsen, those with only k < 1 (α = 0) rigid under XPBD.
        """
    @property
    def attachments(self) -> list:
        """
        The particles attached to colliders: collider, particle, local (m, its position in the collider's frame); on a mesh collider also triangle (the nearest when attached, -1 otherwise) and frame (u, v, w): local = a + u (b - a) + v (c - a) + w n in that triangle (w in m), the point that follows the mesh when it deforms.
        """
    @property
    def grabs(self) -> list:
        """
        The grabs held now: handle, particle, target (m), compliance (m/N).
        """
    @property
    def settings(self) -> PbdSettings:
        ...
    @property
    def substep_size(self) -> float:
        """
        h = dt/substeps, s
        """
    @property
    def threads_used(self) -> int:
        """
        threads the last step used
        """
    @property
    def workspace_bytes(self) -> int:
        """
        bytes of the stepper's per-model workspace (from the vectors' capacities)
        """
class Pick:
    """
    What a ray cast found: the particle (-1: none), the distance along the ray (m) and the surface triangle hit (-1: found by proximity to the ray).
    """
    def __repr__(self) -> str:
        ...
    @property
    def distance(self) -> float:
        ...
    @property
    def particle(self) -> int:
        ...
    @property
    def triangle(self) -> int:
        ...
class ForceStepper(Integrator):
    """
    Force-based mass-spring integrators on the reference's spring network (every constraint a spring of stiffness 1/α): the methods that fail, for the stability studies.
    """
    def __init__(self, *, method: str = 'symplectic-euler', dt: typing.SupportsFloat | typing.SupportsIndex = 0.0001, substeps: int = 1, gravity: typing.Any = [0.0, -9.81, 0.0], damping: typing.SupportsFloat | typing.SupportsIndex = 0.0, drag: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> None:
        """
        method: 'explicit-euler', 'symplectic-euler' or 'velocity-verlet'. dt: s. damping: N s/m along springs. drag: 1/s.
        """
    def step(self, model: Model, state: State, steps: int = 1, interrupt: typing.Any = None) -> None:
        """
        Advances state by `steps` steps of dt (the GIL is released meanwhile; Ctrl-C, or `interrupt` (a callable asked between steps) returning True, stops it between steps, the state left at the end of the last completed one). A request that would take more than a year at 1e9 spring and particle updates a second is refused (csb.ParameterError, with the estimate).
        """
    @property
    def force_evaluations(self) -> int:
        """
        Evaluations of the spring network's forces since construction: one per sub-step (velocity Verlet reuses the end of a sub-step's forces at the start of the next, unless damping or drag make them depend on the velocity: then two).
        """
class Plugin:
    """
    A method brought as a plug-in: a shared library written against csb_plugin.h (in csb.plugin_include_dir()), loaded by csb.load_plugin(path). Calling it, plugin(dt=..., substeps=1, iterations=10, gravity=(0, -9.81, 0)), makes a csb.PluginIntegrator, a csb.Integrator that the runner, the viewer and the studies step like a built-in; so the Plugin itself can be passed wherever a callable making an Integrator is taken (csb.studies.make_stepper).
    """
    def __call__(self, dt: typing.SupportsFloat | typing.SupportsIndex, *, substeps: int = 1, iterations: int = 10, gravity: typing.Any = [0.0, -9.81, 0.0]) -> PluginIntegrator:
        """
        An integrator of this plug-in with step dt (s), `substeps` sub-steps per step, `iterations` constraint sweeps per sub-step and gravity (m/s²): a csb.PluginIntegrator. Settings out of range are a csb.ParameterError naming them, as are settings the plug-in refuses (with its message).
        """
    def __reduce__(self) -> tuple:
        ...
    def __repr__(self) -> str:
        ...
    @property
    def abi_version(self) -> int:
        """
        the version of csb_plugin.h it was built for
        """
    @property
    def name(self) -> str:
        """
        the method's name, as csb_plugin_name() gives it
        """
    @property
    def path(self) -> str:
        """
        the file it was loaded from, as given
        """
class PluginIntegrator(Integrator):
    """
    An integrator of a plug-in (csb.load_plugin(path)(dt=...)): a csb.Integrator. step() calls the plug-in one step at a time, checks that every position and velocity is finite and advances state.t and state.step; a step the plug-in reports as failed, or one that leaves a non-finite value, puts the state back at the end of the last completed step and raises csb.SimulationError (csb.ParameterError for a model or settings the plug-in refuses), naming the plug-in, its file, the step and the plug-in's message.
    """
    @property
    def gravity(self) -> numpy.ndarray:
        """
        m/s²
        """
    @property
    def iterations(self) -> int:
        ...
    @property
    def plugin(self) -> Plugin:
        """
        the csb.Plugin it was made from
        """
    @property
    def substeps(self) -> int:
        ...
class SpringNetwork:
    """
    The reference's first-order system y' = f(y), y = [x; v] of the dynamic particles: for tests and studies.
    """
    def __init__(self, model: Model, start: State, *, gravity: typing.Any = [0.0, -9.81, 0.0], damping: typing.SupportsFloat | typing.SupportsIndex = 0.0, drag: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> None:
        ...
    def jacobian(self, y: typing.Annotated[numpy.typing.ArrayLike, numpy.float64]) -> tuple[numpy.typing.NDArray[numpy.int64], numpy.typing.NDArray[numpy.int64], numpy.typing.NDArray[numpy.float64]]:
        """
        (indptr, indices, data) of ∂f/∂y in compressed sparse columns (scipy.sparse.csc_matrix order); with bending, only the spring and attachment part
        """
    def pack(self, state: State) -> numpy.typing.NDArray[numpy.float64]:
        """
        y = [x; v] of the dynamic particles
        """
    def rhs(self, y: typing.Annotated[numpy.typing.ArrayLike, numpy.float64]) -> numpy.typing.NDArray[numpy.float64]:
        ...
    @property
    def has_analytic_jacobian(self) -> bool:
        ...
    @property
    def num_dynamic(self) -> int:
        ...
    @property
    def size(self) -> int:
        ...
class BackwardEulerResidual:
    """
    The backward-Euler residual ∇E of a step (N): its 2-norm, its largest component and the step's force scale (the largest of m|g|, the constraint forces and the inertia m|x - x̃|/h²).
    """
    def __repr__(self) -> str:
        ...
    @property
    def max(self) -> float:
        """
        N, largest component
        """
    @property
    def norm(self) -> float:
        """
        N, 2-norm over the dynamic particles' coordinates
        """
    @property
    def scale(self) -> float:
        """
        N, the step's force scale
        """
class IncrementalPotential:
    """
    The incremental potential of one backward Euler step, E(x) = Σ m|x - x̃|²/(2h²) + U(x), from the state before the step: for tests and studies. Positions are (N, 3) arrays of all particles; the pinned ones stay where `pinned_at` (default: `previous`) has them and carry no gradient.
    """
    def __init__(self, model: Model, previous: State, dt: typing.SupportsFloat | typing.SupportsIndex, *, gravity: typing.Any = [0.0, -9.81, 0.0], pinned_at: typing.Any = None) -> None:
        ...
    def energy(self, x: typing.Any) -> float:
        """
        E(x), J
        """
    def gradient(self, x: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        ∇E(x), N, (N, 3), zero on the pinned particles
        """
    def hessian(self, x: typing.Any, *, definite: bool = False) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        """
        ∇²E(x), N/m, dense (3n, 3n) over the dynamic particles (rows in dynamic_particles' order); with definite=True the Gauss-Newton form Newton's method falls back to
        """
    @property
    def dynamic_particles(self) -> numpy.typing.NDArray[numpy.int32]:
        """
        the particles that move, in the order of the Hessian's rows (3 each)
        """
    @property
    def inertial_positions(self) -> numpy.typing.NDArray[numpy.float64]:
        """
        x̃ = x + h v + h² g of the dynamic particles, m, (n, 3)
        """
class BackwardEuler(Integrator):
    """
    Implicit (backward) Euler over every compliant constraint (distance, bending, volume, balloons, attachments, tethers and the other families), each step's incremental potential minimised by Newton's method (Baraff and Witkin 1998). newton_iterations = 0 (the default, method 'backward-euler'): to convergence (sparse LDLᵀ, Armijo line search, Gauss-Newton where the Hessian is indefinite), the same-step reference. newton_iterations = n > 0 (method 'implicit-euler'): the budgeted form, at most n Newton iterations per step, each solved by block-Jacobi preconditioned conjugate gradients on a fixed budget (the Gauss-Newton Hessian) or by the sparse LDLᵀ.
    """
    def __init__(self, *, dt: typing.SupportsFloat | typing.SupportsIndex = 0.016666666666666666, substeps: int = 1, gravity: typing.Any = [0.0, -9.81, 0.0], rtol: typing.SupportsFloat | typing.SupportsIndex = 1e-09, max_iterations: int = 100, newton_iterations: int = 0, linear_solver: str = 'direct', cg_iterations: int = 100, cg_tolerance: typing.SupportsFloat | typing.SupportsIndex = 0.0001, line_search: bool = True, initial_guess: str = 'inertia', contact_stiffness: typing.SupportsFloat | typing.SupportsIndex = 10000.0) -> None:
        """
        dt: s, the time a step advances, in `substeps` backward Euler steps of dt/substeps. gravity: m/s². rtol: the largest residual component at which a step stops, relative to the step's force scale, on top of the rounding floor. max_iterations: Newton iterations per step of the converged form. newton_iterations: 0 to convergence, n > 0 the budgeted form. linear_solver: 'direct' or 'cg' (budgeted form). cg_iterations, cg_tolerance: CG's budget per Newton iteration and its relative residual for stopping early. line_search: Armijo backtracking (the converged form needs it). initial_guess: 'inertia' (x̃), 'previous' (xⁿ) or 'lower' (the one with the lower incremental potential). contact_stiffness: κ, contacts with colliders as a penalty of stiffness κ m/h² (N/m).
        """
    def step(self, model: Model, state: State, steps: int = 1, interrupt: typing.Any = None) -> None:
        """
        Advances state by `steps` steps of dt (the GIL released meanwhile; `interrupt`, a callable asked between steps, returning True stops it, the state left at the end of the last completed step).
        """
    @property
    def cg_iterations(self) -> int:
        """
        conjugate-gradient iterations of the last step, in all (budgeted form with linear_solver 'cg')
        """
    @property
    def definiteness_fixes(self) -> int:
        """
        Newton steps of the last step that took the Gauss-Newton form or a shift
        """
    @property
    def gravity(self) -> numpy.ndarray:
        """
        m/s²
        """
    @property
    def history(self) -> numpy.typing.NDArray[numpy.float64]:
        """
        N, the last step's largest residual component before each Newton step and at the end
        """
    @property
    def line_search_halvings(self) -> int:
        ...
    @property
    def linear_solver(self) -> str:
        ...
    @property
    def max_iterations(self) -> int:
        ...
    @property
    def max_residual(self) -> float:
        """
        N, over all steps so far
        """
    @property
    def newton_iterations(self) -> int:
        """
        Newton iterations of the last step
        """
    @property
    def residual(self) -> float:
        """
        N, the last step's largest residual component at the end
        """
    @property
    def residual_norm(self) -> float:
        """
        N, its 2-norm
        """
    @property
    def rtol(self) -> float:
        ...
    @property
    def self_collision(self) -> dict:
        """
        what self-collision did in the last sub-step: contacts, continuous, failsafe, unresolved, skipped and candidates there; searches, tests and culled (pairs left untested in certified patches) since the model was first stepped
        """
    @property
    def substeps(self) -> int:
        ...
    @property
    def tolerance(self) -> float:
        """
        N, the bound the last step's residual met
        """
    @property
    def total_iterations(self) -> int:
        """
        Newton iterations, all steps
        """
class VertexBlockDescent(Integrator):
    """
    Vertex Block Descent (Chen, Liu, Yang and Yuksel 2024): each sub-step minimises the backward Euler step's incremental potential over every compliant constraint by `iterations` sweeps of per-vertex Newton steps, colour by colour (a colour's vertices share no constraint and update in parallel). Reads compliance; takes contacts with colliders as a penalty and self-collision as a layer after each sub-step's solve; refuses hard constraints.
    """
    def __init__(self, *, dt: typing.SupportsFloat | typing.SupportsIndex = 0.016666666666666666, substeps: int = 1, iterations: int = 10, gravity: typing.Any = [0.0, -9.81, 0.0], initialization: str = 'adaptive', acceleration: typing.SupportsFloat | typing.SupportsIndex = 0.0, threads: int = 0, contact_stiffness: typing.SupportsFloat | typing.SupportsIndex = 10000.0) -> None:
        """
        dt: s, the time a step advances, in `substeps` sub-steps. iterations: VBD sweeps over all vertices per sub-step. gravity: m/s². initialization: 'adaptive', 'inertia' or 'previous'. acceleration: ρ of the Chebyshev acceleration in [0, 1), 0 off. threads: 0 automatic; the result does not depend on it. contact_stiffness: κ, contacts with colliders as a penalty of stiffness κ m/h² (N/m).
        """
    def residual(self, model: Model) -> BackwardEulerResidual:
        """
        The backward-Euler residual (csb.BackwardEulerResidual, N) of the last sub-step taken on `model`: what the sweeps left of ∇E; computed when asked.
        """
    def step(self, model: Model, state: State, steps: int = 1, interrupt: typing.Any = None) -> None:
        """
        Advances state by `steps` steps of dt (the GIL released meanwhile).
        """
    @property
    def acceleration(self) -> float:
        ...
    @property
    def gravity(self) -> numpy.ndarray:
        """
        m/s²
        """
    @property
    def initialization(self) -> str:
        ...
    @property
    def iterations(self) -> int:
        ...
    @property
    def num_colours(self) -> int:
        """
        vertex colours of the last model stepped
        """
    @property
    def self_collision(self) -> dict:
        """
        what self-collision did in the last sub-step: contacts, continuous, failsafe, unresolved, skipped and candidates there; searches, tests and culled (pairs left untested in certified patches) since the model was first stepped
        """
    @property
    def substeps(self) -> int:
        ...
    @property
    def threads(self) -> int:
        """
        as set (0: automatic)
        """
    @property
    def threads_used(self) -> int:
        """
        threads of the last step
        """
class ProjectiveDynamics(Integrator):
    """
    Projective Dynamics (Bouaziz et al. 2014) with optional Chebyshev acceleration (Wang 2015): each sub-step minimises backward Euler's incremental potential with every constraint's potential made projective, by `iterations` local projections and global solves with a matrix factored once per model and sub-step length. Reads compliance: exact for distance constraints and attachments, first order for bending, volumes, balloons and tethers. Holds contacts with colliders by projection after each global solve and runs self-collision as a layer after each sub-step's solve; refuses hard constraints.
    """
    def __init__(self, *, dt: typing.SupportsFloat | typing.SupportsIndex = 0.016666666666666666, substeps: int = 1, iterations: int = 10, gravity: typing.Any = [0.0, -9.81, 0.0], chebyshev: bool = False, spectral_radius: typing.SupportsFloat | typing.SupportsIndex = 0.0, chebyshev_delay: int = 10, relaxation: typing.SupportsFloat | typing.SupportsIndex = 0.9, threads: int = 0, record_residuals: bool = False) -> None:
        """
        dt: s, the time a step advances, in `substeps` sub-steps. iterations: local/global iterations per sub-step. gravity: m/s². chebyshev: Wang 2015's acceleration, with spectral_radius ρ in (0, 1) (0: measured each sub-step), chebyshev_delay S plain iterations first and the under-relaxation `relaxation` γ in (0, 1]. threads: of the local step, 0 automatic; the result does not depend on it. record_residuals: keep the backward-Euler residual after each iteration of the last sub-step.
        """
    def step(self, model: Model, state: State, steps: int = 1, interrupt: typing.Any = None) -> None:
        """
        Advances state by `steps` steps of dt (the GIL released meanwhile).
        """
    @property
    def chebyshev(self) -> bool:
        ...
    @property
    def chebyshev_delay(self) -> int:
        ...
    @property
    def factorization_time(self) -> float:
        """
        s, wall time of all factorisations (the terms' set-up included)
        """
    @property
    def factorizations(self) -> int:
        """
        factorisations of the global matrix so far (one per model and sub-step length)
        """
    @property
    def gravity(self) -> numpy.ndarray:
        """
        m/s²
        """
    @property
    def iterations(self) -> int:
        ...
    @property
    def last_factorization_time(self) -> float:
        """
        s, wall time of the latest factorisation
        """
    @property
    def measured_spectral_radius(self) -> float:
        """
        the last measurement of ρ (spectral_radius 0), also when outside (0, 1) and so not used
        """
    @property
    def record_residuals(self) -> bool:
        ...
    @property
    def relaxation(self) -> float:
        ...
    @property
    def residual_history(self) -> list[float]:
        """
        N, with record_residuals: the largest backward-Euler residual component of the last sub-step at its start (x̃) and after each iteration (iterations + 1 values); empty otherwise
        """
    @property
    def self_collision(self) -> dict:
        """
        what self-collision did in the last sub-step: contacts, continuous, failsafe, unresolved, skipped and candidates there; searches, tests and culled (pairs left untested in certified patches) since the model was first stepped
        """
    @property
    def spectral_radius(self) -> float:
        """
        as set (0: measured each sub-step)
        """
    @property
    def spectral_radius_used(self) -> float:
        """
        ρ the last sub-step's Chebyshev acceleration used (0: none)
        """
    @property
    def substeps(self) -> int:
        ...
    @property
    def threads(self) -> int:
        """
        as set (0: automatic)
        """
    @property
    def threads_used(self) -> int:
        """
        threads of the last sub-step's local steps
        """
def _add_python_family(builder: ModelBuilder, evaluate: typing.Any, name: str, label: str, arity: typing.SupportsInt | typing.SupportsIndex, param_names: collections.abc.Sequence[str], param_units: collections.abc.Sequence[str], unilateral: bool, compliance_unit: str) -> None:
    """
    Registers a constraint family written in Python with the builder (csb.ModelBuilder.add_family).
    """
def _clean(mesh: Mesh, weld: bool = True, weld_tolerance: typing.SupportsFloat | typing.SupportsIndex = 1e-06, drop_unreferenced: bool = True) -> tuple[Mesh, dict]:
    ...
def _integrate_reference(model: Model, start: State, times: collections.abc.Sequence[typing.SupportsFloat | typing.SupportsIndex], gravity: typing.Any, rtol: typing.SupportsFloat | typing.SupportsIndex, atol: typing.SupportsFloat | typing.SupportsIndex, damping: typing.SupportsFloat | typing.SupportsIndex, drag: typing.SupportsFloat | typing.SupportsIndex, max_order: int, stability_limit_detection: bool, linear_solver: str, max_steps: int, max_wall_time: typing.SupportsFloat | typing.SupportsIndex) -> tuple[numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.float64], dict]:
    ...
def _load_animation(path: str, times: typing.Any = None, animation: typing.SupportsInt | typing.SupportsIndex = 0, animation_name: str = '', timeout: typing.SupportsFloat | typing.SupportsIndex = 0.0, max_memory: typing.SupportsFloat | typing.SupportsIndex = 2147483648.0) -> dict:
    ...
def _load_mesh(path: str, weld: bool = True, weld_tolerance: typing.SupportsFloat | typing.SupportsIndex = 1e-06, timeout: typing.SupportsFloat | typing.SupportsIndex = 0.0, max_memory: typing.SupportsFloat | typing.SupportsIndex = 2147483648.0) -> tuple[Mesh, dict, dict, typing.Any]:
    ...
def _require_time_for(what: str, operations: typing.SupportsFloat | typing.SupportsIndex) -> None:
    ...
def backward_euler_residual(model: Model, previous: State, next: State, dt: typing.SupportsFloat | typing.SupportsIndex, gravity: typing.Any = [0.0, -9.81, 0.0]) -> BackwardEulerResidual:
    """
    The backward-Euler residual |∇E(x_next)| (N) of a step of dt (s) from `previous` to `next` taken by any method: E(x) = Σ m|x - x̃|²/(2h²) + Σ C²/(2α), x̃ = x_prev + h v_prev + h² g (gravity, m/s²), the pinned particles where `next` has them. Zero for a converged backward Euler step; the solver error of an iterative method's step. A hard constraint (α = 0) is a csb.ParameterError naming it.
    """
def balloon_volumes(model: Model, state: State) -> numpy.typing.NDArray[numpy.float64]:
    """
    Volume enclosed by every balloon's surface, m³.
    """
def benchmark_dispatch(model: Model, positions: typing.Any, sweeps: int, repeats: int) -> dict:
    """
    Gauss-Seidel sweeps through the batched kernels and through one virtual Constraint object per constraint: ns per projection of each repeat, and whether the results agree bit for bit.
    """
def benchmark_jacobian(network: ..., state: State, repeats: int) -> list[float]:
    """
    ms per assembly of the reference's sparse Jacobian (the values into its fixed CSC pattern), per repeat.
    """
def benchmark_plain_distance(model: Model, positions: typing.Any, sweeps: int, repeats: int) -> list[float]:
    """
    The baseline the coloured sweep is measured against: a plain sequential loop over the model's distance constraints in build order, in double precision (Müller's projection, stiffness 1), one thread; ns per projection of each repeat.
    """
def bending_violations(model: Model, state: State) -> numpy.typing.NDArray[numpy.float64]:
    """
    Violation θ - θ0 of every bending constraint, rad.
    """
def build_info() -> dict:
    """
    Versions of csb and of the libraries it was built against, and whether the viewer was built.
    """
def chain(links: int, link_length: typing.SupportsFloat | typing.SupportsIndex, start: typing.Any = [0.0, 0.0, 0.0], direction: typing.Any = [1.0, 0.0, 0.0]) -> Mesh:
    """
    A chain of `links` segments of link_length m from start (m) along direction.
    """
def check_obj(path: str) -> None:
    """
    Strict OBJ syntax check naming the line of the first problem.
    """
def cloth_grid(width: typing.SupportsFloat | typing.SupportsIndex, height: typing.SupportsFloat | typing.SupportsIndex, nx: int, ny: int, plane: str = 'xz', center: typing.Any = [0.0, 0.0, 0.0]) -> Mesh:
    """
    Rectangular cloth of nx x ny particles spanning width x height m in `plane`, centred on `center` (m).
    """
def colour_constraints(particles: typing.Annotated[numpy.typing.ArrayLike, numpy.int32], num_particles: int, min_colour_size: int = 64) -> dict:
    """
    The greedy colouring a Model gives a batch whose constraint c has particles[c] (see Model.colouring).
    """
def corrected_stiffness(stiffness: typing.SupportsFloat | typing.SupportsIndex, iterations: int) -> float:
    """
    1 - (1 - k)^(1/iterations), Müller 2007 §3.3.
    """
def distance_violations(model: Model, state: State) -> numpy.typing.NDArray[numpy.float64]:
    """
    Violation |xi - xj| - rest of every distance constraint, m.
    """
def elastic_energy(model: Model, state: State) -> float:
    """
    Σ C²/(2α) over the constraints with compliance α > 0, J.
    """
def load_plugin(path: typing.Any) -> Plugin:
    """
    Loads the method in the shared library at `path` (a str or os.PathLike; a name without a directory is taken in the working directory, not searched for) and returns a csb.Plugin, which makes integrators: csb.load_plugin(path)(dt=0.01, substeps=1, iterations=10, gravity=(0, -9.81, 0)). A missing file is a FileNotFoundError; a file that is not a shared library, lacks one of csb_plugin.h's entry points (named) or was built for another version of csb_plugin.h is a csb.ParameterError naming the file.
    """
def lumped_measure(mesh: Mesh) -> numpy.typing.NDArray[numpy.float64]:
    """
    Per vertex: a third of the adjacent triangle area (m²), or half the adjacent segment length (m).
    """
def make_integrator(name: str, dt: typing.SupportsFloat | typing.SupportsIndex, *, substeps: int = 1, iterations: int = 10, gravity: typing.Any = [0.0, -9.81, 0.0], **kwargs) -> Integrator:
    """
    The built-in method `name` (see csb.methods()) with step dt (s), `substeps` sub-steps per step, `iterations` constraint sweeps per sub-step (methods that iterate) and gravity (m/s²); a method's own settings as further keywords (csb.method_info(name).settings lists them), the others at their defaults. An unknown name or setting, or a setting out of range, is a csb.ParameterError (a ValueError) naming it.
    """
def measure(model: Model, state: State, gravity: typing.Any) -> dict:
    """
    What a state holds, measured (gravity in m/s²; pinned particles included): t (s); kinetic_energy ½ Σ m |v|², gravitational_energy -Σ m g·x (zero at the origin), elastic_energy Σ C²/(2α) over the constraints with compliance α > 0 (hard ones store none: see their violations), total_energy their sum (J); linear_momentum Σ m v (kg m/s) and angular_momentum Σ m x × v about the origin (kg m²/s), (3,) arrays; per batch a dict of count, max |violation| and rms: distance (m), bending (rad), attachment (m), volume (V - V0 per tet, m³), balloon (V - pressure V0, m³) and each constraint family by its name (C₊ in its C's unit); max_strain and rms_strain, |violation| / rest length over the distance constraints.
    """
def method_info(name: str) -> MethodInfo:
    """
    The built-in method of that name or alias; a csb.ParameterError listing the known ones otherwise.
    """
def methods() -> list[MethodInfo]:
    """
    The built-in methods, in csb's order: name, label, source, reads, iterates.
    """
def pbd_variant_names(*, aliases: bool = False) -> list[str]:
    """
    The names PbdStepper(method=...) and a scene's solver.method take, in csb's order (with their aliases).
    """
def pendulum(length: typing.SupportsFloat | typing.SupportsIndex, angle: typing.SupportsFloat | typing.SupportsIndex, anchor: typing.Any = [0.0, 0.0, 0.0]) -> Mesh:
    """
    Anchor (vertex 0) and bob (vertex 1) at `length` m, `angle` rad from the downward vertical towards +x.
    """
def pick_particle(model: Model, state: State, origin: typing.Any, direction: typing.Any, *, max_distance: typing.SupportsFloat | typing.SupportsIndex = 0.05) -> Pick:
    """
    The particle under a ray (the cursor): the first surface triangle it crosses, then that triangle's vertex nearest the hit; without a hit, the particle nearest the ray within max_distance (m).
    """
def readable_extensions() -> list[str]:
    """
    Extensions (with the dot) that load_mesh reads.
    """
def save_mesh(mesh: Mesh, path: str) -> None:
    """
    Writes the mesh's triangles; the format follows the extension (.obj .stl .ply .gltf .glb .dae .3ds .fbx ...).
    """
def tear(model: typing.Any, state: typing.Any, *, max_strain: typing.SupportsFloat | typing.SupportsIndex, max_tears: int = 1) -> dict:
    """
    Tearing (Müller 2007 §4.6): splits up to max_tears vertices of distance constraints strained past max_strain (|l - l0|/l0 > 0), most strained first. Returns a dict: torn (how many), split (the particles split), model and state — new ones if anything tore (the new particles are appended), else the ones given.
    """
def tet_box(size: typing.Any, divisions: typing.Annotated[collections.abc.Sequence[int], "FixedSize(3)"], center: typing.Any = [0.0, 0.0, 0.0]) -> TetMesh:
    """
    A box of size (3 lengths, m) centred on `center` (m) with divisions (nx, ny, nz) cells of 6 positively oriented tets each (Kuhn split, conforming).
    """
def topology(mesh: Mesh) -> dict:
    """
    Unique edges, bending quads (a, b, c, d), boundary and non-manifold edge counts.
    """
def volume_violations(model: Model, state: State) -> numpy.typing.NDArray[numpy.float64]:
    """
    Violation V - V0 of every tetrahedral volume constraint, m³.
    """
MAX_COLOURS: int = 64
MAX_INDEX: int = 2147483647
MAX_ITERATIONS: int = 1000000
MAX_SUBSTEPS: int = 1000000
MAX_THREADS: int = 1024
MIN_COLOUR_SIZE: int = 64
MIN_TASK_COLOUR_SIZE: int = 8
