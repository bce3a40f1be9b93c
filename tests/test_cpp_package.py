"""C++ users: the library installs with a CMake package config, and a program that does
find_package(csb) builds against it and runs (examples/cpp/hello_cloth.cpp). The build here
pretends GLFW is missing: the viewer is optional, so the library, the Python module and that
program still build, and the module says what the viewer lacks."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
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
    import pybind11

    configure = sh("cmake", "-S", ROOT, "-B", tmp_path / "build", f"-DCMAKE_INSTALL_PREFIX={tmp_path / 'prefix'}",
                   "-DCMAKE_DISABLE_FIND_PACKAGE_glfw3=ON", "-DCSB_PYTHON=ON", f"-DPython_EXECUTABLE={sys.executable}",
                   f"-Dpybind11_DIR={pybind11.get_cmake_dir()}")
    assert "csb viewer: not built, missing GLFW 3.3 (libglfw3-dev)" in configure
    sh("cmake", "--build", tmp_path / "build", "-j", jobs)
    # The Python package with this viewer-less module: it works, and the viewer says what is missing.
    package = tmp_path / "site" / "csb"
    shutil.copytree(ROOT / "python" / "csb", package)
    (module,) = (tmp_path / "build" / "src" / "python").glob("_core*.so")
    shutil.copy(module, package)
    code = ("import csb\nassert not csb.viewer_available()\nprint(csb.build_info()['viewer'])\n"
            "try:\n    csb.render('cloth_drop', 'unused', frames=1)\nexcept csb.Error as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(tmp_path / "site")}, cwd=tmp_path).stdout
    assert "not built: GLFW 3.3 (libglfw3-dev)" in out
    assert "the viewer is not part of this build of csb: missing GLFW 3.3 (libglfw3-dev)" in out
    assert "apt-get install libglfw3-dev" in out
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
