"""Results back into the user's tools: the simulation as a USD stage (Pixar's ``usd-core``, the
``usd`` extra), its cloths and bodies on the user's own meshes and its colliders with their motion.

A mesh read from a file (:func:`csb.load_mesh`) is written as the file has it: its vertices before
welding (each distinct position, UV and normal once, in the order its polygons first use them:
``SourceMesh.distinct_vertices``), its polygons (quads and n-gons kept), its UVs and, where the
file had normals, normals recomputed from the moving polygons at every frame; each of its vertices
moves with the particle it was welded into (``SourceMesh.weld_map``). A mesh built in code (a
shape, arrays) is written as csb simulates it, triangles over its particles. The points are time
samples at t x fps (t in s), the stage in metres (``metersPerUnit = 1``), y up unless gravity
points along z, ``timeCodesPerSecond`` and ``framesPerSecond`` the frame rate. Blender, Houdini,
Maya, Omniverse and the game engines that read USD open it as an animated mesh.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from . import _core
from .model import MeshInstance

if TYPE_CHECKING:
    from .scene import Simulation

__all__ = ["UsdWriter", "usd_available", "polygon_normals", "plot_usd"]


def usd_available() -> bool:
    """Whether Pixar's USD (``usd-core``) can be imported."""
    try:
        import pxr.Usd  # noqa: F401
    except ImportError:
        return False
    return True


def _pxr():
    try:
        from pxr import Gf, Sdf, Tf, Usd, UsdGeom, Vt
    except ImportError:
        raise ImportError("writing USD needs Pixar's usd-core, the 'usd' extra: pip install 'csb[usd]' "
                          "(or pip install usd-core)") from None
    return Gf, Sdf, Tf, Usd, UsdGeom, Vt


def polygon_normals(points: np.ndarray, face_sizes: np.ndarray, face_vertices: np.ndarray) -> np.ndarray:
    """(M, 3) unit vertex normals of a polygon mesh at `points` ((M, 3), m): each vertex sums the
    area-weighted normals of the polygons using it (Newell's method, right-handed: counterclockwise
    corners face the viewer); a vertex no polygon uses, or whose polygons cancel, gets 0. A vertex
    split at a hard edge (one per side, as files store them) keeps its side's normal."""
    p = np.asarray(points, dtype=float)
    fv = np.asarray(face_vertices, dtype=np.int64)
    sizes = np.asarray(face_sizes, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    nxt = np.arange(len(fv)) + 1
    ends = starts + sizes  # the corner after a polygon's last is its first
    nxt[ends - 1] = starts
    face = np.add.reduceat(np.cross(p[fv], p[fv[nxt]]), starts, axis=0) if len(fv) else np.zeros((0, 3))
    out = np.zeros_like(p)
    np.add.at(out, fv, np.repeat(face, sizes, axis=0))
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, length, out=np.zeros_like(out), where=length > 0)


