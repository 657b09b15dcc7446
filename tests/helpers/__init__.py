"""Helpers shared by the test modules (tests/ is on sys.path under pytest: ``from helpers.x import y``)."""

import ctypes.util
import os
from pathlib import Path

import pytest

from hupbench.core.processes import usable_cores

#: the repository's root
REPO = Path(__file__).resolve().parents[2]

#: torch (and OpenMP) threads of one test process: the usable cores shared among pytest-xdist's workers, at least
#: one. tests/conftest.py sets OMP_NUM_THREADS to it before torch loads, so the commands the tests start inherit it.
#: Each worker taking every core slowed the collapse guard's HUPNet 4x (70 s alone, 304 s beside another worker)
THREADS = max(1, usable_cores() // int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))

#: OSMesa's tests skip without it: install.sh leaves the fallback out rather than upgrade installed Mesa packages
needs_osmesa = pytest.mark.skipif(ctypes.util.find_library("OSMesa") is None,
                                  reason="libosmesa6 is not installed (./install.sh --allow-upgrade installs it "
                                         "where it would upgrade installed Mesa packages)")
