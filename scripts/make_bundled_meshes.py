#!/usr/bin/env python3
"""Writes python/csb/scenes/meshes/cloth_panels.obj, the cloth of the bundled cloth_drop scene.

It is written the way modelling tools export cloth: two panels as separate objects whose shared
seam repeats the same positions, quads rather than triangles, texture coordinates and normals
per corner. csb must weld the seam and triangulate the quads for the cloth to hold together.
Run it again only to change the asset; the file is committed.
"""

from pathlib import Path

N = 33            # vertices along each side of the whole cloth
SIZE = 1.0        # m
SEAM = 16         # column index where the two panels meet (repeated in both)


def main() -> None:
    out = Path(__file__).resolve().parents[1] / "python/csb/scenes/meshes/cloth_panels.obj"
    lines = [
        "# csb bundled asset: a 1 m x 1 m cloth in two panels (33 x 33 vertices once welded)",
        "# written by scripts/make_bundled_meshes.py; units: metres, y up, cloth in the x-z plane",
    ]
    v_base = vt_base = 0
    for name, cols in (("panel_left", range(0, SEAM + 1)), ("panel_right", range(SEAM, N))):
        cols = list(cols)
        lines.append(f"o {name}")
        for j in range(N):
            for i in cols:
                x = SIZE * (i / (N - 1) - 0.5)
                z = SIZE * (j / (N - 1) - 0.5)
                lines.append(f"v {x:.6f} 0.000000 {z:.6f}")
        for j in range(N):
            for i in cols:
                lines.append(f"vt {(i - cols[0]) / (len(cols) - 1):.6f} {j / (N - 1):.6f}")
        lines.append("vn 0 1 0")
        vn = 1 + sum(1 for line in lines if line.startswith("vn ")) - 1
        w = len(cols)
        for j in range(N - 1):
            for i in range(w - 1):
                a = v_base + j * w + i + 1
                b, c, d = a + 1, a + w + 1, a + w
                ta = vt_base + j * w + i + 1
                tb, tc, td = ta + 1, ta + w + 1, ta + w
                lines.append(f"f {a}/{ta}/{vn} {d}/{td}/{vn} {c}/{tc}/{vn} {b}/{tb}/{vn}")
        v_base += N * w
        vt_base += N * w
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n", encoding="ascii")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
