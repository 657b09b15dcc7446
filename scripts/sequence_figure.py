"""docs/sequence_clip.gif and docs/sequence_probe_speed.png: one clip of a dataset of clips (`hupbench generate
+track=clinic_sequences`) with a model's tracked prediction drawn over each frame beside the truth, and the probe's
speed over the clip, true, per frame and tracked.

The model runs over the clip's frames as ``hupbench eval`` runs it (the dataset's depth); the tracked prediction is
the fits started where they left the frame before (a model with fits, :func:`hupbench.fits.track_fits`), then the
1-euro filter of ``--track`` (the settings ``hupbench eval`` chose on val, its "tracking" line, or read from its
results JSON with ``--results``) in time order, drawn as its projection with the frame's K. The speed is the probe centre's (keypoints 21-28) over each frame interval, in the
room: each frame's prediction taken there with the camera's pose in the room (a headset's head tracking), the
skill-assessment figure.

Usage: python scripts/sequence_figure.py MODEL [DATASET] [--split val] [--clip 0] (--track MIN_CUTOFF_HZ,BETA |
       --results RESULTS.json) [--out-dir docs] [--side 256]
       (DATASET default hupbench_out/dataset_clinic_sequences)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: the truth's colour in the frames (RGB), drawn under the prediction
TRUTH_RGB = (255, 255, 255)


def _speed_mm_per_s(points: np.ndarray, T_room_cam: np.ndarray, fps: float) -> np.ndarray:
    """(F - 1,) the probe centre's speed in the room over each frame interval, mm/s, from (F, 29, 3) camera-frame
    metres and (F, 4, 4) each frame's camera in the room."""
    from hupbench.core.geometry import transform_points

    centre = transform_points(T_room_cam, points[:, 21:].mean(axis=1)[:, None])[:, 0]
    return 1e3 * fps * np.linalg.norm(np.diff(centre, axis=0), axis=1)


