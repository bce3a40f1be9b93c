"""One material, two forms: every constraint carries PBD's stiffness k and XPBD's compliance α.
PBD and Jakobsen read k, XPBD α; a method that cannot read the form a constraint was declared in
says so with a csb.MaterialWarning the first time a stepper steps the model (src/csb/material.hpp)."""

from __future__ import annotations

import dataclasses
import re
import warnings

import numpy as np
import pytest

import csb

ALL_METHODS = ("pbd", "xpbd", "jakobsen")


def chain(stiffness: float = 1.0, compliance: float = 0.0, links: int = 3) -> csb.Model:
    """A chain of `links` distance constraints of 0.1 m hanging from a pinned particle."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(links, 0.1), particle_mass=0.01, stretch_stiffness=stiffness, stretch_compliance=compliance)
    b.pin(0)
    return b.build()


def cloth(n: int = 24, **kwargs) -> csb.Model:
    """An n x n cloth of 1 m, pinned at two corners; kwargs go to add_mesh (the material)."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.2, **kwargs)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    return b.build()


def family_model(family: str, stiffness: float, compliance: float) -> csb.Model:
    """A small model whose constraints of `family` have the given material; every other
    constraint is rigid for every method (k = 1, α = 0)."""
    b = csb.ModelBuilder()
    if family == "distance":
        b.add_mesh(csb.chain(3, 0.1), particle_mass=0.01, stretch_stiffness=stiffness, stretch_compliance=compliance)
        b.pin(0)
    elif family == "bending":
        b.add_mesh(csb.cloth_grid(0.3, 0.3, 3, 3), mass=0.05, bending_stiffness=stiffness,
                   bending_compliance=compliance)
    elif family == "volume":
        b.add_tet_mesh(csb.tet_box([0.1] * 3, [1, 1, 1]), mass=0.1, volume_stiffness=stiffness,
                       volume_compliance=compliance)
    elif family == "balloon":
        inst = b.add_tet_mesh(csb.tet_box([0.1] * 3, [1, 1, 1]), mass=0.1, volume_stiffness=None)
        b.add_balloon(inst, pressure=1.0, stiffness=stiffness, compliance=compliance)
    elif family == "attachment":
        g = b.add_group("bob")
        i = b.add_particle([0.0, 0.0, 0.0], 0.01, g)
        b.attach(i, [0.0, 0.0, 0.0], stiffness=stiffness, compliance=compliance)
    return b.build()