class UsdWriter:
    """Writes a simulation frame by frame into a USD stage (``.usd``, ``.usda`` or ``.usdc``).

    ``meshes``: name -> :class:`csb.MeshInstance` (a Simulation's ``meshes``; each becomes a prim
    under ``/World``); ``model``: for the colliders (``model.colliders``, under
    ``/World/colliders``, drawn as meshes and moved by their pose); ``fps``: frames per second of
    the stage's time codes. Call :meth:`write` once per frame, then :meth:`close`."""

    def __init__(self, path: str | Path, meshes: dict[str, MeshInstance], model: _core.Model | None = None, *,
                 fps: float = 30.0, gravity: Sequence[float] = (0.0, -9.81, 0.0)):
        Gf, Sdf, Tf, Usd, UsdGeom, Vt = _pxr()
        if not (np.isfinite(fps) and fps > 0):
            raise _core.ParameterError(f"UsdWriter: fps must be > 0 frames per second, got {fps!r}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fps = float(fps)
        stage = Usd.Stage.CreateNew(str(self.path))
        if stage is None:
            raise _core.ParameterError(f"UsdWriter: cannot create a USD stage at {self.path}")
        self.stage = stage
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        g = np.abs(np.asarray(gravity, dtype=float))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if g[2] > max(g[0], g[1]) else UsdGeom.Tokens.y)
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        stage.SetStartTimeCode(0.0)
        world = UsdGeom.Xform.Define(stage, "/World")
        stage.SetDefaultPrim(world.GetPrim())
        used: set[str] = set()

        def prim_name(name: str) -> str:
            base = Tf.MakeValidIdentifier(name) or "mesh"
            out, k = base, 1
            while out in used:
                k += 1
                out = f"{base}_{k}"
            used.add(out)
            return out

        # (instance, points attribute, normals attribute, the file's distinct vertices and its polygons over them)
        self._meshes: list[tuple[MeshInstance, Any, Any, Any, Any]] = []
        for name, inst in meshes.items():
            path_ = f"/World/{prim_name(name)}"
            src = inst.source
            if src is not None:
                keep, index = src.distinct_vertices()
                faces = index[np.asarray(src.face_vertices)]
                mesh = UsdGeom.Mesh.Define(stage, path_)
                mesh.CreateFaceVertexCountsAttr(Vt.IntArray([int(n) for n in src.face_sizes]))
                mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(faces.tolist()))
                mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
                if src.uv is not None:
                    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                                 UsdGeom.Tokens.vertex)
                    st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(src.uv, dtype=np.float32)[keep]))
                normals = None
                if src.normals is not None:
                    normals = mesh.CreateNormalsAttr()
                    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
                self._meshes.append((inst, mesh.CreatePointsAttr(), normals, keep, faces))
            elif len(inst.triangles):
                mesh = UsdGeom.Mesh.Define(stage, path_)
                tris = np.asarray(inst.triangles, dtype=np.int64) - inst.first_particle
                mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(tris)))
                mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(tris.reshape(-1).tolist()))
                mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
                self._meshes.append((inst, mesh.CreatePointsAttr(), None, None, None))
            else:  # a rope or chain: its particles as points
                points = UsdGeom.Points.Define(stage, path_)
                self._meshes.append((inst, points.CreatePointsAttr(), None, None, None))
        self._colliders: list[tuple[int, Any, Any, bool]] = []   # (index, transform op, points attribute, deforms)
        if model is not None and len(model.colliders):
            from .output import _collider_triangles

            UsdGeom.Scope.Define(stage, "/World/colliders")
            extent = 1.0
            if meshes:
                allv = np.concatenate([np.asarray(i.vertices) for i in meshes.values()])
                extent = max(float(np.max(allv.max(axis=0) - allv.min(axis=0))), 1e-3)
            for k, c in enumerate(model.colliders):
                tris = _collider_triangles(c, 2 * extent).reshape(-1, 3)
                mesh = UsdGeom.Mesh.Define(stage, f"/World/colliders/{prim_name(c.get('name') or f'collider{k}')}")
                if c["kind"] == "mesh":  # its own vertices and triangles, so that a deforming one can move them
                    verts = np.asarray(c["vertices"], dtype=float)
                    faces = np.asarray(c["triangles"], dtype=np.int64)
                else:
                    verts, faces = tris, np.arange(len(tris)).reshape(-1, 3)
                mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
                mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(faces.reshape(-1).tolist()))
                mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
                points = mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(verts, dtype=np.float32)))
                op = mesh.AddTransformOp()
                self._colliders.append((k, op, points, c["kind"] == "mesh"))
        self.frames = 0
        self.last_time: float | None = None

    def write(self, state: _core.State, poses: Sequence[tuple[Any, Any]] | None = None,
              collider_vertices: Sequence[Any | None] | None = None) -> None:
        """One frame at ``state.t``: every mesh's points (and normals), and per collider its pose
        (R, translation in m; None: as declared) and a deforming mesh collider's vertices (m)."""
        Gf, Sdf, Tf, Usd, UsdGeom, Vt = _pxr()
        t = float(state.t)
        if self.last_time is not None and not t > self.last_time:
            raise _core.ParameterError(f"UsdWriter: frame at t = {t} s does not come after the last, "
                                       f"t = {self.last_time} s")
        # t sums the steps' dt: a frame's time code is t x fps to 1e-9 (3, not 2.9999999999999996).
        code = Usd.TimeCode(round(t * self.fps, 9))
        x = np.asarray(state.x)
        if not np.all(np.isfinite(x)):
            raise _core.SimulationError(f"UsdWriter: the state at t = {t} s has non-finite positions; not written")
        for inst, points, normals, keep, faces in self._meshes:
            welded = x[inst.first_particle:inst.first_particle + inst.num_particles]
            p = inst.source.positions(welded)[keep] if inst.source is not None else welded
            points.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(p, dtype=np.float32)), code)
            if normals is not None:
                n = polygon_normals(p, inst.source.face_sizes, faces)
                normals.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(n, dtype=np.float32)), code)
        for k, op, points, deforms in self._colliders:
            R, tr = (np.eye(3), np.zeros(3)) if poses is None or poses[k] is None else (np.asarray(poses[k][0]),
                                                                                         np.asarray(poses[k][1]))
            m = np.eye(4)
            m[:3, :3] = np.asarray(R, dtype=float).T  # USD's row vectors: p' = p M
            m[3, :3] = tr
            op.Set(Gf.Matrix4d(m.tolist()), code)
            if deforms and collider_vertices is not None and collider_vertices[k] is not None:
                points.Set(Vt.Vec3fArray.FromNumpy(np.asarray(collider_vertices[k], dtype=np.float32)), code)
        self.stage.SetEndTimeCode(code.GetValue())
        self.last_time = t
        self.frames += 1

    def close(self) -> Path:
        """Saves the stage; returns its path."""
        self.stage.GetRootLayer().Save()
        return self.path


