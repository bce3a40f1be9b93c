"""The reference: the model's constraints as springs (E = C²/(2α)) integrated with SUNDIALS CVODE,
and errors measured against it. See src/csb/reference.hpp and papers/reference.md."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterator, Sequence

import numpy as np

from . import _core
from ._core import SpringNetwork

__all__ = ["ReferenceResult", "SpringNetwork", "integrate_reference", "position_error"]


@dataclass
class ReferenceResult:
    times: np.ndarray      # (T,) s
    x: np.ndarray          # (T, N, 3) m, pinned particles included
    v: np.ndarray          # (T, N, 3) m/s
    stats: dict[str, Any] = field(default_factory=dict)
    """CVODE's counts (steps, rhs_evals, newton_iters, jacobian_evals, linear_iters, ...),
    last_order, last_step (s), wall_time (s) and linear_solver ("klu" or "gmres")"""

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
    rtol: float = 1e-8,
    atol: float = 1e-10,
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
    particles stay where ``state`` has them. gravity in m/s²; rtol relative; atol absolute on
    positions (m) and velocities (m/s); damping (N s/m) a dashpot along each distance
    constraint and on attachments; drag (1/s) a force -drag m v on every particle (brings a
    hanging chain to rest, which a dashpot along the links does not); max_order caps the BDF order (1-5); linear_solver "auto"
    (KLU with the analytic Jacobian, or GMRES when compliant bending is present), "klu" or
    "gmres". Raises csb.ParameterError for bad input and csb.SimulationError if CVODE fails,
    needs more than max_steps steps or more than max_wall_time seconds (0: no limit).
    """
    t, x, v, stats = _core._integrate_reference(
        model, state, [float(t) for t in np.atleast_1d(np.asarray(times, dtype=float))], gravity=gravity, rtol=rtol,
        atol=atol, damping=damping, drag=drag, max_order=max_order, stability_limit_detection=stability_limit_detection,
        linear_solver=linear_solver, max_steps=max_steps, max_wall_time=max_wall_time,
    )
    return ReferenceResult(t, x, v, stats)


def position_error(x: np.ndarray, x_ref: np.ndarray) -> tuple[float, float]:
    """RMS and max over particles of |x - x_ref| (m), for (N, 3) arrays."""
    d = np.linalg.norm(np.asarray(x) - np.asarray(x_ref), axis=-1)
    return float(np.sqrt(np.mean(d**2))), float(d.max())
