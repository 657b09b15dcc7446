"""Rebuild docs/robustness.md from the tests: its rows are the matrix cases, its answers their recordings.

    python3 scripts/robustness_doc.py                # runs `pytest -m matrix`, recording, and rewrites the doc
    python3 scripts/robustness_doc.py --from FILE    # uses a recording made before (JSON lines)
    python3 scripts/robustness_doc.py --check        # exit 1 when the doc would change (prints the diff)

The tests record every error line they assert on, and the command a CLI case ran
(tests/helpers/answers.py, ``HUPBENCH_RECORD_ANSWERS``). Each section's prose and each row's "input"
cell stay as written; the rows follow the collected cases (a new case gets a row in the section of
its test function or module, a removed case loses its row), and every quoted error line of an answer
cell is replaced by the line the test recorded, with the test's temporary folders cut from paths and
pids, hosts and times written as PID, HOST and TIME. ``git diff docs/robustness.md`` then shows every
error line whose wording changed.
"""

from __future__ import annotations

import argparse
import difflib
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
QUOTED = re.compile(r"``\s?(?:.*?error:.*?)\s?``|`(?:[^`]*?error:[^`]*)`")
#: a test's temporary folder (under pytest-xdist, inside its worker's popen-gwN folder)
TMP_FOLDER = re.compile(r"/tmp/(?:pytest-of-[^/\s]+/pytest-\d+/(?:popen-gw\d+/)?[^/\s'\"]+|tmp[\w-]+)(/?)")
HOLDER = re.compile(r"pid \d+ on [^\s,]+, since [0-9TZ:-]+")
MAX_LINE = 400
#: words the doc writes for a test's own folders and files
PLACEHOLDERS = ("DATASET", "FOLDER", "DISK", "RUN", "MODEL", "CKPT", "PATH", "FILE", "RESULTS")


def record(markers: str = "matrix") -> Path:
    """Run the matrix cases with recording on; returns the recording."""
    path = Path(tempfile.mkdtemp()) / "answers.jsonl"
    env = {**os.environ, "HUPBENCH_RECORD_ANSWERS": str(path)}
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", markers, str(REPO / "tests")],
                   cwd=REPO, env=env, check=False)
    return path


def collected() -> list[tuple[str, str]]:
    """(module path, case) of every matrix case, in collection order."""
    proc = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-n", "0", "-q", "-m", "matrix", "-p",
                           "no:cacheprovider", str(REPO / "tests")], capture_output=True, text=True, cwd=REPO)
    if proc.returncode != 0:
        raise SystemExit(proc.stdout[-3000:] + proc.stderr[-3000:])
    return [tuple(line.split("::", 1)) for line in proc.stdout.splitlines() if "::" in line]


def plain(line: str) -> str:
    """A recorded line as the doc shows it: no temporary folders, no live pids, one table cell."""
    line = TMP_FOLDER.sub(lambda m: "" if m.group(1) else "FOLDER", line)
    line = HOLDER.sub("pid PID on HOST, since TIME", line)
    if len(line) > MAX_LINE:
        line = line[:MAX_LINE] + "..."
    return line.replace("|", "\\|")


def quote(line: str) -> str:
    return f"`` {line} ``" if "`" in line else f"`{line}`"


def read_recording(path: Path) -> tuple[dict[str, list[str]], dict[str, str]]:
    """{case: answer lines in order, without repeats}, {case: the command it ran}."""
    answers: dict[str, list[str]] = {}
    inputs: dict[str, str] = {}
    for text in path.read_text().splitlines():
        row = json.loads(text)
        case = row["test"].split("::")[-1]
        if "answer" in row and plain(row["answer"]) not in answers.setdefault(case, []):
            answers[case].append(plain(row["answer"]))
        if "input" in row:
            inputs.setdefault(case, plain(row["input"]))
    return answers, inputs


def answer_cell(cell: str, lines: list[str]) -> str:
    """The cell with its quoted error lines replaced, in order, by the recorded ones; a cell that quotes
    none keeps its words (a fault's behaviour), unless it is a bare unquoted error line."""
    spans = QUOTED.findall(cell)
    if not spans:
        return " ".join(quote(line) for line in lines) if cell.startswith("error:") else cell
    for span, line in zip(spans, lines):
        if not same_answer(span, line):
            cell = cell.replace(span, quote(line), 1)
    return cell


def same_answer(span: str, line: str) -> bool:
    """Whether the quoted ``span`` already says ``line``, its hand-written placeholders (DATASET, FOLDER,
    ...) standing for any path and its ``...`` for any text: such a row keeps its readable wording."""
    text = span.strip("`").strip()
    pattern = "".join(".*?" if part.rstrip("/") in (*PLACEHOLDERS, "...") else re.escape(part)
                      for part in re.split(r"(\.\.\.|\b(?:%s)\b/?)" % "|".join(PLACEHOLDERS), text) if part)
    return re.fullmatch(pattern, line, flags=re.S) is not None


def rebuild(text: str, cases: list[tuple[str, str]], answers: dict[str, list[str]], inputs: dict[str, str]) -> str:
    lines = text.splitlines()
    rows = {m.group(1): i for i, line in enumerate(lines) if (m := ROW.match(line))}
    wanted = {case for _, case in cases}
    # a new case goes to the table of its test function, else of its module, else the last table
    table_end: dict[str, int] = {}
    for case, i in rows.items():
        table_end[case.split("[")[0]] = max(table_end.get(case.split("[")[0], 0), i)
    module_of = {case: module for module, case in cases}
    for case, i in rows.items():
        if case in module_of:
            table_end[module_of[case]] = max(table_end.get(module_of[case], 0), i)
    out: dict[int, list[str]] = {}
    for module, case in cases:
        if case in rows:
            match = ROW.match(lines[rows[case]])
            cell = answer_cell(match.group(3).strip(), answers[case]) if answers.get(case) else match.group(3).strip()
            lines[rows[case]] = f"| `{case}` | {match.group(2).strip()} | {cell} |"
        else:
            at = table_end.get(case.split("[")[0]) or table_end.get(module) or max(rows.values())
            given = inputs.get(case, case.split("[")[-1].rstrip("]"))
            cell = " ".join(quote(line) for line in answers.get(case, [])) or "(no error line recorded)"
            out.setdefault(at, []).append(f"| `{case}` | `{given}` | {cell} |")
    result = []
    for i, line in enumerate(lines):
        match = ROW.match(line)
        if not (match and match.group(1) not in wanted):
            result.append(line)
        result.extend(out.get(i, []))
    return "\n".join(result) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--from", dest="source", type=Path, help="a recording (JSON lines) made before")
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 when the doc would change")
    args = parser.parse_args(argv)
    answers, inputs = read_recording(args.source or record())
    old = DOC.read_text()
    new = rebuild(old, collected(), answers, inputs)
    if args.check:
        diff = list(difflib.unified_diff(old.splitlines(), new.splitlines(), "docs/robustness.md", "regenerated",
                                         lineterm=""))
        print("\n".join(diff) or "docs/robustness.md is up to date")
        return 1 if diff else 0
    DOC.write_text(new)
    print(f"wrote {DOC.relative_to(REPO)}: {sum(1 for _ in filter(ROW.match, new.splitlines()))} cases")
    return 0


if __name__ == "__main__":
    sys.exit(main())
