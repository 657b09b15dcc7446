"""``hupbench quickstart``: the main job on the embedded default, end to end.

Stages, each the same code as its own verb: a preview sheet of a hand-set
grasp -> grasps (``hupbench grasps``) -> a small dataset (``hupbench
generate``) -> ``hupbench verify`` -> a short training of HUPNet reading depth, with both fits (``train.py``)
-> ``hupbench eval`` on the test split -> ``hupbench export`` (ONNX, parity
checked) -> ``hupbench predict`` on a rendered test image. Every stage's
config is composed before the first one runs, so a bad override fails at
once. Rerunning after a kill resumes: the dataset writer skips finished
chunks and the training continues from its last checkpoint.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from pathlib import Path

from omegaconf import DictConfig

from hupbench.core.camera import Intrinsics
from hupbench.core.contract import MODALITIES
from hupbench.datagen.dataset.spec import check_principal_point
from hupbench.core.errors import BadValueError, RunFailedError
from hupbench.core.input_checks import check_int, check_number
from hupbench.core.io import OutputLock, check_writable, write_json
from hupbench.datagen.dataset.writer import GenerateRun, check_platform
from hupbench.datagen.render.preview import PreviewView
from hupbench.config import build, build_group, compose
from hupbench.provenance import run_info
from hupbench.training.run_config import TrainRun, train_config
from hupbench.verbs.generate import probe_overrides
from hupbench.verbs.grasps import GraspsRun
from hupbench.verbs.train import RECOMMENDED_EXPERIMENT

STAGES = ("preview", "grasps", "dataset", "verify", "train", "eval", "export", "predict")
#: the stages whose verbs take a list of overrides (the quickstart's keys of the same names)
STAGE_LISTS = ("grasps", "dataset", "train")
#: the preview camera's largest image side, pixels (it renders offscreen at that size)
MAX_PREVIEW_SIDE = 4096
#: the preview camera's farthest distance from the probe, metres (as generate's z_ego_m)
MAX_VIEW_DISTANCE_M = 10.0


@dataclass(frozen=True)
class QuickstartRun:
    """``conf/quickstart.yaml`` (``_recursive_: false``: the camera and the view are built after the types of
    their fields are checked here, since Hydra passes ``fast=maybe`` on as a string and ``camera.fx=nan`` as
    a float). grasps, dataset, train: key=value overrides of those stages' verbs, composed by
    :func:`run_quickstart`; ``fast`` reads them and ``eval_latency`` from ``fast_overrides`` instead.
    camera, view, render: the preview's intrinsics, viewpoint, platform and modalities.
    """

    out_dir: str
    camera: Intrinsics
    view: PreviewView
    fast: bool = False
    stop_after: str | None = None
    grasps: list = ()
    dataset: list = ()
    train: list = ()
    eval_latency: bool = True
    fast_overrides: dict = None
    render: dict = None
    probe: dict = None

    def __post_init__(self) -> None:
        if self.stop_after is not None and self.stop_after not in STAGES:
            raise BadValueError(f"stop_after must be one of {', '.join(STAGES)} or null, got {self.stop_after!r}")
        fast_overrides = self.fast_overrides or {}
        for key, value in (("fast", self.fast), ("eval_latency", self.eval_latency),
                           ("fast_overrides.eval_latency", fast_overrides.get("eval_latency", False))):
            if not isinstance(value, bool):
                raise BadValueError(f"{key} must be true or false, got {value!r}")
        for source, lists in (("", vars(self)), ("fast_overrides.", fast_overrides)):
            for stage in STAGE_LISTS:
                value = lists.get(stage, [])
                if not (isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)):
                    raise BadValueError(f"{source}{stage} must be a list of key=value overrides of the {stage} stage "
                                        f"(e.g. {source}{stage}=[a.b=1]), got {value!r}")
        if self.fast:
            # the fast run reads fast_overrides.*: a changed grasps/dataset/train list would be ignored without a word
            packaged = compose("quickstart")
            for key in (*STAGE_LISTS, "eval_latency"):
                if getattr(self, key) != packaged[key]:
                    raise BadValueError(f"{key} is not used by the fast quickstart (fast=true reads "
                                        f"fast_overrides.{key}); set fast_overrides.{key} instead, or leave fast off")
        check_writable(self.out_dir, "out_dir")
        self._check_preview()

    def _check_preview(self) -> None:
        camera, view, render = self.camera, self.view, self.render or {}
        # the image size first: fx, fy, cx, cy are derived from it (conf/quickstart.yaml)
        for key in ("width", "height"):
            # the preview renders offscreen at this size: 100000 px asked for 10^10 pixels
            check_int(camera[key], f"camera.{key}", 1, MAX_PREVIEW_SIDE, hint=" (pixels)")
        for key in ("fx", "fy", "cx", "cy"):  # pixels; focal lengths positive
            check_number(camera[key], f"camera.{key}", 0 if key in ("fx", "fy") else None, low_open=True)
        for key in ("distance_m", "azimuth_deg", "elevation_deg"):
            # beyond MAX_VIEW_DISTANCE_M the hand and probe fill a few pixels
            check_number(view[key], f"view.{key}", high=MAX_VIEW_DISTANCE_M if key == "distance_m" else None)
        object.__setattr__(self, "camera", build_group(camera, "camera"))
        check_principal_point(self.camera, "camera.")
        object.__setattr__(self, "view", build_group(view, "view"))
        check_platform(render.get("platform"), "render.platform")
        modalities = render.get("modalities", list(MODALITIES))
        if not (isinstance(modalities, (list, tuple)) and all(isinstance(m, str) for m in modalities)):
            raise BadValueError(f"render.modalities must be a list of {', '.join(MODALITIES)}, got {modalities!r}")
        from hupbench.datagen.render.renderer import check_modalities

        check_modalities(modalities, "render.modalities: ")

    def stage_overrides(self) -> dict:
        """{stage: its list of overrides, "eval_latency": bool}, from ``fast_overrides`` when ``fast``."""
        source = self.fast_overrides if self.fast else vars(self)
        out = {**{stage: list(source[stage]) for stage in STAGE_LISTS}, "eval_latency": source["eval_latency"]}
        probe = self.probe or {}
        if probe.get("mesh") is not None:
            # grasps and dataset use the same probe
            same = probe_overrides(probe["mesh"], probe.get("mesh_unit", "m"), probe.get("align", False))
            out["grasps"] += same
            out["dataset"] += same
        return out


@contextlib.contextmanager
def _stage_errors(stage: str, fast: bool):
    """Name the stage (and its list of overrides) in an error of a later stage's config: the config classes
    name their field, the CLI would name conf/quickstart.yaml, where the key is not looked up."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from hupbench.error_lines import hydra_error_line

    config_name = {"dataset": "generate"}.get(stage, stage)
    listed = f"fast_overrides.{stage}" if fast else stage
    where = f"{stage} stage (conf/quickstart.yaml's {listed} list over conf/{config_name}.yaml)"
    try:
        yield
    except (HydraException, OmegaConfBaseException) as exc:
        raise BadValueError(f"{where}: {hydra_error_line(exc, f'conf/{config_name}.yaml', 'key=value')}") from exc
    except (ValueError, TypeError) as exc:
        raise type(exc)(f"{where}: {exc}") from exc


