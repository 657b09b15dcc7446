"""Compare the error lines the matrix tests print today with the answers docs/robustness.md records.

    python3 scripts/robustness_answers.py            # runs `pytest -m matrix` recording every answer
    python3 scripts/robustness_answers.py --from FILE  # compares a recording made before

The tests record each error line they assert on (tests/conftest.py, HUPBENCH_RECORD_ANSWERS). The doc
quotes them with the test's folders written as FOLDER, DATASET or a relative path, so both sides are
compared with every path cut to its last component and every temporary folder name read as one word.
Prints each case whose wording changed and a count; exits 1 when any changed.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "robustness.md"
ROW = re.compile(r"^\|\s*`(test_\w+(?:\[[^\]]+\])?)`\s*\|(.*)\|(.*)\|\s*$")
QUOTED = re.compile(r"``\s?(.*?error:.*?)\s?``|`([^`]*?error:[^`]*)`")
PLACEHOLDER = re.compile(r"\b(FOLDER|DATASET|RUN|MODEL|DISK|FILE|PID|HOST|TIME|test_\w+?\d+|pytest-\d+|tmp\w*)\b")


def normalise(line: str) -> str:
    """``line`` with paths cut to their last component and folder placeholders made one word."""
    line = re.sub(r"[^\s'\"(`]*/(?=[^\s/])", "", line)
    line = PLACEHOLDER.sub("PATH", line)
    return " ".join(line.split()).rstrip(" .")


def documented() -> dict[str, list[str]]:
    """{case id: the error lines its answer cell quotes}."""
    out = {}
    for text in DOC.read_text().splitlines():
        match = ROW.match(text)
        if match:
            out[match.group(1)] = [a or b for a, b in QUOTED.findall(match.group(3))]
    return out


def record() -> Path:
    path = Path(tempfile.mkdtemp()) / "answers.jsonl"
    env = {**os.environ, "HUPBENCH_RECORD_ANSWERS": str(path)}
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "matrix", str(REPO / "tests")],
                   cwd=REPO, env=env, check=False)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--from", dest="source", type=Path, help="a recording (JSON lines) made before")
    args = parser.parse_args(argv)
    source = args.source or record()
    recorded: dict[str, list[str]] = {}
    for text in source.read_text().splitlines():
        row = json.loads(text)
        recorded.setdefault(row["test"].split("::")[-1], []).append(row["answer"])
    changed = same = unquoted = 0
    for case, quoted in documented().items():
        if not quoted or case not in recorded:
            unquoted += 1
            continue
        now = {normalise(line) for line in recorded[case]}
        if all(normalise(line) in now for line in quoted):
            same += 1
            continue
        changed += 1
        print(f"{case}\n  recorded in the doc: {quoted}\n  answered now:        {recorded[case]}")
    print(f"{same} answers unchanged, {changed} changed, {unquoted} rows quote no error line or were not recorded")
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
