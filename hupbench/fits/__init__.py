"""What runs after the network: a model's keypoints refined by fitting known shapes to its depth input.

A model's saved config asks for the fits (``probe_fit: depth``, ``hand_fit: depth``); :func:`after_network` runs
them on its output, in eval (:mod:`hupbench.evaluation.prediction`) and ``hupbench predict`` alike. The probe's fit
(:mod:`hupbench.fits.probe_fit`) poses the probe's surface; the hand's (:mod:`hupbench.fits.hand_fit`) fits a capsule
hand and leaves that probe's surface out; both read the depth input through :mod:`hupbench.fits.depth_points`. Both
fit one probe (:class:`hupbench.fits.known_probe.FitProbe`): the one of the dataset the model was trained on, which
its model file carries, else the default procedural probe; data made with another probe is refused by
:func:`check_fitted_probe`. Tracking a video, :func:`track_fits` starts each frame's fits where they left the frame
before (the probe's pose).

Numpy only, no torch: ``hupbench predict`` runs the fits of an exported model where torch is not installed.
May import: ``hupbench.core``, ``hupbench.input_geometry``, numpy, and the generator's probe and hand
(``datagen.assets``, the shapes the fits fit; ``datagen.dataset`` for a training dataset's probe) where the model
file does not carry them: they are built by the generator when a fit first needs them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hupbench.core.contract import SEGMENT_CLASSES
from hupbench.core.errors import BadValueError
from hupbench.fits.known_probe import FitProbe
from hupbench.fits.settings import HandFitSettings, ProbeFitSettings, model_fit_settings

__all__ = ["FITTED_PROBE", "HandFitSettings", "ProbeFitSettings", "after_network", "check_fitted_probe",
           "fits", "model_fit_settings", "track_fits"]

#: the probe record (a dataset manifest's ``probe``, :attr:`hupbench.datagen.assets.probe.Probe.record`) of the one
#: probe the fits know: the procedural probe of the default spec
FITTED_PROBE = {"kind": "procedural"}


def fits(model_config: dict) -> tuple[str, ...]:
    """What a model's saved config (a checkpoint's, or an ONNX file's ``hupbench.model_config``) asks to run after
    the network, in the order it runs: "probe" (``probe_fit: depth``) and "hand" (``hand_fit: depth``); a config
    without the fields fits nothing."""
    return tuple(part for part in ("probe", "hand") if model_config.get(f"{part}_fit", "none") == "depth")


def check_fitted_probe(model_config: dict, probe_record: dict | None, source: str,
                       fitted: FitProbe | None = None) -> None:
    """Refuse data of another probe for a model that fits: the fits pose and leave out their own probe only.

    Args:
        model_config: the model's saved config (:func:`fits`).
        probe_record: the data's probe record (a manifest's ``probe``; None or absent: the procedural probe).
        source: the data's manifest, named in the error.
        fitted: the probe the model's fits know (its model file's); None: :data:`FITTED_PROBE`.

    Raises:
        BadValueError: the model fits and the data's probe is another one.
    """
    record = FITTED_PROBE if probe_record is None else probe_record
    known = FITTED_PROBE if fitted is None else fitted.record
    asked = fits(model_config)
    if asked and record != known:
        own = ("the default procedural probe" if known == FITTED_PROBE
               else f"the probe {_shown(known)!r} ({known.get('kind')}) of its model file")
        raise BadValueError(f"{source}: the data shows the probe {_shown(record)!r} ({record.get('kind')}), but the "
                            f"model's {' and '.join(asked)} fit{'s' if len(asked) > 1 else ''} (probe_fit/hand_fit: "
                            f"depth) {'know' if len(asked) > 1 else 'knows'} only {own}; use a model without the fits "
                            "on this data")


def _shown(record: dict) -> str:
    """A probe record's name in a message: its mesh file, its spec, or its kind."""
    return record.get("path") or record.get("spec") or record.get("kind")


