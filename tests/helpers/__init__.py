"""Helpers shared by the test modules (tests/ is on sys.path under pytest: ``from helpers.x import y``)."""

import ctypes.util
from pathlib import Path

import pytest

#: the repository's root
REPO = Path(__file__).resolve().parents[2]

#: OSMesa's tests skip without it: install.sh leaves the fallback out rather than upgrade installed Mesa packages
needs_osmesa = pytest.mark.skipif(ctypes.util.find_library("OSMesa") is None,
                                  reason="libosmesa6 is not installed (./install.sh --allow-upgrade installs it "
                                         "where it would upgrade installed Mesa packages)")
