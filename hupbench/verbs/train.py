"""``hupbench train`` and ``python train.py``: training as a Hydra app over conf/train.yaml.

Both run :func:`command`: :func:`main` hands the command line to Hydra (``key=value`` overrides, ``-m`` for a
sweep, ``--cfg job``) with the packaged configs (:func:`hupbench.config.config_dir`) and runs :func:`task` in
Hydra's output folder; ``--help`` lists the config's keys instead of Hydra's generic page. How the run ends
reaches the user through :func:`hupbench.error_lines.answered`: every deliberate refusal is one line, ``PROG:
error: ...``, exit code 1, Hydra's own (a malformed override, an unknown key or config option) as well as the
run's; Ctrl-C is one line and exit code 130. ``--debug`` (``HYDRA_FULL_ERROR=1`` for train.py) shows the
traceback of a refusal.
"""

from __future__ import annotations

import os
import shlex
import sys
from collections.abc import Sequence

from omegaconf import DictConfig, open_dict

from hupbench.error_lines import answered

#: the best measured row of leaderboard/README.md: its model (conf/model/) and its recipe (conf/experiment/)
RECOMMENDED_MODEL = "hupnet_seg"
RECOMMENDED_EXPERIMENT = "paper_hupnet_seg_60_cpu"

DESCRIPTION = ("Train a 3D hand + probe pose model on a dataset made by `hupbench generate` (conf/train.yaml: the "
               "groups model, data and optim). Writes OUT_ROOT/RUN_NAME/: run.json, metrics.jsonl, "
               "checkpoints/last.pt and best.pt, tb/, summary.json; the same command resumes an interrupted run. "
               "Recommended model: the best measured row of leaderboard/README.md is the depth-anchored HUPNet "
               "with a segmentation head and the probe and the hand fitted to the depth on their own pixels, "
               f"model={RECOMMENDED_MODEL} (its recipe: +experiment={RECOMMENDED_EXPERIMENT}; it reads depth, so the "
               "dataset needs its depth modality, the default). The quickstart trains model=hupnet_handfit on a "
               "ResNet-10 for 500 steps.")


def run_train(cfg: DictConfig, log=print) -> dict:
    """Train the run of a composed conf/train.yaml (:func:`hupbench.config.compose`) in its run folder (run_dir,
    else out_root/run_name); returns the run's summary (:func:`hupbench.training.loop.run_train`)."""
    from hupbench.training import loop

    return loop.run_train(cfg, log)


def examples(prog: str) -> list[str]:
    """The examples of ``PROG --help``, each a command line to run."""
    command = "python train.py" if prog == "train.py" else prog
    return [f"{command} +experiment={RECOMMENDED_EXPERIMENT}    # the recommended model's recipe (conf/experiment/)",
            (f"{command} model=hupnet_handfit model.backbone=resnet10 train.max_steps=500 data.batch_size=32 "
             "precision=fp32    # a short run of the quickstart's model"),
            f"{command} model={RECOMMENDED_MODEL} data.root=hupbench_out/dataset device=cuda",
            f"{command} -m model=hopenet_r10_128,resnet50_128 train.max_steps=500    # a sweep, one folder per job",
            f"{command} --cfg job +experiment={RECOMMENDED_EXPERIMENT}    # print the composed config, run nothing"]


def help_text(prog: str, overrides: Sequence[str] = ()) -> str:
    """``PROG --help``: Hydra's command line, conf/train.yaml's keys with defaults and meanings, examples."""
    from hupbench.config import hydra_verb_parser

    parser = hydra_verb_parser(prog, "train", DESCRIPTION, examples(prog), overrides)
    parser.add_argument("-m", "--multirun", action="store_true",
                        help="a sweep: one run per combination of comma-separated values (model=a,b)")
    parser.add_argument("--info", nargs="?", const="all", metavar="WHAT",
                        help="Hydra's information on the config search path and defaults")
    return parser.format_help()


def task(cfg: DictConfig, log=print) -> float:
    """One Hydra job: the run of ``cfg`` (its run folder Hydra's output folder unless run_dir is set), then,
    when it finished, the commands to run on its checkpoint next. Returns the last validation MPJPE (all
    keypoints, mm): what a Hydra sweeper minimises."""
    if cfg.run_dir is None:
        from hydra.core.hydra_config import HydraConfig

        with open_dict(cfg):
            cfg.run_dir = HydraConfig.get().runtime.output_dir
    result = run_train(cfg, log)
    if result["complete"] and int(os.environ.get("RANK", "0")) == 0:  # torchrun's rank: one process says it
        for line in next_commands(result["checkpoint"], cfg.data.root):
            log(line)
    return result["val_mpjpe_mm"]["all"]


def next_commands(checkpoint: str, dataset: str) -> list[str]:
    """The lines that end a finished run: what to run on its checkpoint next."""
    ckpt, data = shlex.quote(str(checkpoint)), shlex.quote(str(dataset))
    return [f"next: hupbench eval {ckpt} {data}    # MPJPE and the other metrics on the test split",
            f"      hupbench export {ckpt}    # ONNX model, checked against PyTorch"]


def command(argv: Sequence[str], prog: str = "hupbench train", debug: bool | None = None) -> int:
    """Training from the command line ``argv`` (:func:`main`), its end answered by
    :func:`hupbench.error_lines.answered`; returns the exit code. ``debug`` (default: ``HYDRA_FULL_ERROR=1``)
    lets the traceback of a refusal through."""
    if debug is None:
        debug = os.environ.get("HYDRA_FULL_ERROR") == "1"
    return answered(prog, lambda: main(argv, prog), bool(debug),
                    interrupted="interrupted (Ctrl-C); the same command continues from the run's last checkpoint")


def main(argv: Sequence[str], prog: str = "hupbench train") -> int:
    """``--help`` here, everything else by Hydra: one run, or with ``-m`` a sweep, of :func:`task`; exit code 0
    (Hydra's own usage errors exit 2)."""
    import hydra

    from hupbench.config import HYDRA_VERSION_BASE, config_dir

    argv = list(argv)
    if "-h" in argv or "--help" in argv:
        overrides = [a for a in argv if "=" in a and not a.startswith("-")]
        print(help_text(prog, overrides), end="")  # composed with them: a bad one is an error
        return 0
    def job(cfg: DictConfig) -> float:
        try:
            return task(cfg)
        except Exception as exc:  # past Hydra, which would print a line of its own for an Exception
            raise _JobFailed(exc) from None

    saved_argv, saved_full_error = sys.argv, os.environ.get("HYDRA_FULL_ERROR")
    # Hydra prints its own errors over several lines (and a hint about this variable); with it set they
    # propagate to the one catch, which answers them in one line like every other error
    os.environ["HYDRA_FULL_ERROR"] = "1"
    sys.argv = [prog, *argv]  # Hydra reads its command line there
    failed = None
    try:
        # Hydra names the job after this module (train): the log file is RUN/train.log as with train.py
        hydra.main(config_path=str(config_dir()), config_name="train", version_base=HYDRA_VERSION_BASE)(job)()
    except _JobFailed as carried:
        failed = carried.args[0]
    finally:
        sys.argv = saved_argv
        if saved_full_error is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = saved_full_error
    if failed is not None:
        raise failed  # outside the handler: its own traceback and cause, nothing of the carrier
    return 0


class _JobFailed(BaseException):
    """A job's exception carried past Hydra's job runner (a BaseException: Hydra catches only Exception)."""
