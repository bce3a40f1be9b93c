"""Results back into the user's tools: the simulation as a USD stage (Pixar's ``usd-core``, the
``usd`` extra), its cloths and bodies on the user's own meshes and its colliders with their motion;
for game engines, an animated glTF (one morph target per frame) and a per-frame OBJ or PLY sequence.

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

import base64
import json
import struct
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from . import _core
from .model import MeshInstance

if TYPE_CHECKING:
    from .scene import Simulation

__all__ = ["UsdWriter", "GltfWriter", "SequenceWriter", "GltfBuilder", "usd_available", "polygon_normals", "plot_usd"]


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


def _next_frame(writer: str, state: _core.State, last: float | None) -> tuple[float, np.ndarray]:
    """A frame's time (s) and positions (N, 3) m, checked: later than the last frame written (at
    `last`) and finite; `writer` names the writer in the errors."""
    t = float(state.t)
    if last is not None and not t > last:
        raise _core.ParameterError(f"{writer}: frame at t = {t} s does not come after the last, t = {last} s")
    x = np.asarray(state.x)
    if not np.all(np.isfinite(x)):
        raise _core.SimulationError(f"{writer}: the state at t = {t} s has non-finite positions; not written")
    return t, x


def _surface(inst: MeshInstance) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, np.ndarray | None, bool]:
    """What a mesh is written as: (keep, face_sizes, faces, uv, normals?) over the file's distinct
    vertices (keep: into SourceMesh.vertices) or, built in code, its triangles over its particles
    (keep None)."""
    src = inst.source
    if src is not None:
        keep, index = src.distinct_vertices()
        uv = np.asarray(src.uv, dtype=float)[keep] if src.uv is not None else None
        return keep, np.asarray(src.face_sizes), index[np.asarray(src.face_vertices)], uv, src.normals is not None
    tris = np.asarray(inst.triangles, dtype=np.int64) - inst.first_particle
    return None, np.full(len(tris), 3), tris.reshape(-1), None, len(tris) > 0


def _points(inst: MeshInstance, x: np.ndarray, keep: np.ndarray | None) -> np.ndarray:
    welded = np.asarray(x)[inst.first_particle:inst.first_particle + inst.num_particles]
    return inst.source.positions(welded)[keep] if keep is not None else welded


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

        # (instance, points attribute, normals attribute, and what _surface gives: the file's distinct
        # vertices, its polygons' sizes and corners over them)
        self._meshes: list[tuple[MeshInstance, Any, Any, Any, Any, Any]] = []
        for name, inst in meshes.items():
            path_ = f"/World/{prim_name(name)}"
            if not len(inst.triangles):  # a rope or chain: its particles as points
                points = UsdGeom.Points.Define(stage, path_)
                self._meshes.append((inst, points.CreatePointsAttr(), None, None, None, None))
                continue
            keep, sizes, faces, uv, _ = _surface(inst)
            mesh = UsdGeom.Mesh.Define(stage, path_)
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray(sizes.tolist()))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(faces.tolist()))
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            if uv is not None:
                st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                             UsdGeom.Tokens.vertex)
                st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(uv, dtype=np.float32)))
            normals = None
            if inst.source is not None and inst.source.normals is not None:  # where the file had normals
                normals = mesh.CreateNormalsAttr()
                mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
            self._meshes.append((inst, mesh.CreatePointsAttr(), normals, keep, sizes, faces))
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
        t, x = _next_frame("UsdWriter", state, self.last_time)
        # t sums the steps' dt: a frame's time code is t x fps to 1e-9 (3, not 2.9999999999999996).
        code = Usd.TimeCode(round(t * self.fps, 9))
        for inst, points, normals, keep, sizes, faces in self._meshes:
            p = _points(inst, x, keep)
            points.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(p, dtype=np.float32)), code)
            if normals is not None:
                n = polygon_normals(p, sizes, faces)
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
    from .output import frame_axes

    frame_axes(ax, (lo + hi) / 2, 0.65 * max(float(np.max(hi - lo)), 1e-3),
               title or f"{Path(path).name} at time code {code.GetValue():g}")
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return Path(png)


# ------------------------------------------------------------------------ game engines: glTF, OBJ, PLY


def _fan(face_sizes: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(T, 3) the polygons as triangle fans from their first corner (glTF holds triangles only;
    a convex polygon, as cloth quads are, is covered exactly)."""
    out, at = [], 0
    for n in np.asarray(face_sizes).tolist():
        out.extend((faces[at], faces[at + k], faces[at + k + 1]) for k in range(1, n - 1))
        at += n
    return np.asarray(out, dtype=np.int64).reshape(-1, 3)


