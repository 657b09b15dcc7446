"""What `hupbench VERB --help` teaches (keys or options with their defaults, examples), `--cfg job` of the
Hydra verbs, verbs' own options in any order, and `hupbench train` as the same command as `python train.py`."""

from __future__ import annotations

import json
import logging
import os
import re
import shlex
import subprocess
import sys

import pytest
import yaml
from helpers import REPO
from helpers.cli import assert_clean_error, run_cli
from helpers.training import tiny_overrides
from omegaconf import OmegaConf

from hupbench.cli import HYDRA_VERBS, VERBS
from hupbench.config import compose, described_keys

#: a Hydra verb's config name
CONFIG = {verb: name for verb, (name, _) in HYDRA_VERBS.items()} | {"train": "train"}
#: an option of each argparse verb and the default its --help must state
ARGPARSE_DEFAULTS = {
    "verify": ("--workers", "(default: 2)"),
    "eval": ("--batch-size", "(default: 32)"),
    "export": ("--opset", "(default: 18)"),
    "leaderboard": ("--dir", "(default: leaderboard)"),
    "predict": ("--batch-size", "(default: 16)"),
    "export-dataset": ("--images", "(default: hardlink)"),
    "import-hup3d": ("--depth", "(default: auto)"),
}


@pytest.fixture(autouse=True)
def _fixed_width(monkeypatch):
    """Help wrapped at 100 columns whatever the terminal, so that lines compare across processes."""
    monkeypatch.setenv("COLUMNS", "100")


