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

import numpy as np
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
    # csb in the user's own loop: positions and normals to a renderer every frame; the last frame an image.
    out = sh(tmp_path / "example" / "own_loop", "60", tmp_path / "last.ppm")
    m = re.match(r"60 frames of 1024 vertices and 1922 triangles, t = 1\.000 s, lowest point ([0-9.-]+) m", out)
    assert m, out
    assert 0.0 < float(m.group(1)) < 0.3  # draped over the ball (its top at 0.55 m), not through it
    image = (tmp_path / "last.ppm").read_bytes()
    assert image.startswith(b"P6\n480 300\n255\n") and len(image) == len(b"P6\n480 300\n255\n") + 480 * 300 * 3
    pixels = np.frombuffer(image[-480 * 300 * 3:], dtype=np.uint8).reshape(300, 480, 3).astype(int)
    blue = (pixels[..., 2] > pixels[..., 0] + 60).mean()
    assert 0.02 < blue < 0.8  # the blue cloth covers part of the grey frame
