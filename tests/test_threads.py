"""What may be shared between threads, enforced; and a long step that stops on Ctrl-C.

A Model is immutable and may be shared; a stepper and the State it steps belong to one thread at
a time (src/csb/use_guard.hpp). Two threads each with their own stepper and State run in
parallel and give the bits of one after the other; a second thread using a stepper while it
steps gets csb.ConcurrentUseError at once, and the running step is not disturbed."""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import threading
import time

import numpy as np
import pytest

import csb


def cloth(n: int = 48, *, floor: bool = False) -> csb.Model:
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n, "xz", (0, 1, 0)), mass=0.2, stretch_stiffness=1.0,
                      bending_stiffness=0.1)
    b.pin(inst.nearest([-0.5, 1, -0.5]))
    b.pin(inst.nearest([0.5, 1, -0.5]))
    if floor:
        b.add_plane(point=(0, -5, 0))
    return b.build()


def digest(state: csb.State) -> str:
    return hashlib.sha256(np.ascontiguousarray(state.x).tobytes() + np.ascontiguousarray(state.v).tobytes()).hexdigest()


def test_two_threads_with_their_own_steppers_share_a_model_and_give_the_same_bits():
    model = cloth()
    alone = model.initial_state()
    csb.PbdStepper(substeps=4, iterations=2, threads=1).step(model, alone, 30)
    states = [model.initial_state() for _ in range(2)]
    errors = []

    def run(state):
        try:
            csb.PbdStepper(substeps=4, iterations=2, threads=1).step(model, state, 30)
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=run, args=(s,)) for s in states]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert digest(states[0]) == digest(states[1]) == digest(alone)


def step_while_the_main_thread_calls(model: csb.Model):
    """A worker steps a fresh stepper 40 times while this thread calls it: read-only calls until
    one is refused (the worker is then inside its one call of step(), so a call that changes the
    stepper, a grab or a step, can only succeed once that step has ended). Returns the worker's
    state, the messages of the refused calls and the worker's own refusal (None if it stepped)."""
    stepper = csb.PbdStepper(substeps=10, iterations=2)
    state = model.initial_state()
    worker_refused = []

    def step():
        try:
            stepper.step(model, state, 40)
        except csb.ConcurrentUseError as e:
            worker_refused.append(e)

    worker = threading.Thread(target=step)
    worker.start()
    refused = []
    deadline = time.monotonic() + 10
    other = model.initial_state()
    calls = [stepper.contacts, stepper.multipliers]
    while worker.is_alive() and time.monotonic() < deadline:
        for call in calls:
            try:
                call()
            except csb.ConcurrentUseError as e:
                refused.append(str(e))
        if refused and len(calls) == 2:
            calls += [lambda: stepper.step(model, other, 1), lambda: stepper.grab(model, other, 5, [0.0, 1.0, 0.0])]
        time.sleep(0.001)
    worker.join()
    return state, refused, worker_refused[0] if worker_refused else None


def test_a_second_thread_using_a_stepper_while_it_steps_is_refused_and_the_step_is_not_disturbed():
    model = cloth()
    expected = model.initial_state()
    csb.PbdStepper(substeps=10, iterations=2).step(model, expected, 40)
    # Of two calls that start together, which is second is the scheduler's choice: a read begun
    # as the worker enters step() can hold the stepper first, and then the step is the call
    # refused, before it changes anything. That start is tried again (slower calls, as in the
    # sanitizer build, meet it more often).
    for _ in range(5):
        state, refused, worker_refused = step_while_the_main_thread_calls(model)
        if worker_refused is None:
            break
        assert "in use by another thread" in str(worker_refused)
        assert state.step == 0 and digest(state) == digest(model.initial_state())
    assert worker_refused is None, "the worker's step was refused five times in a row"
    assert refused, "the step ended before a second call could meet it"
    assert all("in use by another thread" in m and "own stepper" in m for m in refused)
    assert isinstance(csb.ConcurrentUseError("x"), RuntimeError) and issubclass(csb.ConcurrentUseError, csb.Error)
    # The running step was not disturbed (the grabs tried from the main thread were refused, not applied).
    assert digest(state) == digest(expected)


class Stop(Exception):
    pass


@contextlib.contextmanager
def sigint_after(seconds: float):
    """SIGINT to this process after `seconds`, with a handler that raises Stop; yields a list
    that receives the seconds the body ran."""
    def handler(signum, frame):
        raise Stop

    previous = signal.signal(signal.SIGINT, handler)
    timer = threading.Timer(seconds, os.kill, args=(os.getpid(), signal.SIGINT))
    waited = []
    try:
        timer.start()
        t0 = time.monotonic()
        with pytest.raises(Stop):
            yield waited
        waited.append(time.monotonic() - t0)
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("floor", [False, True], ids=["fused", "sub-step by sub-step"])
def test_a_long_step_stops_on_a_signal_at_the_end_of_a_completed_sub_step(floor):
    """A step of 3000 sub-steps (seconds of work) is stopped by SIGINT from another thread within
    a fraction of a second; the state is finite and at the end of a completed sub-step (a fused
    step is cut every 64 sub-steps), and stepping on from it works."""
    model = cloth(32, floor=floor)
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=1 / 60, substeps=3000, iterations=1)
    h = 1 / 60 / 3000

    with sigint_after(0.2) as waited:
        stepper.step(model, state, 5)
    assert waited[0] < 2.0
    assert state.step < 5 and np.all(np.isfinite(state.x)) and np.all(np.isfinite(state.v))
    done = round((state.t - state.step / 60) / h)  # sub-steps into the interrupted step
    assert state.t == pytest.approx(state.step / 60 + done * h, rel=1e-12)
    if not floor:
        assert done % 64 == 0  # a fused step stops between its forks of 64 sub-steps
    steps = state.step
    stepper.step(model, state, 1)  # the stepper is free again
    assert state.step == steps + 1


def test_the_force_stepper_stops_on_a_signal_between_steps():
    """The force-based stepper too: a run of 10^6 steps (minutes) stops within a fraction of a
    second of SIGINT, at the end of a completed step, and steps on from there."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 16, 16), density=0.2, stretch_compliance=1e-4)
    model = b.build()
    state = model.initial_state()
    stepper = csb.ForceStepper(dt=1e-4)

    with sigint_after(0.2) as waited:
        stepper.step(model, state, 10**6)
    assert waited[0] < 2.0
    assert 0 < state.step < 10**6 and np.all(np.isfinite(state.x))
    assert state.t == pytest.approx(state.step * 1e-4, rel=1e-9)
    steps = state.step
    stepper.step(model, state, 1)
    assert state.step == steps + 1
