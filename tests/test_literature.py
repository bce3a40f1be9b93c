"""The literature's test scenes (csb.studies.literature): each builds with its published
parameters, refuses bad arguments by name, and meets a closed form where the scene has one."""

from __future__ import annotations

import inspect
import math
import time
import warnings

import numpy as np
import pytest

import csb
from csb.studies import pendulum_period
from csb.studies.literature import (SETUPS, cantilever, mass_ratio_chain, oscillator_period, stiffness_ratio_chain,
                                    twisting_cloth, xpbd_chain, xpbd_oscillator)
from csb.studies.same_step import falling_chain

G = 9.81


def model_and_state(made):
    return made if isinstance(made, tuple) else (made, made.initial_state())


def pinned(model: csb.Model) -> np.ndarray:
    return np.where(np.asarray(model.inv_mass) == 0)[0]


# ------------------------------------------------------------------------------------ every set-up


def test_every_setup_takes_keyword_only_arguments_and_documents_its_source():
    assert set(SETUPS) == {"xpbd_oscillator", "xpbd_chain", "cantilever", "mass_ratio_chain",
                           "stiffness_ratio_chain", "twisting_cloth"}
    for name, f in SETUPS.items():
        params = inspect.signature(f).parameters.values()
        assert all(p.kind is p.KEYWORD_ONLY and p.default is not p.empty for p in params), name
        assert "What to see" in f.__doc__ and "20" in f.__doc__, name  # the paper's year and what to look for


@pytest.mark.parametrize("name", sorted(SETUPS))
def test_every_setup_builds_fast_and_steps_a_second_of_xpbd_at_60_hz(name):
    t0 = time.perf_counter()
    model, state = model_and_state(SETUPS[name]())
    assert time.perf_counter() - t0 < 0.5
    x0 = np.array(state.x)
    stepper = csb.make_integrator("xpbd", 1 / 60, iterations=10)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", csb.AccuracyWarning)  # the mass-ratio chain's ratio is its point
        stepper.step(model, state, 60)
    x = np.asarray(state.x)
    assert np.all(np.isfinite(x))
    size = np.linalg.norm(x0.max(axis=0) - x0.min(axis=0))
    assert np.abs(x - x0).max() < 10 * max(size, 1.0)
    assert np.array_equal(x[pinned(model)], x0[pinned(model)])


@pytest.mark.parametrize("name, argument, value", [
    ("xpbd_oscillator", "mass", 0.0), ("xpbd_oscillator", "compliance", -1e-3),
    ("xpbd_oscillator", "start_length", math.nan), ("xpbd_oscillator", "rest_length", math.inf),
    ("xpbd_chain", "particles", 1), ("xpbd_chain", "particles", 2.5), ("xpbd_chain", "link", 0.0),
    ("xpbd_chain", "compliance", math.nan), ("xpbd_chain", "start", "sideways"),
    ("cantilever", "cells", 0), ("cantilever", "density", -1.0), ("cantilever", "bulk_modulus", math.nan),
    ("cantilever", "cross_cells", True),
    ("mass_ratio_chain", "ratio", 0.0), ("mass_ratio_chain", "ratio", -10.0), ("mass_ratio_chain", "ratio", math.nan),
    ("mass_ratio_chain", "links", 0), ("mass_ratio_chain", "heavy", "middle"), ("mass_ratio_chain", "mass", "1"),
    ("stiffness_ratio_chain", "ratio", 0.0), ("stiffness_ratio_chain", "ratio", math.inf),
    ("stiffness_ratio_chain", "links", 0), ("stiffness_ratio_chain", "compliance", 0.0),
    ("twisting_cloth", "n", 1), ("twisting_cloth", "angle", math.nan), ("twisting_cloth", "size", 0.0),
])
def test_bad_arguments_are_refused_by_name(name, argument, value):
    with pytest.raises(csb.ParameterError, match=rf"^{argument} must"):
        SETUPS[name](**{argument: value})


# ------------------------------------------------------------------------------------ the oscillator


def test_oscillator_has_the_stated_spring_and_start():
    model = xpbd_oscillator()
    assert model.num_particles == 2 and model.num_constraints == 1
    assert list(pinned(model)) == [0] and model.mass[1] == 1.0
    assert model.distance["rest_length"][0] == 1.0 and model.distance["compliance"][0] == 1e-3
    assert np.linalg.norm(model.rest_positions[1] - model.rest_positions[0]) == 1.5
    assert oscillator_period() == pytest.approx(2 * math.pi * math.sqrt(1e-3))


def test_oscillator_period_at_a_small_step_is_two_pi_sqrt_m_alpha():
    model = xpbd_oscillator()
    state = model.initial_state()
    stepper = csb.make_integrator("xpbd", 1e-4, iterations=1, gravity=(0, 0, 0))
    t, y = [], []
    for _ in range(10_000):
        stepper.step(model, state)
        t.append(state.t)
        y.append(-(state.x[1][1] + 1.0))  # displacement from rest, positive down the spring
    # measured: 0.198692 s against 0.198692 s (3.3e-6 relative; XPBD's O((ωh)²) period error)
    assert pendulum_period(np.array(t), np.array(y)) == pytest.approx(oscillator_period(), rel=1e-4)


# ------------------------------------------------------------------------------------ XPBD's chain


def test_xpbd_chain_has_the_papers_parameters_and_is_the_same_steps_chain():
    model = xpbd_chain()
    assert model.num_particles == 20 and model.num_constraints == 19
    assert np.all(np.asarray(model.mass) == 1.0) and list(pinned(model)) == [0]
    assert np.all(np.asarray(model.distance["compliance"]) == 1e-8)
    assert np.allclose(model.distance["rest_length"], 1.0, rtol=0, atol=1e-12)
    assert np.all(np.asarray(model.rest_positions)[:, 1:] == 0)  # horizontal: it falls
    other = falling_chain(1.0)
    for key in ("particles", "rest_length", "compliance"):
        assert np.array_equal(np.asarray(model.distance[key]), np.asarray(other.distance[key]))
    assert np.array_equal(model.rest_positions, other.rest_positions)


