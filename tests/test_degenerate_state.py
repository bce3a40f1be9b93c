"""Degenerate states warn before they give wrong results, and tearing refuses a diverged state.

A distance constraint whose particles coincide has no direction to correct along, and a tet
collapsed onto a line or a point has a zero volume gradient: every PBD kernel leaves such
constraints alone, so the state stays collapsed. The stepper says so (csb.AccuracyWarning, once
per model and stepper), checking on its first step of a model and every 64 steps after.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import csb


def cloth():
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 5, 5), density=0.2, stretch_stiffness=1.0)
    return b.build()


def body():
    b = csb.ModelBuilder()
    b.add_tet_mesh(csb.tet_box((0.1, 0.1, 0.1), (1, 1, 1)), density=100.0, volume_compliance=0.0,
                   stretch_compliance=0.0)
    return b.build()


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_a_tet_body_squashed_to_a_point_warns_and_stays_collapsed(method):
    model = body()
    state = model.initial_state()
    state.x[:] = [0.0, 1.0, 0.0]
    stepper = csb.PbdStepper(method=method, iterations=20)
    with pytest.warns(csb.AccuracyWarning, match=r"the state is degenerate at t = 0 s: 19 distance constraint\(s\) "
                      r"join coincident particles .*6 tet\(s\) are collapsed onto a line or a point"):
        stepper.step(model, state)
    # What the warning says: nothing separates the particles.
    x = np.array(state.x)
    assert np.ptp(x, axis=0).max() == 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stepper.step(model, state, 10)  # once per model and stepper


def test_a_body_flattened_onto_a_line_warns_about_its_tets_only():
    model = body()
    state = model.initial_state()
    x = np.array(state.x)
    x[:, 1:] = 0.0  # every point on the x axis: distinct particles, zero volume gradient
    x[:, 0] += np.arange(len(x)) * 1e-3
    state.x[:] = x
    with pytest.warns(csb.AccuracyWarning, match=r"at t = 0 s: 6 tet\(s\) are collapsed onto a line or a point "
                      r"\(first: volume constraint 0\)") as got:
        csb.PbdStepper(method="xpbd").step(model, state)
    assert "distance constraint(s)" not in str(got[0].message)


def test_a_healthy_state_and_a_flat_cloth_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for model in (cloth(), body()):
            state = model.initial_state()
            csb.PbdStepper(method="xpbd", substeps=4).step(model, state, 100)
            for _ in range(100):
                csb.PbdStepper(method="pbd").step(model, state)


def test_a_state_collapsed_mid_run_is_reported_within_64_steps():
    model = cloth()
    state = model.initial_state()
    stepper = csb.PbdStepper()
    stepper.step(model, state, 10)
    state.x[:] = state.x[0]  # crushed to a point after ten steps
    with pytest.warns(csb.AccuracyWarning, match=r"degenerate at t = ([\d.]+) s: 56 distance constraint\(s\)") as got:
        for _ in range(64):
            stepper.step(model, state)
    assert len(got) == 1
    t = float(str(got[0].message).split("t = ")[1].split(" s")[0])
    assert 10 / 60 < t <= 74 / 60 + 1e-9


def test_tear_refuses_a_non_finite_state_by_particle():
    model = cloth()
    state = model.initial_state()
    state.x[3, 1] = np.nan
    with pytest.raises(csb.ParameterError, match=r"tear: particle 3 has a non-finite position"):
        csb.tear(model, state, max_strain=0.1)
    state = model.initial_state()
    state.v[7] = [np.inf, 0.0, 0.0]
    with pytest.raises(csb.ParameterError, match=r"tear: particle 7 has a non-finite velocity"):
        csb.tear(model, state, max_strain=0.1)