def after_network(model_config: dict, points2d: np.ndarray, points3d: np.ndarray, images: np.ndarray,
                  K_input: np.ndarray, probe: ProbeFitSettings | None = None, hand: HandFitSettings | None = None,
                  fitted: FitProbe | None = None, segmentation: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The fits a model asks for (:func:`fits`) on its output: the probe's first, the hand's on the probe it left.

    Args:
        model_config: the model's saved config.
        points2d: (B, N, 2) float, normalised input coordinates; points3d: (B, N, 3) float, metres, OpenCV camera
            frame of ``K_input``: the network's output.
        images: (B, C, S, S) float32 model images (C = 4 for a model that fits: RGB in [0, 1], depth in metres).
        K_input: (3, 3) intrinsics of the model input, pixels.
        probe, hand: the fits' settings; None: the model's own (:func:`hupbench.fits.settings.model_fit_settings`:
            the defaults with its config's ``fit_settings``).
        fitted: the probe the fits know (the model file's); None: the default procedural probe.
        segmentation: (B, S, S) int, the model's class of each input pixel (:data:`hupbench.core.contract.
            SEGMENT_CLASSES`): the probe's fit takes only the depth of probe pixels, the hand's only that of hand
            pixels (the patient's skin, the arm and the room are neither's). None (a model without the head): every
            pixel near the object, as each fit's docstring says.

    Returns:
        float64 (points2d (B, N, 2), points3d (B, N, 3)); the output itself where the model fits nothing.
    """
    return _run(model_config, points2d, points3d, images, K_input, probe, hand, fitted, segmentation)[:2]


def track_fits(model_config: dict, points2d: np.ndarray, points3d: np.ndarray, images: np.ndarray,
               K_input: np.ndarray, probe_start: np.ndarray | None, probe: ProbeFitSettings | None = None,
               hand: HandFitSettings | None = None, fitted: FitProbe | None = None,
               segmentation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`after_network` on the frames of a video, the frame before's fits carried: the probe's fit starts at
    the probe's pose there (``probe_start``, :func:`hupbench.fits.probe_fit.fit_probe`'s ``start``: no search over
    turns, ``probe.tracking_iterations`` steps) and the hand's takes ``hand.tracking_iterations`` steps from the
    network's hand.

    Args:
        probe_start: (B, 4, 4) the probe's pose where this function left the frames before (its third return;
            NaN rows or None: none, as at a video's first frame). The other arguments: :func:`after_network`'s.

    Returns:
        (points2d, points3d) as :func:`after_network`'s, and the probe's fitted pose (B, 4, 4) (NaN where the fit
        kept the network's corners), the next frames' ``probe_start``; None for a model without the probe's fit.
    """
    hand = model_fit_settings(model_config)[1] if hand is None else hand
    tracking = replace(hand, iterations=hand.tracking_iterations)
    return _run(model_config, points2d, points3d, images, K_input, probe, tracking, fitted, segmentation, probe_start)


def _run(model_config: dict, points2d: np.ndarray, points3d: np.ndarray, images: np.ndarray, K_input: np.ndarray,
         probe: ProbeFitSettings | None, hand: HandFitSettings | None, fitted: FitProbe | None,
         segmentation: np.ndarray | None, probe_start: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`track_fits`' work, with or without a start."""
    asked = fits(model_config)
    own_probe, own_hand = model_fit_settings(model_config)
    probe, hand = own_probe if probe is None else probe, own_hand if hand is None else hand

    def _own(part: str) -> np.ndarray | None:
        return None if segmentation is None else np.asarray(segmentation) == SEGMENT_CLASSES.index(part)

    probe_pose = None
    if "probe" in asked:
        from hupbench.fits.probe_fit import fit_probe

        points2d, points3d, report = fit_probe(points2d, points3d, images, K_input, probe, fitted,
                                               pixels=_own("probe"), start=probe_start)
        probe_pose = report.pose
    if "hand" in asked:
        from hupbench.fits.hand_fit import fit_hand

        points2d, points3d, _ = fit_hand(points2d, points3d, images, K_input, hand, fitted, pixels=_own("hand"),
                                         templates=model_config.get("hand_templates"))
    return np.asarray(points2d, np.float64), np.asarray(points3d, np.float64), probe_pose
