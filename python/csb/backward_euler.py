"""Backward (implicit) Euler on the model's distance springs, each step solved by Newton's method
to convergence: the same-step reference for XPBD.

XPBD (Macklin, Müller, Chentanez 2016) approximates one implicit Euler step of the energy
U = Σ C_j²/(2α_j) (their Eq. 4-9): with the inertial position x̃ = xⁿ + h vⁿ + h² g, the step's
positions x minimise

    E(x) = Σ_i m_i |x_i - x̃_i|² / (2h²) + Σ_j C_j(x)² / (2α_j),

so the residual (N) r_i = m_i (x_i - x̃_i)/h² + Σ_j (C_j/α_j) ∇_i C_j vanishes, and
vⁿ⁺¹ = (x - xⁿ)/h. The paper checks its constraint forces against this step solved by Newton's
method; ``BackwardEulerStepper`` is that solver for any csb Model whose constraints are distance
constraints (C = |x_b - x_a| - L, ∇_b C = n = (x_b - x_a)/|x_b - x_a| = -∇_a C):

* Hessian: M/h² plus, per constraint, the block K = nnᵀ/α + (C/α)(I - nnᵀ)/|x_b - x_a| on
  (a, a) and (b, b) and -K on (a, b); where a compressed spring (C < 0) makes it indefinite,
  the step is retried with those negative geometric terms dropped (always positive definite).
* Linear solve: banded Cholesky (A = UᵀU) with the free particles in reverse Cuthill-McKee
  order, so a chain's half-bandwidth is 5 degrees of freedom and a cloth's about 3 rows'.
* Line search: backtracking from the full step, accepting the first that meets Armijo's
  condition on E or, where E's decrease is below its rounding, shrinks the residual.
* Stops when the largest residual component is below rtol times the step's force scale (the
  largest of m|g|, |C/α| and m|x - x̃|/h²) plus its rounding floor (4 eps (|x_a| + |x_b|)/α, N:
  C is a difference of coordinates, amplified by 1/α); the last step's residual is kept.

csb.BackwardEuler is the same solve in C++ over every constraint type csb has (bending, volumes,
balloons, attachments, tethers too), and the same-step reference from here on; this numpy stepper
stays as an independent implementation of the distance-only case, which the C++ one reproduces to
round-off (tests/test_implicit_euler.py).

The spring force of constraint j is C_j/α_j (N, positive when stretched), the converged value of
XPBD's -λ_j/h². Inequalities (sense '>=' or '<=') act only while violated, as in the reference.
Pinned particles (inverse mass 0) stay where the state has them, with zero velocity.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Sequence

import numpy as np

from . import _core

__all__ = ["BackwardEulerStepper"]


class _NotPositiveDefinite(Exception):
    pass


def _rcm_order(n: int, edges: np.ndarray) -> np.ndarray:
    """Reverse Cuthill-McKee order of n nodes joined by edges (E, 2): positions along it keep
    joined nodes close, so the Hessian's band stays narrow."""
    adjacency: list[list[int]] = [[] for _ in range(n)]
    for a, b in edges:
        adjacency[a].append(int(b))
        adjacency[b].append(int(a))
    degree = [len(set(a)) for a in adjacency]
    for i in range(n):
        adjacency[i] = sorted(set(adjacency[i]), key=lambda j: (degree[j], j))
    seen = [False] * n
    order: list[int] = []
    for start in sorted(range(n), key=lambda i: (degree[i], i)):
        if seen[start]:
            continue
        seen[start] = True
        queue = deque([start])
        while queue:
            i = queue.popleft()
            order.append(i)
            for j in adjacency[i]:
                if not seen[j]:
                    seen[j] = True
                    queue.append(j)
    return np.asarray(order[::-1], dtype=np.int64)