def test_hanging_xpbd_chain_carries_its_weight_at_the_top():
    model = xpbd_chain(start="hanging")
    state = model.initial_state()
    x0 = np.array(state.x)
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, iterations=200)
    stepper.step(model, state, 10)
    top = abs(stepper.multipliers()["distance"][0]) / stepper.substep_size**2
    # measured: 186.48 N against 19 x 1 kg x 9.81 m/s² = 186.39 N; it stays within 1.1 mm of its start
    assert top == pytest.approx(19 * G, rel=2e-3)
    assert np.abs(np.asarray(state.x) - x0).max() < 5e-3


# ------------------------------------------------------------------------------------ the cantilever


def test_cantilever_is_clamped_and_its_tip_sags():
    model = cantilever()
    assert model.num_particles == 81 and len(model.volume["rest_volume"]) == 192
    assert len(model.distance["rest_length"]) == 344
    assert float(np.sum(model.mass)) == pytest.approx(1000.0 * 0.4 * 0.1 * 0.1)
    x0 = np.array(model.rest_positions)
    assert set(pinned(model)) == set(np.where(x0[:, 0] < 1e-12)[0]) and len(pinned(model)) == 9
    state = model.initial_state()
    csb.make_integrator("xpbd", 1 / 60, substeps=10, iterations=1).step(model, state, 60)
    x = np.asarray(state.x)
    tip = np.abs(x0[:, 0] - 0.4) < 1e-12
    assert np.all(np.isfinite(x))
    assert np.all(x[tip, 1] < x0[tip, 1] - 1e-3)  # measured: 6.0 cm down after 1 s


# ------------------------------------------------------------------------------------ ratio chains


@pytest.mark.parametrize("ratio", [1.0, 1e2, 1e4])
def test_mass_ratio_chain_masses(ratio):
    end = mass_ratio_chain(ratio=ratio)
    masses = np.asarray(end.mass)
    assert end.num_particles == 11 and end.num_constraints == 10 and list(pinned(end)) == [0]
    assert masses[-1] == pytest.approx(0.1 * ratio) and np.all(masses[:-1] == 0.1)
    assert masses.sum() == pytest.approx(11 * 0.1 + (ratio - 1) * 0.1)
    alternating = np.asarray(mass_ratio_chain(ratio=ratio, heavy="alternating").mass)
    assert alternating.sum() == pytest.approx(11 * 0.1 + 5 * (ratio - 1) * 0.1)
    assert list(np.where(alternating > 0.1 * (1 + 1e-12))[0]) == ([] if ratio == 1 else [2, 4, 6, 8, 10])


def test_mass_ratio_chain_hangs_about_its_static_stretch_when_the_solver_converges():
    # Released at rest length, the chain oscillates about its static stretch (the heavy end on the
    # chain's 1e5 N/m, a period of 0.2 s): over 2 s (ten periods) the mean stretch is the static one.
    model = mass_ratio_chain(ratio=1e3)
    state = model.initial_state()
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=100, iterations=10)
    stretch = []
    for _ in range(120):
        stepper.step(model, state)
        stretch.append(np.linalg.norm(np.diff(np.asarray(state.x), axis=0), axis=1) - 0.1)
    below = np.cumsum(np.asarray(model.mass)[::-1])[::-1][1:]  # the mass below each link, kg
    # measured: 0.9967 of α g (mass below) on every link
    assert np.mean(stretch, axis=0) == pytest.approx(1e-6 * G * below, rel=0.02)


def test_stiffness_ratio_chain_alternates_its_compliance():
    model = stiffness_ratio_chain(ratio=1e4)
    alpha = np.asarray(model.distance["compliance"])
    assert model.num_particles == 11 and list(pinned(model)) == [0]
    assert np.all(alpha[0::2] == 1e-4) and np.allclose(alpha[1::2], 1e-8, rtol=1e-12)
    assert np.all(np.asarray(model.mass) == 0.1)


# ------------------------------------------------------------------------------------ the twisting cloth


@pytest.mark.parametrize("angle", [math.pi, math.pi / 3, -2.5])
def test_twisting_cloth_turns_its_held_edge_by_the_angle(angle):
    model, state = twisting_cloth(angle=angle)
    rest = np.asarray(model.rest_positions)
    x = np.asarray(state.x)
    assert model.num_particles == 256
    held = pinned(model)
    assert len(held) == 32 and set(np.round(np.abs(rest[held, 0]), 12)) == {0.5}
    c, s = math.cos(angle), math.sin(angle)
    turned = held[rest[held, 0] > 0]
    expected = np.column_stack([rest[turned, 0], rest[turned, 1] * c - rest[turned, 2] * s,
                                rest[turned, 1] * s + rest[turned, 2] * c])
    assert np.allclose(x[turned], expected, rtol=0, atol=1e-12)
    fixed = held[rest[held, 0] < 0]
    assert np.array_equal(x[fixed], rest[fixed])
    assert np.all(np.asarray(state.v) == 0)


# ------------------------------------------------------------------------------------ the printed figures


def test_the_module_prints_the_figures_of_the_papers_note():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "csb.studies.literature"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    out = r.stdout
    assert "period at dt = 1e-4 s, no gravity 0.198692 s; 2π sqrt(m α) = 0.198692 s" in out
    assert "tension at the top after 10 steps of 200 iterations 186.48 N" in out
    for name in SETUPS:
        assert name in out