def _frame(image: np.ndarray, truth_px: np.ndarray, tracked_px: np.ndarray, names, edges, side: int, caption: str
           ) -> np.ndarray:
    """One frame at ``side`` pixels: the truth's skeleton in white, the tracked prediction's over it."""
    import cv2

    from hupbench.core.draw import titled
    from hupbench.inference.overlay import draw_prediction

    scale = side / image.shape[1]
    big = cv2.resize(image, (side, side), interpolation=cv2.INTER_LINEAR)
    truth = (truth_px + 0.5) * scale - 0.5
    for a, b in edges:
        cv2.line(big, tuple(int(round(v)) for v in truth[a]), tuple(int(round(v)) for v in truth[b]), TRUTH_RGB, 3,
                 cv2.LINE_AA)
    drawn = draw_prediction(big, (tracked_px + 0.5) * scale - 0.5, names, edges)
    return titled(drawn, caption)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path, help="a hupbench checkpoint (.pt) or exported model (.onnx)")
    parser.add_argument("dataset", type=Path, nargs="?", default=Path("hupbench_out/dataset_clinic_sequences"))
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--clip", type=int, default=0, help="the clip's place among the split's clips")
    parser.add_argument("--track", help="the 1-euro filter's settings, MIN_CUTOFF_HZ,BETA")
    parser.add_argument("--results", type=Path, help="a results JSON of `hupbench eval` on this dataset: its filter")
    parser.add_argument("--out-dir", type=Path, default=Path("docs"))
    parser.add_argument("--side", type=int, default=256, help="the animation's frame side, pixels")
    args = parser.parse_args()

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    from hupbench.core import keypoints as kp
    from hupbench.core.camera import project_points
    from hupbench.core.contract import SEQUENCE, read_annotations, read_manifest
    from hupbench.data.reader import read_rgb
    from hupbench.evaluation.prediction import EvalModel, predict_split, split_reader
    from hupbench.evaluation.sequence_metrics import FIELDS, clip_rows, room_poses, tracked
    from hupbench.inference.tracking import parse_track

    if (args.track is None) == (args.results is None):
        parser.error("give the filter's settings: --track MIN_CUTOFF_HZ,BETA or --results RESULTS.json")
    if args.track is not None:
        settings = parse_track(args.track)
    else:
        settings = json.loads(args.results.read_text())["sequence"]["filter"]["settings"]
        if settings is None:
            parser.error(f"{args.results}: eval kept no filter (every setting raised the MPJPE on val)")
    manifest = read_manifest(args.dataset, args.split)
    if SEQUENCE not in manifest:
        parser.error(f"{args.dataset} is not a dataset of clips (its manifest has no 'sequence' record)")
    fps = float(manifest[SEQUENCE]["fps"])
    fields = read_annotations(args.dataset, args.split, FIELDS + ("K",), manifest)
    clips = clip_rows(fields)
    if not 0 <= args.clip < len(clips):
        parser.error(f"--clip must be 0 to {len(clips) - 1} ({len(clips)} clips in {args.split})")
    rows = clips[args.clip]
    net = EvalModel(args.model)
    reader = split_reader(args.dataset, args.split, net)
    predicted = predict_split(net, reader, 32, rows=rows, clips=np.asarray(fields["clip_id"])[rows])
    pred, truth = predicted.points3d, predicted.labels3d
    clip_fields = {"time_s": fields["time_s"][rows]}
    smooth = tracked(predicted.tracked3d, clip_fields, [np.arange(len(rows))], settings)
    K = fields["K"][rows]
    size = tuple(int(v) for v in manifest["image_size"])
    truth_px = project_points(truth, K, behind="nan")
    tracked_px = project_points(smooth, K, behind="nan")
    names, edges = list(kp.KEYPOINT_NAMES), [tuple(e) for e in kp.SKELETON_EDGES]
    clip_id = int(fields["clip_id"][rows[0]])
    record = next(c for c in manifest[SEQUENCE]["clips"] if c["clip_id"] == clip_id)
    frames = []
    for f, row in enumerate(rows):
        image = read_rgb(reader.path(int(row)), size)
        error = 1e3 * np.linalg.norm(smooth[f] - truth[f], axis=1).mean()
        frames.append(_frame(image, truth_px[f], tracked_px[f], names, edges, args.side,
                             f"{args.split} clip {clip_id}, {fields['time_s'][row]:.2f} s, tracked {error:.0f} mm"))
    args.out_dir.mkdir(parents=True, exist_ok=True)
    gif = args.out_dir / "sequence_clip.gif"
    images = [Image.fromarray(frame) for frame in frames]
    images[0].save(gif, save_all=True, append_images=images[1:], duration=int(round(1000 / fps)), loop=0,
                   optimize=True)

    time_s = fields["time_s"][rows]
    middle = 0.5 * (time_s[1:] + time_s[:-1])
    fig, ax = plt.subplots(figsize=(7.0, 3.2), dpi=120)
    for points, label, style in ((truth, "true", "k-"), (pred, "per frame", "C3-"), (smooth, "tracked", "C0-")):
        speed = _speed_mm_per_s(points, room_poses(fields)[rows], fps)
        ax.plot(middle, speed, style, lw=1.5 if label != "per frame" else 0.8,
                label=f"{label} (mean {speed.mean():.1f} mm/s)")
    ax.set_xlabel("time in the clip, s")
    ax.set_ylabel("probe speed over the patient, mm/s")
    ax.set_yscale("log")
    ax.set_title(f"{args.split} clip {clip_id}: the probe on the skin at {record['kinematics']['speed_mm_per_s']:.1f} "
                 f"mm/s (skill {record['skill']:.2f})\nthe predictions taken to the room with the headset's pose",
                 fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    plot = args.out_dir / "sequence_probe_speed.png"
    fig.savefig(plot)
    print(f"{gif} ({len(frames)} frames, {gif.stat().st_size / 1e6:.1f} MB) and {plot}; filter {settings}")


if __name__ == "__main__":
    main()