@dataclass(frozen=True)
class _Stages:
    """The later stages' configs, composed and built before the first stage runs."""

    work: Path
    fast: bool
    grasps_cfg: DictConfig
    grasps: GraspsRun
    generate_cfg: DictConfig
    generate: GenerateRun
    train: TrainRun
    eval_latency: bool


def _stage_configs(work: Path, overrides: dict, fast: bool) -> _Stages:
    """Compose and build the grasps, generate and train configs of the later stages (so a bad stage
    override fails before the preview renders)."""
    with _stage_errors("grasps", fast):
        grasps_cfg = compose("grasps", [*overrides["grasps"], f"out_dir={work / 'grasps'}"])
        grasps = build(grasps_cfg)
    dataset_dir = work / "dataset"
    with _stage_errors("dataset", fast):
        generate_cfg = compose("generate", [*overrides["dataset"], f"out_dir={dataset_dir}",
                                            f"grasps_path={work / 'grasps' / 'grasps.npz'}"])
        generate = build(generate_cfg)
    with _stage_errors("train", fast):
        train = train_config(compose("train", [*overrides["train"], f"data.root={dataset_dir}",
                                               f"run_dir={work / 'run'}", "run_name=quickstart"]))
    return _Stages(work, fast, grasps_cfg, grasps, generate_cfg, generate, train, overrides["eval_latency"])


