#!/usr/bin/env python3
"""Study: the simulation back in the user's tools — the bundled cloth_drop written as USD on its
OBJ's own quads and read back with Pixar's USD.

cloth_drop (a 1 m cloth of two OBJ panels, 1,024 quads with texture seams, welded into 1,089
particles, PBD 40 x 1) runs with its [output] set to USD alone, 30 frames per second. The file is
opened again with pxr and compared with the same scene stepped here frame by frame: the stage's
metadata, the quads and UVs against the OBJ's, and at every frame each point against the position
of the particle its vertex was welded into (USD stores points as 32-bit floats, so the comparison
is to float32 rounding: the largest difference is printed, and must be at most half a float32 ulp
of the largest coordinate: 6e-8 m for coordinates between 1 and 2 m). A still of the last frame is
drawn from the USD. Writes cloth_drop.usd and usd_still.png.

    python validation/usd_export.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

import csb
from csb.export import plot_usd, usd_available


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="0.5 s instead of the scene's 3 s (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not usd_available():
        raise SystemExit("usd_export: needs Pixar's usd-core (pip install 'csb[usd]')")
    from pxr import Usd, UsdGeom

    scene = csb.load_scene("cloth_drop")
    output = dataclasses.replace(scene.output, xdmf=False, vtu=False, csv=False, plot=False, usd=True)
    scene = dataclasses.replace(scene, output=output, duration=0.5 if args.quick else scene.duration)
    result = scene.run(out)
    path = out / "cloth_drop.usd"

    sim = scene.build()
    src = sim.meshes["cloth"].source
    keep, index = src.distinct_vertices()
    steps_per_frame = max(1, round(1.0 / (scene.output.fps * scene.solver.dt)))
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/cloth"))
    points = mesh.GetPointsAttr()
    times = points.GetTimeSamples()
    faces = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    uv = np.asarray(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Get())
    assert np.array_equal(src.vertices[keep][faces], src.vertices[src.face_vertices])
    assert np.array_equal(uv[faces], src.uv[src.face_vertices].astype(np.float32))
    worst, largest = 0.0, 0.0
    for k, code in enumerate(times):
        if k:
            sim.step(steps_per_frame)
        want = src.positions(np.asarray(sim.state.x))[keep]
        got = np.asarray(points.Get(Usd.TimeCode(code)), dtype=float)
        worst = max(worst, float(np.max(np.abs(got - want))))
        largest = max(largest, float(np.max(np.abs(want))))
    ulp = float(np.spacing(np.float32(largest)))
    print(f"{path.name}: {len(times)} frames (time codes {times[0]:g}-{times[-1]:g} at "
          f"{stage.GetTimeCodesPerSecond():g} per second), metersPerUnit {UsdGeom.GetStageMetersPerUnit(stage):g}, "
          f"up axis {UsdGeom.GetStageUpAxis(stage)}")
    print(f"  mesh: {len(keep)} points ({len(src.vertices)} corners as Assimp read the OBJ, welded into "
          f"{sim.meshes['cloth'].num_particles} particles), {len(counts)} polygons of "
          f"{sorted(set(counts.tolist()))} corners, UVs and normals")
    print(f"  largest |USD point - simulated particle| over every frame: {worst:.3g} m "
          f"(coordinates up to {largest:.3g} m, float32 ulp there {ulp:.3g} m)")
    if not worst <= ulp / 2:
        raise SystemExit(f"usd_export: the USD points differ from the simulation by {worst:.3g} m, more than "
                         f"float32 rounding ({ulp / 2:.3g} m)")
    still = plot_usd(path, out / "usd_still.png", title=f"cloth_drop.usd read back, t = {sim.state.t:.2f} s")
    print(f"  wrote {still} ({result.wall_time:.2f} s of stepping)")


if __name__ == "__main__":
    main()