class GltfBuilder:
    """A glTF 2.0 document built accessor by accessor over one binary buffer, written as ``.glb``
    (binary, what engines load fastest) or ``.gltf`` (JSON, the buffer embedded as base64)."""

    _COMPONENT = {np.float32: 5126, np.uint32: 5125, np.uint16: 5123, np.uint8: 5121}

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def accessor(self, array: Any, kind: str, dtype: Any = np.float32, *, target: int | None = None) -> int:
        """An accessor of `kind` ("SCALAR", "VEC2", "VEC3", "VEC4", "MAT4") over `array` cast to
        `dtype`; float SCALAR and VEC3 accessors carry the bounds glTF requires of positions and
        animation times. `target`: the bufferView's target (34962 vertices, 34963 indices)."""
        a = np.ascontiguousarray(np.asarray(array, dtype=dtype))
        while len(self.blob) % 4:
            self.blob.append(0)
        view = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": a.nbytes}
        if target is not None:
            view["target"] = target
        self.views.append(view)
        self.blob += a.tobytes()
        acc = {"bufferView": len(self.views) - 1, "componentType": self._COMPONENT[a.dtype.type], "count": len(a),
               "type": kind}
        if kind in ("SCALAR", "VEC3") and a.dtype == np.float32 and len(a):
            flat = a.reshape(len(a), -1)
            acc["min"], acc["max"] = flat.min(0).tolist(), flat.max(0).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def document(self, document: dict, *, embed: bool) -> dict:
        buffer = {"byteLength": len(self.blob)}
        if embed:
            buffer["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bytes(self.blob)).decode()
        return dict(document, asset={"version": "2.0", "generator": "csb"}, scene=0, bufferViews=self.views,
                    accessors=self.accessors, buffers=[buffer])

    def write(self, path: str | Path, document: dict) -> Path:
        """`document` (scenes, nodes, meshes, animations, ...) with this buffer, as .glb or .gltf
        by the path's suffix."""
        path = Path(path)
        if path.suffix.lower() != ".glb":
            path.write_text(json.dumps(self.document(document, embed=True), separators=(",", ":")) + "\n")
            return path
        text = json.dumps(self.document(document, embed=False), separators=(",", ":")).encode()
        text += b" " * (-len(text) % 4)
        blob = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
        with open(path, "wb") as f:
            f.write(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + 8 + len(blob)))
            f.write(struct.pack("<I4s", len(text), b"JSON") + text)
            f.write(struct.pack("<I4s", len(blob), b"BIN\0") + blob)
        return path


class GltfWriter:
    """Writes a simulation's meshes as one animated glTF (``.glb`` or ``.gltf``) for game engines:
    each mesh once, at its first frame (with the file's UVs; its polygons split into triangle fans,
    glTF holding triangles only), and one morph target per later frame, its displacement from the
    first, driven by an animation of the morph weights (linear between frames: the positions
    interpolate linearly, as the frames were sampled). Morph targets are what Unity, Unreal, Godot
    and three.js play as vertex animation. Frames are kept in memory until :meth:`close`."""

    def __init__(self, path: str | Path, meshes: dict[str, MeshInstance]):
        self.path = Path(path)
        if self.path.suffix.lower() not in (".glb", ".gltf"):
            raise _core.ParameterError(f"GltfWriter: {self.path} must end in .glb or .gltf")
        self.meshes = [(name, inst, *_surface(inst)) for name, inst in meshes.items() if len(inst.triangles)]
        self.times: list[float] = []
        self.frames: list[list[np.ndarray]] = []

    def write(self, state: _core.State) -> None:
        t, x = _next_frame("GltfWriter", state, self.times[-1] if self.times else None)
        self.times.append(t)
        self.frames.append([_points(inst, x, keep) for _, inst, keep, *_ in self.meshes])

    def close(self) -> Path:
        if not self.frames:
            raise _core.ParameterError("GltfWriter: no frame was written")
        g = GltfBuilder()
        nodes, meshes, channels, samplers = [], [], [], []
        t0 = self.times[0]
        times = g.accessor(np.asarray(self.times) - t0, "SCALAR")
        F = len(self.frames)
        for m, (name, inst, keep, sizes, faces, uv, with_normals) in enumerate(self.meshes):
            base = self.frames[0][m]
            tris = _fan(sizes, faces)
            attributes = {"POSITION": g.accessor(base, "VEC3", target=34962)}
            normals = [polygon_normals(f[m], sizes, faces) for f in self.frames] if with_normals else None
            if normals is not None:
                attributes["NORMAL"] = g.accessor(normals[0], "VEC3", target=34962)
            if uv is not None:  # glTF's v runs down the image: 1 - v
                attributes["TEXCOORD_0"] = g.accessor(np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]), "VEC2", target=34962)
            targets = []
            for k in range(1, F):
                target = {"POSITION": g.accessor(self.frames[k][m] - base, "VEC3", target=34962)}
                if normals is not None:
                    target["NORMAL"] = g.accessor(normals[k] - normals[0], "VEC3", target=34962)
                targets.append(target)
            primitive = {"attributes": attributes, "indices": g.accessor(tris.reshape(-1), "SCALAR", np.uint32, target=34963)}
            if targets:
                primitive["targets"] = targets
            meshes.append({"name": name, "primitives": [primitive], **({"weights": [0.0] * len(targets)} if targets else {})})
            nodes.append({"name": name, "mesh": m})
            if targets:
                # At frame k (k >= 1) target k - 1 weighs 1 and the others 0.
                weights = np.zeros((F, F - 1), dtype=np.float32)
                weights[np.arange(1, F), np.arange(F - 1)] = 1.0
                samplers.append({"input": times, "output": g.accessor(weights.reshape(-1), "SCALAR"), "interpolation": "LINEAR"})
                channels.append({"sampler": len(samplers) - 1, "target": {"node": m, "path": "weights"}})
        document = {"scenes": [{"nodes": list(range(len(nodes)))}], "nodes": nodes, "meshes": meshes}
        if channels:
            document["animations"] = [{"name": "simulation", "samplers": samplers, "channels": channels}]
        self.path.parent.mkdir(parents=True, exist_ok=True)
        return g.write(self.path, document)


