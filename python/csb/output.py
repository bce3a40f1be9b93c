"""Writing results: a VTU or XDMF time series for ParaView (through meshio), a CSV of metrics and
a PNG summary plot."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, Sequence
from xml.sax.saxutils import quoteattr

import numpy as np

from . import _core

__all__ = ["FrameWriter", "METRIC_COLUMNS", "metrics_row", "volume_errors", "write_csv", "plot_summary",
           "plot_snapshot"]


def _cells(model: _core.Model) -> list[tuple[str, np.ndarray]]:
    """Tetrahedra, triangles, plus a line cell for every distance constraint that is not an edge
    of either (chains, pendulums, springs), so that everything the model holds is visible."""
    cells: list[tuple[str, np.ndarray]] = []
    tets = np.asarray(model.volume["particles"], dtype=np.int64).reshape(-1, 4)
    if len(tets):
        cells.append(("tetra", tets))
    tris = np.asarray(model.triangles, dtype=np.int64)
    if len(tris):
        cells.append(("triangle", tris))
    pairs = np.sort(np.asarray(model.distance["particles"], dtype=np.int64), axis=1)
    if len(pairs):
        covered = [tris[:, [a, b]] for a, b in ((0, 1), (1, 2), (2, 0))] if len(tris) else []
        covered += [tets[:, [a, b]] for a, b in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))] if len(tets) else []
        if covered:
            edges = np.sort(np.concatenate(covered), axis=1)
            n = model.num_particles
            on_cell = np.isin(pairs[:, 0] * n + pairs[:, 1], edges[:, 0] * n + edges[:, 1])
            pairs = pairs[~on_cell]
        if len(pairs):
            cells.append(("line", pairs))
    if not cells:
        cells.append(("vertex", np.arange(model.num_particles, dtype=np.int64)[:, None]))
    return cells


def _particle_strain(model: _core.Model, state: _core.State) -> np.ndarray:
    """Largest |strain| of the distance constraints at each particle (0 where there are none)."""
    out = np.zeros(model.num_particles)
    pairs = np.asarray(model.distance["particles"])
    if len(pairs):
        strain = np.abs(_core.distance_violations(model, state) / model.distance["rest_length"])
        np.maximum.at(out, pairs[:, 0], strain)
        np.maximum.at(out, pairs[:, 1], strain)
    return out


def _xdmf_writer(path: Path):
    """meshio's XDMF time-series writer, with its HDF5 file beside the .xdmf: meshio 5.3 creates
    it in the working directory, while the .xdmf refers to it by a path relative to itself."""
    import h5py
    import meshio

    class Writer(meshio.xdmf.TimeSeriesWriter):
        def __enter__(self):
            self.h5_filename = str(self.filename.with_suffix(".h5"))
            self.h5_file = h5py.File(self.h5_filename, "w")
            return self

    return Writer(path)


class FrameWriter:
    """Writes one frame per call to ``write`` into an XDMF (+HDF5) series and/or a VTU series with
    a ParaView .pvd collection."""

    def __init__(self, directory: Path, name: str, model: _core.Model, *, xdmf: bool = True, vtu: bool = True):

        self.directory, self.name, self.model = directory, name, model
        self.cells = _cells(model)
        self.group = np.asarray(model.group, dtype=np.int32)
        self.pinned = (np.asarray(model.inv_mass) == 0).astype(np.int32)
        self.files: list[Path] = []
        self._pvd: list[tuple[float, str]] = []
        self._vtu = vtu
        self._xdmf = None
        directory.mkdir(parents=True, exist_ok=True)
        if vtu:
            (directory / "frames").mkdir(exist_ok=True)
        if xdmf:
            path = directory / f"{name}.xdmf"
            self._xdmf = _xdmf_writer(path)
            self._xdmf.__enter__()
            # meshio's XDMF writer cannot mix line cells with others (it reshapes them in place and
            # fails), so the XDMF series leaves lines out when there are triangles or tets; the
            # VTU series has every cell.
            xdmf_cells = [c for c in self.cells if c[0] != "line"] or self.cells
            self._xdmf.write_points_cells(np.asarray(model.rest_positions), xdmf_cells)
            self.files += [path, path.with_suffix(".h5")]

    def write(self, state: _core.State) -> None:
        import meshio

        point_data = {
            "velocity": np.array(state.v),
            "strain": _particle_strain(self.model, state),
            "group": self.group,
            "pinned": self.pinned,
        }
        if self._xdmf is not None:
            # meshio's XDMF series keeps the points of its first frame; the motion goes in as
            # 'displacement' from the rest positions (ParaView: Warp By Vector). The VTU series
            # stores the moved points themselves.
            self._xdmf.write_data(state.t, point_data={**point_data, "displacement": np.array(state.x) - np.asarray(self.model.rest_positions)})
        if self._vtu:
            k = len(self._pvd)
            rel = f"frames/{self.name}_{k:05d}.vtu"
            meshio.write(str(self.directory / rel), meshio.Mesh(np.array(state.x), self.cells, point_data=point_data))
            self._pvd.append((state.t, rel))

    def set_model(self, model: _core.Model) -> None:
        """A torn model (more particles, new cells) for the frames that follow; VTU frames only,
        since an XDMF series keeps the points of its first frame."""
        if self._xdmf is not None:
            raise _core.ParameterError("an XDMF series cannot change its number of points (tearing); write VTU")
        self.model = model
        self.cells = _cells(model)
        self.group = np.asarray(model.group, dtype=np.int32)
        self.pinned = (np.asarray(model.inv_mass) == 0).astype(np.int32)

    def close(self) -> list[Path]:
        if self._xdmf is not None:
            self._xdmf.__exit__(None, None, None)
            self._xdmf = None
        if self._vtu:
            pvd = self.directory / f"{self.name}.pvd"
            entries = "\n".join(
                f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(f)}/>' for t, f in self._pvd)
            pvd.write_text(
                '<?xml version="1.0"?>\n'
                '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
                f"  <Collection>\n{entries}\n  </Collection>\n</VTKFile>\n",
                encoding="utf-8",
            )
            self.files.append(pvd)
            self._vtu = False
        return self.files


METRIC_COLUMNS = (
    "t", "step", "kinetic_energy", "gravitational_energy", "mechanical_energy",
    "max_strain", "rms_strain", "distance_max", "distance_rms", "bending_max", "bending_rms",
    "attachment_max", "momentum_x", "momentum_y", "momentum_z",
    "angular_momentum_x", "angular_momentum_y", "angular_momentum_z",
    "volume_error", "balloon_volume_error",
)


def volume_errors(model: _core.Model, state: _core.State) -> dict[str, float]:
    """Relative volume errors: of the total signed volume of all tets against its rest value, and
    the largest of every balloon's enclosed volume against its target pressure x V0 (0 without)."""
    out = {"volume_error": 0.0, "balloon_volume_error": 0.0}
    tets = np.asarray(model.volume["particles"]).reshape(-1, 4)
    if len(tets):
        x = np.asarray(state.x)
        a, b, c, d = (x[tets[:, k]] for k in range(4))
        v = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6
        rest = float(np.sum(model.volume["rest_volume"]))
        out["volume_error"] = float(np.sum(v)) / rest - 1
    bal = model.balloons
    if len(bal["rest_volume"]):
        target = np.asarray(bal["pressure"]) * np.asarray(bal["rest_volume"])
        err = _core.balloon_volumes(model, state) / target - 1
        out["balloon_volume_error"] = float(err[np.argmax(np.abs(err))])
    return out


