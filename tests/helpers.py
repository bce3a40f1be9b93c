"""Model builders shared by the tests."""

from __future__ import annotations

import os

import pytest

import csb

# The sanitizer build (./dev sanitize) sets CSB_SANITIZE=1. There a reader that reaches the
# RLIMIT_AS cap of csb's loaders dies with AddressSanitizer's "allocator is out of memory" report
# where csb would name the max_memory limit: ASan's operator new never throws std::bad_alloc (the
# Assimp child), and its malloc reports instead of returning null unless allocator_may_return_null
# is set (numpy's MemoryError in the meshio child), which ./dev sanitize leaves off so that no
# failed allocation passes silently. The tests of that message (and only those) skip there,
# saying so; ./dev test runs them.
reaches_memory_cap = pytest.mark.skipif(
    os.environ.get("CSB_SANITIZE") == "1",
    reason="the sanitizer build: AddressSanitizer ends a reader that reaches its RLIMIT_AS cap with an "
           "out-of-memory report instead of std::bad_alloc or MemoryError")
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


def cloth_over_sphere(n: int) -> csb.Model:
    """An n x n cloth (1 m, 0.2 kg, stretch 1e-5 m/N, bending 1 1/(N m), 1 cm thick) above a sphere
    of 0.3 m radius centred at (0, -0.4, 0), friction 0.4 / 0.3: the implicit methods' drape."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.2, stretch_compliance=1e-5, bending_stiffness=1.0,
               bending_compliance=1.0, thickness=0.01)
    b.add_sphere(center=[0, -0.4, 0], radius=0.3, friction_static=0.4, friction_kinetic=0.3)
    return b.build()


def copies_here() -> tuple[str, ...]:
    """The copies of the blocked kernels this processor runs (portable x86-64 build), or
    ("auto",) where there is one copy (a native build, other processors)."""
    best = csb.kernels.kernel_isa("auto")
    order = ("sse2", "avx2", "avx512")
    return order[:order.index(best) + 1] if best in order else ("auto",)
