#!/usr/bin/env bash
# Installs hupbench and everything it needs on a Debian/Ubuntu machine, with or without a GPU or X11:
#   1. the Debian packages of the offscreen renderer: Mesa EGL (libegl1 + libegl-mesa0, the DRI drivers
#      with llvmpipe in libgl1-mesa-dri, and libopengl0, the GL library without GLX/X11 that PyOpenGL's
#      EGL platform loads) and OSMesa as the fallback (libosmesa6). No X11 client library is needed:
#      hupbench.datagen.render.gl imports pyrender without its pyglet viewer. And, as test data only, opencv-doc:
#      its two real hand photographs (handSrc.jpg, handDst.jpg) are the fixture of predict's
#      out-of-distribution test (about 96 MB; --no-test-data leaves it out, and that test is then skipped).
#      Only packages that are missing are installed, with --no-upgrade. A missing package whose install would
#      upgrade installed ones (a new Mesa library pulling newer versions of the installed ones, as on a
#      Debian 12 image whose Mesa predates the archive's) is, unless --allow-upgrade says so, left out with a
#      line saying so when hupbench can do without it (libosmesa6: EGL renders; opencv-doc: its test skips),
#      and otherwise stops the script before anything is installed. --no-apt prints the packages and the apt
#      command instead of running it;
#   2. the package itself with its test extras into the current Python (pip), plus the optional extras
#      asked for with --with (e.g. `./install.sh --with ray` for `hupbench generate launcher=ray`);
#   3. PyOpenGL 3.1.10 over pyrender's pinned 3.1.0: EGL works with both, OSMesa only with >= 3.1.7
#      (pip reports the pin as a conflict; the renderer is tested with 3.1.10).
# --dry-run prints what would be run (apt and pip) and runs nothing. Nothing is downloaded at run time afterwards.
set -euo pipefail
cd "$(dirname "$0")"

usage="usage: ./install.sh [--with EXTRA[,EXTRA...]] [--no-apt] [--no-test-data] [--allow-upgrade] [--dry-run]
  --with EXTRA     extras of pyproject.toml besides test: ray
  --no-apt         install no Debian package: print the missing ones and the apt command to install them
  --no-test-data   leave out opencv-doc (test data: real hand photographs for predict's tests)
  --allow-upgrade  let apt upgrade installed packages where a missing one needs newer versions of them
  --dry-run        print the apt and pip commands, run nothing"
see="see ./install.sh --help"
EXTRAS="test"
NO_APT=0
TEST_DATA=1
ALLOW_UPGRADE=0
DRY_RUN=0
while [ $# -gt 0 ]; do
  extras_arg=""
  case "$1" in
    --with)
      [ $# -ge 2 ] || { echo "install.sh: --with needs an extra, e.g. --with ray; $see" >&2; exit 2; }
      extras_arg="$2"; shift 2 ;;
    --with=?*) extras_arg="${1#--with=}"; shift ;;
    --no-apt) NO_APT=1; shift ;;
    --no-test-data) TEST_DATA=0; shift ;;
    --allow-upgrade) ALLOW_UPGRADE=1; shift ;;
    --dry-run) DRY_RUN=1; shift ;;
    -h|--help) echo "$usage"; exit 0 ;;
    *) echo "install.sh: unknown argument '$1'; $see" >&2; exit 2 ;;
  esac
  for extra in ${extras_arg//,/ }; do
    case "$extra" in
      ray) EXTRAS="$EXTRAS,$extra" ;;
      *) echo "install.sh: unknown extra '$extra' (known: ray); $see" >&2; exit 2 ;;
    esac
  done
done

# run a command, or with --dry-run only show it
run() {
  if [ "$DRY_RUN" = 1 ]; then echo "install.sh: would run: $*"; else "$@"; fi
}

