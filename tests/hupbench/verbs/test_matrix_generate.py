"""The bad-input matrix of `hupbench generate` (docs/robustness.md, ## generate).

Every case runs the CLI in this process on the tiny dataset's config with one thing broken: one case per
field group (tests/hupbench/verbs/test_generate_config.py has the others, as unit tests) and every file. The
answer must be one line `hupbench generate: error: ...` naming the field or file and what was
expected, exit 1, no traceback, and the output folder as it was (no manifest, no temporary file,
nothing changed).
"""

import json
import os
import shutil
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from helpers.faults import run_in_namespace
from helpers.cli import assert_clean_error, run_cli  # noqa: E402  (tests/ is on sys.path)

#: helpers.datasets.TINY_SPEC as overrides (2 grasps: train 1, test 1; 64 px)
TINY = ["dataset.splits={train:1,val:0,test:1}", "dataset.z_ego_m=[0.5]", "dataset.n_backgrounds=2",
        "dataset.n_gloves=1", "dataset.sphere.r_circ_m=0.4", "dataset.sphere.exclude=[poles]", "dataset.width=64",
        "dataset.height=64", "dataset.fx=120.0", "dataset.fy=120.0", "dataset.cx=32.0", "dataset.cy=32.0",
        "workers=1", "progress=false"]


def _npz(path, **arrays):
    np.savez(path, **arrays)
    return path


def _good_arrays(grasps):
    with np.load(grasps) as data:
        return {k: data[k] for k in data.files}


def _grasps_with(tmp, grasps, **changes):
    arrays = _good_arrays(grasps)
    for key, value in changes.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value
    return _npz(tmp / "bad_grasps.npz", **arrays)


def _write(path, data: bytes):
    path.write_bytes(data)
    return path


