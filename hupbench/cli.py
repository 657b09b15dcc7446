"""The ``hupbench`` command: one subcommand per user verb, each a thin main over ``run_<verb>``; how a verb's
end reaches the user (a refusal, Ctrl-C, a closed or full stdout) is :func:`hupbench.error_lines.answered`'s."""

from __future__ import annotations

import argparse
import sys

from hupbench import __version__
from hupbench.error_lines import answered

VERBS = {
    "quickstart": "the main job end to end: grasps, a small dataset, verify, training, eval, ONNX, predict (--fast: smoke)",
    "grasps": "synthesise, score and select grasps (which ones depends on the CPU's floating point: generate renders "
              "the default grasps shipped with hupbench); writes grasps.npz/json and a contact sheet",
    "train-grasp-sampler": "make the refinement corpus and retrain the grasp CVAE shipped in the package",
    "generate": "render the dataset (Algorithm 1 of HUP-3D); resumable, workers=N, shard=k/n, launcher=ray",
    "verify": "re-check a dataset: files, counts, projections, depth and mask consistency",
    "train": "train a pose model on a dataset (conf/train.yaml; the same as python train.py); resumable, -m sweeps",
    "eval": "evaluate a checkpoint or ONNX model on a dataset split: metrics, breakdowns, latency; results JSON",
    "export": "export a checkpoint to ONNX (opset 18, dynamic batch) with a parity check against PyTorch",
    "leaderboard": "rebuild leaderboard/README.md and its plots from leaderboard/results/*.json",
    "predict": "2D + 3D keypoints for new images or videos with an exported .onnx model: JSON and overlays (no torch)",
    "export-dataset": "write a dataset in the BOP format (the probe as the object) or as COCO keypoints (hand, probe)",
    "import-hup3d": "convert the published HUP-3D dataset (meta pickles, 8-bit depth, 3-channel masks) into a dataset",
}
#: the verbs over a Hydra config: the config's name (conf/NAME.yaml) and the examples of their --help
HYDRA_VERBS = {
    "quickstart": ("quickstart", ("hupbench quickstart --fast    # the one-to-two-minute smoke version",
                                  "hupbench quickstart out_dir=/tmp/qs view.azimuth_deg=120 stop_after=verify",
                                  "hupbench quickstart --cfg job --fast    # the composed config, nothing run")),
    "grasps": ("grasps", ("hupbench grasps out_dir=/tmp/grasps generate.n_select=5",
                          "hupbench grasps generate.sampler=random refine.iterations=500 threads=4",
                          "hupbench grasps --cfg job generate.n_select=5    # the composed config, nothing run")),
    "train-grasp-sampler": ("train_grasp_sampler", (
        "hupbench train-grasp-sampler out=/tmp/grasp_cvae.npz    # leave the shipped weights alone",
        "hupbench train-grasp-sampler out=/tmp/small.npz corpus.n_orientations=16 cvae.epochs=20",
        "hupbench train-grasp-sampler --cfg job cvae.latent_dim=32    # the composed config, nothing run")),
    "generate": ("generate", ("hupbench generate workers=4 out_dir=/data/hupbench",
                              "hupbench generate +track=unseen_views dataset.width=128 dataset.height=128",
                              "hupbench generate shard=0/2 out_dir=/shared/ds    # and shard=1/2 on a second machine",
                              "hupbench generate --cfg job dataset.n_gloves=1    # the composed config, nothing run")),
}


