"""What a training run shows its user: the labelled progress bar (epoch, learning rate, the loss of every step
as the mean of its log window), the phases after the last step, the end lines naming the checkpoint and the
next commands, train.log, "already complete" for a finished run and the fix in a refusal."""

import json
import re

import pytest
from helpers.training import TRAIN_PREFIX, tiny_cfg, train_answer

from hupbench.config import compose
from hupbench.training import loop
from hupbench.training.run_config import train_config
from hupbench.training.resume import new_run_override
from hupbench.training.run_log import RunConsole
from hupbench.verbs.train import task

LOSS = re.compile(r"loss (\S+) \((?:step (\d+)|avg of steps (\d+)-(\d+))\)")


def test_bar_shows_each_steps_window_mean_and_the_phases(tiny_dataset, tmp_path, monkeypatch, capsys):
    """log_every=50 in a 4-step run: log steps are 1 and 4 only, yet the bar's loss changes every step and is
    the mean of the losses since the last log step; after the last step the bar names what runs."""
    losses, postfixes = [], []
    step = loop.train_step

    def recorded_step(*args):
        loss, terms = step(*args)
        losses.append(float(loss))
        return loss, terms

    shown = RunConsole.step

    def recorded_postfix(self, postfix):
        postfixes.append(postfix)
        shown(self, postfix)

    monkeypatch.setattr(loop, "train_step", recorded_step)
    monkeypatch.setattr(RunConsole, "step", recorded_postfix)
    capsys.readouterr()
    result = loop.run_train(tiny_cfg(tiny_dataset, tmp_path / "run", tmp_path / "cache", "run_name=tiny", "train.max_steps=4",
                            "data.batch_size=8", "train.log_every=50", "train.val_every=4", "train.ckpt_every=4", "train.progress=true"),
                   log=lambda *_: None)
    assert len(losses) == len(postfixes) == 4
    windows = [LOSS.search(p).groups() for p in postfixes]
    assert [w[1:] for w in windows] == [("1", None, None), ("2", None, None), (None, "2", "3"), (None, "2", "4")]
    for k, window in enumerate(windows):
        first = 0 if k == 0 else 1  # step 1 is a log step: the next window starts at step 2
        assert float(window[0]) == pytest.approx(sum(losses[first:k + 1]) / (k + 1 - first), rel=1e-3), k
    assert len({w[0] for w in windows}) == 4  # a new number every step
    # 20 training frames make 2 batches of 8 an epoch; the learning rate decays along the cosine
    assert [p.split(", ")[0] for p in postfixes] == ["epoch 1/2", "epoch 1/2", "epoch 2/2", "epoch 2/2"]
    rates = [float(re.search(r"lr (\S+),", p).group(1)) for p in postfixes]
    assert rates == sorted(rates, reverse=True) and rates[0] > rates[-1]
    bar = capsys.readouterr().err
    for phase in ("recomputing batch-norm statistics", "validating", "saving checkpoint last.pt"):
        assert f"tiny: {phase} ...: 100%|" in bar, phase
    assert "tiny: 100%|" in bar and postfixes[-1] in bar  # the bar's last state: its run name and numbers
    # it ends on the final validation, the figure the run's summary (and the quickstart) reports
    assert f"val {result['val_mpjpe_mm']['all']:.1f} mm" in bar.rstrip("\n").split("\r")[-1]


@pytest.fixture(scope="module")
def finished(tiny_dataset, tmp_path_factory):
    """A 2-step run finished through train.py's body in out_root/run_name: (its overrides, printed lines)."""
    root = tmp_path_factory.mktemp("runs")
    overrides = (tiny_dataset, root / "tiny", root / "cache", "run_name=tiny", f"out_root={root}")
    lines = []
    task(tiny_cfg(*overrides), log=lines.append)
    return overrides, lines


def test_the_end_names_the_checkpoint_and_the_next_commands(finished, tiny_dataset):
    (_, run_dir, *_), lines = finished
    checkpoint = run_dir / "checkpoints" / "last.pt"
    assert lines[-3].startswith(f"checkpoint {checkpoint} (lowest validation MPJPE, ")
    assert lines[-2].startswith(f"next: hupbench eval {checkpoint} {tiny_dataset}    # ")
    assert lines[-1].startswith(f"      hupbench export {checkpoint}    # ")
    assert lines[-4].startswith("finished 2 steps in ")


