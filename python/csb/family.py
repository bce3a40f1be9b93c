"""Constraints written in Python: a constraint family states C(x) and its gradient, and csb's
steppers project it in their sweeps with the built-in constraints (PBD with a stiffness, XPBD with
a compliance and its multipliers, Jakobsen), the references and the metrics read it too. For
prototyping and teaching: each sweep calls back into Python, so it is slow (a model holding one is
stepped on one thread), and a kind worth keeping is written in C++ as a family header
(``src/csb/constraints/family.hpp``), with the same corrections.

    class Distance(csb.ConstraintFamily):
        name, arity, params, units = "my_distance", 2, ("rest_length",), ("m",)

        def evaluate(self, x, params):            # x (M, 2, 3) m, params (M, 1)
            d = x[:, 0] - x[:, 1]
            length = np.linalg.norm(d, axis=1)
            n = d / length[:, None]
            return length - params[:, 0], np.stack([n, -n], axis=1)

    b = csb.ModelBuilder()
    ...
    b.add_family(Distance())
    b.add_constraint("my_distance", [i, j], [0.1], stiffness=1.0, compliance=1e-6)

What the stepper does with C and ∇C (for one constraint with particles of inverse masses w_j):
PBD moves Δx_j = -k C w_j ∇_j C / Σ_i w_i |∇_i C|² (Müller et al. 2007, Eq. 4-5); XPBD takes
Δλ = (-C - α̃ λ) / (Σ_i w_i |∇_i C|² + α̃) and Δx_j = w_j ∇_j C Δλ (Macklin et al. 2016, Eq. 18),
α̃ = α/h². A unilateral family is satisfied by C <= 0. In a Gauss-Seidel sweep the family's
constraints are coloured as they are added (no two of a colour share a particle) and evaluated one
colour per call, so each sees the corrections before it: the sweep visits them colour by colour,
in the order they were added within a colour.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from . import _core

__all__ = ["ConstraintFamily", "ShapeMatching"]


class ConstraintFamily:
    """A kind of constraint, written in Python. A subclass sets

    - ``name``: the family's name (unique in a model; ``add_constraint`` takes it),
    - ``arity``: particles per constraint,
    - ``params`` and ``units``: the names and SI units of each constraint's parameters (Reals),
    - ``unilateral`` (default False): True when C <= 0 is satisfied (an inequality),
    - ``compliance_unit`` (default "m/N"): the unit of α, the inverse stiffness of C²/(2α),

    and defines :meth:`evaluate` (vectorised over the constraints) or :meth:`evaluate_one` (one
    constraint at a time, slower still), and optionally :meth:`check`."""

    name: str = ""
    label: str | None = None
    arity: int = 0
    params: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    unilateral: bool = False
    compliance_unit: str = "m/N"

    def evaluate(self, x: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """C (M,) and ∇C (M, arity, 3) of M constraints at their particles' positions x
        (M, arity, 3), m, with their parameters (M, len(params)). A constraint whose gradient has
        no direction (a degenerate one) returns a zero gradient: it is left alone."""
        c = np.empty(len(x))
        g = np.empty_like(x)
        for k in range(len(x)):
            c[k], g[k] = self.evaluate_one(x[k], params[k])
        return c, g

    def evaluate_one(self, x: np.ndarray, params: np.ndarray) -> tuple[float, np.ndarray]:
        """C and ∇C (arity, 3) of one constraint at x (arity, 3), m: define this or evaluate."""
        raise NotImplementedError(f"{type(self).__name__} defines neither evaluate nor evaluate_one")

    def check(self, params: np.ndarray) -> str:
        """Why a constraint with these parameters cannot be made ("" when it can)."""
        return ""


class ShapeMatching(ConstraintFamily):
    """Meshless shape matching (Müller, Heidelberger, Teschner and Gross 2005) as one constraint per
    body: the goal positions g_i = R (x0_i - c0) + c, c the centre of mass, R the rotation of the
    polar decomposition of A = Σ_i m_i (x_i - c)(x0_i - c0)ᵀ, and C = sqrt(Σ_i m_i |x_i - g_i|² /
    M), the mass-weighted RMS distance to them, with ∇_i C = m_i (x_i - g_i) / (M C) (g taken as
    fixed). Its PBD projection with w_i = 1/m_i moves each particle by k (g_i - x_i): the paper's
    update with α = k. The rest shape x0 (n, 3) m and masses (n,) kg are the family's own: one
    ShapeMatching family per shape, its constraints the bodies of that shape (arity n)."""

    def __init__(self, rest: Any, masses: Any, name: str = "shape_matching"):
        rest = np.asarray(rest, dtype=float)
        masses = np.asarray(masses, dtype=float)
        if rest.ndim != 2 or rest.shape[1] != 3 or len(rest) < 2 or not np.all(np.isfinite(rest)):
            raise _core.ParameterError(f"ShapeMatching: rest must be (n >= 2, 3) finite positions in m, got shape {rest.shape}")
        if masses.shape != (len(rest),) or not np.all(masses > 0) or not np.all(np.isfinite(masses)):
            raise _core.ParameterError(f"ShapeMatching: masses must be {len(rest)} masses > 0 kg")
        self.name, self.label, self.arity = name, "shape", len(rest)
        self.params, self.units = (), ()
        self.compliance_unit = "m/N"  # C is a length
        self.masses = masses
        self.offsets = rest - (masses @ rest) / masses.sum()

    def evaluate(self, x: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = self.masses
        total = m.sum()
        centre = np.einsum("j,mjk->mk", m, x) / total                      # (M, 3)
        a = np.einsum("j,mjr,js->mrs", m, x - centre[:, None], self.offsets)  # A (M, 3, 3)
        u, _, vt = np.linalg.svd(a)
        flip = np.sign(np.linalg.det(u @ vt))                              # a rotation, not a reflection
        u[:, :, 2] *= flip[:, None]
        rotation = u @ vt
        goals = np.einsum("mrs,js->mjr", rotation, self.offsets) + centre[:, None]
        d = x - goals
        c = np.sqrt(np.einsum("j,mjk,mjk->m", m, d, d) / total)
        with np.errstate(invalid="ignore", divide="ignore"):
            g = np.where(c[:, None, None] > 0, m[None, :, None] * d / (total * c[:, None, None]), 0.0)
        return c, g


def add_family(builder: _core.ModelBuilder, family: ConstraintFamily) -> str:
    """Registers `family` with `builder` (ModelBuilder.add_family); returns its name."""
    if not isinstance(family, ConstraintFamily):
        raise _core.ParameterError(f"add_family: give a csb.ConstraintFamily, got {family!r}")
    name = family.name
    if not isinstance(name, str) or not name:
        raise _core.ParameterError(f"add_family: {type(family).__name__} needs a name (a non-empty string)")
    arity = family.arity
    if isinstance(arity, bool) or not isinstance(arity, (int, np.integer)) or arity < 1:
        raise _core.ParameterError(f"add_family: family '{name}' needs an arity >= 1 (particles per constraint), got {arity!r}")
    params, units = tuple(family.params), tuple(family.units)
    if len(units) != len(params):
        raise _core.ParameterError(f"add_family: family '{name}' gives {len(params)} parameters and {len(units)} units")
    _core._add_python_family(builder, family.evaluate, name, family.label or name, int(arity), list(params), list(units),
                             bool(family.unilateral), str(family.compliance_unit))
    families = builder.__dict__.setdefault("_python_families", {})
    families[name] = family
    return name


def add_constraint(builder: _core.ModelBuilder, family: str | ConstraintFamily, particles: Sequence[int],
                   params: Sequence[float] = (), stiffness: float = 1.0, compliance: float = 0.0) -> int:
    """A constraint of a family (registered, or added with add_family, by name or object), the
    family's own check first."""
    name = family.name if isinstance(family, ConstraintFamily) else family
    own = builder.__dict__.get("_python_families", {}).get(name)
    if own is not None and len(params) == len(own.params) and len(particles) == own.arity:  # else C++ says what is wrong
        why = own.check(np.asarray(params, dtype=float))
        if why:
            raise _core.ParameterError(f"{own.label or own.name} {list(particles)}: {why}")
    return _core.ModelBuilder.add_constraint(builder, name, list(particles), list(params), stiffness, compliance)