class _DefaultsHelp(argparse.HelpFormatter):
    """Help with each option's default, ``(default: X)``, where it has one that its text does not already give;
    a description or epilog of several lines (examples) is printed as written, one line is wrapped."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (action.option_strings and action.default not in (None, False, argparse.SUPPRESS)
                and "default" not in text):
            text += " (default: %(default)s)"
        return text


def _hydra_verb(verb: str, args: list[str], run) -> int:
    """A verb over a Hydra config: ``--help`` (the config's keys with defaults), ``--cfg job`` (the composed
    config as YAML, nothing run), else ``run(overrides)`` (quickstart's ``--fast`` as ``fast=true``)."""
    from hupbench.config import config_yaml, hydra_verb_parser

    config_name, examples = HYDRA_VERBS[verb]
    overrides = [a for a in args if "=" in a and not a.startswith("-")]
    parser = hydra_verb_parser(f"hupbench {verb}", config_name, VERBS[verb], examples,
                               overrides if "-h" in args or "--help" in args else None)
    if verb == "quickstart":
        parser.add_argument("--fast", action="store_true", help="the one-to-two-minute smoke version (fast=true)")
    # intermixed: options may stand anywhere among the overrides
    ns = parser.parse_intermixed_args(args)
    fast = ["fast=true"] if getattr(ns, "fast", False) else []
    if ns.cfg:
        print(config_yaml(config_name, [*ns.overrides, *fast], resolve=ns.resolve), end="")
        return 0
    if ns.resolve:
        parser.error("--resolve goes with --cfg job")
    return run([*ns.overrides, *fast])


def _quickstart(overrides: list[str]) -> int:
    from hupbench.config import compose
    from hupbench.verbs.quickstart import run_quickstart, summary_lines

    result = run_quickstart(compose("quickstart", overrides))
    print("\n".join(summary_lines(result)))
    return 0


def _grasps(overrides: list[str]) -> int:
    from hupbench.config import compose
    from hupbench.verbs.grasps import run_grasps

    result = run_grasps(compose("grasps", overrides))
    print(f"hupbench grasps finished in {result['seconds']:.0f} s: {result['plausible']} of "
          f"{result['candidates']} candidates plausible, {result['selected']} selected")
    for key in ("grasps_npz", "grasps_json", "contact_sheet"):
        print(f"  {key:14s}: {result[key]}")
    return 0


def _train_grasp_sampler(overrides: list[str]) -> int:
    from hupbench.config import compose
    from hupbench.verbs.grasps import run_train_grasp_sampler

    result = run_train_grasp_sampler(compose("train_grasp_sampler", overrides))
    print(f"hupbench train-grasp-sampler finished in {result['seconds']:.0f} s: {result['corpus_size']} "
          f"plausible grasps of {result['n_refined']} refined; weights: {result['path']}")
    return 0


def _generate(overrides: list[str]) -> int:
    from hupbench.config import compose
    from hupbench.verbs.generate import run_generate

    result = run_generate(compose("generate", overrides))
    rate = result["frames_rendered"] / result["seconds"] if result["seconds"] > 0 else 0.0
    state = "complete" if result["complete"] else "partial (other shards pending)"
    print(f"hupbench generate: {result['frames_rendered']} frames rendered in {result['seconds']:.0f} s "
          f"({rate:.1f} frames/s); dataset {state}: {result['out_dir']}")
    if result["complete"]:
        print("  frames per split: " + ", ".join(f"{k} {v}" for k, v in result["counts"].items()))
    return 0


def _count(minimum: int):
    """An argparse type: a whole number >= ``minimum`` (argparse names the option; the message, what came)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"must be a whole number >= {minimum}, got {text!r}")
        return value
    return parse


def _verify(args: list[str]) -> int:
    from hupbench.datagen.dataset.verify import report_lines, verify

    parser = argparse.ArgumentParser(
        prog="hupbench verify", formatter_class=_DefaultsHelp,
        description="Re-check a dataset: files, counts, projections, depth, masks, and each RGB image against its "
                    "own labels. Exit code 0 when every check passes, 1 when a problem is reported.",
        epilog="examples:\n"
               "  hupbench verify hupbench_out/dataset\n"
               "  hupbench verify --workers 1 --max-report 10 hupbench_out/dataset\n"
               "  hupbench verify hupbench_out/dataset --sample-sheet /tmp/samples.png    # and a picture of it")
    parser.add_argument("dataset", help="a dataset folder written by hupbench generate (with manifest.json)")
    parser.add_argument("--workers", type=_count(1), default=2, help="processes for the per-frame checks")
    parser.add_argument("--max-report", type=_count(0), default=50, help="problems printed in full")
    parser.add_argument("--sample-sheet", metavar="PNG", help="also write one frame per background and glove")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="progress bar with ETA on stderr (default: when stderr is a terminal)")
    ns = parser.parse_args(args)
    if ns.sample_sheet is not None:
        from hupbench.core.io import check_writable

        # before the checks, which can take minutes: a folder or a read-only place fails now, in one line
        check_writable(ns.sample_sheet, "--sample-sheet", file=True)
    result = verify(ns.dataset, workers=ns.workers, progress=ns.progress)
    print("\n".join(report_lines(result, ns.max_report)))
    if ns.sample_sheet:
        # after the report: a sheet that cannot be drawn from a damaged dataset must not hide it
        from hupbench.datagen.dataset.sample_sheet import sample_sheet
        from hupbench.core.draw import write_png

        print(f"sample sheet: {write_png(ns.sample_sheet, sample_sheet(ns.dataset))}")
    return 0 if result["ok"] else 1


def _import_hup3d(args: list[str]) -> int:
    from hupbench.datagen.dataset.import_hup3d import DEPTH_SOURCES, run_import_hup3d

    parser = argparse.ArgumentParser(
        prog="hupbench import-hup3d", formatter_class=_DefaultsHelp,
        description="Convert the published HUP-3D dataset (meta/img_meta_N.pkl, rgb/, depth/, segm/; in split "
                    "folders train/ val/ test/ or one folder) into a hupbench dataset that verify, eval and training "
                    "read. The probe PLY is not public: supply the one the dataset was rendered with.",
        epilog="examples:\n"
               "  hupbench import-hup3d /data/HUP-3D --probe-mesh voluson_painted_downscaled.ply /data/hup3d_hupbench\n"
               "  hupbench import-hup3d /data/combined_train --split train --probe-mesh probe.ply /tmp/hup3d\n"
               "  hupbench import-hup3d /data/HUP-3D --probe-mesh probe.ply --depth png /tmp/hup3d    # 8-bit depth only")
    parser.add_argument("dir", help="the published HUP-3D folder")
    parser.add_argument("out", help="a new or empty folder for the hupbench dataset")
    parser.add_argument("--probe-mesh", required=True, metavar="PLY",
                        help="the probe mesh the frames were rendered with (required)")
    parser.add_argument("--split", choices=("train", "val", "test"),
                        help="the split of a folder without split folders (default: test)")
    parser.add_argument("--depth", choices=DEPTH_SOURCES, default="auto",
                        help="auto: the raw EXR depth where kept, else the 8-bit PNG; png: always the PNG")
    ns = parser.parse_args(args)
    run_import_hup3d(ns.dir, ns.probe_mesh, ns.out, split=ns.split, depth=ns.depth)
    return 0


def _export_dataset(args: list[str]) -> int:
    from hupbench.datagen.dataset.export_bop_coco import (
        FORMATS,
        IMAGE_MODES,
        ExportOptions,
        run_export_dataset,
    )
    from hupbench.provenance import run_provenance

    parser = argparse.ArgumentParser(
        prog="hupbench export-dataset", formatter_class=_DefaultsHelp,
        description="Write a finished dataset in the BOP format (the probe as object 1: models/, per-grasp scenes with "
                    "poses, cameras, depth and masks) or as COCO keypoints (categories hand and probe, visibility, "
                    "3D keypoints in mm and K as extra fields). README: 'Exporting to BOP and COCO'.",
        epilog="examples:\n"
               "  hupbench export-dataset hupbench_out/dataset --format bop /data/bop/hupbench\n"
               "  hupbench export-dataset hupbench_out/dataset --format coco /data/coco_hupbench --images copy\n"
               "  hupbench export-dataset hupbench_out/dataset --format bop /data/bop/hupbench --force  # replace it")
    parser.add_argument("dataset", help="a finished dataset folder (with manifest.json)")
    parser.add_argument("--format", required=True, choices=FORMATS, help="bop or coco (required)")
    parser.add_argument("out", metavar="OUT", help="a new or empty output folder")
    parser.add_argument("--images", choices=IMAGE_MODES, default="hardlink",
                        help="hard links to the dataset's image files (a copy where the file system has none), or copies")
    parser.add_argument("--force", action="store_true", help="replace OUT when it holds an earlier export")
    parser.add_argument("--no-symmetry", action="store_true",
                        help="BOP: leave the probe's half turn about its long axis out of models_info.json")
    ns = parser.parse_intermixed_args(args)
    opts = ExportOptions(ns.dataset, ns.out, ns.format, images=ns.images, force=ns.force, symmetry=not ns.no_symmetry)
    result = run_export_dataset(opts, run_provenance(), log=lambda *_: None)
    print(f"hupbench export-dataset: {result['format'].upper()} export of "
          + ", ".join(f"{n} {split}" for split, n in result["frames"].items())
          + f" frames in {result['seconds']:.0f} s -> {result['out']} ({result['linked']} image files linked, "
          f"{result['copied']} copied)")
    return 0


def _leaderboard(args: list[str]) -> int:
    from hupbench.evaluation.leaderboard import run_leaderboard

    parser = argparse.ArgumentParser(prog="hupbench leaderboard", formatter_class=_DefaultsHelp, epilog="examples:\n"
                                     "  hupbench leaderboard    # leaderboard/README.md and its plots\n"
                                     "  hupbench leaderboard --dir /tmp/my_leaderboard")
    parser.add_argument("--dir", default="leaderboard", help="leaderboard folder holding results/ (and logs/)")
    ns = parser.parse_args(args)
    result = run_leaderboard(ns.dir)
    print(f"hupbench leaderboard: {result['rows']} rows ({result['measured']} measured, {result['reported']} "
          f"reported) -> {result['readme']}, " + ", ".join(str(p) for p in result["plots"]))
    return 0


def _predict(args: list[str]) -> int:
    # only hupbench.inference.predict: the inference path must run without torch
    from hupbench.inference.predict import (
        DEFAULT_BATCH_SIZE,
        DEFAULT_DEPTH_SCALE_M,
        PredictOptions,
        run_predict,
    )

    parser = argparse.ArgumentParser(
        prog="hupbench predict", formatter_class=_DefaultsHelp,
        description="2D and 3D keypoints for PNG/JPEG images and for videos, frame by frame, with onnxruntime.",
        epilog="examples:\n"
               "  hupbench predict RUN/checkpoints/last.onnx my_photos/ --out /tmp/predictions\n"
               "  hupbench predict RUN/checkpoints/last.onnx scan.mp4    # every frame, and scan_overlay.mp4\n"
               "  hupbench predict RUN/checkpoints/last.onnx hupbench_out/dataset/test/rgb/000000.jpg \\\n"
               "      --depth hupbench_out/dataset/test/depth    # a model that reads depth (model=hupnet_handfit)")
    parser.add_argument("model", metavar="MODEL.onnx", help="a model written by `hupbench export`")
    parser.add_argument("inputs", nargs="+", metavar="IMAGE_VIDEO_OR_DIR",
                        help="image files, video files (.mp4, .avi, .mov, .mkv, .webm) and/or folders of them")
    parser.add_argument("--out", default="predictions",
                        help="output folder (predictions.json, *_overlay.png, *_overlay.mp4)")
    parser.add_argument("--K", metavar="fx,fy,cx,cy", help="intrinsics of the original images, pixels "
                        "(default: the training camera scaled to each image)")
    parser.add_argument("--depth", metavar="DIR", help="for a model that reads depth: a 16-bit depth PNG per image, "
                        "DIR/<image stem>.png (a dataset's <split>/depth folder)")
    parser.add_argument("--depth-scale-m", type=float, default=DEFAULT_DEPTH_SCALE_M, metavar="M",
                        help="metres per unit of the depth PNGs (default: the dataset's 0.0001)")
    parser.add_argument("--no-overlay", action="store_true", help="write the JSON only")
    parser.add_argument("--batch-size", type=_count(1), default=DEFAULT_BATCH_SIZE,
                        help="images per onnxruntime call")
    parser.add_argument("--track", metavar="MIN_CUTOFF_HZ,BETA",
                        help="track a video's frames with the 1-euro filter of these settings (the ones `hupbench "
                             "eval` chose on a split of clips, its 'tracking' line); default: each frame alone")
    parser.add_argument("--fps", type=float, metavar="F",
                        help="with --track: the image files are one sequence's frames at F frames/s, in name order, "
                             "tracked as a video's (a fitting model's fits start where they left the frame before)")
    ns = parser.parse_args(args)
    result = run_predict(PredictOptions(ns.model, ns.inputs, ns.out, K=ns.K, overlay=not ns.no_overlay,
                                        batch_size=ns.batch_size, progress=True, depth_dir=ns.depth,
                                        depth_scale_m=ns.depth_scale_m, track=ns.track, fps=ns.fps))
    bad_videos = sum(not v["ok"] for v in result["videos"])
    print(f"hupbench predict: {result['ok']} image(s) predicted, {result['failed']} of {result['images']} failed"
          + (f" (video frames among them; {bad_videos} of {len(result['videos'])} video(s) unread or cut short)"
             if result["videos"] else "")
          + f"; {result['json']}" + (f" and {len(result['overlays'])} overlay(s)" if result["overlays"] else ""))
    return 1 if result["failed"] or bad_videos else 0


def _eval(args: list[str]) -> int:
    from hupbench.data.reader import DEPTH_SENSORS
    from hupbench.evaluation.evaluate import EvalOptions, run_eval

    parser = argparse.ArgumentParser(
        prog="hupbench eval", formatter_class=_DefaultsHelp,
        description="Every benchmark metric of a model on one dataset split; a results JSON (docs/metrics.md).",
        epilog="examples:\n"
               "  hupbench eval RUN/checkpoints/last.pt hupbench_out/dataset --figures\n"
               "      -> RUN/checkpoints/eval/last.pt.test.json and RUN/checkpoints/eval/last.pt.test.figures/\n"
               "  hupbench eval RUN/checkpoints/last.pt hupbench_out/dataset --out leaderboard/results/NAME.json \\\n"
               "      --training-command 'python train.py +experiment=NAME'   # a leaderboard row "
               "(then: hupbench leaderboard)")
    parser.add_argument("model", help="a hupbench checkpoint (.pt) or an exported ONNX model (.onnx)")
    parser.add_argument("dataset", help="a finished dataset folder (with manifest.json)")
    parser.add_argument("--split", default="test", choices=("train", "val", "test"), help="the split to evaluate")
    parser.add_argument("--out", help="results JSON (default: beside the model, <model folder>/eval/<model file>."
                        "<split>.json); its stem is then the run name. Only --out leaderboard/results/NAME.json "
                        "adds a leaderboard row")
    parser.add_argument("--run-name", help="default: the training run name, the ONNX metadata's, or the stem of --out")
    parser.add_argument("--batch-size", type=_count(1), default=32, help="frames per forward pass")
    parser.add_argument("--latency", action=argparse.BooleanOptionalAction, default=True,
                        help="time PyTorch and onnxruntime at batch 1 and 32")
    parser.add_argument("--threads", type=_count(1),
                        help="intra-op threads of PyTorch and onnxruntime (default: torch's)")
    parser.add_argument("--training-command", help="the committed command that reproduces the training run")
    parser.add_argument("--training-log", help="the run's metrics.jsonl relative to the leaderboard folder")
    parser.add_argument("--label", help="the model's name in the results (default: the run's label, else "
                        "model, backbone and input size)")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True,
                        help="progress bars with ETA on a terminal")
    parser.add_argument("--figures", nargs="?", const="", metavar="DIR",
                        help="also draw PNGs: prediction beside ground truth on sample and worst frames, the PCK "
                        "curve (default DIR: <model folder>/eval/<model file>.<split>.figures)")
    parser.add_argument("--depth-sensor", default="dataset", choices=DEPTH_SENSORS,
                        help="the depth a depth-reading model gets: the dataset's sensor's (else its clean depth), "
                        "none (the clean z-buffer), or a sensor preset made from the clean depth, seeded per frame")
    ns = parser.parse_args(args)
    result = run_eval(EvalOptions(ns.model, ns.dataset, split=ns.split, out=ns.out, run_name=ns.run_name,
                                  batch_size=ns.batch_size, latency=ns.latency, threads=ns.threads,
                                  training_command=ns.training_command, training_log=ns.training_log,
                                  label=ns.label, progress=ns.progress, figures=ns.figures is not None,
                                  figures_dir=ns.figures or None, depth_sensor=ns.depth_sensor))
    print(result["table"])
    print(f"hupbench eval: results written to {result['out']}")
    for name, path in result.get("figures", {}).items():
        print(f"  figure, {name}: {path}")
    if not result["leaderboard_row"]:
        print("  (not a leaderboard row: --out leaderboard/results/NAME.json --training-command '...' adds one, "
              "then hupbench leaderboard)")
    return 0


def _export(args: list[str]) -> int:
    from hupbench.inference.export import OPSET, ExportOptions, run_export

    parser = argparse.ArgumentParser(
        prog="hupbench export", formatter_class=_DefaultsHelp,
        description="Export a checkpoint to ONNX (dynamic batch) and check it against PyTorch on dataset images.",
        epilog="examples:\n"
               "  hupbench export hupbench_out/runs/hopenet_r10_128/checkpoints/last.pt    # -> .../last.onnx\n"
               "  hupbench export RUN/checkpoints/best.pt --out /tmp/model.onnx --dataset hupbench_out/dataset")
    parser.add_argument("checkpoint", help="a hupbench checkpoint (.pt)")
    parser.add_argument("--out", help="destination .onnx (default: the checkpoint path with suffix .onnx)")
    parser.add_argument("--dataset", help="dataset for the parity images (default: the checkpoint's training dataset)")
    parser.add_argument("--opset", type=int, default=OPSET, help="ONNX opset")
    parser.add_argument("--run-name", help="hupbench.run_name metadata (default: the training run name)")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True,
                        help="a progress bar over the stages on a terminal")
    ns = parser.parse_args(args)
    result = run_export(ExportOptions(ns.checkpoint, out=ns.out, dataset=ns.dataset, opset=ns.opset,
                                      run_name=ns.run_name, progress=ns.progress))
    print(f"hupbench export: {result['onnx']} (opset {result['opset']}, parity max |ORT - PyTorch|: "
          f"points3d {result['parity']['points3d_mm']:.2e} mm, points2d {result['parity']['points2d_px']:.2e} px)")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="hupbench",
        description="Synthetic hand + ultrasound-probe data, training and benchmarks (HUP-3D).",
        epilog="Config overrides are Hydra's key=value, e.g. hupbench quickstart camera.width=128; "
               "hupbench VERB --help lists a verb's keys or options with their defaults, and examples",
    )
    parser.add_argument("--version", action="version", version=f"hupbench {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the Python traceback of an error")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for verb, help_text in VERBS.items():
        sub.add_parser(verb, help=help_text, add_help=False)
    argv = list(sys.argv[1:] if argv is None else argv)
    # --debug is hupbench's, wherever it stands (after the verb it would be taken as the verb's option)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    # everything after the verb is the verb's: its own parser reads it (options in any order, +key=value)
    at = next((i for i, a in enumerate(argv) if not a.startswith("-")), len(argv))
    args = parser.parse_args(argv[: at + 1])
    args.debug = debug
    if args.verb is None:
        # the help lists the verbs; the error line says what was missing (argparse's usage errors exit 2 too)
        parser.print_help()
        print(f"hupbench: error: a verb is required, one of: {', '.join(VERBS)} (hupbench VERB --help describes "
              f"one)", file=sys.stderr)
        return 2
    verb_args = argv[at + 1:]
    if args.verb == "train":
        from hupbench.verbs.train import command as train_command

        return train_command(verb_args, prog="hupbench train", debug=debug)
    handlers = {"quickstart": _quickstart, "grasps": _grasps, "train-grasp-sampler": _train_grasp_sampler,
                "generate": _generate, "verify": _verify, "leaderboard": _leaderboard,
                "predict": _predict, "eval": _eval, "export": _export,
                "export-dataset": _export_dataset, "import-hup3d": _import_hup3d}
    if args.verb in HYDRA_VERBS:
        work = lambda: _hydra_verb(args.verb, verb_args, handlers[args.verb])  # noqa: E731
    else:
        work = lambda: handlers[args.verb](verb_args)  # noqa: E731
    return answered(f"hupbench {args.verb}", work, debug, config=f"conf/{args.verb}.yaml", example="out_dir=PATH")

if __name__ == "__main__":
    sys.exit(main())