def _truncated(tmp, grasps):
    data = Path(grasps).read_bytes()
    return _write(tmp / "truncated.npz", data[: len(data) // 2])


def _bad_member(tmp, grasps):
    """A zip whose member's CRC does not match its bytes (a flipped byte inside hand_pose)."""
    path = tmp / "flipped.npz"
    shutil.copyfile(grasps, path)
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("hand_pose.npy")
    data[info.header_offset + 30 + len(info.filename) + 200] ^= 0xFF
    return _write(path, bytes(data))


def _background_dir(tmp, files):
    folder = tmp / "backgrounds"
    folder.mkdir()
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return folder


def _png(h, w):
    ok, buf = cv2.imencode(".png", np.full((h, w, 3), 128, np.uint8))
    return buf.tobytes()


def _finished_other_config(tmp, dataset):
    out = tmp / "ds"
    shutil.copytree(dataset, out)
    return out


def _partial(tmp, progress: str, grasps_bytes: bytes | None = None):
    out = tmp / "ds"
    out.mkdir()
    (out / ".progress.json").write_text(progress)
    if grasps_bytes is not None:
        (out / "grasps.npz").write_bytes(grasps_bytes)
    return out


def _manifest_not_json(tmp):
    out = tmp / "ds"
    out.mkdir()
    (out / "manifest.json").write_text("{")
    return out


def _partial_with_other_grasps(tmp, grasps):
    """A partial run of this very config whose copy of the grasps differs from the grasps given now."""
    arrays = _good_arrays(grasps)
    arrays["hand_trans"] = arrays["hand_trans"] + 0.01
    other = _npz(tmp / "other.npz", **arrays)
    return _partial(tmp, json.dumps({"config_hash": _same_config_hash(tmp, grasps)}), other.read_bytes())


def _same_config_hash(tmp, grasps):
    """The config hash the tiny config gives (what a partial run of it wrote)."""
    from hupbench.datagen.dataset.writer import config_hash
    from hupbench.config import compose
    from omegaconf import OmegaConf

    cfg = compose("generate", [f"out_dir={tmp / 'ds'}", f"grasps_path={grasps}", *TINY])
    return config_hash(OmegaConf.to_container(cfg, resolve=True))


# id -> make(tmp, grasps, dataset) -> (overrides, needles[, out_dir])
CASES = {
    # malformed overrides
    "override-without-equals": lambda t, g, d: (["workers"], ["key=value", "workers"]),
    "override-unknown-key": lambda t, g, d: (["dataset.colour=red"], ["dataset.colour"]),
    "override-unknown-top-key": lambda t, g, d: (["colour=red"], ["colour"]),
    "override-bad-syntax": lambda t, g, d: (["dataset.z_ego_m=[0.5"], ["dataset.z_ego_m"]),
    # workers and shard
    "workers-zero": lambda t, g, d: (["workers=0"], ["workers", ">= 1"]),
    "shard-3-of-2": lambda t, g, d: (["shard=3/2"], ["shard", "0 <= k < n"]),
    "ray-num-workers-zero": lambda t, g, d: (["ray.num_workers=0"], ["ray.num_workers"]),
    # z_ego
    "z-ego-negative": lambda t, g, d: (["dataset.z_ego_m=[-0.5]"], ["z_ego_m"]),
    # image and camera
    "width-zero": lambda t, g, d: (["dataset.width=0"], ["width", "from 16 to 8192"]),
    "sphere-circle-too-big": lambda t, g, d: (["dataset.sphere.r_circ_m=0.9"], ["r_circ_m", "r_sph_m"]),
    # datasets nobody could use: a camera that sees a fraction of the hand, every frame twice, images the readers
    # refuse, images smaller than a background is made at, a view id beyond the sphere
    "focal-length-beyond-the-hand": lambda t, g, d: (["dataset.fx=1e9", "dataset.fy=1e9"],
                                                     ["dataset.fx", "at most 172 px", "hand", "1e+09"]),
    "z-ego-listed-twice": lambda t, g, d: (["dataset.z_ego_m=[0.5,0.5]"], ["z_ego_m", "[0.5]", "more than once"]),
    "image-not-square": lambda t, g, d: (["dataset.width=64", "dataset.height=48", "dataset.cy=24.0"],
                                         ["dataset.width", "dataset.height", "square", "64 x 48"]),
    "image-smaller-than-a-background": lambda t, g, d: (["dataset.width=8", "dataset.height=8", "dataset.cx=4.0",
                                                         "dataset.cy=4.0"], ["dataset.width", "from 16", "got 8"]),
    "sphere-exclude-id-beyond-the-sphere": lambda t, g, d: (["dataset.sphere.exclude=[poles,99]"],
                                                            ["exclude id 99", "not a view"]),
    # counts
    "n-backgrounds-beyond-the-set": lambda t, g, d: (["dataset.n_backgrounds=9"], ["n_backgrounds", "9", "8"]),
    "splits-not-adding-up": lambda t, g, d: (["dataset.splits={train:5,val:0,test:0}"], ["splits", "5", "2"]),
    "splits-unknown-name": lambda t, g, d: (["dataset.splits={train:1,holdout:1}"], ["splits", "holdout"]),
    # the clinic track (+track=clinic): its cameras, its splits, its grasps
    "clinic-elevation-leaves-no-camera": lambda t, g, d: (["+track=clinic", "dataset.head.elevation_min_deg=90"],
                                                          ["dataset.head.elevation_min_deg", "[0, 90)", "got 90"]),
    "clinic-distances-inverted": lambda t, g, d: (["+track=clinic", "dataset.head.distance_m=[0.8,0.35]"],
                                                  ["dataset.head.distance_m", "[0.8, 0.35]"]),
    "clinic-no-training-grasps": lambda t, g, d: (["+track=clinic", "dataset.splits={train:0,val:0,test:2}"],
                                                  ["dataset.splits", "train at least 1 grasp", "clinic"]),
    "clinic-grasps-without-subjects": lambda t, g, d: (["+track=clinic"], [str(g), "subjects and patients",
                                                                           "+subjects=clinic"]),
    # the grasps file
    "grasps-missing": lambda t, g, d: ([f"grasps_path={t / 'nope.npz'}"], ["nope.npz", "not found"]),
    "grasps-a-folder": lambda t, g, d: ([f"grasps_path={t}"], [str(t), "folder"]),
    "grasps-empty": lambda t, g, d: ([f"grasps_path={_write(t / 'empty.npz', b'')}"], ["empty.npz", "empty"]),
    "grasps-truncated": lambda t, g, d: ([f"grasps_path={_truncated(t, g)}"], ["truncated.npz", "npz"]),
    "grasps-random-bytes": lambda t, g, d: ([f"grasps_path={_write(t / 'random.npz', os.urandom(4096))}"],
                                            ["random.npz", "npz"]),
    "grasps-damaged-member": lambda t, g, d: ([f"grasps_path={_bad_member(t, g)}"], ["flipped.npz", "hand_pose"]),
    "grasps-json-file": lambda t, g, d: ([f"grasps_path={_write(t / 'grasps.json', b'{}')}"], ["grasps.json", "npz"]),
    "grasps-missing-key": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, hand_trans=None)}"],
                                           ["bad_grasps.npz", "hand_trans"]),
    "grasps-wrong-pose-shape": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, hand_pose=np.zeros((2, 47)))}"],
                                                ["bad_grasps.npz", "hand_pose", "48"]),
    "grasps-wrong-trans-shape": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, hand_trans=np.zeros((2, 2)))}"],
                                                 ["bad_grasps.npz", "hand_trans", "3"]),
    "grasps-nan-pose": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, hand_pose=np.full((2, 48), np.nan))}"],
                                        ["bad_grasps.npz", "hand_pose", "finite"]),
    "grasps-inf-trans": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, hand_trans=np.full((2, 3), np.inf))}"],
                                         ["bad_grasps.npz", "hand_trans", "finite"]),
    "grasps-row-counts-differ": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, hand_trans=np.zeros((3, 3)))}"],
                                                 ["bad_grasps.npz", "rows"]),
    "grasps-no-rows": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, hand_pose=np.zeros((0, 48)), hand_trans=np.zeros((0, 3)), grasp_id=np.zeros(0, np.int64))}"],
                                       ["bad_grasps.npz", "no grasps"]),
    "grasps-text-pose": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, hand_pose=np.full((2, 48), 'x'))}"],
                                         ["bad_grasps.npz", "hand_pose", "float"]),
    "grasps-object-array": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, grasp_id=np.array([0, None], dtype=object))}"],
                                            ["bad_grasps.npz", "grasp_id"]),
    "grasps-fractional-ids": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, grasp_id=np.array([0.5, 1.5]))}"],
                                              ["bad_grasps.npz", "grasp_id", "int"]),
    "grasps-pose-times-1000": lambda t, g, d: (
        [f"grasps_path={_grasps_with(t, g, hand_pose=_good_arrays(g)['hand_pose'] * 1000)}"],
        ["bad_grasps.npz", "hand_pose", "half a turn", "rows [0, 1]", "radians"]),
    "grasps-wrist-in-millimetres": lambda t, g, d: (
        [f"grasps_path={_grasps_with(t, g, hand_trans=_good_arrays(g)['hand_trans'] * 1000)}"],
        ["bad_grasps.npz", "hand_trans", "wrist", "metres"]),
    "grasps-duplicate-ids": lambda t, g, d: ([f"grasps_path={_grasps_with(t, g, grasp_id=np.array([4, 4]))}"],
                                             ["bad_grasps.npz", "grasp_id", "unique"]),
    # background photographs
    "backgrounds-missing": lambda t, g, d: ([f"backgrounds.dir={t / 'none'}"], ["none", "does not exist"]),
    "backgrounds-a-file": lambda t, g, d: ([f"backgrounds.dir={_write(t / 'bg.png', _png(64, 64))}"],
                                           ["bg.png", "not a folder"]),
    "backgrounds-empty": lambda t, g, d: ([f"backgrounds.dir={_background_dir(t, {})}"], ["backgrounds", "no images"]),
    "backgrounds-broken-image": lambda t, g, d: ([f"backgrounds.dir={_background_dir(t, {'a.png': _png(64, 64), 'b.jpg': b'not a jpeg'})}"],
                                                 ["b.jpg", "decodable"]),
    "backgrounds-fewer-than-asked": lambda t, g, d: ([f"backgrounds.dir={_background_dir(t, {'a.png': _png(64, 64)})}"],
                                                     ["n_backgrounds", "2", "1"]),
    # the output folder
    "out-dir-is-a-file": lambda t, g, d: ([f"out_dir={_write(t / 'file', b'x')}"], ["file", "not a folder"],
                                          t / "file"),
    "out-dir-under-a-file": lambda t, g, d: ([f"out_dir={_write(t / 'file', b'x') / 'ds'}"], ["file", "is a file"],
                                             t / "file"),
    "out-dir-empty": lambda t, g, d: (["out_dir="], ["out_dir", "folder path"]),
    "out-dir-another-configs-dataset": lambda t, g, d: ([f"out_dir={_finished_other_config(t, d)}"],
                                                        ["another config", "new out_dir"]),
    "out-dir-manifest-not-json": lambda t, g, d: ([f"out_dir={_manifest_not_json(t)}"], ["manifest.json", "JSON"]),
    "out-dir-partial-of-another-config": lambda t, g, d: (
        [f"out_dir={_partial(t, json.dumps({'config_hash': 'other'}))}"], ["partial dataset", "another config"]),
    "out-dir-progress-not-json": lambda t, g, d: ([f"out_dir={_partial(t, 'garbage')}"], [".progress.json", "JSON"]),
    "out-dir-partial-with-other-grasps": lambda t, g, d: ([f"out_dir={_partial_with_other_grasps(t, g)}"],
                                                          ["other grasps", str(g)]),
}