def simulation_usd_writer(path: str | Path, sim: "Simulation", fps: float) -> UsdWriter:
    """A UsdWriter for a scene's Simulation: its meshes, its colliders and its gravity's up axis."""
    return UsdWriter(path, sim.meshes, sim.model, fps=fps, gravity=sim.scene.solver.gravity)


def collider_frame(sim: "Simulation") -> tuple[list | None, list | None]:
    """The colliders' poses and deformed mesh vertices now (a PbdStepper's; None otherwise)."""
    if not isinstance(sim.stepper, _core.PbdStepper) or not len(sim.model.colliders):
        return None, None
    colliders = sim.model.colliders
    poses = [sim.stepper.collider_pose(k) for k in range(len(colliders))]
    vertices = [sim.stepper.collider_vertices(sim.model, k) if c["kind"] == "mesh" else None
                for k, c in enumerate(colliders)]
    return poses, vertices


def plot_usd(path: str | Path, png: str | Path, time: float | None = None, title: str | None = None) -> Path:
    """A still of a USD stage read back with Pixar's USD: every mesh under ``/World`` at the time
    code `time` (None: the last), its polygons as the file stores them (quads drawn as quads),
    colliders grey, y up; written to `png`."""
    Gf, Sdf, Tf, Usd, UsdGeom, Vt = _pxr()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise _core.ParameterError(f"{path}: not a USD stage Pixar's USD can open")
    code = Usd.TimeCode(stage.GetEndTimeCode() if time is None else time)
    to_plot = lambda p: p[..., [0, 2, 1]] * np.array([1, -1, 1])  # noqa: E731  (matplotlib's z up)
    fig = plt.figure(figsize=(6.5, 6), constrained_layout=True)
    ax = fig.add_subplot(projection="3d")
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    drawn = 0
    for prim in Usd.PrimRange(stage.GetPrimAtPath("/World")):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        world = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(code))
        points = np.asarray(mesh.GetPointsAttr().Get(code), dtype=float)
        points = points @ world[:3, :3] + world[3, :3]
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
        corners = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
        polygons = np.split(points[corners], np.cumsum(counts)[:-1])
        collider = "/colliders/" in str(prim.GetPath())
        ax.add_collection3d(Poly3DCollection([to_plot(q) for q in polygons],
                                             facecolor=(0.6, 0.6, 0.6, 0.25) if collider else (0.85, 0.45, 0.2, 0.9),
                                             edgecolor=(0.4, 0.4, 0.4, 0.3) if collider else (0.3, 0.15, 0.05, 0.6),
                                             linewidth=0.2 if collider else 0.3))
        if not collider:
            lo, hi = np.minimum(lo, points.min(axis=0)), np.maximum(hi, points.max(axis=0))
            drawn += 1
    if drawn == 0:
        raise _core.ParameterError(f"{path}: no mesh under /World to draw")
    centre, half = (lo + hi) / 2, 0.65 * max(float(np.max(hi - lo)), 1e-3)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(-centre[2] - half, -centre[2] + half)
    ax.set_zlim(centre[1] - half, centre[1] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("-z (m)")
    ax.set_zlabel("y (m)")
    ax.view_init(elev=22, azim=-60)
    ax.set_title(title or f"{Path(path).name} at time code {code.GetValue():g}", fontsize="medium")
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return Path(png)
