"""The per-field cases of `hupbench quickstart`'s bad-input matrix, as unit tests of ``QuickstartRun`` (its own
options, the preview camera, view and rendering): each answers with the line the CLI prints
(tests/hupbench/verbs/test_matrix_quickstart.py keeps one case per field group, the stages' lists and the files)."""

import re
import shlex
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from helpers.answers import assert_refusal
from hupbench.config import compose
from hupbench.verbs.quickstart import QuickstartRun, _stage_configs


@pytest.fixture(scope="module")
def packaged():
    """conf/quickstart.yaml's fields, resolved, as Hydra hands them to the run."""
    fields = OmegaConf.to_container(compose("quickstart"), resolve=True)
    return {k: v for k, v in fields.items() if k not in ("_target_", "_recursive_")}


def change(**fields):
    def make(base, tmp):
        merged = {**base, "out_dir": str(tmp / "qs"), **fields}
        for group in ("camera", "view", "render"):
            merged[group] = {**base[group], **fields.get(group, {})}
        return QuickstartRun(**merged)
    return make


NAN, INF = float("nan"), float("inf")
# id -> (make(packaged fields, tmp), the override a user types, needles); values as Hydra makes them
CASES = {
    "stop-after-number": (change(stop_after=3), "stop_after=3", ["stop_after", "got 3"]),
    "fast-maybe": (change(fast="maybe"), "fast=maybe", ["fast", "true or false", "'maybe'"]),
    "fast-number": (change(fast=2), "fast=2", ["fast", "true or false", "got 2"]),
    "eval-latency-maybe": (change(eval_latency="maybe"), "eval_latency=maybe", ["eval_latency", "true or false"]),
    "camera-width-huge": (change(camera={"width": 100000}), "camera.width=100000", ["camera.width", "4096", "100000"]),
    "camera-width-word": (change(camera={"width": "wide"}), "camera.width=wide", ["camera.width", "'wide'"]),
    "camera-width-fraction": (change(camera={"width": 255.5}), "camera.width=255.5", ["camera.width", "255.5"]),
    "camera-height-negative": (change(camera={"height": -1}), "camera.height=-1", ["camera", "height", "from 1 to 4096"]),
    "camera-fx-nan": (change(camera={"fx": NAN}), "camera.fx=nan", ["camera.fx", "finite", "nan"]),
    "camera-fx-zero": (change(camera={"fx": 0}), "camera.fx=0", ["camera.fx", "> 0", "got 0"]),
    "camera-fy-word": (change(camera={"fy": "long"}), "camera.fy=long", ["camera.fy", "finite number", "'long'"]),
    "camera-cx-inf": (change(camera={"cx": INF}), "camera.cx=inf", ["camera.cx", "finite", "inf"]),
    "camera-cx-outside-the-image": (change(camera={"cx": -5000}), "camera.cx=-5000",
                                    ["camera.cx", "inside the image", "-5000"]),
    "view-distance-nan": (change(view={"distance_m": NAN}), "view.distance_m=nan", ["view.distance_m", "finite"]),
    "view-distance-huge": (change(view={"distance_m": 1e9}), "view.distance_m=1e9", ["view.distance_m", "<= 10", "1000000000.0"]),
    "view-elevation-100": (change(view={"elevation_deg": 100}), "view.elevation_deg=100",
                           ["view", "elevation_deg", "[-90, 90]"]),
    "view-azimuth-nan": (change(view={"azimuth_deg": NAN}), "view.azimuth_deg=nan", ["view.azimuth_deg", "finite"]),
    "view-azimuth-word": (change(view={"azimuth_deg": "left"}), "view.azimuth_deg=left",
                          ["view.azimuth_deg", "'left'"]),
    "render-modalities-unknown": (change(render={"modalities": ["rgb", "thermal"]}), "render.modalities=[rgb,thermal]",
                                  ["render.modalities", "thermal"]),
    "render-modalities-empty": (change(render={"modalities": []}), "render.modalities=[]",
                                ["render.modalities", "at least one"]),
    "render-modalities-not-a-list": (change(render={"modalities": "rgb"}), "render.modalities=rgb",
                                     ["render.modalities", "list of"]),
    "stage-list-not-a-list": (change(grasps=5), "grasps=5", ["grasps", "list of key=value", "got 5"]),
    "stage-list-of-numbers": (change(train=[1, 2]), "train=[1,2]", ["train", "list of key=value"]),
}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_quickstart(case, packaged, tmp_path):
    make, given, needles = CASES[case]
    assert_refusal(lambda: make(packaged, tmp_path), *needles, prog="hupbench quickstart", given=given)
    assert list(tmp_path.iterdir()) == []  # nothing created


def test_the_run_builds_the_preview_camera_and_view(packaged, tmp_path):
    built = change()(packaged, tmp_path)
    assert (built.camera.width, built.camera.fx, built.view.distance_m) == (256, 480.0, 0.5)
    assert built.stage_overrides()["grasps"] == ["generate.n_select=5"]
    fast = change(fast=True)(packaged, tmp_path)
    assert fast.stage_overrides()["eval_latency"] is False


def test_a_probe_mesh_reaches_the_grasps_and_dataset_stages_as_given(packaged, tmp_path):
    """The grasps and dataset stages name the run's probe; a path with a quote, a backslash, '=' and a space
    composes back to itself in both stage configs."""
    mesh = str(tmp_path / "it's a=b\\probe.stl")
    built = change(probe={"mesh": mesh, "mesh_unit": "mm", "align": True})(packaged, tmp_path)
    overrides = built.stage_overrides()
    for stage, config in (("grasps", "grasps"), ("dataset", "generate")):
        probe = compose(config, overrides[stage]).probe
        assert (probe.mesh, probe.mesh_unit, probe.align) == (mesh, "mm", True), stage


def test_the_readmes_other_model_command_trains_that_model(tmp_path):
    """README's quickstart command with another model (HOPE-Net) parses as typed (each list element quoted) and its
    train stage is that model with the values it lists."""
    readme = (Path(__file__).parents[3] / "README.md").read_text()
    line = re.search(r"^hupbench quickstart .*'train=\[.*$", readme, re.MULTILINE)
    assert line, "README shows no quickstart command with a train list"
    argv = shlex.split(line.group(0))[2:]
    fields = OmegaConf.to_container(compose("quickstart", [*argv, f"out_dir={tmp_path / 'qs'}"]), resolve=True)
    run = QuickstartRun(**{k: v for k, v in fields.items() if k not in ("_target_", "_recursive_")})
    train = _stage_configs(tmp_path / "qs" / "full", run.stage_overrides(), fast=False).train
    assert train.model_id == "hopenet_r10_128"
    assert (train.train.max_steps, train.data.batch_size, train.threads) == (400, 32, 2)
    assert train.model.backbone == "resnet10"