def _files(folder):
    folder = Path(folder)
    if not folder.exists():
        return {}
    if folder.is_file():
        return {".": folder.read_bytes()}
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_generate(case, tmp_path, tiny_grasps, tiny_dataset, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an empty out_dir names the current folder
    made = CASES[case](tmp_path, tiny_grasps, tiny_dataset)
    overrides, needles = made[0], made[1]
    out = made[2] if len(made) > 2 else tmp_path / "ds"
    before = _files(out)
    argv = ["generate", f"out_dir={tmp_path / 'ds'}", f"grasps_path={tiny_grasps}", *TINY, *overrides]
    answer = run_cli(capsys, *argv)
    assert_clean_error(answer, *needles, prefix="hupbench generate: error:")
    # the folder is as it was: no manifest, no temporary file, nothing written or changed
    assert _files(out) == before
    assert not list(tmp_path.rglob(".*.tmp*"))


@pytest.mark.matrix
def test_matrix_generate_read_only_out_dir(tmp_path, tiny_grasps):
    """An output folder on a read-only filesystem (root writes through file modes, so a read-only
    bind mount in a private mount namespace; skipped where one cannot be made)."""
    mount = tmp_path / "ro"
    mount.mkdir()
    answer = run_in_namespace(["generate", f"out_dir={mount / 'ds'}", f"grasps_path={tiny_grasps}", *TINY],
                              read_only=(mount,))
    assert_clean_error(answer, mount / "ds", "read-only", prefix="hupbench generate: error:")
    assert answer.rc == 1