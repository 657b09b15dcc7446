"""``hupbench eval --figures``: what the numbers look like. Prediction beside ground truth on a few evenly
spaced frames and on the worst frames (by MPJPE over all 29 keypoints), and the 3D PCK curve of the hand
and the probe.

The images are drawn on matplotlib's Agg canvas (no pyplot, no global backend), each frame's RGB shown
at ``PANEL_IN`` inches a panel whatever its pixel size (a 64 px frame is enlarged, nearest pixel), the
keypoints drawn over it as vectors, so that small inputs stay readable.

Convention: 2D keypoints in pixels of the stored frames (OpenCV, pixel centres at integers), errors in mm.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.io import atomic_output
from hupbench.core.draw import FINGER_RGB, PROBE_RGB

__all__ = ["FIGURES", "N_SAMPLE", "N_WORST", "frame_choice", "write_eval_figures"]

#: frames drawn evenly spaced over the split, and the worst frames drawn
N_SAMPLE = 4
N_WORST = 4
#: one panel's side (inches) and the resolution of the PNGs
PANEL_IN = 3.2
DPI = 100
#: file names of the three figures
FIGURES = {"samples": "samples.png", "worst": "worst.png", "pck": "pck.png"}


def frame_choice(frame_errors_mm: np.ndarray, n_sample: int = N_SAMPLE, n_worst: int = N_WORST
                 ) -> tuple[list[int], list[int]]:
    """(evenly spaced row indices, worst row indices, worst first) of frames with (N,) mean errors in mm; ties
    between equal errors go to the earlier row, so the choice is reproducible."""
    n = len(frame_errors_mm)
    samples = sorted({round(float(v)) for v in np.linspace(0, n - 1, min(n_sample, n))}) if n else []
    worst = [int(i) for i in np.argsort(-np.asarray(frame_errors_mm), kind="stable")[:min(n_worst, n)]]
    return samples, worst


def _colour(index: int) -> tuple[float, float, float]:
    rgb = PROBE_RGB if index >= kp.NUM_HAND else FINGER_RGB[kp.finger_of(index)]
    return tuple(c / 255.0 for c in rgb)


def _draw_skeleton(ax, uv: np.ndarray, linestyle: str = "-") -> None:
    """The 29 keypoints (29, 2) pixels on ``ax``: hand chains coloured by finger, the probe box orange."""
    for a, b in kp.SKELETON_EDGES:
        ax.plot(uv[[a, b], 0], uv[[a, b], 1], color=_colour(b), linewidth=1.6, linestyle=linestyle)
    ax.scatter(uv[:, 0], uv[:, 1], s=10, c=[_colour(i) for i in range(kp.NUM_KEYPOINTS)], edgecolors="black",
               linewidths=0.4, zorder=3)


def _legend_handles():
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=_colour(kp.FINGER_START[f]), linewidth=2, label=f) for f in kp.FINGERS]
    return handles + [Line2D([], [], color=_colour(kp.NUM_HAND), linewidth=2, label="probe box (8 corners)")]


def _new_figure(width_in: float, height_in: float):
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    matplotlib.rcdefaults()  # a user's matplotlibrc must not restyle the figures
    fig = Figure(figsize=(width_in, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _png(fig) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    return buffer.getvalue()


def frames_figure(title: str, images: list[np.ndarray], gt_px: np.ndarray, pred_px: np.ndarray,
                  captions: list[tuple[str, str]]) -> bytes:
    """PNG: one row per frame, ground truth left and prediction right, keypoints drawn over the RGB.

    Args:
        title: the figure's title. images: F (H, W, 3) uint8 RGB frames.
        gt_px, pred_px: (F, 29, 2) float pixels of the frames. captions: F (ground truth, prediction) lines.
    """
    import matplotlib

    rows = len(images)
    with matplotlib.rc_context():
        fig = _new_figure(2 * PANEL_IN, rows * (PANEL_IN + 0.35) + 0.9)
        axes = fig.subplots(rows, 2, squeeze=False)
        for r, (image, caption) in enumerate(zip(images, captions)):
            height, width = image.shape[:2]
            for c, (uv, name) in enumerate(((gt_px[r], "ground truth"), (pred_px[r], "prediction"))):
                caption_line = caption[c]
                ax = axes[r, c]
                ax.imshow(image, interpolation="nearest")
                _draw_skeleton(ax, uv)
                # keypoints outside the frame would stretch the axes: keep the frame's extent
                ax.set_xlim(-0.5, width - 0.5)
                ax.set_ylim(height - 0.5, -0.5)
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_title(f"{name}\n{caption_line}", fontsize=8)
        fig.suptitle(title, fontsize=10)
        fig.legend(handles=_legend_handles(), loc="lower center", ncol=3, fontsize=7, frameon=False)
        fig.tight_layout(rect=(0.0, 0.55 / fig.get_size_inches()[1], 1.0, 1.0))
        return _png(fig)


def pck_figure(errors_mm: np.ndarray, title: str) -> bytes:
    """PNG of the 3D PCK curves (fraction of keypoints within each threshold, 0-50 mm) of the hand, the
    probe and all 29 keypoints, from (N, 29) errors in mm, each labelled with its AUC."""
    import matplotlib

    from hupbench.metrics import PCK_THRESHOLDS_MM, pck_auc_from_errors, pck_mm

    with matplotlib.rc_context():
        fig = _new_figure(6.4, 4.4)
        ax = fig.add_subplot()
        for name, part, style in (("hand (21 joints)", kp.HAND_SLICE, "-"), ("probe (8 corners)", kp.CORNER_SLICE, "-"),
                                  ("all 29 keypoints", slice(None), "--")):
            part_errors = errors_mm[:, part]
            ax.plot(PCK_THRESHOLDS_MM, pck_mm(part_errors), linestyle=style, linewidth=1.8,
                    label=f"{name}: AUC {pck_auc_from_errors(part_errors):.3f}")
        ax.set_xlim(0, float(PCK_THRESHOLDS_MM[-1]))
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("threshold (mm, 3D distance in the camera frame)")
        ax.set_ylabel("fraction of keypoints within the threshold")
        ax.set_title(title, fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
        fig.tight_layout()
        return _png(fig)


def _caption(frame_id: int, errors_mm: np.ndarray) -> tuple[str, str]:
    error = (f"MPJPE {errors_mm.mean():.1f} mm (hand {errors_mm[kp.HAND_SLICE].mean():.1f}, "
             f"probe {errors_mm[kp.CORNER_SLICE].mean():.1f})")
    return f"frame {frame_id}", error


def write_eval_figures(out_dir: str | Path, label: str, split: str, read_frame, frame_ids: np.ndarray,
                       gt_px: np.ndarray, pred_px: np.ndarray, errors_mm: np.ndarray) -> dict[str, Path]:
    """Write ``samples.png``, ``worst.png`` and ``pck.png`` into ``out_dir`` (made).

    Args:
        out_dir: the figures' folder. label: the model's name in titles. split: the evaluated split.
        read_frame: row index -> (H, W, 3) uint8 RGB of that frame as stored.
        frame_ids: (N,) int frame ids (captions). gt_px, pred_px: (N, 29, 2) float, pixels of the stored frames.
        errors_mm: (N, 29) float, 3D errors per keypoint, mm.

    Returns:
        {"samples", "worst", "pck"}: the paths written.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    samples, worst = frame_choice(errors_mm.mean(axis=1))
    pictures = {}
    for key, rows, what in (("samples", samples, f"{len(samples)} frames evenly spaced over the {split} split"),
                            ("worst", worst, f"the {len(worst)} {split} frames of largest MPJPE (29 keypoints)")):
        pictures[key] = frames_figure(f"{label}\n{what}", [read_frame(i) for i in rows], gt_px[rows], pred_px[rows],
                                      [_caption(int(frame_ids[i]), errors_mm[i]) for i in rows])
    pictures["pck"] = pck_figure(errors_mm, f"3D PCK on the {split} split ({len(errors_mm)} frames)\n{label}")
    paths = {}
    for key, data in pictures.items():
        with atomic_output(out_dir / FIGURES[key]) as tmp:
            tmp.write_bytes(data)
        paths[key] = out_dir / FIGURES[key]
    return paths
