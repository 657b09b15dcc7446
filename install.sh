#!/usr/bin/env bash
# Installs hupbench and everything it needs on a Debian/Ubuntu machine, with or without a GPU or X11:
#   1. the Debian packages of the offscreen renderer: Mesa EGL (libegl1 + libegl-mesa0, the DRI drivers
#      with llvmpipe in libgl1-mesa-dri, and libopengl0, the GL library without GLX/X11 that PyOpenGL's
#      EGL platform loads) and OSMesa as the fallback (libosmesa6). No X11 client library is needed:
#      datagen.render.gl imports pyrender without its pyglet viewer;
#   2. the package itself with its test extras into the current Python (pip), plus the optional extras
#      asked for with --with (e.g. `./install.sh --with ray` for `hupbench generate launcher=ray`);
#   3. PyOpenGL 3.1.10 over pyrender's pinned 3.1.0: EGL works with both, OSMesa only with >= 3.1.7
#      (pip reports the pin as a conflict; the renderer is tested with 3.1.10).
# Nothing is downloaded at run time afterwards.
set -euo pipefail
cd "$(dirname "$0")"

usage="usage: ./install.sh [--with EXTRA[,EXTRA...]]   (extras of pyproject.toml besides test: ray)"
EXTRAS="test"
while [ $# -gt 0 ]; do
  case "$1" in
    --with)
      [ $# -ge 2 ] || { echo "install.sh: --with needs an extra, e.g. --with ray; $usage" >&2; exit 2; }
      extras_arg="$2"; shift 2 ;;
    --with=?*) extras_arg="${1#--with=}"; shift ;;
    -h|--help) echo "$usage"; exit 0 ;;
    *) echo "install.sh: unknown argument '$1'; $usage" >&2; exit 2 ;;
  esac
  for extra in ${extras_arg//,/ }; do
    case "$extra" in
      ray) EXTRAS="$EXTRAS,$extra" ;;
      *) echo "install.sh: unknown extra '$extra' (known: ray); $usage" >&2; exit 2 ;;
    esac
  done
done

DEB_PACKAGES="libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0 libosmesa6"
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
"$PYTHON" -m pip install --disable-pip-version-check -q -e ".[$EXTRAS]"
"$PYTHON" -m pip install --disable-pip-version-check -q "PyOpenGL==3.1.10" 2>&1 \
  | grep -v "pyrender 0.1.45 requires PyOpenGL==3.1.0\|dependency resolver does not currently\|^WARNING: Running pip as" || true
# pyenv installs console scripts behind shims that need a rehash
command -v pyenv >/dev/null 2>&1 && pyenv rehash || true
echo "install.sh: hupbench installed with extras [$EXTRAS] ($("$PYTHON" -c 'import hupbench; print(hupbench.__version__)'))"
