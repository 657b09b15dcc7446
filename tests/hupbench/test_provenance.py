"""Provenance: which package files differ from the commit, the refusal that names them, and run names."""

import subprocess

import pytest

from hupbench import provenance as P
from hupbench.core.errors import BadValueError, RunFailedError


def git(repo, *args):
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@example.org", *args], cwd=repo, check=True,
                   capture_output=True)


@pytest.fixture
def repo(tmp_path):
    """A source tree with the package folders committed, and a file outside them."""
    for name in ("hupbench/a.py", "core/b.py", "conf/c.yaml", "docs/notes.md"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("x = 1\n")
    git(tmp_path, "init", "-q")
    git(tmp_path, "add", ".")
    git(tmp_path, "commit", "-q", "-m", "first")
    return tmp_path


def test_a_committed_tree_is_clean_and_its_commit_plain(repo):
    assert P.changed_package_files(repo) == []
    assert len(P.git_commit(repo)) == 40
    P.refuse_uncommitted_package("a leaderboard row", repo)


def test_changed_new_deleted_and_staged_package_files_are_named_docs_are_not(repo):
    (repo / "hupbench" / "a.py").write_text("x = 2\n")
    (repo / "core" / "new.py").write_text("y = 1\n")
    (repo / "conf" / "c.yaml").unlink()
    (repo / "docs" / "notes.md").write_text("changed\n")
    git(repo, "mv", "core/b.py", "core/b2.py")
    assert P.changed_package_files(repo) == ["conf/c.yaml", "core/b2.py", "core/new.py", "hupbench/a.py"]
    assert P.git_commit(repo).endswith("+dirty")
    with pytest.raises(RunFailedError) as info:
        P.refuse_uncommitted_package("a leaderboard row (leaderboard/results/x.json)", repo)
    line = str(info.value)
    assert line.startswith("a leaderboard row (leaderboard/results/x.json) must be reproducible from its commit")
    assert "conf/c.yaml, core/b2.py, core/new.py, hupbench/a.py; commit them first" in line


def test_outside_git_nothing_is_known(tmp_path):
    assert P.changed_package_files(tmp_path) is None and P.git_commit(tmp_path) == "unknown"


@pytest.mark.parametrize("name", ["", "../../x", "a\nb", "-x", "a b", "é", "x" * 129, 7])
def test_a_run_name_is_a_file_stem(name):
    with pytest.raises(BadValueError, match="--run-name must be a run name"):
        P.check_run_name(name, "--run-name")


@pytest.mark.parametrize(("recorded", "path", "expected"), [
    ("paper_hupnet", "x/last.pt", "paper_hupnet"), (None, "x/last.pt", "last"), ("  ", "x/best.pt", "best"),
    ("my run/é", "x/last.pt", "my_run__"), ("..hidden", "x/last.pt", "hidden"), ("///", "x/last.pt", "model")])
def test_the_default_run_name_is_a_run_name(recorded, path, expected):
    assert P.check_run_name(P.default_run_name(recorded, path), "name") == expected