def run_quickstart(cfg: DictConfig, log=print) -> dict:
    """Run the quickstart pipeline.

    Args:
        cfg: the composed ``quickstart`` config.
        log: receives one line per stage (and the stages' own progress lines).

    Returns:
        dict with "out_dir", "stages" ({stage: seconds}), the paths each stage made ("preview",
        "grasps_npz", "dataset", "checkpoint", "results", "onnx", "predictions", "overlay"),
        "metrics" (test MPJPE mm: all / hand / probe), "floor_mm" (the test split's floor, the same keys, or
        None), "val_mpjpe_mm" (first and last validation),
        "parity" (ONNX vs PyTorch), "render_platform", "keypoints_in_view", "run_info" and "seconds".
    """
    from hupbench.datagen.render import gl
    from hupbench.datagen.assets.probe import probe_of
    from hupbench.datagen.render.preview import handset_grasp, preview

    start = time.perf_counter()
    # build (and so check) every stage's config before anything runs or is written
    run: QuickstartRun = build(cfg)
    out_dir = Path(run.out_dir)
    last = STAGES.index(run.stop_after) if run.stop_after else len(STAGES) - 1
    stages = _stage_configs(out_dir / ("fast" if run.fast else "full"), run.stage_overrides(), run.fast)

    result: dict = {"out_dir": str(out_dir), "stages": {}}
    n = last + 1

    def stage(index: int, name: str, what: str):
        log(f"[{index + 1}/{n}] {name}: {what}")
        return time.perf_counter()

    def done(name: str, t0: float) -> bool:
        result["stages"][name] = round(time.perf_counter() - t0, 1)
        return STAGES.index(name) >= last

    with OutputLock(out_dir, "quickstart"):
        t0 = stage(0, "preview", "render a hand-set grasp (RGB, depth, labels, keypoints)")
        render = run.render or {}
        shot = preview(out_dir / "preview.png", handset_grasp(), run.camera, run.view,
                       modalities=list(render.get("modalities", MODALITIES)), platform=render.get("platform"),
                       probe=None if stages.generate.probe.mesh is None else probe_of(stages.generate.probe))
        uv = shot["keypoints_2d"]
        result["preview"] = str(shot["path"])
        result["render_platform"] = gl.configure()
        result["keypoints_in_view"] = int(((uv[:, 0] >= -0.5) & (uv[:, 0] < run.camera.width - 0.5)
                                           & (uv[:, 1] >= -0.5) & (uv[:, 1] < run.camera.height - 0.5)).sum())
        if not done("preview", t0):
            result.update(_pipeline(stages, stage, done, log))
        result["seconds"] = time.perf_counter() - start
        result["run_info"] = str(write_json(out_dir / "run.json", run_info(
            cfg, verb="quickstart", seconds=result["seconds"], stages=result["stages"],
            render_platform=result["render_platform"])))
    return result