class _Banded:
    """A symmetric matrix of n rows and half-bandwidth b in upper band storage,
    ab[i, d] = A[i, i + d], padded with b rows so that updates near the end need no bounds."""

    def __init__(self, n: int, b: int):
        self.n, self.b = n, b
        self.ab = np.zeros((n + b, b + 1))
        p, q = np.triu_indices(b)
        # Flat offsets, from row k + 1, of A[k+1+p, k+1+q] (q >= p): the trailing update of column k.
        self._update = (p * (b + 1) + (q - p), p, q)

    def cholesky(self) -> None:
        """In place: A = UᵀU, U upper with the same band. Raises _NotPositiveDefinite."""
        ab, b, w = self.ab, self.b, self.b + 1
        flat = ab.ravel()
        off, p, q = self._update
        for k in range(self.n):
            pivot = ab[k, 0]
            if not pivot > 0.0:
                raise _NotPositiveDefinite
            ukk = math.sqrt(pivot)
            row = ab[k, 1:] / ukk
            ab[k, 0] = ukk
            ab[k, 1:] = row
            if b:
                flat[(k + 1) * w + off] -= row[p] * row[q]

    def solve(self, r: np.ndarray) -> np.ndarray:
        """x with UᵀU x = r, after cholesky()."""
        ab, n, b = self.ab, self.n, self.b
        y = np.concatenate([r, np.zeros(b)])
        for k in range(n):
            y[k] /= ab[k, 0]
            y[k + 1:k + b + 1] -= ab[k, 1:] * y[k]
        x = np.concatenate([y[:n], np.zeros(b)])
        for k in range(n - 1, -1, -1):
            x[k] = (x[k] - ab[k, 1:] @ x[k + 1:k + b + 1]) / ab[k, 0]
        return x[:n]


def _vector(value: Sequence[float], name: str) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise _core.ParameterError(f"{name} must be 3 finite numbers, got {value!r}")
    return v


