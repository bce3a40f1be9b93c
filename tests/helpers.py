"""Model builders shared by the tests."""

from __future__ import annotations

import os

import pytest

import csb

# The sanitizer build (./dev sanitize) sets CSB_SANITIZE=1. Under AddressSanitizer a failed
# operator new reports "allocator is out of memory" and aborts instead of throwing std::bad_alloc
# (allocator_may_return_null covers malloc only), so the Assimp child that reaches its RLIMIT_AS
# cap dies with a report where csb would name the max_memory limit. The tests of that message
# (and only those) skip there, saying so; the child's death is still a MeshError.
needs_bad_alloc = pytest.mark.skipif(
    os.environ.get("CSB_SANITIZE") == "1",
    reason="the sanitizer build: ASan's operator new aborts on exhaustion instead of throwing std::bad_alloc")
# Resident memory there also holds ASan's shadow, redzones and freed-memory quarantine.
measures_resident_memory = pytest.mark.skipif(
    os.environ.get("CSB_SANITIZE") == "1",
    reason="the sanitizer build: AddressSanitizer's shadow, redzones and quarantine add to resident memory")


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
