"""Model builders shared by the tests."""

from __future__ import annotations

import csb


def cloth_model(n: int = 8, *, bending: float | None = 0.5, bending_compliance: float = 0.0, pins: bool = True,
                mass: float = 0.2) -> csb.Model:
    """An n x n cloth over 1 m x 1 m with stretch (and bending: PBD stiffness `bending`, compliance
    `bending_compliance` in 1/(N m) for XPBD), pinned at two corners."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=mass, stretch_stiffness=1.0, bending_stiffness=bending,
                      bending_compliance=bending_compliance)
    if pins:
        b.pin(inst.first_particle)
        b.pin(inst.first_particle + n - 1)
    return b.build()
