"""What Model.memory counts and what it leaves out, against the process's resident memory.

Model.memory is the model's arrays; stepping adds PbdStepper.workspace_bytes and the state, and
building peaks at about 5 times Model.memory (the builder's arrays, the mesh and the model at
once). A 256 x 256 cloth is measured in a fresh interpreter (Linux: /proc/self/status, its peak
reset through /proc/self/clear_refs; glibc's malloc_trim returns freed memory first, so that
resident memory is what is live). The bounds are wide enough for the allocator's page rounding
and the interpreter's own allocations (a few hundred kB against tens of MB).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

import csb
from helpers import measures_resident_memory

SCRIPT = r"""
import ctypes, gc, json, warnings
import csb
warnings.simplefilter("ignore")
libc = ctypes.CDLL("libc.so.6")
def rss():
    d = dict(l.split(":", 1) for l in open("/proc/self/status"))
    return int(d["VmRSS"].split()[0]) * 1024, int(d["VmHWM"].split()[0]) * 1024
def reset():
    open("/proc/self/clear_refs", "w").write("5")
base, _ = rss()
reset()
mesh = csb.cloth_grid(1.0, 1.0, 256, 256)
b = csb.ModelBuilder()
b.add_mesh(mesh, density=0.2, stretch_compliance=1e-6, bending_compliance=1.0)
model = b.build()
_, build_peak = rss()
del b, mesh
gc.collect(); libc.malloc_trim(0)
model_alone, _ = rss()
stepper = csb.PbdStepper(method="xpbd")
state = model.initial_state()
stepper.step(model, state)
gc.collect(); libc.malloc_trim(0)
stepping, _ = rss()
print(json.dumps(dict(base=base, build_peak=build_peak, model_alone=model_alone, stepping=stepping,
                      model=model.memory["total"], stepper=stepper.workspace_bytes,
                      state=48 * model.num_particles)))
"""


@measures_resident_memory
@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux's /proc to measure resident memory")
def test_model_memory_and_what_it_leaves_out_match_resident_memory():
    r = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300, check=True)
    m = json.loads(r.stdout.strip().splitlines()[-1])
    model = m["model_alone"] - m["base"]
    stepping = m["stepping"] - m["base"]
    build = m["build_peak"] - m["base"]
    # The model's arrays are what stays after the builder is gone.
    assert 0.9 <= model / m["model"] <= 1.3, m
    # Stepping adds the workspace and one state: nothing else of size.
    assert 0.9 <= stepping / (m["model"] + m["stepper"] + m["state"]) <= 1.2, m
    # Building peaks at about 5 times Model.memory (what the docstring and csb run's summary say).
    assert 4.0 <= build / m["model"] <= 6.5, m


def test_a_run_reports_its_memory_and_the_process_peak():
    result = csb.load_scene("pendulum").run()
    mem = result.memory
    sim = result.simulation
    assert mem["model"] == sim.model.memory["total"] > 0
    assert mem["stepper"] == sim.stepper.workspace_bytes > 0
    assert mem["state"] == 48 * sim.model.num_particles
    if sys.platform != "win32":
        assert mem["peak_resident"] >= mem["model"] + mem["stepper"] + mem["state"]
    assert "memory: model" in result.summary() and "process peak" in result.summary()
