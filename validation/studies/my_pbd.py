"""A user's own method, as docs/your_own_method.md writes it: PBD over distance constraints and pins
in Python (numpy), a csb.Integrator. validation/studies/peers.toml runs it beside csb's methods and
the peers."""

import math

import numpy as np

import csb


class MyPbd(csb.Integrator):
    """PBD over distance constraints and pins (inverse mass 0): predict, sweep, update."""

    def __init__(self, dt, *, iterations=10, gravity=(0.0, -9.81, 0.0)):
        super().__init__()  # required: csb.Integrator's own set-up
        self._dt, self.iterations, self.gravity = dt, iterations, np.asarray(gravity, dtype=float)

    def name(self):
        return "my-pbd"

    def dt(self):
        return self._dt  # s

    def step(self, model, state, steps=1, interrupt=None):
        d, w = model.distance, np.asarray(model.inv_mass)
        if model.num_constraints != len(d["rest_length"]) or np.any(np.asarray(d["sense"]) != 0):
            raise csb.ParameterError("my-pbd projects distance constraints (equalities) only")
        pairs, rest = np.asarray(d["particles"]).tolist(), np.asarray(d["rest_length"]).tolist()
        k = [csb.corrected_stiffness(s, self.iterations) for s in np.asarray(d["stiffness"]).tolist()]
        h, x, v = self._dt, np.array(state.x), np.array(state.v)
        for _ in range(steps):
            v += np.where(w > 0, h, 0.0)[:, None] * self.gravity  # gravity on what can move
            p = (x + h * v).tolist()  # the prediction
            for _ in range(self.iterations):
                for (i, j), l0, kc in zip(pairs, rest, k):
                    e = [p[i][c] - p[j][c] for c in range(3)]
                    length = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
                    if w[i] + w[j] <= 0 or length <= 0:
                        continue
                    s = kc * (length - l0) / ((w[i] + w[j]) * length)
                    for c in range(3):
                        p[i][c] -= w[i] * s * e[c]
                        p[j][c] += w[j] * s * e[c]
            p = np.array(p)
            v, x = (p - x) / h, p  # velocities from the positions
            state.t += h
            state.step += 1
        state.x, state.v = x, v
