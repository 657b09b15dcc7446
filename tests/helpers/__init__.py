"""Helpers shared by the test modules (tests/ is on sys.path under pytest: ``from helpers.x import y``)."""

from pathlib import Path

#: the repository's root
REPO = Path(__file__).resolve().parents[2]
