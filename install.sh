#!/usr/bin/env bash
# Installs hupbench and everything it needs on a Debian/Ubuntu machine without a GPU:
#   1. the Debian packages of the offscreen renderer (Mesa EGL; OSMesa as the fallback),
#   2. the package itself with its test extras into the current Python (pip),
#   3. PyOpenGL 3.1.10 over pyrender's pinned 3.1.0: EGL works with both, OSMesa only with >= 3.1.7
#      (pip reports the pin as a conflict; the renderer is tested with 3.1.10).
# Nothing is downloaded at run time afterwards.
set -euo pipefail
cd "$(dirname "$0")"

DEB_PACKAGES="libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libgles2 libosmesa6"
if command -v dpkg-query >/dev/null 2>&1; then
  missing=""
  for p in $DEB_PACKAGES; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
  done
  if [ -n "$missing" ]; then
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    echo "install.sh: installing Debian packages:$missing"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing
  fi
else
  echo "install.sh: no dpkg here; make sure Mesa EGL (or OSMesa) is installed for offscreen rendering" >&2
fi

PYTHON="${PYTHON:-python3}"
"$PYTHON" -m pip install --disable-pip-version-check -q -e ".[test]"
"$PYTHON" -m pip install --disable-pip-version-check -q "PyOpenGL==3.1.10" 2>&1 \
  | grep -v "pyrender 0.1.45 requires PyOpenGL==3.1.0\|dependency resolver does not currently\|^WARNING: Running pip as" || true
# pyenv installs console scripts behind shims that need a rehash
command -v pyenv >/dev/null 2>&1 && pyenv rehash || true
echo "install.sh: hupbench installed ($("$PYTHON" -c 'import hupbench; print(hupbench.__version__)'))"
