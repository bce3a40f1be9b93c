"""The reference: the model's constraints as springs (E = C²/(2α)) integrated with SUNDIALS CVODE,
and errors measured against it. See src/csb/reference.hpp and papers/reference.md.

How well the reference keeps the energy of an undamped scene depends on the tolerance, the
frequency of the modes that carry the energy and the duration, not on the frequency alone
(``validation/reference_energy.py``): BDF5 changes a spring mode's energy by a fraction

    ε ≈ c · rtol^(5/6) per period of the mode,   c ≤ ENERGY_CONSTANT,

always a loss. The exponent is BDF5's: CVODE takes steps whose local error, of order (hω)⁶, is
held at rtol; at odd orders that error changes the amplitude, so the energy changes by about
that much per step, and a period takes 2π/(hω) ∝ rtol^(-1/6) steps. Over a run of T seconds a
mode of ω rad/s goes through ωT/(2π) periods, so the relative energy error is at most
c · rtol^(5/6) · ωT/(2π) with ω the fastest mode holding energy. ``rtol="auto"`` inverts that
for ``energy_tolerance`` (see ``energy_rtol``), with ω from ``frequency`` or, by default, an upper
bound of the scene's fastest spring mode (``frequency_bound``), so the bound holds whichever
modes carry the energy."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any, Iterator, Sequence

import numpy as np

from . import _core
from ._core import SpringNetwork

__all__ = ["ReferenceResult", "SpringNetwork", "integrate_reference", "position_error", "energy_rtol", "energy_bound",
           "frequency_bound", "ENERGY_CONSTANT", "RTOL_CEILING", "RTOL_FLOOR"]

# c of the energy law: the largest ε / rtol^(5/6) that validation/reference_energy.py measured on
# one spring (1 to 1000 rad/s, rtol 1e-6 to 1e-12, 10 to 1000 periods, amplitudes down to 1e-3 of
# the particle's distance from the origin: CVODE's relative test on positions loosens as the
# amplitude shrinks against the coordinates; at 1e-4 of it c reached 60).
ENERGY_CONSTANT = 40.0
# rtol="auto" never runs looser than this, the tolerance at which the reference's trajectories are
# converged (validation/reference_self_convergence.py), nor asks for less than RTOL_FLOOR, the
# tightest tolerance at which the law was measured to hold.
RTOL_CEILING = 1e-8
RTOL_FLOOR = 1e-14
_BDF5 = 5


def _finite_positive(name: str, value, unit: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise _core.ParameterError(f"{name} must be a finite number > 0{unit}, got {value!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise _core.ParameterError(f"{name} must be a finite number > 0{unit}, got {value!r}")
    return x


def energy_bound(rtol: float, frequency: float, duration: float) -> float:
    """The law's bound on the relative energy error of BDF5 at ``rtol`` over ``duration`` (s) for
    modes no faster than ``frequency`` (rad/s): ENERGY_CONSTANT · rtol^(5/6) · frequency · duration / (2π)."""
    return ENERGY_CONSTANT * rtol ** (5 / 6) * frequency * duration / (2 * math.pi)


def energy_rtol(frequency: float, duration: float, energy_tolerance: float = 1e-6) -> float:
    """The tolerance ``rtol="auto"`` uses: the largest rtol whose ``energy_bound`` over ``duration``
    (s) at ``frequency`` (rad/s) is ``energy_tolerance`` (relative), at most RTOL_CEILING.
    Raises csb.ParameterError for impossible values, or when the bound would need an rtol below
    RTOL_FLOOR."""
    tol = _finite_positive("energy_tolerance", energy_tolerance, " (relative)")
    if tol >= 1:
        raise _core.ParameterError(f"energy_tolerance must be below 1 (relative), got {energy_tolerance!r}")
    w = float(frequency)
    if not (math.isfinite(w) and w >= 0):
        raise _core.ParameterError(f"frequency must be a finite angular frequency >= 0 rad/s, got {frequency!r}")
    T = float(duration)
    if not (math.isfinite(T) and T >= 0):
        raise _core.ParameterError(f"the duration must be finite and >= 0 s, got {duration!r}")
    periods = w * T / (2 * math.pi)
    if periods == 0:
        return RTOL_CEILING
    rtol = (tol / (ENERGY_CONSTANT * periods)) ** (6 / 5)
    if rtol < RTOL_FLOOR:
        reach = energy_bound(RTOL_FLOOR, w, T)
        raise _core.ParameterError(
            f"rtol='auto' cannot keep the energy within energy_tolerance={tol:g} over {periods:.4g} periods of "
            f"frequency={w:.6g} rad/s ({T:g} s): that needs rtol={rtol:.2g}, below {RTOL_FLOOR:g} (at {RTOL_FLOOR:g} "
            f"the bound is {reach:.2g}). Give a larger energy_tolerance, a shorter run, the frequency (rad/s) of the "
            f"fastest mode that actually carries energy as frequency=..., or an explicit rtol")
    return min(RTOL_CEILING, rtol)


def frequency_bound(model: _core.Model, state: _core.State, gravity: Sequence[float] = (0.0, -9.81, 0.0)) -> float:
    """An upper bound (rad/s) of the fastest mode of the model's springs, attachments and volumes
    at ``state``: the square root of the largest absolute row sum of M⁻¹K (Gershgorin's bound on
    its eigenvalues ω²), read from the analytic Jacobian's ∂v̇/∂x block. Compliant bending and
    balloons, which that Jacobian leaves out, are not counted. 0 for a model without springs."""
    net = SpringNetwork(model, state, gravity=gravity)
    n3 = net.size // 2
    indptr, indices, data = net.jacobian(net.pack(state))
    cols = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    block = (cols < n3) & (indices >= n3)
    rows = np.bincount(indices[block] - n3, weights=np.abs(data[block]), minlength=n3)
    return float(math.sqrt(rows.max())) if len(rows) else 0.0


@dataclass
class ReferenceResult:
    times: np.ndarray      # (T,) s
    x: np.ndarray          # (T, N, 3) m, pinned particles included
    v: np.ndarray          # (T, N, 3) m/s
    stats: dict[str, Any] = field(default_factory=dict)
    """CVODE's counts (steps, rhs_evals, newton_iters, jacobian_evals, linear_iters, ...),
    last_order, last_step (s), wall_time (s), linear_solver ("klu" or "gmres"), the rtol and atol
    used, the frequency (rad/s) the energy bound counts with and that bound, energy_bound
    (relative; None when max_order < 5)"""

    def states(self, model: _core.Model) -> Iterator[_core.State]:
        """The result as csb States (e.g. for csb.measure)."""
        for k, t in enumerate(self.times):
            s = model.initial_state()
            s.x = self.x[k]
            s.v = self.v[k]
            s.t = float(t)
            yield s


def integrate_reference(
    model: _core.Model,
    state: _core.State,
    times: Sequence[float] | np.ndarray,
    *,
    gravity: Sequence[float] = (0.0, -9.81, 0.0),
    rtol: float | str = "auto",
    atol: float | str = "auto",
    energy_tolerance: float = 1e-6,
    frequency: float | None = None,
    damping: float = 0.0,
    drag: float = 0.0,
    max_order: int = 5,
    stability_limit_detection: bool = False,
    linear_solver: str = "auto",
    max_steps: int = 10_000_000,
    max_wall_time: float = 0.0,
) -> ReferenceResult:
    """Integrate the model's continuous system from ``state`` (at ``state.t``) with CVODE (BDF,
    Newton) and return positions and velocities at ``times`` (s, increasing, not before
    ``state.t``).

    Every constraint needs a compliance α > 0 (it becomes the spring energy C²/(2α)); pinned
    particles stay where ``state`` has them. gravity in m/s².

    rtol: "auto" (default) or a relative tolerance. "auto" takes ``energy_rtol(frequency,
    duration, energy_tolerance)``: the largest rtol (at most 1e-8) for which BDF5's measured
    energy law bounds the relative energy error of the run by ``energy_tolerance`` (default
    1e-6), for modes up to ``frequency`` rad/s (default: ``frequency_bound``, an upper bound of the
    fastest spring mode, so the bound holds whichever modes carry the energy; a scene whose stiff
    modes are known to hold no energy may name the fastest one that does). A bound that would
    need rtol below 1e-14 is refused with a csb.ParameterError that says what would work.
    atol: "auto" (default, rtol/100) or an absolute tolerance on positions (m) and velocities (m/s).
    The result's ``stats`` record the rtol, atol and frequency used and the law's ``energy_bound``
    (with max_order 5; the law is BDF5's, so "auto" needs max_order 5).

    damping (N s/m): a dashpot along each distance constraint and an isotropic one on each
    attachment; bending and volume constraints are not damped (unlike XPBD's damping, which acts
    along every constraint's gradient). drag (1/s): a force -drag m v on every particle (brings a
    hanging chain to rest, which a dashpot along the links does not). max_order caps the BDF
    order (1-5); linear_solver "auto" (KLU with the analytic Jacobian, or GMRES when compliant
    bending is present), "klu" or "gmres". Raises csb.ParameterError for bad input and
    csb.SimulationError if CVODE fails, needs more than max_steps steps or more than
    max_wall_time seconds (0: no limit).
    """
    out_times = [float(t) for t in np.atleast_1d(np.asarray(times, dtype=float))]
    if frequency is None:
        w = frequency_bound(model, state, gravity)
    else:
        w = float(frequency) if isinstance(frequency, numbers.Real) and not isinstance(frequency, bool) else math.nan
        if not (math.isfinite(w) and w > 0):
            raise _core.ParameterError(f"frequency must be a finite angular frequency > 0 rad/s, got {frequency!r}")
    duration = max(out_times[-1] - state.t, 0.0) if out_times and math.isfinite(out_times[-1]) else 0.0
    if isinstance(rtol, str):
        if rtol != "auto":
            raise _core.ParameterError(f"rtol must be 'auto' or a finite tolerance > 0, got {rtol!r}")
        if max_order in range(1, _BDF5):  # (an impossible max_order is refused below, by name)
            raise _core.ParameterError(
                f"rtol='auto' follows BDF5's energy law and needs max_order=5, got max_order={max_order!r}: "
                "give rtol explicitly")
        rtol = energy_rtol(w, duration, energy_tolerance)
    else:
        energy_rtol(w, 0.0, energy_tolerance)  # checks energy_tolerance
    if isinstance(atol, str):
        if atol != "auto":
            raise _core.ParameterError(f"atol must be 'auto' or a finite tolerance > 0, got {atol!r}")
        atol = rtol / 100
    t, x, v, stats = _core._integrate_reference(
        model, state, out_times, gravity=gravity, rtol=rtol,
        atol=atol, damping=damping, drag=drag, max_order=max_order, stability_limit_detection=stability_limit_detection,
        linear_solver=linear_solver, max_steps=max_steps, max_wall_time=max_wall_time,
    )
    stats.update(rtol=float(rtol), atol=float(atol), frequency=w,
                 energy_bound=energy_bound(rtol, w, duration) if max_order == _BDF5 else None)
    return ReferenceResult(t, x, v, stats)


def position_error(x: np.ndarray, x_ref: np.ndarray) -> tuple[float, float]:
    """RMS and max over particles of |x - x_ref| (m), for (N, 3) arrays."""
    d = np.linalg.norm(np.asarray(x) - np.asarray(x_ref), axis=-1)
    return float(np.sqrt(np.mean(d**2))), float(d.max())