@pytest.fixture
def restore_logging():
    """The root logger as it was: Hydra's run configures it (a console and a log file handler) for the process."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    for handler in [h for h in root.handlers if h not in handlers]:
        root.removeHandler(handler)
        handler.close()
    root.setLevel(level)


def _leaves(node, prefix: str = "") -> dict:
    """``{dotted key: value}`` of every leaf of a plain config container, Hydra's private keys left out."""
    out = {}
    for key, value in node.items():
        if str(key).startswith("_"):
            continue
        if isinstance(value, dict) and not (isinstance(value, str)):
            out |= _leaves(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_every_verb_is_covered():
    assert set(CONFIG) | set(ARGPARSE_DEFAULTS) == set(VERBS)


@pytest.mark.parametrize("verb", list(VERBS))
def test_help_states_defaults_and_examples(verb, capsys):
    answer = run_cli(capsys, verb, "--help")
    assert answer.rc == 0 and answer.err == "", answer
    assert answer.out.startswith(f"usage: hupbench {verb}"), answer.out[:200]
    examples = answer.out.split("\nexamples:\n", 1)[1].splitlines()
    assert len([e for e in examples if e.startswith(f"  hupbench {verb} ")]) >= 2, examples
    if verb in CONFIG:
        # every key of the composed config, with its composed value
        config = OmegaConf.to_container(compose(CONFIG[verb]), resolve=False)
        leaves = {k: v for k, v in _leaves(config).items() if not isinstance(v, (list, dict))}
        listed = dict(re.findall(r"^  ([\w.]+)=(\S*)", answer.out, flags=re.MULTILINE))
        assert set(leaves) <= set(listed), set(leaves) - set(listed)
        for key, value in leaves.items():
            assert listed[key] == ("null" if value is None else str(value).lower() if isinstance(value, bool)
                                   else str(value)), key
    else:
        option, default = ARGPARSE_DEFAULTS[verb]
        line = re.search(rf"^  {option}\b.*?(?=^  -|\n\n)", answer.out, flags=re.MULTILINE | re.DOTALL)
        assert line and default in " ".join(line.group(0).split()), answer.out


def test_help_gives_each_key_its_yaml_comment(capsys):
    answer = run_cli(capsys, "generate", "--help")
    line = next(line for line in answer.out.splitlines() if line.startswith("  launcher=local"))
    # conf/generate.yaml's comment above `launcher:`
    assert "local: `workers` processes on this machine; ray: one Ray actor per" in line
    # a group's chosen config describes its node: conf/model/hupnet_fit.yaml's first line
    answer = run_cli(capsys, "train", "--help", "model=hupnet_fit")
    assert re.search(r"^  model\.\* +HUPNet reading each keypoint's depth from the depth input", answer.out, re.MULTILINE)
    assert re.search(r"^  model\.probe_fit=depth$", answer.out, re.MULTILINE), answer.out


def test_help_shows_the_overrides_given(capsys):
    answer = run_cli(capsys, "generate", "dataset.width=128", "--help")
    assert answer.rc == 0
    assert re.search(r"^  dataset\.width=128 *$", answer.out, re.MULTILINE)
    assert "conf/generate.yaml composed with dataset.width=128" in answer.out


def test_help_with_a_bad_override_is_one_error_line(capsys):
    answer = run_cli(capsys, "generate", "--help", "dataset.nosuch=1")
    assert_clean_error(answer, "dataset.nosuch", "not in the config", prefix="hupbench generate: error:")


def test_described_keys_are_every_leaf_of_the_composed_config():
    """The key table is read from the composed config, so it cannot miss a key or keep a removed one."""
    for name in set(CONFIG.values()):
        config = OmegaConf.to_container(compose(name), resolve=False)
        rows = [key for key, _, _ in described_keys(name) if not key.endswith(".*")]
        assert rows == list(_leaves(config)), name


@pytest.mark.parametrize("verb", list(CONFIG))
def test_examples_compose(verb):
    from hupbench.verbs.train import examples as train_examples

    examples = train_examples("hupbench train") if verb == "train" else HYDRA_VERBS[verb][1]
    assert len(examples) >= 2
    for example in examples:
        words = shlex.split(example.split("#", 1)[0])
        assert words[:2] == ["hupbench", verb], example
        overrides = [w.split(",")[0] if "," in w and "[" not in w and "{" not in w else w
                     for w in words[2:] if "=" in w]  # a sweep's first job
        flags = ("--fast" in words) + ("--cfg" in words) * 2 + ("-m" in words)
        assert len(overrides) + flags == len(words) - 2, example  # no word left unread
        compose(CONFIG[verb], [*overrides, *(["fast=true"] if "--fast" in words else [])])


@pytest.mark.parametrize("verb, override, key, value", [
    ("generate", "dataset.n_gloves=1", "dataset.n_gloves", 1),
    ("grasps", "generate.n_select=4", "generate.n_select", 4),
    ("train-grasp-sampler", "cvae.epochs=3", "cvae.epochs", 3),
    ("quickstart", "stop_after=grasps", "stop_after", "grasps"),
    ("train", "+experiment=paper_hupnet_fit_cpu", "run_name", "paper_hupnet_fit_cpu"),
])
def test_cfg_job_prints_the_composed_config(verb, override, key, value, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    answer = run_cli(capsys, verb, "--cfg", "job", override)
    assert answer.rc == 0 and answer.err == "", answer
    printed = yaml.safe_load(answer.out)
    assert OmegaConf.select(OmegaConf.create(printed), key) == value
    assert printed == OmegaConf.to_container(compose(CONFIG[verb], [override]), resolve=False)
    assert list(tmp_path.iterdir()) == []  # nothing run


def test_cfg_job_resolve_and_quickstart_fast(capsys):
    answer = run_cli(capsys, "generate", "dataset.width=128", "--cfg", "job", "--resolve", "dataset.height=128")
    assert answer.rc == 0, answer
    # a 60 mm lens on a 32 mm sensor across 128 px: 60 / 32 * 128 = 240 px
    assert yaml.safe_load(answer.out)["dataset"]["fx"] == 240.0
    answer = run_cli(capsys, "quickstart", "--cfg", "job", "--fast")
    assert yaml.safe_load(answer.out)["fast"] is True
    answer = run_cli(capsys, "generate", "--resolve")
    assert_clean_error(answer, "--resolve goes with --cfg job", prefix="hupbench generate: error:")
    assert answer.rc == 2


def test_verify_options_in_any_order(tiny_dataset, capsys):
    """verify reads its own options before the dataset as well as after it."""
    answer = run_cli(capsys, "verify", "--workers", "1", "--max-report", "3", tiny_dataset)
    assert answer.rc == 0, answer
    assert answer.out.strip().splitlines()[-1] == "hupbench verify: OK, 60 frames checked"
    answer = run_cli(capsys, "verify", "--workers", "0", tiny_dataset)
    assert_clean_error(answer, "--workers", "whole number >= 1", "'0'", prefix="hupbench verify: error:")
    assert answer.rc == 2


def test_train_cfg_job_is_train_py_cfg_job(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    answer = run_cli(capsys, "train", "--cfg", "job", "+experiment=paper_hupnet_fit_cpu", "train.max_steps=7")
    assert answer.rc == 0, answer
    printed = yaml.safe_load(answer.out)
    assert (printed["model_id"], printed["train"]["max_steps"], printed["loss"]["probe_symmetry"]) == \
        ("hupnet_fit", 7, "half_turn")
    done = subprocess.run([sys.executable, str(REPO / "train.py"), "--cfg", "job", "+experiment=paper_hupnet_fit_cpu",
                           "train.max_steps=7"], check=False, capture_output=True, text=True, cwd=tmp_path,
                          timeout=120,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 0 and done.stdout == answer.out, done.stderr


def test_train_py_help_is_hupbench_train_help(capsys, tmp_path):
    answer = run_cli(capsys, "train", "--help")
    assert answer.rc == 0
    done = subprocess.run([sys.executable, str(REPO / "train.py"), "--help"], check=False, capture_output=True,
                          text=True,
                          cwd=tmp_path, timeout=120, env={**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "100"})
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: train.py")
    ours = answer.out.split("\nconfig keys", 1)[1].replace("hupbench train", "python train.py")
    assert done.stdout.split("\nconfig keys", 1)[1] == ours
    # the recommended model and a short example
    assert "model=hupnet_seg (its recipe: +experiment=paper_hupnet_seg_60_cpu" in " ".join(answer.out.split())
    assert "  hupbench train model=hupnet_handfit model.backbone=resnet10 train.max_steps=500" in answer.out


@pytest.mark.parametrize("argv, needles", [
    (["nosuch.key=1"], ("'nosuch.key'", "not in the config", "+nosuch.key=1 adds it")),
    (["experiment=paper_hupnet_fit_cpu"], ("'experiment'", "+experiment=paper_hupnet_fit_cpu")),
    (["model=nosuch"], ("model/nosuch", "hupnet_fit")),
    (["model"], ("'model'", "key=value")),
])
def test_train_bad_input_is_one_line(argv, needles, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    answer = run_cli(capsys, "train", *argv)
    assert_clean_error(answer, *needles, prefix="hupbench train: error:")
    assert answer.rc == 1
    assert list(tmp_path.iterdir()) == []


def test_hupbench_train_trains(tiny_dataset, capsys, tmp_path, monkeypatch, restore_logging):
    """hupbench train runs train.py's training: the run folder is Hydra's, out_root/run_name; a refused
    run names hupbench train."""
    monkeypatch.chdir(tmp_path)
    overrides = [o for o in tiny_overrides(tiny_dataset, "unused", tmp_path / "cache") if not o.startswith("run_dir=")]
    answer = run_cli(capsys, "train", *overrides, f"out_root={tmp_path / 'runs'}", "run_name=tiny")
    assert answer.rc == 0, answer
    run = tmp_path / "runs" / "tiny"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["steps"] == 2, summary
    assert (run / "checkpoints" / "last.pt").is_file()
    assert json.loads((run / "run.json").read_text())["config"]["run_dir"] == str(run)
    answer = run_cli(capsys, "train", *overrides, f"out_root={tmp_path / 'runs'}", "run_name=tiny",
                     "data.batch_size=8")
    assert_clean_error(answer, "data.batch_size", prefix="hupbench train: error:")
    assert answer.rc == 1