def _pipeline(stages: _Stages, stage, done, log) -> dict:
    from hupbench.evaluation.evaluate import EvalOptions, run_eval
    from hupbench.inference.export import ExportOptions, run_export
    from hupbench.datagen.dataset.verify import verify
    from hupbench.verbs.generate import generate_dataset, resolved_config
    from hupbench.verbs.grasps import make_grasps
    from hupbench.inference.predict import PredictOptions, run_predict
    from hupbench.training.loop import train

    quiet = lambda *_: None  # noqa: E731 - the stages' own chatter is summarised by the stage lines
    work, run = stages.work, stages.train
    # a model that reads depth predicts from an image and its depth map (predict's --depth)
    out: dict = {"reads_depth": run.data.reader.depth}
    t0 = stage(1, "grasps", f"synthesise, score and select {stages.grasps.generate.n_select} grasps "
                            f"({'under a minute' if stages.fast else 'a few minutes'} on 2 cores; nothing is printed "
                            "until it ends)")
    grasps = make_grasps(stages.grasps, stages.grasps_cfg, log=quiet)
    out["grasps_npz"] = grasps["grasps_npz"]
    out["contact_sheet"] = grasps["contact_sheet"]
    log(f"      {grasps['plausible']} of {grasps['candidates']} candidates plausible, {grasps['selected']} selected")
    if done("grasps", t0):
        return out

    spec = stages.generate.dataset
    t0 = stage(2, "dataset", f"render {spec.width} px frames; {split_words(dict(spec.splits))}")
    generated = generate_dataset(stages.generate, resolved_config(stages.generate_cfg), log=quiet)
    out["dataset"] = generated["out_dir"]
    log("      frames per split: " + ", ".join(f"{k} {v}" for k, v in generated["counts"].items()))
    if done("dataset", t0):
        return out

    t0 = stage(3, "verify", "re-check files, projections, depth and masks")
    verified = verify(out["dataset"], log=quiet)
    if not verified["ok"]:
        raise RunFailedError(f"the quickstart dataset failed verification: {verified['by_kind']}")
    log(f"      OK, {verified['frames']} frames")
    if done("verify", t0):
        return out

    t0 = stage(4, "train", f"{run.model_id}, {run.train.max_steps} steps of {run.data.batch_size}")
    trained = train(run, log=lambda line: log("      " + line))
    out["checkpoint"] = trained["checkpoint"]
    out["run_dir"] = trained["run_dir"]
    out["val_mpjpe_mm"] = {"first": trained["first_val_mpjpe_mm"]["all"], "last": trained["val_mpjpe_mm"]["all"],
                           "steps": trained["steps"]}
    if done("train", t0):
        return out

    t0 = stage(5, "eval", "all metrics on the test split, and figures of prediction against truth")
    evaluated = run_eval(EvalOptions(trained["checkpoint"], out["dataset"], split="test",
                                     out=work / "results" / "quickstart.json", latency=stages.eval_latency,
                                     figures_dir=work / "results" / "figures"),
                         log=quiet)
    out["results"] = evaluated["out"]
    out["eval_figures"] = evaluated["figures"]
    out["metrics"] = {k: evaluated["results"]["metrics"]["mpjpe_mm"][k] for k in ("all", "hand", "probe")}
    out["floor_mm"] = (evaluated["results"]["split_floor"] or {}).get("floor_mm")
    out["latency_ms_per_image"] = evaluated["results"]["latency_ms_per_image"]
    if done("eval", t0):
        return out

    t0 = stage(6, "export", "ONNX with a parity check against PyTorch")
    exported = run_export(ExportOptions(trained["checkpoint"], out=work / "model.onnx", dataset=out["dataset"]),
                          log=quiet)
    out["onnx"] = exported["onnx"]
    out["parity"] = exported["parity"]
    if done("export", t0):
        return out

    t0 = stage(7, "predict", "keypoints for a rendered test image, onnxruntime only")
    image, depth_dir, depth_scale_m = _first_test_image(Path(out["dataset"]))
    # a model that reads depth takes the frame's depth map (the dataset's PNG, named by the image's stem) with it
    predicted = run_predict(PredictOptions(out["onnx"], [image], out_dir=work / "predict",
                                           depth_dir=depth_dir if out["reads_depth"] else None,
                                           depth_scale_m=depth_scale_m), log=quiet)
    if predicted["failed"]:
        raise RunFailedError(f"predict failed on {image}: {predicted['records'][0].get('error')}")
    out["predictions"] = str(predicted["json"])
    out["overlay"] = str(predicted["overlays"][0])
    done("predict", t0)
    return out


def _first_test_image(dataset: Path) -> tuple[Path, Path, float]:
    """The first test frame's RGB file, the test split's depth folder and its metres per depth unit."""
    from hupbench.core.contract import frame_path, read_annotations, read_manifest

    manifest = read_manifest(dataset, "test")
    frame_id = int(read_annotations(dataset, "test", (), manifest)["frame_id"][0])
    return (frame_path(dataset, "test", "rgb", frame_id, manifest["rgb_format"]),
            frame_path(dataset, "test", "depth", frame_id).parent, float(manifest["depth_scale_m"]))


def split_words(splits: dict) -> str:
    """``{"train": 3, "val": 1, "test": 1}`` (grasps per split) in words: "3 grasps to train on, 1 to validate
    on, 1 held out for the test"."""
    def grasps(n: int) -> str:
        return f"{n} grasp{'s' if n != 1 else ''}"
    return (f"{grasps(splits['train'])} to train on, {splits['val']} to validate on, {splits['test']} held out "
            "for the test (each grasp seen from every camera view of the sphere)")


#: what each folder of a quickstart run holds, by its name under ``<out_dir>/fast`` or ``<out_dir>/full``
FOLDERS = (
    ("grasps", "the selected grasps (grasps.npz/json) and their contact sheet"),
    ("dataset", "the rendered dataset: <split>/rgb, depth, seg, annotations.npz, manifest.json"),
    ("run", "the training run: checkpoints/, metrics.jsonl, tb/ (TensorBoard), run.json, summary.json"),
    ("results", "the test results JSON and figures/ (prediction against truth, PCK curve)"),
    ("predict", "predictions.json and the overlay PNG of predict"),
)


