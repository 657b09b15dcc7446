"""Small datasets for tests: the tiny spec, a grasps file of the hand-set grasp, annotation reading."""

import numpy as np

from hupbench.core.geometry import axis_angle_to_matrix, matrix_to_axis_angle
from hupbench.core.io import save_npz
from hupbench.datagen.render.preview import handset_grasp
from hupbench.datagen.dataset.sphere import SphereSpec


# a tiny dataset: r_circ = 0.4 on r_sph = 0.8 gives two rings of 5 views (poles excluded: no view of so
# coarse a sphere is near the elbow, so the default exclusion would keep all 12), 64 x 64 images; the
# sphere axis and the look-at are the paper protocol's defaults
TINY_SPEC = dict(splits={"train": 1, "val": 0, "test": 1}, z_ego_m=(0.5,), n_backgrounds=2, n_gloves=1,
                 sphere=SphereSpec(r_circ_m=0.4, exclude=("poles",)), width=64, height=64, fx=120.0, fy=120.0,
                 cx=32.0, cy=32.0)


def write_grasps(path, n=2):
    """The hand-set grasp, turned about the probe axis n ways, as a grasps.npz."""
    g = handset_grasp()
    poses, trans = [], []
    for k in range(n):
        Rz = axis_angle_to_matrix(np.array([0.0, 0.0, k * np.pi / 2]))
        pose = g.hand_pose.copy()
        pose[:3] = matrix_to_axis_angle(Rz @ axis_angle_to_matrix(g.hand_pose[:3]))
        poses.append(pose)
        trans.append(Rz @ g.hand_trans)
    return save_npz(path, {"hand_pose": np.array(poses), "hand_trans": np.array(trans),
                           "grasp_id": np.arange(n, dtype=np.int64)})


def annotations(root, splits=("train", "test")):
    """{split: {array name: array}} of a finished dataset's annotation files."""
    out = {}
    for split in splits:
        with np.load(root / split / "annotations.npz") as data:
            out[split] = {k: data[k] for k in data.files}
    return out


#: the grasps per split of a tiny clinic dataset: the first grasps of the shipped clinic grasps (train, val, test)
CLINIC_SPLITS = {"train": 2, "val": 1, "test": 1}


def clinic_spec(**changes):
    """A tiny clinic-track spec: 48 x 48, 3 head cameras per grasp, 2 rooms, 1 glove, the track's depth sensor; ``changes`` override."""
    from hupbench.datagen.dataset.head import HeadSpec
    from hupbench.datagen.dataset.spec import DatasetSpec

    return DatasetSpec(**{"track": "clinic", "splits": CLINIC_SPLITS, "head": HeadSpec(views_per_grasp=3),
                          "depth_sensor": "hololens2_ahat",
                          "n_backgrounds": 2, "n_gloves": 1, "width": 48, "height": 48, "fx": 90.0, "fy": 90.0,
                          "cx": 24.0, "cy": 24.0} | changes)


def generate_clinic(out, grasps, **changes):
    """Generate the tiny clinic dataset (:func:`clinic_spec`) of ``grasps`` into ``out``; generate's result."""
    from hupbench.datagen.dataset.writer import GenerateRun, generate

    return generate(GenerateRun(clinic_spec(**changes), str(out), str(grasps), progress=False), {"test": "clinic"},
                    log=lambda *_: None)


#: a tiny dataset of clips (:func:`sequence_spec`): clips per grasp, their frame rate and frames (1 s)
CLIPS_PER_GRASP, CLIP_FPS, CLIP_FRAMES = 2, 10.0, 11


def sequence_spec(**changes):
    """A tiny dataset of clips: :func:`clinic_spec` with 2 clips per grasp of 1 s at 10 frames/s, whose fingers
    adjust quickly (:data:`TINY_FINGERS`)."""
    from hupbench.datagen.dataset.head import HeadSpec
    from hupbench.datagen.dataset.head_motion import HeadMotionSpec
    from hupbench.datagen.dataset.scan_motion import ScanMotionSpec

    return clinic_spec(**{"head": HeadSpec(views_per_grasp=CLIPS_PER_GRASP),
                          "scan": ScanMotionSpec(duration_s=(1.0, 1.0), fps=CLIP_FPS), "head_motion": HeadMotionSpec(),
                          "fingers": tiny_fingers()} | changes)


def tiny_fingers():
    """Finger adjustments that fit a 1 s clip: about two, each 0.2-0.6 s long."""
    from hupbench.datagen.dataset.finger_motion import FingerMotionSpec

    return FingerMotionSpec(rate_hz=4.0, open_deg=(10.0, 20.0), move_s=(0.1, 0.2), hold_s=(0.0, 0.2))


def kill_after_first_chunk(code: str, out, timeout_s: float = 300.0) -> None:
    """Run ``code`` (a generation into ``out``) in a new Python process and SIGKILL it as soon as its first chunk is
    complete, while later chunks are being written (pathlib's glob also matches the hidden temporary file a chunk is
    written to, .NAME.tmpPID.npz: not that one)."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    proc = subprocess.Popen([sys.executable, "-c", code])
    deadline = time.time() + timeout_s
    while time.time() < deadline and not list(Path(out).glob("*/.chunks/[!.]*.npz")):
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
