"""docs/robustness.md lists exactly the matrix cases the suite runs (marker ``matrix``), so it cannot drift."""

import runpy

from helpers import REPO

#: the doc's script (scripts/robustness_doc.py): its doc, row pattern and collection of the matrix cases
SCRIPT = runpy.run_path(str(REPO / "scripts" / "robustness_doc.py"))


def documented_cases() -> list[str]:
    return [m.group(1) for line in SCRIPT["DOC"].read_text().splitlines() if (m := SCRIPT["ROW"].match(line))]


def collected_cases() -> list[str]:
    return [case for _, case in SCRIPT["collected"]()]


def test_robustness_doc_lists_every_matrix_case():
    documented = documented_cases()
    assert len(documented) == len(set(documented)), "a case is listed twice in docs/robustness.md"
    collected = collected_cases()
    assert collected, "no test carries the matrix marker"
    missing = sorted(set(collected) - set(documented))
    stale = sorted(set(documented) - set(collected))
    assert not missing, f"matrix cases missing from docs/robustness.md: {missing}"
    assert not stale, f"docs/robustness.md lists cases no test runs: {stale}"
