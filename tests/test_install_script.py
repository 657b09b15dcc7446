"""install.sh's arguments, through its --dry-run and --no-apt paths only: nothing is installed.

A stand-in ``dpkg-query`` on PATH reports every Debian package missing, so the apt commands the script would
run are shown whatever this machine has installed."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from helpers import REPO

RENDER_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0 libosmesa6"


@pytest.fixture(scope="module")
def nothing_installed(tmp_path_factory) -> dict[str, str]:
    """The environment of a machine where dpkg knows none of the packages."""
    bin_dir = tmp_path_factory.mktemp("bin")
    fake = bin_dir / "dpkg-query"
    fake.write_text("#!/bin/sh\nexit 1\n")
    fake.chmod(0o755)
    # apt's simulation of installing PKG (the last argument): PKG new, and an upgrade of the installed libgbm1
    # when PKG is in FAKE_UPGRADES
    apt = bin_dir / "apt-get"
    apt.write_text('#!/bin/sh\n[ "$2" = "-s" ] || exit 0\nfor last; do :; done\n'
                   'case " $FAKE_UPGRADES " in *" $last "*) '
                   'echo "Inst libgbm1 [22.3.6-1+deb12u1] (22.3.6-1+deb12u2 Debian:12.12/oldstable [amd64])";; esac\n'
                   'echo "Inst $last (1.0 Debian:12.12/oldstable [amd64])"\n')
    apt.chmod(0o755)
    return os.environ | {"PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "PYTHON": "python3", "FAKE_UPGRADES": ""}


def install(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(Path(REPO) / "install.sh"), *args], check=False, capture_output=True, text=True,
                          env=env, timeout=60)


def test_dry_run_shows_apt_without_upgrades_and_pip(nothing_installed):
    done = install("--dry-run", env=nothing_installed)
    assert done.returncode == 0, done.stderr
    sudo = "" if os.geteuid() == 0 else "sudo "
    assert (f"would run: {sudo}apt-get install -y -qq --no-install-recommends --no-upgrade {RENDER_PACKAGES} "
            "opencv-doc\n") in done.stdout
    assert "would run: python3 -m pip install --disable-pip-version-check -q -e .[test]\n" in done.stdout


def test_no_apt_prints_the_packages_and_the_command_and_runs_no_apt(nothing_installed):
    done = install("--dry-run", "--no-apt", "--no-test-data", "--with", "ray", env=nothing_installed)
    assert done.returncode == 0, done.stderr
    assert f"--no-apt: hupbench uses the Debian packages {RENDER_PACKAGES}\n" in done.stdout
    assert "--no-upgrade" in done.stdout and "opencv-doc" not in done.stdout
    assert "would run: " + ("" if os.geteuid() == 0 else "sudo ") + "apt-get" not in done.stdout
    assert "-e .[test,ray]\n" in done.stdout


@pytest.mark.parametrize(("args", "message"), [
    (("--with", "nope"), "install.sh: unknown extra 'nope' (known: ray); see ./install.sh --help\n"),
    (("--with",), "install.sh: --with needs an extra, e.g. --with ray; see ./install.sh --help\n"),
    (("--frobnicate",), "install.sh: unknown argument '--frobnicate'; see ./install.sh --help\n"),
])
def test_bad_arguments_are_one_line_and_exit_2(args, message):
    done = install(*args)
    assert (done.returncode, done.stderr, done.stdout) == (2, message, "")


def test_help_lists_every_option():
    done = install("--help")
    assert done.returncode == 0
    for option in ("--with EXTRA", "--no-apt", "--no-test-data", "--allow-upgrade", "--dry-run"):
        assert option in done.stdout


UPGRADE = "libgbm1 22.3.6-1+deb12u1 -> 22.3.6-1+deb12u2"


def test_an_optional_package_that_would_upgrade_installed_ones_is_left_out(nothing_installed):
    """A Debian 12 image whose Mesa predates the archive's: libosmesa6 (the fallback) would upgrade libgbm1."""
    done = install("--dry-run", env=nothing_installed | {"FAKE_UPGRADES": "libosmesa6"})
    assert done.returncode == 0, done.stderr
    assert (f"install.sh: left out libosmesa6 (optional): installing it would upgrade installed packages: {UPGRADE} "
            "(--allow-upgrade installs it)\n") in done.stdout
    sudo = "" if os.geteuid() == 0 else "sudo "
    assert (f"would run: {sudo}apt-get install -y -qq --no-install-recommends --no-upgrade libegl1 libegl-mesa0 "
            "libgl1-mesa-dri libopengl0 opencv-doc\n") in done.stdout


def test_a_required_package_that_would_upgrade_installed_ones_stops_before_installing(nothing_installed):
    done = install("--dry-run", env=nothing_installed | {"FAKE_UPGRADES": "libegl-mesa0"})
    assert done.returncode == 1
    assert done.stderr.splitlines() == [
        f"install.sh: installing libegl-mesa0 would upgrade installed packages: {UPGRADE}",
        ("install.sh: nothing installed; rerun with --allow-upgrade to accept that, or with --no-apt and install "
         "them yourself")]
    assert "apt-get install" not in done.stdout and "pip install" not in done.stdout


def test_allow_upgrade_installs_every_missing_package(nothing_installed):
    done = install("--dry-run", "--allow-upgrade", env=nothing_installed | {"FAKE_UPGRADES": "libegl-mesa0 libosmesa6"})
    assert done.returncode == 0, done.stderr
    assert f"--no-upgrade {RENDER_PACKAGES} opencv-doc\n" in done.stdout and "left out" not in done.stdout