def metrics_row(m: dict[str, Any], step: int, volumes: dict[str, float] | None = None) -> dict[str, float]:
    p, L = m["linear_momentum"], m["angular_momentum"]
    volumes = volumes or {"volume_error": 0.0, "balloon_volume_error": 0.0}
    return {
        "t": m["t"], "step": step,
        "kinetic_energy": m["kinetic_energy"], "gravitational_energy": m["gravitational_energy"],
        "mechanical_energy": m["kinetic_energy"] + m["gravitational_energy"],
        "max_strain": m["max_strain"], "rms_strain": m["rms_strain"],
        "distance_max": m["distance"]["max"], "distance_rms": m["distance"]["rms"],
        "bending_max": m["bending"]["max"], "bending_rms": m["bending"]["rms"],
        "attachment_max": m["attachment"]["max"],
        "momentum_x": p[0], "momentum_y": p[1], "momentum_z": p[2],
        "angular_momentum_x": L[0], "angular_momentum_y": L[1], "angular_momentum_z": L[2],
        "volume_error": volumes["volume_error"], "balloon_volume_error": volumes["balloon_volume_error"],
    }


def write_csv(path: Path, rows: Sequence[dict[str, float]]) -> Path:
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=METRIC_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: repr(float(v)) if k != "step" else int(v) for k, v in r.items()})
    return path