class SequenceWriter:
    """Writes one mesh file per frame into `directory`: ``<name>_<frame>.obj`` (every mesh an OBJ
    object, with the file's UVs and normals) or, with ``format="ply"``, ``<mesh>_<frame>.ply`` per
    mesh (binary, through meshio, normals and UVs as vertex properties). Houdini, Blender's
    sequence importers and game pipelines read numbered sequences."""

    def __init__(self, directory: str | Path, name: str, meshes: dict[str, MeshInstance], *, format: str = "obj"):
        if format not in ("obj", "ply"):
            raise _core.ParameterError(f"SequenceWriter: format must be 'obj' or 'ply', got {format!r}")
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.name, self.format = name, format
        self.meshes = [(mesh_name, inst, *_surface(inst)) for mesh_name, inst in meshes.items() if len(inst.triangles)]
        self.files: list[Path] = []
        self.last_time: float | None = None

    def write(self, state: _core.State) -> None:
        t, x = _next_frame("SequenceWriter", state, self.last_time)
        frame = len(self.files) if self.format == "obj" else len(self.files) // max(len(self.meshes), 1)
        if self.format == "obj":
            self.files.append(self._obj(self.directory / f"{self.name}_{frame:05d}.obj", x, t))
        else:
            for mesh_name, inst, keep, sizes, faces, uv, with_normals in self.meshes:
                self.files.append(self._ply(self.directory / f"{mesh_name}_{frame:05d}.ply", inst, keep, sizes, faces, uv,
                                            with_normals, x))
        self.last_time = t

    def _obj(self, path: Path, x: np.ndarray, t: float) -> Path:
        # By hand: meshio's OBJ writer leaves the UV and normal indices out of the faces, which
        # importers then ignore.
        lines = [f"# csb: {self.name} at t = {t:.6g} s; units: metres"]
        offset = 0
        for mesh_name, inst, keep, sizes, faces, uv, with_normals in self.meshes:
            p = _points(inst, x, keep)
            lines.append(f"o {mesh_name}")
            lines += [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p.tolist()]
            if uv is not None:
                lines += [f"vt {a:.9g} {b:.9g}" for a, b in uv.tolist()]
            if with_normals:
                lines += [f"vn {a:.6g} {b:.6g} {c:.6g}" for a, b, c in polygon_normals(p, sizes, faces).tolist()]
            corner = (lambda i: f"{i}/{i}/{i}") if uv is not None and with_normals else \
                (lambda i: f"{i}/{i}") if uv is not None else (lambda i: f"{i}//{i}") if with_normals else str
            at = 0
            for n in sizes.tolist():
                lines.append("f " + " ".join(corner(int(i) + 1 + offset) for i in faces[at:at + n]))
                at += n
            offset += len(p)
        path.write_text("\n".join(lines) + "\n")
        return path

    @staticmethod
    def _ply(path: Path, inst: MeshInstance, keep, sizes, faces, uv, with_normals, x) -> Path:
        import meshio

        p = _points(inst, x, keep)
        data: dict[str, np.ndarray] = {}
        if with_normals:
            n = polygon_normals(p, sizes, faces)
            data.update(nx=n[:, 0], ny=n[:, 1], nz=n[:, 2])
        if uv is not None:
            data.update(s=uv[:, 0], t=uv[:, 1])
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        cells = []
        for n in sorted(set(sizes.tolist())):  # meshio groups faces by corner count
            rows = np.stack([faces[s:s + n] for s, k in zip(starts.tolist(), sizes.tolist()) if k == n]).astype(np.int32)
            cells.append(("triangle" if n == 3 else "quad" if n == 4 else "polygon", rows))
        meshio.write_points_cells(path, p, cells, point_data=data, binary=True)
        return path

    def close(self) -> list[Path]:
        return list(self.files)
