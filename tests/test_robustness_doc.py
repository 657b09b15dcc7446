"""docs/robustness.md lists exactly the matrix cases the suite runs (marker ``matrix``), so it cannot drift."""

import re
import subprocess
import sys

from helpers import REPO

DOC = REPO / "docs" / "robustness.md"
ROW = re.compile(r"^\|\s*`(test_\w+(?:\[[^\]]+\])?)`\s*\|")


def documented_cases() -> list[str]:
    return [m.group(1) for line in DOC.read_text().splitlines() if (m := ROW.match(line))]


def collected_cases() -> list[str]:
    proc = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-n", "0", "-q", "-m", "matrix", "-p",
                           "no:cacheprovider", str(REPO / "tests")], capture_output=True, text=True, cwd=REPO, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return [line.split("::", 1)[1] for line in proc.stdout.splitlines() if "::" in line]


def test_robustness_doc_lists_every_matrix_case():
    documented = documented_cases()
    assert len(documented) == len(set(documented)), "a case is listed twice in docs/robustness.md"
    collected = collected_cases()
    assert collected, "no test carries the matrix marker"
    missing = sorted(set(collected) - set(documented))
    stale = sorted(set(documented) - set(collected))
    assert not missing, f"matrix cases missing from docs/robustness.md: {missing}"
    assert not stale, f"docs/robustness.md lists cases no test runs: {stale}"