def notes(model: csb.Model, method: str, stepper: csb.PbdStepper | None = None, steps: int = 1) -> list[str]:
    """The MaterialWarnings of stepping `model` (with a fresh stepper of `method` unless given)."""
    stepper = stepper or csb.PbdStepper(method=method, dt=1 / 60, iterations=2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        stepper.step(model, model.initial_state(), steps)
    assert all(issubclass(w.category, csb.MaterialWarning) for w in caught), [str(w.message) for w in caught]
    return [str(w.message) for w in caught]


# ---------------------------------------------------------------------- compliance only: PBD, Jakobsen


@pytest.mark.parametrize("method, name", [("pbd", "PBD"), ("jakobsen", "Jakobsen")])
def test_a_compliance_that_pbd_cannot_read_is_named(method, name):
    assert notes(chain(compliance=1e-3), method) == [
        f"{name} reads stiffness, not compliance: 3 distance (stretch) constraints have compliance 0.001 m/N and "
        f"stiffness 1, so {name} makes them rigid; give a stiffness below 1 to choose {name}'s material"]


# Units of each family's compliance, as the notes print them.
UNITS = {"distance": "m/N", "bending": "1/(N m)", "volume": "m⁶/J", "balloon": "m⁶/J", "attachment": "m/N"}
LABELS = {"distance": "distance (stretch)", "bending": "bending", "volume": "volume", "balloon": "balloon",
          "attachment": "attachment"}


@pytest.mark.parametrize("family", list(UNITS))
def test_every_family_is_named_with_its_count_and_unit(family):
    """PBD on compliance only and XPBD on stiffness only, per family: one note each, naming the
    family, how many constraints and the value ignored."""
    model = family_model(family, 1.0, 0.25)
    count = {"distance": model.distance, "bending": model.bending, "volume": model.volume,
             "balloon": model.balloons, "attachment": model.attachments}[family]["stiffness"].size
    assert count > 0
    constraints, have, pronoun = ("constraint", "has", "it") if count == 1 else ("constraints", "have", "them")
    assert notes(model, "pbd") == [
        f"PBD reads stiffness, not compliance: {count} {LABELS[family]} {constraints} {have} compliance 0.25 "
        f"{UNITS[family]} and stiffness 1, so PBD makes {pronoun} rigid; give a stiffness below 1 to choose PBD's "
        "material"]
    model = family_model(family, 0.25, 0.0)
    assert notes(model, "xpbd") == [
        f"XPBD reads compliance, not stiffness: {count} {LABELS[family]} {constraints} {have} stiffness 0.25 and "
        f"compliance 0, so XPBD makes {pronoun} rigid; give a compliance ({UNITS[family]}) to choose XPBD's material"]


# ---------------------------------------------------------------------- stiffness only: XPBD


def test_a_stiffness_that_xpbd_cannot_read_is_named():
    """The bundled cloth_drop's material (stretch k = 1, bending k = 0.05, no compliance) on a
    larger cloth: only the bending is soft for PBD, so only the bending is named for XPBD."""
    model = cloth(24, stretch_stiffness=1.0, bending_stiffness=0.05)
    count = model.bending["stiffness"].size
    assert count > 1000  # the count is printed with thousands separators
    assert notes(model, "xpbd") == [
        f"XPBD reads compliance, not stiffness: {count:,} bending constraints have stiffness 0.05 and compliance 0, "
        "so XPBD makes them rigid; give a compliance (1/(N m)) to choose XPBD's material"]
    assert notes(model, "pbd") == [] and notes(model, "jakobsen") == []


def test_a_range_of_values_is_given_as_a_range():
    b = csb.ModelBuilder()
    g = b.add_group("beads")
    p = [b.add_particle([0.1 * i, 0.0, 0.0], 0.01, g) for i in range(4)]
    b.add_distance(p[0], p[1], stiffness=0.2)
    b.add_distance(p[1], p[2], stiffness=0.5)
    b.add_distance(p[2], p[3], stiffness=1.0)  # rigid for every method: not counted
    assert notes(b.build(), "xpbd") == [
        "XPBD reads compliance, not stiffness: 2 distance (stretch) constraints have stiffness 0.2 to 0.5 and "
        "compliance 0, so XPBD makes them rigid; give a compliance (m/N) to choose XPBD's material"]


def test_the_force_based_integrators_and_the_reference_refuse_a_stiffness_only_material():
    """They read the compliance too, and a hard constraint has no potential: an error naming the
    constraint and the compliance, not a warning."""
    model = chain(stiffness=0.5)
    with pytest.raises(csb.ParameterError, match=r"distance constraint 0 is hard \(compliance 0\).*needs a compliance"):
        csb.ForceStepper(dt=1e-4).step(model, model.initial_state())
    with pytest.raises(csb.ParameterError, match=r"distance constraint 0 is hard \(compliance 0\).*needs a compliance"):
        csb.integrate_reference(model, model.initial_state(), [0.01])
    compliant = chain(compliance=1e-3)  # the form they read: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        csb.ForceStepper(dt=1e-4).step(compliant, compliant.initial_state(), 10)


# ---------------------------------------------------------------------- both forms, or rigid


@pytest.mark.parametrize("method", ALL_METHODS)
@pytest.mark.parametrize("family", list(UNITS))
def test_both_forms_declared_say_nothing(method, family):
    """k < 1 and α > 0: each method reads its own form. k = 1 and α = 0: rigid for all."""
    assert notes(family_model(family, 0.5, 1e-3), method) == []
    assert notes(family_model(family, 1.0, 0.0), method) == []


def test_each_method_reads_its_own_form():
    """With both forms declared the methods do step different materials: PBD's bending follows k,
    XPBD's α (the compliance changes XPBD's cloth and not PBD's, the stiffness the reverse)."""
    def lowest(method, k, alpha):
        model = cloth(12, stretch_stiffness=1.0, bending_stiffness=k, bending_compliance=alpha)
        state = model.initial_state()
        csb.PbdStepper(method=method, dt=1 / 60, substeps=10, iterations=1).step(model, state, 30)
        return float(np.asarray(state.x)[:, 1].min())

    assert lowest("pbd", 0.05, 1.0) == lowest("pbd", 0.05, 100.0)
    assert lowest("pbd", 0.05, 1.0) != lowest("pbd", 0.5, 1.0)
    assert lowest("xpbd", 0.05, 1.0) == lowest("xpbd", 0.5, 1.0)
    assert lowest("xpbd", 0.05, 1.0) != lowest("xpbd", 0.05, 100.0)


# ---------------------------------------------------------------------- how it is issued


def test_warnings_as_errors_stop_the_step():
    assert issubclass(csb.MaterialWarning, UserWarning) and "MaterialWarning" in csb.__all__
    model = chain(compliance=1e-3)
    state = model.initial_state()
    stepper = csb.PbdStepper()
    with warnings.catch_warnings():
        warnings.simplefilter("error", csb.MaterialWarning)
        for _ in range(2):  # an error is not a report: the next step raises again
            with pytest.raises(csb.MaterialWarning, match="PBD reads stiffness, not compliance"):
                stepper.step(model, state)
            assert state.step == 0 and state.t == 0  # nothing was stepped
    with pytest.warns(csb.MaterialWarning):
        stepper.step(model, state)
    assert state.step == 1


def test_once_per_model_and_stepper_at_the_callers_line():
    a, b = chain(compliance=1e-3), chain(compliance=1e-3, links=4)
    sa, sb = a.initial_state(), b.initial_state()
    stepper = csb.PbdStepper()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(5):
            stepper.step(a, sa, 2)
        assert len(caught) == 1 and caught[0].filename == __file__  # the user's call, not csb's
        stepper.step(b, sb)  # another model: its own note
        assert len(caught) == 2 and re.search(r": 4 distance", str(caught[1].message))
        stepper.step(a, sa)  # back to the first: already said
        csb.PbdStepper().step(a, sa)  # another stepper: says it again
        assert len(caught) == 3
    assert sa.step == 12 and sb.step == 1


# ---------------------------------------------------------------------- scenes


@pytest.mark.parametrize("name", sorted(csb.bundled_scenes()))
def test_bundled_scenes_declare_what_their_method_reads(name):
    """Every bundled scene steps with its own method without a MaterialWarning (pytest turns
    warnings into errors)."""
    sim = csb.load_scene(name).build()
    sim.stepper.step(sim.model, sim.state)
    assert sim.state.step == 1


def test_a_scene_run_with_another_method_says_what_changes():
    """cloth_drop declares its bending for PBD only (k = 0.05): run with XPBD, it is told."""
    scene = csb.load_scene("cloth_drop")
    xpbd = dataclasses.replace(scene, duration=scene.solver.dt,
                               solver=dataclasses.replace(scene.solver, method="xpbd"))
    with pytest.warns(csb.MaterialWarning, match=r"XPBD reads compliance, not stiffness: [\d,]+ bending constraints "
                                                  r"have stiffness 0\.05 and compliance 0"):
        result = xpbd.run(None)
    assert result.steps == 1