class BackwardEulerStepper(_core.Integrator):
    """Backward Euler of the model's distance springs (energy C²/(2α)), solved by Newton's
    method to convergence each step: a csb.Integrator written in Python, so the scene runner,
    the viewer and the studies take it as they take a built-in method.

    dt: time step, s (> 0). gravity: m/s². rtol: the residual at which a step stops, relative
    to the step's force scale (> 0), on top of the residual's rounding floor (module docstring).
    max_iterations: Newton iterations per step before csb.SimulationError.

    After a step: ``forces`` (M,) spring forces C/α of the distance constraints, N (positive:
    stretched); ``residual`` the largest residual component, N, and ``tolerance`` the bound it
    met; ``newton_iterations`` used; ``max_residual`` the largest residual of all steps so far.
    """

    def __init__(self, *, dt: float = 1.0 / 60.0, gravity: Sequence[float] = (0.0, -9.81, 0.0),
                 rtol: float = 1e-9, max_iterations: int = 100):
        super().__init__()
        if not (math.isfinite(dt) and dt > 0):
            raise _core.ParameterError(f"dt must be a finite time step > 0 s, got {dt!r}")
        if not (math.isfinite(rtol) and rtol > 0):
            raise _core.ParameterError(f"rtol must be finite and > 0, got {rtol!r}")
        if int(max_iterations) != max_iterations or max_iterations < 1:
            raise _core.ParameterError(f"max_iterations must be an integer >= 1, got {max_iterations!r}")
        self._dt = float(dt)
        self.gravity = _vector(gravity, "gravity")
        self.rtol = float(rtol)
        self.max_iterations = int(max_iterations)
        self.forces = np.zeros(0)
        self.residual = 0.0
        self.tolerance = 0.0
        self.newton_iterations = 0
        self.max_residual = 0.0
        self._model: _core.Model | None = None

    def name(self) -> str:
        return "backward-euler"

    def dt(self) -> float:
        """s, the time one step advances."""
        return self._dt

    # -- per-model set-up ------------------------------------------------------------------
    def _prepare(self, model: _core.Model) -> None:
        others = {"bending": len(model.bending["particles"]), "volume": len(model.volume["particles"]),
                  "balloons": len(model.balloons["rest_volume"]), "attachments": len(model.attachments["particle"]),
                  "colliders": len(model.colliders)}
        present = [f"{n} {k}" for k, n in others.items() if n]
        if present:
            raise _core.ParameterError("BackwardEulerStepper models distance constraints only; the model also has "
                                       + ", ".join(present))
        d = model.distance
        pairs = np.asarray(d["particles"], dtype=np.int64).reshape(-1, 2)
        alpha = np.asarray(d["compliance"], dtype=float)
        bad = np.flatnonzero(~(alpha > 0) | ~np.isfinite(alpha))
        if bad.size:
            raise _core.ParameterError(
                f"compliance of distance constraint {int(bad[0])} is {alpha[bad[0]]!r}: backward Euler needs every "
                "distance constraint compliant (α > 0 m/N; a hard constraint has no potential C²/(2α))")
        self._pairs = pairs
        self._rest = np.asarray(d["rest_length"], dtype=float)
        self._alpha = alpha
        self._sense = np.asarray(d["sense"], dtype=np.int64)
        self._mass = np.asarray(model.mass, dtype=float)
        self._free = np.asarray(model.inv_mass, dtype=float) > 0
        free_ids = np.flatnonzero(self._free)
        both = self._free[pairs[:, 0]] & self._free[pairs[:, 1]] if len(pairs) else np.zeros(0, bool)
        local = np.full(model.num_particles, -1, dtype=np.int64)
        local[free_ids] = np.arange(free_ids.size)
        order = _rcm_order(free_ids.size, local[pairs[both]])
        position = np.empty(free_ids.size, dtype=np.int64)
        position[order] = np.arange(free_ids.size)
        slot = np.full(model.num_particles, -1, dtype=np.int64)  # particle -> place in the band (-1: pinned)
        slot[free_ids] = position
        self._slot = slot
        self._dof_particle = free_ids[order]  # band place -> particle
        sa, sb = slot[pairs[:, 0]], slot[pairs[:, 1]]
        spread = int(np.abs(sa - sb)[both].max()) if both.any() else 0
        self._half_band = 3 * spread + 2 if free_ids.size else 0
        self._model = model  # held: the identity test in step() cannot match a new model at a reused address

    # -- the Newton solve -----------------------------------------------------------------------
    def _springs(self, y: np.ndarray):
        pairs = self._pairs
        e = y[pairs[:, 1]] - y[pairs[:, 0]]
        length = np.linalg.norm(e, axis=1)
        if np.any(length == 0):
            raise _core.SimulationError("a distance constraint's particles coincide: its direction is undefined")
        n = e / length[:, None]
        c = length - self._rest
        c = np.where(self._sense > 0, np.minimum(c, 0.0), np.where(self._sense < 0, np.maximum(c, 0.0), c))
        return n, length, c

    def _residual(self, y, x_tilde, n, c):
        h2 = self._dt**2
        inertia = self._mass[:, None] * (y - x_tilde) / h2
        r = inertia.copy()
        f = (c / self._alpha)[:, None] * n
        np.add.at(r, self._pairs[:, 1], f)
        np.add.at(r, self._pairs[:, 0], -f)
        r[~self._free] = 0.0
        return r, inertia

    def _rounding(self, y: np.ndarray) -> float:
        """The residual's rounding floor, N: a spring's C = |x_b - x_a| - L is only known to about
        eps (|x_a| + |x_b|), and that error is multiplied by 1/α."""
        if not len(self._pairs):
            return 0.0
        size = np.abs(y[self._pairs[:, 0]]).max(axis=1) + np.abs(y[self._pairs[:, 1]]).max(axis=1)
        return float(4 * np.finfo(float).eps * np.max(size / self._alpha))

    def _energy(self, y, x_tilde, c):
        return float(0.5 / self._dt**2 * np.sum(self._mass[self._free, None] * (y - x_tilde)[self._free] ** 2)
                     + np.sum(c**2 / (2 * self._alpha)))

    def _hessian(self, n, length, c, project: bool) -> _Banded:
        nfree = self._dof_particle.size
        H = _Banded(3 * nfree, self._half_band)
        ab = H.ab
        m = self._mass[self._dof_particle] / self._dt**2
        ab[:3 * nfree, 0] += np.repeat(m, 3)
        active = (self._sense == 0) | (c != 0)
        geometric = c / self._alpha / length
        if project:
            geometric = np.maximum(geometric, 0.0)
        K = (np.einsum("ja,jb->jab", n, n) * (1 / self._alpha - geometric)[:, None, None]
             + geometric[:, None, None] * np.eye(3)) * active[:, None, None]
        ia, ib = np.triu_indices(3)  # upper triangle of a diagonal block
        sa, sb = self._slot[self._pairs[:, 0]], self._slot[self._pairs[:, 1]]
        for s in (sa, sb):
            j = np.flatnonzero(s >= 0)
            rows = 3 * s[j][:, None] + ia[None, :]
            np.add.at(ab, (rows, (ib - ia)[None, :]), K[j][:, ia, ib])
        j = np.flatnonzero((sa >= 0) & (sb >= 0))
        lo, hi = np.minimum(sa[j], sb[j]), np.maximum(sa[j], sb[j])
        a3, b3 = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
        rows = 3 * lo[:, None, None] + a3[None]
        cols = 3 * (hi - lo)[:, None, None] + b3[None] - a3[None]
        np.add.at(ab, (rows, cols), -K[j])
        return H

    def _step(self, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = self._dt
        free = self._free
        x_tilde = x + (h * v + h * h * self.gravity) * free[:, None]
        y = x_tilde.copy()
        weight = float(np.max(self._mass[free]) * np.linalg.norm(self.gravity)) if free.any() else 0.0
        for it in range(self.max_iterations + 1):
            n, length, c = self._springs(y)
            r, inertia = self._residual(y, x_tilde, n, c)
            scale = max(weight, float(np.max(np.abs(c) / self._alpha, initial=0.0)),
                        float(np.max(np.linalg.norm(inertia[free], axis=1), initial=0.0)))
            res = float(np.max(np.abs(r), initial=0.0))
            tol = self.rtol * scale + self._rounding(y)
            if res <= tol:
                break
            if it == self.max_iterations:
                raise _core.SimulationError(f"backward Euler: Newton's residual {res:.3g} N after {it} iterations, "
                                            f"above the tolerance {tol:.3g} N (rtol {self.rtol:g})")
            rb = r[self._dof_particle].ravel()
            for project in (False, True):
                H = self._hessian(n, length, c, project)
                try:
                    H.cholesky()
                    break
                except _NotPositiveDefinite:
                    if project:
                        raise _core.SimulationError("backward Euler: the projected Hessian is not positive definite")
            dx = np.zeros_like(y)
            dx[self._dof_particle] = -H.solve(rb).reshape(-1, 3)
            energy = self._energy(y, x_tilde, c)
            slope = float(np.sum(r * dx))  # < 0: dx is a descent direction of E
            t = 1.0
            while True:
                trial = y + t * dx
                nt, _, ct = self._springs(trial)
                if self._energy(trial, x_tilde, ct) <= energy + 1e-4 * t * slope:
                    break
                if np.max(np.abs(self._residual(trial, x_tilde, nt, ct)[0])) < (1 - 1e-4 * t) * res:
                    break
                t *= 0.5
                if t < 1e-12:
                    raise _core.SimulationError(f"backward Euler: the line search stalled at residual {res:.3g} N "
                                                f"(tolerance {tol:.3g} N)")
            y = trial
        self.forces = c / self._alpha
        self.residual, self.tolerance, self.newton_iterations = res, tol, it
        self.max_residual = max(self.max_residual, res)
        v_new = (y - x) / h
        v_new[~free] = 0.0
        y[~free] = x[~free]
        return y, v_new

    def step(self, model: _core.Model, state: _core.State, steps: int = 1, interrupt=None) -> None:
        """Advances ``state`` by ``steps`` backward Euler steps of dt (s); ``interrupt``, if given,
        is asked between steps whether to stop (csb.Error then, the state at the end of a step)."""
        if int(steps) != steps or steps < 0:
            raise _core.ParameterError(f"steps must be an integer >= 0, got {steps!r}")
        if state.num_particles != model.num_particles:
            raise _core.ParameterError(f"state has {state.num_particles} particles, the model {model.num_particles}")
        if self._model is not model:
            self._prepare(model)
        x = np.array(state.x, dtype=float)
        v = np.array(state.v, dtype=float)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
            raise _core.ParameterError("state.x and state.v must be finite")
        try:
            for k in range(int(steps)):
                if k > 0 and interrupt is not None and interrupt():
                    raise _core.Error(f"interrupted after {k} of {int(steps)} steps (t = {state.t:g} s): the state is "
                                      "left at the end of that step")
                x, v = self._step(x, v)
                state.t += self._dt
                state.step += 1
        finally:
            state.x = x
            state.v = v