def test_train_log_holds_what_the_run_said(finished):
    (_, run_dir, *_), lines = finished
    text = (run_dir / "train.log").read_text()
    stamp = r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d "
    for line in lines[:-2]:  # everything train() printed; the next commands are the command line's
        assert re.search(stamp + re.escape(line) + "\n", text), line
    assert re.search(stamp + "config: model=hopenet_r10_128 seed=0 ", text)
    steps = re.findall(stamp + r"step (\d)/2 \(epoch 1/1\): loss (\S+) \(step \d\), lr", text)
    assert [s for s, _ in steps] == ["1", "2"] and steps[0][1] != steps[1][1]
    log = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    vals = [r for r in log if r["event"] == "val"]
    assert [r["step"] for r in vals] == [0, 2]
    for r in vals:
        assert f"step {r['step']}: val MPJPE {r['val_mpjpe_mm']['all']:.1f} mm (hand " in text


def test_a_finished_run_again_is_already_complete(finished, capsys):
    overrides, _ = finished
    run_dir = overrides[1]
    before = {name: (run_dir / name).read_bytes() for name in ("run.json", "metrics.jsonl", "summary.json",
                                                               "checkpoints/last.pt")}
    lines = []
    task(tiny_cfg(*overrides), log=lines.append)
    assert lines[0].startswith(f"already complete: nothing to do (checkpoint {run_dir / 'checkpoints' / 'last.pt'}: "
                               "step 2, val MPJPE ")
    assert lines[0].endswith("; use run_name=tiny_2 for a new run)")
    assert lines[1].startswith("next: hupbench eval ") and len(lines) == 3
    assert {name: (run_dir / name).read_bytes() for name in before} == before  # nothing trained or rewritten
    assert (run_dir / "train.log").read_text().rstrip().endswith(lines[0])


@pytest.mark.parametrize("extra, needles", [
    (["optim.optimizer.lr=0.002"], ["trained with another config", "optim.optimizer.lr: checkpoint 0.001, now 0.002",
                                    "start a new run, run_name=tiny_2", "give it the values it was trained with"]),
    (["train.resume=never"], ["already holds a checkpoint", "train.resume=auto", "run_name=tiny_2 for a new run"]),
])
def test_a_changed_config_is_refused_naming_the_fix(finished, capsys, extra, needles):
    overrides, _ = finished
    answer = train_answer(capsys, tiny_cfg(*overrides, *extra))
    assert answer.rc == 1 and answer.err.startswith(TRAIN_PREFIX), answer.err
    for needle in needles:
        assert needle in answer.err, (needle, answer.err)


def test_a_new_run_is_offered_in_the_first_free_folder(tmp_path):
    def offer(*overrides):
        return new_run_override(train_config(compose("train", ["model=hopenet_r10_128", *overrides])))

    assert offer(f"out_root={tmp_path}", "run_name=a") == "run_name=a_2"
    (tmp_path / "a_2").mkdir()
    assert offer(f"out_root={tmp_path}", "run_name=a") == "run_name=a_3"
    # Hydra's folder for the run (out_root/run_name, or a sweep's job under it): the run name is the fix
    assert offer(f"out_root={tmp_path}", "run_name=a", f"run_dir={tmp_path}/multirun/a/0_x") == "run_name=a_3"
    # a folder given by run_dir alone
    assert offer("run_name=a", f"run_dir={tmp_path}/mine") == f"run_dir={tmp_path}/mine_2"


def test_train_log_is_appended_after_the_folder_is_held(tmp_path):
    """Lines said before the run holds its folder (a stale lock taken over) reach train.log when it opens;
    another rank writes nothing."""
    said = []
    console = RunConsole(said.append, enabled=True)
    console.line("took over the folder")
    assert not (tmp_path / "train.log").exists()
    console.open_file(tmp_path)
    console.line("step 1: loss", console=False)
    text = (tmp_path / "train.log").read_text().splitlines()
    assert [line[20:] for line in text] == ["took over the folder", "step 1: loss"] and said == ["took over the folder"]
    other = RunConsole(said.append, enabled=False)
    other.line("x")
    other.open_file(tmp_path / "other")
    assert said == ["took over the folder"] and not (tmp_path / "other").exists()
