#!/usr/bin/env bash
# The self-contained wheel on a machine that has none of csb's system libraries, installed by a
# user without root:
#
#   ../shared/tools/fresh-machine-test scripts/check_wheel.sh --disposable
#
# 1. `./dev wheel` builds dist/csb-*.whl (it installs the build's system packages first);
# 2. every package that step installed is purged again (Assimp, SUNDIALS, SuiteSparse, Eigen,
#    GLFW, libepoxy, libpng, Mesa, ...), and the script checks that no Assimp, SUNDIALS, KLU,
#    GLFW or libepoxy library and no Eigen header is left;
# 3. an unprivileged user installs the wheel with its test extra into a new virtual environment,
#    runs a bundled scene with `csb run`, checks that the viewer reports what it lacks, and runs
#    the quick tests (pytest -m "not slow") from a copy of the sources against the installed wheel;
# 4. installs the display libraries the wheel leaves to the system (X11, OpenGL, EGL, Mesa) and
#    renders frames of a scene offscreen with the wheel's viewer.
#
# Step 2 removes system packages, so the script runs only where that is wanted: a fresh root, a
# container or a throw-away virtual machine (--disposable). Debian/Ubuntu, as root.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" != "--disposable" ]; then
  echo "usage: $0 --disposable   (builds the wheel, then purges the system packages the build installed:" >&2
  echo "       run it in a fresh root, e.g. ../shared/tools/fresh-machine-test $0 --disposable)" >&2
  exit 2
fi
[ "$(id -u)" -eq 0 ] || { echo "$0: needs root (it installs and purges system packages)" >&2; exit 2; }
log() { printf '\033[1m[check_wheel]\033[0m %s\n' "$*" >&2; }
# What the wheel's viewer needs of the system (csb.view says the same when it cannot load).
VIEWER_PACKAGES="libx11-6 libgl1 libegl1 libegl-mesa0 libgl1-mesa-dri"

packages() { dpkg-query -W -f='${db:Status-Abbrev} ${Package}\n' | awk '$1 == "ii" {print $2}' | sort; }
before=$(mktemp); packages > "$before"

./dev wheel
whl=$(ls "$PWD"/dist/csb-*.whl)

log "purging the system packages the build installed"
added=$(packages | comm -13 "$before" -)
# shellcheck disable=SC2086 # one package a word
DEBIAN_FRONTEND=noninteractive apt-get purge -y -qq $added >/dev/null
DEBIAN_FRONTEND=noninteractive apt-get autoremove --purge -y -qq >/dev/null
ldconfig
left=$(ldconfig -p | grep -E 'lib(assimp|sundials|klu|glfw|epoxy)' || true)
if [ -n "$left" ] || [ -e /usr/include/eigen3 ]; then
  log "the purge left csb's libraries on the system:"; echo "$left" >&2; exit 1
fi
log "no Assimp, SUNDIALS, KLU, GLFW, libepoxy or Eigen left on the system"

user=csbuser
id "$user" >/dev/null 2>&1 || useradd --create-home "$user"
home=$(getent passwd "$user" | cut -d: -f6)
rm -rf "$home/csb" && mkdir "$home/csb"
git archive HEAD | tar -x -C "$home/csb"
cp "$whl" "$home/"
chown -R "$user:" "$home"

log "installing $(basename "$whl") as $user, without root"
runuser -u "$user" -- env -C "$home" bash -euo pipefail -c '
  python3 -m venv env
  env/bin/python -m pip install --quiet --disable-pip-version-check "$(ls csb-*.whl)[test]"
  env/bin/csb info
  ldd env/lib/python3*/site-packages/csb/libcsb.so | grep -E "assimp|sundials|klu"
  env/bin/csb run cloth_drop --out run --quiet
  ls run
  env/bin/python -c "import csb; print(\"viewer:\", csb.viewer_missing() or \"available\")"
  cd csb
  ../env/bin/python -m pytest -q -p no:cacheprovider -m "not slow"
'
log "the wheel installs, runs a scene and passes the quick tests on a machine without csb's system libraries"

# 4. The viewer, the wheel's optional part, once the display libraries it leaves to the system are
#    there (X11 for GLFW; OpenGL and EGL with Mesa's software renderer, which libepoxy loads).
log "installing the system's X11, OpenGL and EGL libraries for the viewer: $VIEWER_PACKAGES"
# shellcheck disable=SC2086 # one package a word
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $VIEWER_PACKAGES >/dev/null
runuser -u "$user" -- env -C "$home" bash -euo pipefail -c '
  env/bin/python -c "import csb; assert csb.viewer_available(), csb.viewer_missing()"
  env/bin/csb render cloth_drop --frames 3 --size 320x240 --out frames --no-video
  ls frames
'
log "the wheel's viewer renders once the system has X11, OpenGL and EGL"
