"""Constraints written in Python (csb.ConstraintFamily): projected by the steppers in their sweeps
with the built-in ones. The built-in distance constraint rewritten in Python gives the C++ one's
positions to round-off; shape matching (Müller et al. 2005) written this way keeps a body rigid;
what a family gets wrong is an error naming it."""

from __future__ import annotations

import numpy as np
import pytest

import csb


class Distance(csb.ConstraintFamily):
    """The built-in distance constraint, C = |x0 - x1| - L, in Python."""

    name, arity, params, units = "py_distance", 2, ("rest_length",), ("m",)

    def evaluate(self, x, params):
        d = x[:, 0] - x[:, 1]
        length = np.linalg.norm(d, axis=1)
        n = d / length[:, None]
        return length - params[:, 0], np.stack([n, -n], axis=1)

    def check(self, params):
        return "" if params[0] > 0 else f"rest_length must be > 0 m, got {params[0]}"


class DistanceOne(Distance):
    """The same, one constraint at a time (evaluate_one)."""

    name = "py_distance_one"
    evaluate = csb.ConstraintFamily.evaluate

    def evaluate_one(self, x, params):
        d = x[0] - x[1]
        length = float(np.linalg.norm(d))
        return length - params[0], np.array([d / length, -d / length])


def models(family=Distance):
    """An 8 x 8 cloth pinned at two corners: with the built-in stretch constraints, and with the
    same constraints (same order, stiffness 0.9, compliance 1e-5 m/N) as a Python family."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 8, 8), density=0.2, stretch_stiffness=0.9, stretch_compliance=1e-5)
    b.pin(0)
    b.pin(7)
    builtin = b.build()
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 8, 8), density=0.2, stretch_stiffness=None)
    b.pin(0)
    b.pin(7)
    b.add_family(family())
    pairs = np.asarray(builtin.distance["particles"]).tolist()
    for (i, j), rest in zip(pairs, np.asarray(builtin.distance["rest_length"]).tolist()):
        b.add_constraint(family.name, [i, j], [rest], stiffness=0.9, compliance=1e-5)
    return builtin, b.build()


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
@pytest.mark.parametrize("solver,ordering", [("jacobi", "coloured"), ("gauss-seidel", "sequential")])
def test_the_distance_constraint_in_python_matches_the_builtin_to_round_off(method, solver, ordering):
    """Jacobi reads the sweep's start, so the order does not matter; a sequential Gauss-Seidel
    sweep visits the built-in batch in its (colour) order, which is the order the family's
    first-fit colours visit the same constraints added in that order. One step: within 2.3e-16 m
    (an ulp of the 1 m coordinates: the two compute the same corrections, |n|² rounding apart);
    60 steps of 4 x 3 sweeps: within 1e-11 m (measured 1e-13 to 4e-12), round-off grown by 720
    sweeps, far below the 1e-4 m a different sweep order leaves."""
    builtin, python = models()
    for steps, tolerance in ((1, 2.3e-16), (60, 1e-11)):
        out = []
        for model in (builtin, python):
            state = model.initial_state()
            csb.PbdStepper(method=method, dt=1 / 60, substeps=4, iterations=3, solver=solver, ordering=ordering,
                           stiffness_correction=False).step(model, state, steps)
            out.append(np.asarray(state.x).copy())
        assert np.abs(out[0] - out[1]).max() <= tolerance
    assert np.abs(out[0] - python.initial_state().x).max() > 0.01  # it moved


def test_per_constraint_evaluation_agrees_with_the_vectorised():
    """evaluate_one, called once per constraint, against the vectorised evaluate: numpy's norm of
    one vector and of rows round differently, so to round-off (10 steps: within 1e-13 m)."""
    _, vectorised = models(Distance)
    _, one = models(DistanceOne)
    out = []
    for model in (vectorised, one):
        state = model.initial_state()
        csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=2, iterations=2).step(model, state, 10)
        out.append(np.asarray(state.x).copy())
    assert np.abs(out[0] - out[1]).max() < 1e-13


def test_a_model_with_a_python_family_gives_the_same_bits_on_any_thread_setting():
    _, python = models()
    out = []
    for threads in (0, 1, 2):
        state = python.initial_state()
        csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=2, iterations=2, threads=threads).step(python, state, 10)
        out.append(np.asarray(state.x).tobytes())
    assert out[0] == out[1] == out[2]


def shape_matched_body(rest: np.ndarray, stiffness: float) -> csb.Model:
    """Particles of 0.01 kg at `rest`, in one group, held by one ShapeMatching constraint of the
    given stiffness, and nothing else."""
    b = csb.ModelBuilder()
    body = b.add_group("body")
    ids = [b.add_particle(p, 0.01, body) for p in rest]
    b.add_family(csb.ShapeMatching(rest, np.full(len(rest), 0.01)))
    b.add_constraint("shape_matching", ids, stiffness=stiffness)
    return b.build()


def lattice(n: int = 3, spacing: float = 0.1) -> np.ndarray:
    g = np.arange(n) * spacing
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)


def test_shape_matching_keeps_a_spinning_body_rigid_and_restores_a_dented_one():
    """A 3 x 3 x 3 lattice of particles, no other constraint, one ShapeMatching constraint:
    thrown spinning, with k = 1 it keeps every pairwise distance to 1e-12 m over 1 s (PBD moves
    each particle onto its goal: a rigid motion), while its centre of mass falls as gravity says;
    with k = 0.2 a dent pressed into it comes back out."""
    rest = lattice()
    model = shape_matched_body(rest, stiffness=1.0)
    state = model.initial_state()
    centre = rest.mean(axis=0)
    state.v = np.cross([0.0, 0.0, 20.0], rest - centre) + [1.0, 2.0, 0.0]
    csb.PbdStepper(dt=1 / 60, substeps=2, iterations=1, gravity=(0, -9.81, 0)).step(model, state, 60)
    x = np.asarray(state.x)
    d0 = np.linalg.norm(rest[:, None] - rest[None], axis=2)
    d1 = np.linalg.norm(x[:, None] - x[None], axis=2)
    assert np.abs(d1 - d0).max() < 1e-12
    fall = centre + [1.0, 2.0, 0.0] - [0.0, 0.5 * 9.81, 0.0]  # after 1 s: v t + g t²/2 (symplectic: up to h g t)
    assert np.linalg.norm(x.mean(axis=0) - fall) < 9.81 / 120 + 1e-9
    # A dent: the centre particle pushed 3 cm in, released with k = 0.2, comes back within 0.1 mm.
    model = shape_matched_body(rest, stiffness=0.2)
    state = model.initial_state()
    x = np.asarray(state.x)
    x[13] += [0.0, -0.03, 0.0]
    csb.PbdStepper(dt=1 / 60, substeps=2, iterations=2, gravity=(0, 0, 0)).step(model, state, 30)
    x = np.asarray(state.x)
    assert np.abs(np.linalg.norm(x[:, None] - x[None], axis=2) - d0).max() < 1e-4


def test_the_reference_and_the_metrics_read_a_python_family():
    """With compliance, the family is an energy C²/(2α): csb.measure counts it and the reference
    (CVODE) integrates its forces; a compliant Python distance cloth and the built-in one agree."""
    builtin, python = models()
    for model in (builtin, python):
        state = model.initial_state()
        np.asarray(state.x)[20] += [0.0, 0.01, 0.0]
        e = csb.elastic_energy(model, state)
        assert e > 0
    assert csb.elastic_energy(python, python.initial_state()) == pytest.approx(0.0, abs=1e-20)
    ref = [csb.integrate_reference(m, m.initial_state(), [0.05], gravity=(0, -9.81, 0)) for m in (builtin, python)]
    a, b = (np.asarray(r.x[-1]) for r in ref)
    assert np.abs(a - b).max() < 1e-7


class Bad(csb.ConstraintFamily):
    name, arity = "bad", 2

    def __init__(self, what):
        self.what = what

    def evaluate(self, x, params):
        if self.what == "raise":
            raise ZeroDivisionError("the family's own bug")
        if self.what == "shape":
            return np.zeros(len(x)), np.zeros((len(x), 3))
        if self.what == "nan":
            return np.full(len(x), np.nan), np.zeros((len(x), 2, 3))
        return "nonsense"


@pytest.mark.parametrize("what,error,message", [
    ("raise", ZeroDivisionError, "the family's own bug"),
    ("shape", csb.ParameterError, r"constraint family 'bad': evaluate must return grad of shape \(1, 2, 3\) for 1 constraints"),
    ("nan", csb.ParameterError, r"constraint family 'bad': bad 0 \(particles 0, 1\) evaluated to a C or gradient that is not finite"),
    ("tuple", csb.ParameterError, r"constraint family 'bad': evaluate must return \(C, grad\), got 'nonsense'"),
])
def test_what_a_family_gets_wrong_reaches_the_caller_by_name(what, error, message):
    b = csb.ModelBuilder()
    g = b.add_group("pair")
    b.add_particle([0.0, 0.0, 0.0], 1.0, g)
    b.add_particle([1.0, 0.0, 0.0], 1.0, g)
    b.add_family(Bad(what))
    b.add_constraint("bad", [0, 1])
    model = b.build()
    with pytest.raises(error, match=message):
        csb.PbdStepper(dt=1 / 60).step(model, model.initial_state())


def test_a_family_is_checked_when_added():
    b = csb.ModelBuilder()
    g = b.add_group("line")
    for k in range(3):
        b.add_particle([k, 0.0, 0.0], 1.0, g)
    b.add_family(Distance())
    with pytest.raises(csb.ParameterError, match="a constraint family needs a name of its own, and 'py_distance' is taken"):
        b.add_family(Distance())
    with pytest.raises(csb.ParameterError, match="a constraint family needs a name of its own, and 'tethers' is taken"):
        b.add_family(type("T", (Distance,), {"name": "tethers"})())
    with pytest.raises(csb.ParameterError, match=r"rest_length must be > 0 m, got -1.0"):
        b.add_constraint("py_distance", [0, 1], [-1.0])
    with pytest.raises(csb.ParameterError, match=r"joins 2 particles, got 3"):
        b.add_constraint("py_distance", [0, 1, 2], [1.0])
    with pytest.raises(csb.ParameterError, match=r"needs 1 parameters \(rest_length\), got 0"):
        b.add_constraint("py_distance", [0, 1], [])
    with pytest.raises(csb.ParameterError, match="family must be one of 'tethers', got 'nothere'"):
        b.add_constraint("nothere", [0, 1], [1.0])
    with pytest.raises(csb.ParameterError, match="needs an arity >= 1"):
        b.add_family(type("A", (Distance,), {"name": "zero", "arity": 0})())
    assert b.add_constraint("py_distance", [0, 1], [1.0]) == 0
    assert b.add_constraint(Distance(), [1, 2], [1.0]) == 1


def test_the_readme_example_runs_as_written(capsys):
    """The README's family example: a 10-link chain of 0.1 m links held by a Python distance
    family (XPBD, 1e-6 m/N) hangs with its longest link within 2 % of 0.1 m after 1 s."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "csb.ConstraintFamily" in b]
    exec(compile(block, "README.md", "exec"), {})
    longest = float(capsys.readouterr().out.split()[0])
    assert 0.1 <= longest < 0.102
