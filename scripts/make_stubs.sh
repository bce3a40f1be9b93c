#!/usr/bin/env bash
# Regenerates the type stubs of the compiled modules from the installed build: csb._core
# (python/csb/_core/*.pyi) and the viewer, csb._viewer (python/csb/_viewer.pyi). Run after
# changing the bindings in src/python/:  ./dev setup && scripts/make_stubs.sh
set -euo pipefail
cd "$(dirname "$0")/.."
.venv/bin/python -m pip install --quiet --disable-pip-version-check pybind11-stubgen
tmp=$(mktemp -d)
.venv/bin/pybind11-stubgen csb._core -o "$tmp"
.venv/bin/pybind11-stubgen csb._viewer -o "$tmp"
rm -rf python/csb/_core
cp -r "$tmp/csb/_core" python/csb/_core
cp "$tmp/csb/_viewer.pyi" python/csb/_viewer.pyi
rm -rf "$tmp"
echo "wrote python/csb/_core/__init__.pyi, python/csb/_core/kernels.pyi and python/csb/_viewer.pyi"
