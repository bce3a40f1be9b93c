"""PbdStepper.workspace_bytes counts a deforming mesh collider's buffers (collider_motion.cpp):
its vertices at the last step's end and the next one's, at a sub-step's start and end and at the
step's end (3 x V doubles each), the swept triangles' boxes (two 3-vectors a triangle) and the
grid over them."""

from __future__ import annotations

import numpy as np

import csb


def sheet(n: int) -> csb.Mesh:
    """An n x n grid of vertices 1 m wide in the xz plane, 2 (n - 1)² triangles."""
    s = np.linspace(-0.5, 0.5, n)
    x, z = np.meshgrid(s, s, indexing="ij")
    v = np.stack([x.ravel(), np.zeros(n * n), z.ravel()], axis=1)
    tris = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            tris += [[a, c, b], [a, d, c]]
    return csb.Mesh(v, np.array(tris), name="sheet")


def test_workspace_bytes_counts_a_deforming_mesh_collider():
    """A 20 x 20 sheet (V = 400, T = 722) under a particle, stepped once as declared and once
    deformed (raised 1 cm, 4 sub-steps: every buffer above is in use). The workspace grows by at
    least the five vertex buffers and the boxes, 5 x 24 V + 48 T bytes, and by more (the grid's
    cell and item arrays); a step without deformation leaves it as it was."""
    mesh = sheet(20)
    b = csb.ModelBuilder()
    g = b.add_group("puck")
    b.add_particle([0.0, 0.5, 0.0], 0.1, g)
    b.add_collider_mesh(mesh, name="sheet")
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(method="xpbd", dt=0.01, substeps=4, iterations=1)
    stepper.step(model, state, 1)
    before = stepper.workspace_bytes
    stepper.step(model, state, 1)
    assert stepper.workspace_bytes == before
    V, T = len(mesh.vertices), len(mesh.triangles)
    stepper.deform_collider(model, 0, np.asarray(mesh.vertices) + [0.0, 0.01, 0.0])
    stepper.step(model, state, 1)
    grown = stepper.workspace_bytes - before
    buffers = 5 * 3 * 8 * V + 2 * 3 * 8 * T
    assert grown > buffers, (grown, buffers)
    # The grid: an index (4 bytes) per cell boundary and per (cell, triangle) overlap, and every
    # triangle overlaps at least one cell.
    assert grown - buffers >= 4 * T, (grown, buffers)