DEB_PACKAGES="libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0 libosmesa6"
TEST_DEB_PACKAGES="opencv-doc"  # test data: /usr/share/doc/opencv-doc/opencv4/html/hand{Src,Dst}.jpg
# what hupbench can do without: the OSMesa fallback (EGL renders) and the test photographs (their test skips)
OPTIONAL_DEB_PACKAGES="libosmesa6 opencv-doc"
[ "$TEST_DATA" = 1 ] && DEB_PACKAGES="$DEB_PACKAGES $TEST_DEB_PACKAGES"

# the installed packages that installing package $1 would upgrade, "NAME OLD -> NEW" per line: apt's simulation
# (no root needed) writes an upgrade as "Inst NAME [INSTALLED_VERSION] (NEW_VERSION ...)"
upgrades_of() {
  apt-get install -s --no-install-recommends --no-upgrade "$1" 2>/dev/null \
    | awk '/^Inst [^ ]+ \[/ {gsub(/[][()]/, ""); print $2 " " $3 " -> " $4}'
}

if command -v dpkg-query >/dev/null 2>&1; then
  missing=""
  for p in $DEB_PACKAGES; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
  done
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo "
  apt_command="${SUDO}apt-get install -y --no-install-recommends --no-upgrade$missing"
  if [ -z "$missing" ]; then
    echo "install.sh: Debian packages already installed: $DEB_PACKAGES"
  elif [ "$NO_APT" = 1 ]; then
    echo "install.sh: --no-apt: hupbench uses the Debian packages $DEB_PACKAGES"
    echo "install.sh: --no-apt: not installing the missing ones:$missing"
    echo "install.sh: to install them (installed packages stay as they are):"
    echo "  ${SUDO}apt-get update && $apt_command"
  else
    run $SUDO apt-get update -qq
    chosen=""
    for p in $missing; do
      upgrades=""
      [ "$ALLOW_UPGRADE" = 1 ] || upgrades=$(upgrades_of "$p")
      if [ -z "$upgrades" ]; then
        chosen="$chosen $p"
      elif [[ " $OPTIONAL_DEB_PACKAGES " == *" $p "* ]]; then
        echo "install.sh: left out $p (optional): installing it would upgrade installed packages:" \
          $upgrades "(--allow-upgrade installs it)"
      else
        echo "install.sh: installing $p would upgrade installed packages:" $upgrades >&2
        echo "install.sh: nothing installed; rerun with --allow-upgrade to accept that, or with --no-apt and install them yourself" >&2
        exit 1
      fi
    done
    if [ -n "$chosen" ]; then
      echo "install.sh: installing the missing Debian packages:$chosen (installed packages are not upgraded$(
        [ "$ALLOW_UPGRADE" = 1 ] && echo " unless they must be: --allow-upgrade"))"
      DEBIAN_FRONTEND=noninteractive run $SUDO apt-get install -y -qq --no-install-recommends --no-upgrade $chosen
    fi
  fi
else
  echo "install.sh: no dpkg here; make sure Mesa EGL (or OSMesa) is installed for offscreen rendering" >&2
fi

PYTHON="${PYTHON:-python3}"
run "$PYTHON" -m pip install --disable-pip-version-check -q -e ".[$EXTRAS]"
if [ "$DRY_RUN" = 1 ]; then
  run "$PYTHON" -m pip install --disable-pip-version-check -q "PyOpenGL==3.1.10"
  exit 0
fi
"$PYTHON" -m pip install --disable-pip-version-check -q "PyOpenGL==3.1.10" 2>&1 \
  | grep -v "pyrender 0.1.45 requires PyOpenGL==3.1.0\|dependency resolver does not currently\|^WARNING: Running pip as" || true
# pyenv installs console scripts behind shims that need a rehash
command -v pyenv >/dev/null 2>&1 && pyenv rehash || true
echo "install.sh: hupbench installed with extras [$EXTRAS] ($("$PYTHON" -c 'import hupbench; print(hupbench.__version__)'))"
