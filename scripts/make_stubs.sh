#!/usr/bin/env bash
# Regenerates the type stubs of the compiled module (python/csb/_core/*.pyi) from the installed
# build. Run after changing src/python/module.cpp:  ./dev setup && scripts/make_stubs.sh
set -euo pipefail
cd "$(dirname "$0")/.."
.venv/bin/python -m pip install --quiet --disable-pip-version-check pybind11-stubgen
tmp=$(mktemp -d)
.venv/bin/pybind11-stubgen csb._core -o "$tmp"
rm -rf python/csb/_core
cp -r "$tmp/csb/_core" python/csb/_core
rm -rf "$tmp"
echo "wrote python/csb/_core/__init__.pyi and kernels.pyi"