def summary_lines(result: dict) -> list[str]:
    """The end-of-run summary the CLI prints: what was made, where, the metrics, and what to run next."""
    lines = [f"hupbench quickstart finished in {result['seconds'] / 60:.1f} min "
             f"(renderer: {result['render_platform']}); stage times: "
             + ", ".join(f"{k} {v:.0f} s" for k, v in result["stages"].items())]
    out_dir = Path(result["out_dir"])
    work = Path(result.get("dataset", out_dir / "full" / "dataset")).parent
    lines.append(f"folders: {out_dir} holds the preview and run.json; {out_dir / 'full'} everything the full run "
                 f"makes, {out_dir / 'fast'} everything --fast makes (the two never share files):")
    lines += [f"  {work / name}/: {what}" for name, what in FOLDERS if (work / name).exists()]
    paths = (("grasps", "grasps_npz"), ("dataset", "dataset"), ("checkpoint", "checkpoint"),
             ("results", "results"), ("ONNX model", "onnx"), ("predictions", "predictions"),
             ("run record", "run_info"))
    made = [(label, result[key]) for label, key in paths if key in result]
    if made:
        lines.append("files:")
        lines += [f"  {label:14s}: {path}" for label, path in made]
    pictures = [("preview sheet (hand-set grasp: RGB, depth, labels, keypoints)", result.get("preview")),
                ("grasps contact sheet", result.get("contact_sheet")),
                *((f"eval figure, {name}", path) for name, path in (result.get("eval_figures") or {}).items()),
                ("predict overlay", result.get("overlay"))]
    lines.append("pictures:")
    lines += [f"  {label}: {path}" for label, path in pictures if path]
    if "val_mpjpe_mm" in result:
        v = result["val_mpjpe_mm"]
        lines.append(f"validation MPJPE (all 29 keypoints): {v['first']:.1f} mm untrained -> {v['last']:.1f} mm at "
                     f"step {v['steps']} (the progress bar's last figure)")
    if "metrics" in result:
        m = result["metrics"]
        lines.append(f"test MPJPE: all {m['all']:.1f} mm (mean over 29 keypoints), hand {m['hand']:.1f} mm, "
                     f"probe {m['probe']:.1f} mm  (a short CPU run: see leaderboard/ for the real ones)")
        if result.get("floor_mm"):
            f = result["floor_mm"]
            lines.append(f"test split's floor (the nearest training grasp under the true camera, what recalling "
                         f"training grasps scores): all {f['all']:.1f} mm, hand {f['hand']:.1f} mm, probe {f['probe']:.1f} mm")
    if "parity" in result:
        lines.append(f"ONNX vs PyTorch: max 3D difference {result['parity']['points3d_mm']:.2e} mm")
    return lines + next_lines(result)


def next_lines(result: dict) -> list[str]:
    """Commands to run next, filled with this run's paths where it made them."""
    dataset = result.get("dataset", "hupbench_out/dataset")
    onnx = result.get("onnx", "model.onnx")
    checkpoint = result.get("checkpoint", "hupbench_out/runs/RUN/checkpoints/last.pt")
    run_dir = result.get("run_dir", "hupbench_out/runs/RUN")
    if result.get("reads_depth"):
        # the model reads a depth map beside each image: the test split's frames have theirs
        predict = (f"  predict on the test frames:  hupbench predict {onnx} {Path(dataset) / 'test' / 'rgb'} --depth "
                   f"{Path(dataset) / 'test' / 'depth'} --out predictions   (yours: --depth, a PNG per image)")
    else:
        predict = f"  predict on your own images:  hupbench predict {onnx} my_photos/ --out predictions"
    return [
        "next:",
        predict,
        f"  look at the dataset:         hupbench verify {dataset} --sample-sheet sample_sheet.png",
        f"  training curves:             tensorboard --logdir {Path(run_dir) / 'tb'}",
        f"  evaluate with figures:       hupbench eval {checkpoint} {dataset} --figures",
        (f"  train a real model:          hupbench train +experiment={RECOMMENDED_EXPERIMENT}   "
         f"(or: python train.py +experiment={RECOMMENDED_EXPERIMENT}; its dataset first: hupbench generate "
         "+track=unseen_grasps)"),
        f"  the leaderboard's protocol:  bash scripts/paper_protocol.sh {RECOMMENDED_EXPERIMENT}",
    ]