def plot_summary(path: Path, rows: Sequence[dict[str, float]], title: str) -> Path:
    """Energy (kinetic, gravitational, their sum) and strain (max, RMS) against time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([r["t"] for r in rows])
    col = lambda k: np.array([r[k] for r in rows])  # noqa: E731
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7.5, 6.5), sharex=True, constrained_layout=True)
    ax1.plot(t, col("kinetic_energy"), label="kinetic")
    ax1.plot(t, col("gravitational_energy"), label="gravitational")
    ax1.plot(t, col("mechanical_energy"), "k", lw=2, label="kinetic + gravitational")
    ax1.set_ylabel("energy (J)")
    ax1.legend(loc="best", fontsize="small")
    ax1.grid(alpha=0.3)
    ax1.set_title(title, fontsize="medium")
    ax2.plot(t, 100 * col("max_strain"), label="max |strain|")
    ax2.plot(t, 100 * col("rms_strain"), label="RMS strain")
    ax2.set_ylabel("strain of distance constraints (%)")
    ax2.set_xlabel("time (s)")
    ax2.legend(loc="best", fontsize="small")
    ax2.grid(alpha=0.3)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _collider_triangles(c: dict[str, Any], extent: float) -> np.ndarray:
    """A collider as (T, 3, 3) triangles for drawing: planes as a square of side ``extent`` (m),
    spheres and capsules as coarse lat-long meshes, boxes as their 12 faces, meshes as they are."""
    kind = c["kind"]
    if kind == "mesh":
        return np.asarray(c["vertices"])[np.asarray(c["triangles"])]
    if kind == "box":
        e, R, o = np.asarray(c["half_extents"]), np.asarray(c["rotation"]), np.asarray(c["center"])
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * e @ R.T + o
        faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        return np.array([corners[[a, b, d]] for a, b, c_, d in faces] + [corners[[b, c_, d]] for a, b, c_, d in faces])
    if kind == "plane":
        n, p = np.asarray(c["normal"]), np.asarray(c["point"])
        u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        q = [p + extent * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        return np.array([[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
    # Sphere or capsule: a lat-long sphere, stretched along the capsule's axis.
    th, ph = np.meshgrid(np.linspace(0, np.pi, 9), np.linspace(0, 2 * np.pi, 17), indexing="ij")
    unit = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], axis=-1)
    pts = c["radius"] * unit
    if kind == "sphere":
        pts = pts + np.asarray(c["center"])
    else:
        a, b = np.asarray(c["a"]), np.asarray(c["b"])
        axis = (b - a) / np.linalg.norm(b - a)
        pts = pts + np.where((pts @ axis)[..., None] >= 0, b, a)
    quads = [(pts[i, j], pts[i + 1, j], pts[i + 1, j + 1], pts[i, j + 1]) for i in range(8) for j in range(16)]
    return np.array([t for a, b, c_, d in quads for t in ((a, b, c_), (a, c_, d))])


def frame_axes(ax: Any, centre: np.ndarray, half: float, title: str) -> None:
    """A 3D axes of matplotlib (z up) framing a y-up scene: a cube of half-width `half` (m) about
    `centre`, drawn as (x, -z, y), the view from the front left and above."""
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(-centre[2] - half, -centre[2] + half)
    ax.set_zlim(centre[1] - half, centre[1] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("-z (m)")
    ax.set_zlabel("y (m)")
    ax.view_init(elev=22, azim=-60)
    ax.set_title(title, fontsize="medium")


def plot_snapshot(path: Path, model: _core.Model, state: _core.State, title: str,
                  poses: Sequence[tuple[Any, Any]] | None = None,
                  vertices: Sequence[Any | None] | None = None) -> Path:
    """The model's surface (triangles, or its particles and line cells) at ``state``, with its
    colliders in grey: a picture of where the simulation ended, y up. ``poses``: per collider
    (R, translation in m) where a moving collider is (PbdStepper.collider_pose); None: as declared.
    ``vertices``: per collider, a mesh collider's (V, 3) vertices (m, its model frame, the pose
    applied on top) where it has deformed to (PbdStepper.collider_vertices), or None: as declared."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    x = np.asarray(state.x)
    # Matplotlib's 3D axes have z up: draw (x, y, z) as (x, -z, y).
    to_plot = lambda p: p[..., [0, 2, 1]] * np.array([1, -1, 1])  # noqa: E731
    lo, hi = x.min(axis=0), x.max(axis=0)
    extent = max(float(np.max(hi - lo)), 1e-3)
    fig = plt.figure(figsize=(6.5, 6), constrained_layout=True)
    ax = fig.add_subplot(projection="3d")
    centre = (lo + hi) / 2
    for k, c in enumerate(model.colliders):
        if vertices is not None and vertices[k] is not None and c["kind"] == "mesh":
            c = {**c, "vertices": np.asarray(vertices[k], dtype=float)}
        tris = _collider_triangles(c, extent)
        if poses is not None:
            R, t = poses[k]
            tris = tris @ np.asarray(R).T + np.asarray(t)
        # Planes and large meshes are drawn only near the bodies.
        ax.add_collection3d(Poly3DCollection(to_plot(tris), facecolor=(0.6, 0.6, 0.6, 0.25),
                                             edgecolor=(0.4, 0.4, 0.4, 0.3), linewidth=0.3))
    tris = np.asarray(model.triangles)
    if len(tris):
        ax.add_collection3d(Poly3DCollection(to_plot(x[tris]), facecolor=(0.2, 0.45, 0.8, 0.85),
                                             edgecolor=(0.1, 0.2, 0.4, 0.5), linewidth=0.2))
    else:
        ax.scatter(*to_plot(x).T, s=4)
    frame_axes(ax, centre, 0.65 * extent, title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
