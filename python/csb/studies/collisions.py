"""Collision set-ups shared by validation/collisions.py and the collision tests, with exact
signed distance functions and an exact edge-triangle intersection test written here in numpy,
independently of the library's C++ geometry, to check it."""

from __future__ import annotations

import math

import numpy as np

from .. import _core
from ..model import ModelBuilder

G = (0.0, -9.81, 0.0)
KINDS = ("plane", "sphere", "capsule", "box", "mesh")


# --------------------------------------------------------------------------- exact geometry

def signed_distance(collider: dict, x: np.ndarray) -> np.ndarray:
    """Signed distance (m, < 0 inside) of points x (N, 3) to an analytic collider of
    ``Model.colliders``: the textbook closed forms."""
    x = np.atleast_2d(np.asarray(x, dtype=float))
    kind = collider["kind"]
    if kind == "plane":
        return (x - collider["point"]) @ collider["normal"]
    if kind == "sphere":
        return np.linalg.norm(x - collider["center"], axis=1) - collider["radius"]
    if kind == "capsule":
        a, b = collider["a"], collider["b"]
        t = np.clip((x - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
        return np.linalg.norm(x - (a + t[:, None] * (b - a)), axis=1) - collider["radius"]
    if kind == "box":
        local = (x - collider["center"]) @ collider["rotation"]  # rows: Rᵀ (x - c)
        q = np.abs(local) - collider["half_extents"]
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        inside = np.minimum(q.max(axis=1), 0.0)
        return outside + inside
    raise ValueError(f"no closed-form signed distance for a {kind} collider")


def box_sdf(center, half_extents, x: np.ndarray) -> np.ndarray:
    """Signed distance to an axis-aligned box (m), for the box-shaped collider mesh."""
    return signed_distance(dict(kind="box", center=np.asarray(center, float), half_extents=np.asarray(half_extents, float),
                                rotation=np.eye(3)), x)


def box_mesh(center=(0.0, 0.0, 0.0), half_extents=(0.5, 0.5, 0.5), name: str = "box mesh") -> _core.Mesh:
    """The 12 outward-wound triangles of an axis-aligned box."""
    c, e = np.asarray(center, float), np.asarray(half_extents, float)
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * e + c
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, cc, d in quads for t in ((a, b, cc), (a, cc, d))]
    return _core.Mesh(v, np.array(tris), name=name)


def segments_cross_triangles(p0: np.ndarray, p1: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Whether each segment p0-p1 properly crosses triangle (a, b, c), row by row: the ends lie
    strictly on opposite sides of the triangle's plane and the segment's line passes strictly
    inside the triangle (signs of orientation determinants; touching and coplanar do not count)."""
    def orient(p, q, r, s):
        return np.einsum("ij,ij->i", np.cross(q - p, r - p), s - p)

    s0, s1 = orient(a, b, c, p0), orient(a, b, c, p1)
    opposite = s0 * s1 < 0
    e0, e1, e2 = orient(p0, p1, a, b), orient(p0, p1, b, c), orient(p0, p1, c, a)
    inside = ((e0 > 0) & (e1 > 0) & (e2 > 0)) | ((e0 < 0) & (e1 < 0) & (e2 < 0))
    return opposite & inside


def candidate_pairs(x: np.ndarray, edges: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (edge, triangle) pairs of one mesh whose bounding boxes overlap and which share no
    vertex, each once, in increasing (edge, triangle) order. Broad phase: a uniform grid of cells
    twice the median edge length; each edge and triangle is listed in every cell its box touches,
    so that the work grows with the pairs that are near, not with edges x triangles."""
    x = np.asarray(x, float)
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    empty = np.zeros(0, np.int64)
    if len(edges) == 0 or len(triangles) == 0:
        return empty, empty
    lo_e = np.minimum(x[edges[:, 0]], x[edges[:, 1]])
    hi_e = np.maximum(x[edges[:, 0]], x[edges[:, 1]])
    tx = x[triangles]
    lo_t, hi_t = tx.min(axis=1), tx.max(axis=1)
    length = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    cell = 2 * float(np.median(length))
    if not cell > 0:
        cell = max(float(np.max(hi_t - lo_t)), 1e-300)
    origin = np.minimum(lo_e.min(axis=0), lo_t.min(axis=0))

    def spread(lo, hi):
        """(cell key, item) for every cell the boxes [lo, hi] touch."""
        a = np.floor((lo - origin) / cell).astype(np.int64)
        b = np.floor((hi - origin) / cell).astype(np.int64)
        n = b - a + 1
        count = n.prod(axis=1)
        item = np.repeat(np.arange(len(lo)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)  # index within the item's cells
        ni, nj = n[item, 0], n[item, 1]
        c = a[item] + np.stack([k % ni, (k // ni) % nj, k // (ni * nj)], axis=1)
        key = (c[:, 0] * 73856093) ^ (c[:, 1] * 19349663) ^ (c[:, 2] * 83492791)  # hashed; false shares are filtered
        return key, item

    ke, ie = spread(lo_e, hi_e)
    kt, it = spread(lo_t, hi_t)
    order = np.argsort(kt, kind="stable")
    kt, it = kt[order], it[order]
    first = np.searchsorted(kt, ke, side="left")
    last = np.searchsorted(kt, ke, side="right")
    count = last - first
    e = np.repeat(ie, count)
    t = it[np.repeat(first, count) + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)]
    pair = np.unique(e * len(triangles) + t)
    e, t = pair // len(triangles), pair % len(triangles)
    keep = np.all((lo_e[e] <= hi_t[t]) & (hi_e[e] >= lo_t[t]), axis=1)
    for k in range(3):
        for j in range(2):
            keep &= edges[e, j] != triangles[t, k]
    return e[keep], t[keep]


def self_intersections(x: np.ndarray, edges: np.ndarray, triangles: np.ndarray) -> int:
    """Edge-triangle pairs of one mesh (sharing no vertex) whose edge crosses the triangle
    (segments_cross_triangles on the pairs of candidate_pairs)."""
    x = np.asarray(x)
    ei, ti = candidate_pairs(x, edges, triangles)
    if len(ei) == 0:
        return 0
    hit = segments_cross_triangles(x[edges[ei, 0]], x[edges[ei, 1]], x[triangles[ti, 0]], x[triangles[ti, 1]],
                                   x[triangles[ti, 2]])
    return int(hit.sum())


# --------------------------------------------------------------------------- scenes

def add_collider(b: ModelBuilder, kind: str, **material) -> None:
    """One collider of each kind, its top near y = 0 under the drop zone x, z in [-0.2, 0.2]."""
    if kind == "plane":
        b.add_plane(point=(0, 0, 0), normal=(0.2, 1, 0.1), **material)
    elif kind == "sphere":
        b.add_sphere(center=(0, -0.5, 0), radius=0.5, **material)
    elif kind == "capsule":
        b.add_capsule(a=(-0.6, -0.3, 0.1), b=(0.6, -0.3, -0.1), radius=0.3, **material)
    elif kind == "box":
        angle = math.radians(30)
        rot = np.array([[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]])
        b.add_box(center=(0, -0.4, 0), half_extents=(0.4, 0.3, 0.5), rotation=rot, **material)
    elif kind == "mesh":
        b.add_collider_mesh(box_mesh((0, -0.5, 0), (0.5, 0.5, 0.5)), **material)
    else:
        raise ValueError(kind)


def exact_distance(model, kind: str, x: np.ndarray) -> np.ndarray:
    if kind == "mesh":
        return box_sdf((0, -0.5, 0), (0.5, 0.5, 0.5), x)
    return signed_distance(model.colliders[0], x)


def particle_rain(kind: str, *, n: int = 6, seed: int = 5, **material):
    """n x n free particles above the collider, thrown down at 1 to 7 m/s and sideways at up to 0.5 m/s."""
    b = ModelBuilder()
    g = b.add_group("rain")
    rng = np.random.default_rng(seed)
    for u in np.linspace(-0.2, 0.2, n):
        for w in np.linspace(-0.2, 0.2, n):
            b.add_particle([u, 0.3 + 0.2 * rng.random(), w], 0.01, g)
    add_collider(b, kind, **material)
    model = b.build()
    state = model.initial_state()
    state.v[:] = rng.uniform(-1, 1, (n * n, 3)) * (0.5, 3.0, 0.5) + (0.0, -4.0, 0.0)
    return model, state


def max_penetration_history(kind: str, method: str, *, seconds: float = 1.0, dt: float = 1 / 60, substeps: int = 2,
                            iterations: int = 5, solver: str = "gauss-seidel", **material) -> tuple[np.ndarray, int]:
    """Deepest penetration (m, >= 0) below the collider's exact surface at the end of each step,
    and how many particles came within 1 mm of the surface at the end of some step."""
    model, state = particle_rain(kind, **material)
    stepper = _core.PbdStepper(method=method, dt=dt, substeps=substeps, iterations=iterations, gravity=G,
                               solver=solver)
    out = []
    closest = np.full(model.num_particles, np.inf)
    for _ in range(int(round(seconds / dt))):
        stepper.step(model, state)
        d = exact_distance(model, kind, state.x)
        out.append(max(0.0, -float(d.min())))
        closest = np.minimum(closest, d)
    return np.array(out), int(np.sum(closest < 1e-3))


def thin_wall(kind: str, method: str, *, speed: float = 120.0, dt: float = 1 / 60, steps: int = 10):
    """A particle fired at +z at ``speed`` (m/s) against a 1 mm box wall or a one-sheet mesh at
    z = 0, crossing it in one step if nothing stopped it. Returns the largest z it reached (m)."""
    b = ModelBuilder()
    g = b.add_group("bullet")
    b.add_particle([0.013, 0.021, -0.3], 0.01, g)
    if kind == "box":
        b.add_box(center=(0, 0, 0), half_extents=(0.5, 0.5, 0.0005))
    else:
        sheet = _core.Mesh(np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], float),
                           np.array([[0, 1, 2], [0, 2, 3]]), name="sheet")
        b.add_collider_mesh(sheet)
    model = b.build()
    state = model.initial_state()
    state.v[0] = (0.0, 0.0, speed)
    stepper = _core.PbdStepper(method=method, dt=dt, gravity=(0, 0, 0))
    reached = -np.inf
    for _ in range(steps):
        stepper.step(model, state)
        reached = max(reached, float(state.x[0, 2]))
    return reached


def resting_cloth(*, n: int = 16, thickness: float = 0.002, drop: float = 0.01, friction: float = 0.5):
    """An n x n cloth (1 m, 0.2 kg) with stretch and bending, ``drop`` m above a ground plane (its
    particles' thickness included) that has Coulomb friction μs = μk = ``friction``. The bending is
    declared in both forms, stiffness 0.5 for PBD and Jakobsen, compliance 10 1/(N m) for XPBD (the
    cloth_sphere scene's), so that every method steps a soft cloth."""
    b = ModelBuilder()
    b.add_mesh(_core.cloth_grid(1.0, 1.0, n, n, "xz", [0.0, thickness + drop, 0.0]), mass=0.2, stretch_stiffness=1.0,
               bending_stiffness=0.5, bending_compliance=10.0, thickness=thickness)
    b.add_plane(point=(0, 0, 0), normal=(0, 1, 0), friction_static=friction, friction_kinetic=friction)
    return b.build()


def rest_jitter(method: str, *, settle: float = 2.0, seconds: float = 10.0, dt: float = 1 / 60, substeps: int = 2,
                iterations: int = 10, n: int = 16) -> dict:
    """The cloth of resting_cloth() falls and settles for ``settle`` s; then over ``seconds`` s:
    the largest particle speed (m/s) at the end of any step and the largest drift (m) of any
    particle from where it was when the measurement began."""
    model = resting_cloth(n=n)
    state = model.initial_state()
    stepper = _core.PbdStepper(method=method, dt=dt, substeps=substeps, iterations=iterations, gravity=G)
    stepper.step(model, state, int(round(settle / dt)))
    start = np.array(state.x)
    speed = drift = 0.0
    for _ in range(int(round(seconds / dt))):
        stepper.step(model, state)
        speed = max(speed, float(np.linalg.norm(state.v, axis=1).max()))
        drift = max(drift, float(np.linalg.norm(state.x - start, axis=1).max()))
    below = float((model.thickness - state.x[:, 1]).max())
    return dict(max_speed=speed, max_drift=drift, max_below_thickness=max(below, 0.0))


def slope_slide(mu: float, theta: float, *, method: str = "pbd", solver: str = "gauss-seidel", seconds: float = 1.0,
                dt: float = 1 / 60, substeps: int = 10, iterations: int = 10, size: float = 0.1,
                height: float = 0.03) -> float:
    """A rigid box of 8 particles (every pair linked by a hard distance constraint), ``size`` m
    square and ``height`` m high (flat, so that it slides before it tips over, which takes
    tan θ > size/height), on a plane inclined at theta (rad) with μs = μk = mu; returns how far (m)
    its centre slides down the slope in ``seconds``."""
    t = np.array([math.cos(theta), math.sin(theta), 0.0])   # up the slope
    n = np.array([-math.sin(theta), math.cos(theta), 0.0])  # the plane's normal
    z = np.array([0.0, 0.0, 1.0])
    b = ModelBuilder()
    g = b.add_group("box")
    lift = 1e-6  # m: the bottom corners start just above the plane (round-off could put them inside)
    for i in (-0.5, 0.5):
        for j in (0.0, 1.0):
            for k in (-0.5, 0.5):
                b.add_particle(size * (i * t + k * z) + (height * j + lift) * n, 0.1, g)
    for i in range(8):
        for j in range(i + 1, 8):
            b.add_distance(i, j)
    b.add_plane(point=(0, 0, 0), normal=n, friction_static=mu, friction_kinetic=mu)
    model = b.build()
    state = model.initial_state()
    c0 = np.asarray(state.x).mean(axis=0)
    _core.PbdStepper(method=method, solver=solver, dt=dt, substeps=substeps, iterations=iterations, gravity=G).step(
        model, state, int(round(seconds / dt)))
    return float(-(np.asarray(state.x).mean(axis=0) - c0) @ t)


def friction_threshold(mu: float, *, method: str = "pbd", slide: float = 1e-3, bisections: int = 14, **kw) -> float:
    """The slope angle (rad) at which the box of slope_slide() starts to slide more than ``slide``
    m in its time, by bisection on [0, 80°]."""
    lo, hi = 0.0, math.radians(80)
    for _ in range(bisections):
        mid = (lo + hi) / 2
        if slope_slide(mu, mid, method=method, **kw) > slide:
            hi = mid
        else:
            lo = mid
    return (lo + hi) / 2


def bounce_height(restitution: float, *, height: float = 1.0, method: str = "pbd", dt: float = 1 / 60,
                  substeps: int = 10) -> float:
    """A particle dropped from ``height`` m onto the ground: the top of its first bounce (m)."""
    b = ModelBuilder()
    g = b.add_group("ball")
    b.add_particle([0.0, height, 0.0], 0.1, g)
    b.add_plane(point=(0, 0, 0), normal=(0, 1, 0), restitution=restitution)
    model = b.build()
    state = model.initial_state()
    stepper = _core.PbdStepper(method=method, dt=dt, substeps=substeps, gravity=G)
    bounced = False
    top = 0.0
    for _ in range(int(round(4 * math.sqrt(2 * height / 9.81) / dt))):
        stepper.step(model, state)
        y, vy = float(state.x[0, 1]), float(state.v[0, 1])
        if not bounced and vy > 0:
            bounced = True
        if bounced:
            top = max(top, y)
            if vy < 0 and y < top:
                break
    return top


def folded_cloth(*, n: int = 16, width: float = 0.6, gap: float = 0.04, height: float = 0.15,
                 self_collision: float | None = 0.008):
    """A cloth strip folded over itself (a U of two layers ``gap`` m apart) ``height`` m above the
    ground: its bottom layer lands first and the top one falls onto it. Returns (model, edges)."""
    mesh = _core.cloth_grid(width, width, n, n, "xz", [0.0, 0.0, 0.0])
    v = np.array(mesh.vertices)
    u = v[:, 0] + width / 2                      # 0 .. width along the strip
    half = width / 2 - math.pi * gap / 4         # flat length of each layer; the fold is a half circle
    r = gap / 2
    x = np.empty_like(v)
    for k, s in enumerate(u):
        if s <= half:
            x[k] = (s, 0.0, v[k, 2])
        elif s <= half + math.pi * r:
            a = (s - half) / r
            x[k] = (half + r * math.sin(a), r - r * math.cos(a), v[k, 2])
        else:
            x[k] = (half - (s - half - math.pi * r), gap, v[k, 2])
    x[:, 1] += height
    folded = _core.Mesh(x, np.array(mesh.triangles), name="folded cloth")
    b = ModelBuilder()
    inst = b.add_mesh(folded, mass=0.1, stretch_stiffness=1.0, thickness=0.002)
    if self_collision:
        b.enable_self_collision(inst.group, self_collision)
    b.add_plane(point=(0, 0, 0), normal=(0, 1, 0), friction_static=0.4, friction_kinetic=0.3)
    model = b.build()
    return model, np.array(_core.topology(folded)["edges"])
