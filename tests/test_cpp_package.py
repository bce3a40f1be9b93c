"""C++ users: the library installs with a CMake package config, and a program that does
find_package(csb) builds against it and runs (examples/cpp/hello_cloth.cpp)."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def sh(*cmd: str | Path) -> str:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
    return r.stdout


@pytest.mark.slow
def test_find_package_csb_builds_and_runs_a_cpp_program(tmp_path):
    jobs = str(os.cpu_count() or 2)
    sh("cmake", "-S", ROOT, "-B", tmp_path / "build", f"-DCMAKE_INSTALL_PREFIX={tmp_path / 'prefix'}")
    sh("cmake", "--build", tmp_path / "build", "-j", jobs)
    sh("cmake", "--install", tmp_path / "build")
    assert (tmp_path / "prefix" / "include" / "csb" / "csb.hpp").exists()
    sh("cmake", "-S", ROOT / "examples" / "cpp", "-B", tmp_path / "example", f"-DCMAKE_PREFIX_PATH={tmp_path / 'prefix'}")
    sh("cmake", "--build", tmp_path / "example", "-j", jobs)
    exe = tmp_path / "example" / "hello_cloth"
    out = sh(exe, ROOT / "python" / "csb" / "scenes" / "meshes" / "cloth_panels.obj")
    m = re.match(r"1089 particles, 6144 constraints, t = 1\.000 s: .* max strain ([0-9.]+)", out)
    assert m, out
    r = subprocess.run([str(exe), str(tmp_path / "nothere.obj")], capture_output=True, text=True)
    assert r.returncode == 1 and "nothere.obj: no such file" in r.stderr
