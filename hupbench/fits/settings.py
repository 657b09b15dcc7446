"""The tuning values of the fits after the network, as frozen settings passed to each fit.

Plain dataclasses (no torch): :func:`hupbench.fits.after_network` takes them on the torch-free predict path. A
variant is ``dataclasses.replace(HandFitSettings(), free_weight=0.0)``; the defaults are the values a model runs
with unless its config's ``fit_settings`` changes some (:func:`model_fit_settings`), chosen on the val splits of the
paper protocol and the clinic track (``scripts/fit_speed.py``,
``scripts/fit_divergence.py``; docs/results.md gives the figures).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

from hupbench.core.errors import BadValueError
from hupbench.core.input_checks import check_bool, check_int, check_number, is_number

__all__ = ["HandFitSettings", "ProbeFitSettings", "check_fit_settings", "model_fit_settings"]


@dataclass(frozen=True)
class ProbeFitSettings:
    """How :func:`hupbench.fits.probe_fit.fit_probe` poses the probe (its module docstring names the steps).

    Attributes:
        hypotheses: turns of the network's pose about the probe's long axis, evenly spaced (12: every 30 degrees).
        iterations: Gauss-Newton steps per turn.
        tracking_iterations: Gauss-Newton steps from the frame before's pose and from the network's, tracking a
            video (:func:`hupbench.fits.track_fits`; 4 chosen on 8 val clips of the clinic_sequences track,
            docs/sequences.md).
        max_points: measured points per frame; coarse_points: of them, for the first round over every turn.
        finalists: turns refined again on all the points.
        reach_m: points this far beyond the probe's half diagonal from the network's box centre, metres.
        trim_m: points farther from the surface are left out, metres: (first half, second half) of the steps.
        inlier_m: a point within this of the surface is on it, metres.
        inside_m: a point deeper than this inside the probe is inside it, metres; inside_penalty: the score's
            weight of such a point against one on the surface.
        min_inliers: fewer points on the best pose's surface keep the network's corners.
        marker_window: the marker's pixel window reaches this many pixels each side of its site.
        marker_depth_m: a window pixel shows the site when its depth is this close to the site's, metres.
        marker_chroma: the marker's colour: its strongest channel ahead of the others by this much (RGB in [0, 1]).
        marker_facing: a site faces the camera: cosine between its normal and the way to the camera above this.
        marker_seen: a site is unoccluded: this share of its window shows it.
        marker_pixels: given a segmentation, this many of the probe's pixels with the marker's colour (its channel
            ahead of the others by marker_pixel_chroma) anywhere show the marker, and the turn whose site projects
            nearer their centre is taken where the sites' windows do not decide (chosen on the clinic_sequences val
            split, docs/clinic.md).
        marker_roll_deg: a frame kept (too few points on the probe's surface) whose probe pixels show the marker
            takes the roll about the network's long axis, in steps of this many degrees, whose marker site faces the
            camera and projects nearest the marker pixels' centre, and the box moved across the view (at its depth)
            until the site projects there (chosen on the clinic_sequences val split, docs/clinic.md).
        marker_reroll_px: a fitted frame whose marker's pixels (a segmentation's) lie farther than this from both
            turns' marker sites, in pixels, takes the roll they read as a kept frame does (marker_roll_deg): the
            depth's roll is wrong there (76 degrees off, median, where the half turn was lost; chosen on the clinic
            track's val split, docs/clinic.md).
        marker_surface_m: without a segmentation, a fitted frame's probe pixels are those whose measured point lies
            within this of the fitted surface: they are read for the marker's pixels as a segmentation's are, and
            where none has its colour and the sites' windows do not decide, the turn whose site faces away from the
            camera is taken (0: neither; chosen on the paper protocol's val split, docs/results.md).
        marker_hidden_margin: that turn is taken only where the two sites' facings (cosines) differ by more than
            this, and where at least marker_seen of the window of the site facing the camera has depth (chosen on
            the paper protocol's val split, docs/results.md).
        marker_under_hand: given a segmentation, where neither site's window nor the marker's pixels decide the half
            turn, the turn whose site faces the camera more is taken (the marker hidden under the fingers) in place
            of the network's (chosen on the clinic track's val split, docs/clinic.md).
    """

    hypotheses: int = 12
    iterations: int = 4
    tracking_iterations: int = 4
    max_points: int = 768
    coarse_points: int = 128
    finalists: int = 3
    reach_m: float = 0.03
    trim_m: tuple[float, float] = (0.015, 0.006)
    inlier_m: float = 0.0025
    inside_m: float = 0.004
    inside_penalty: float = 3.0
    min_inliers: int = 30
    marker_window: int = 2
    marker_depth_m: float = 0.008
    marker_chroma: float = 0.25
    marker_facing: float = 0.3
    marker_seen: float = 0.5
    marker_pixels: int = 1
    marker_pixel_chroma: float = 0.1
    marker_roll_deg: float = 10.0
    marker_reroll_px: float = 5.0
    marker_surface_m: float = 0.008
    marker_hidden_margin: float = 0.1
    marker_under_hand: bool = False

    def __post_init__(self) -> None:
        assert 1 <= self.finalists <= self.hypotheses, (self.finalists, self.hypotheses)
        assert 1 <= self.coarse_points <= self.max_points, (self.coarse_points, self.max_points)
        assert self.marker_pixels >= 1, self.marker_pixels
        assert 0 < self.marker_roll_deg <= 180, self.marker_roll_deg
        assert self.marker_surface_m >= 0, self.marker_surface_m
        assert self.marker_hidden_margin >= 0, self.marker_hidden_margin


@dataclass(frozen=True)
class HandFitSettings:
    """How :func:`hupbench.fits.hand_fit.fit_hand` fits its capsule hand (its module docstring names the steps).

    Attributes:
        palm_radius_m: radius of the capsules from the wrist to each finger's base, metres.
        knuckle_radius_m: radius of the capsules across the knuckles, index to little, metres.
        reach_m: measured points this close to the network's capsules are the hand's, metres;
        probe_gap_m: and this far outside the probe, metres.
        max_points: measured points per frame; min_points: fewer keep the network's hand.
        iterations: Gauss-Newton steps; tracking_iterations: those tracking a video (:func:`hupbench.fits.
            track_fits`; 2 chosen on 8 val clips of the clinic_sequences track, where 2 scored as 8 do; a start at
            the frame before's fitted hand drifted, docs/sequences.md).
        trim_m: points farther from the capsules are left out, metres: (first half, second half) of the steps.
        free_samples: points on each capsule's axis checked against the measured depth;
        free_margin_m: a sample this far in front of the measured surface would be seen there, metres;
        free_weight: the weight of that free-space residual;
        free_band_m: a sample whose measured surface lies farther than this behind its capsule's front is left out,
            metres (the sensor saw past the hand there: the patient, the room; pushing the capsule back would pull
            it towards them).
        bone_prior_m: each bone's turn costs this many metres per radian (a finger without points stays put).
        length_prior_m: each bone's length, as a share of the network's, costs this many metres per unit (a bone a
            tenth longer than the network's: a tenth of it): the network's lengths are the prior, read from the
            image, and the depth stretches or shortens a bone whose points say so (hands of other sizes than the
            generator's default).
        length_from: the lengths are fitted from this share of the steps on (0: every step; 0.5: the second half;
            1: never, the network's lengths kept).
        wrist_weight: the network's wrist holds the fitted wrist: the residual of their distance (metres) times this.
        damping: added to the normal equations' diagonal, so that a frame with few points stays solvable.
        templates: the fit starts from the training hand nearest the network's (the model's ``hand_templates``,
            one per training grasp, each turned and moved onto the network's 21 joints; the nearest by their mean
            distance), its bones' turns and lengths the priors, in place of the network's own joints; False, or a
            model without templates (every model file before them): the network's. Chosen on the val splits of three
            tracks (docs/results.md, "The hand fit started from a training hand").
    """

    palm_radius_m: float = 0.011
    knuckle_radius_m: float = 0.010
    reach_m: float = 0.015
    probe_gap_m: float = 0.004
    max_points: int = 512
    min_points: int = 30
    iterations: int = 8
    tracking_iterations: int = 2
    trim_m: tuple[float, float] = (0.008, 0.004)
    free_samples: int = 4
    free_margin_m: float = 0.004
    free_weight: float = 0.3
    free_band_m: float = 0.04
    bone_prior_m: float = 0.05
    length_prior_m: float = 0.03
    length_from: float = 0.5
    wrist_weight: float = 3.0
    damping: float = 1e-6
    templates: bool = True


#: a model config's ``fit_settings`` part -> the settings it changes
SETTINGS = {"probe": ProbeFitSettings, "hand": HandFitSettings}


def check_fit_settings(value: Any, asked: tuple[str, ...], name: str = "model.fit_settings") -> dict:
    """A model config's ``fit_settings``, checked where the config enters: None, or a mapping from a fit the model
    asks for (``asked``: "probe", "hand") to the fields of its settings (:class:`ProbeFitSettings`,
    :class:`HandFitSettings`) the model changes, each a number of its default's kind (a whole number where the
    default is one), >= 0, or two for ``trim_m``, or true / false where the default is a bool.

    Returns:
        the plain form a model's saved config holds: {part: {field: value}}, parts and fields sorted, pairs as
        lists; {} for None.

    Raises:
        BadValueError: naming the part or field (``model.fit_settings.hand.iterations``) and what it must be.
    """
    if value is None:
        return {}
    if not isinstance(value, Mapping) or any(part not in asked for part in value):
        raise BadValueError(f"{name} must map a fit the model runs ({', '.join(asked) or 'none'}) to the settings it "
                            f"changes, got {value!r}")
    out = {}
    for part in sorted(value):
        changes, kind = value[part], SETTINGS[part]
        known = {f.name: getattr(kind(), f.name) for f in fields(kind)}
        if not isinstance(changes, Mapping) or any(field not in known for field in changes):
            raise BadValueError(f"{name}.{part} must map fields of {kind.__name__} ({', '.join(known)}) to values, "
                                f"got {changes!r}")
        out[part] = {field: _checked(changes[field], known[field], f"{name}.{part}.{field}")
                     for field in sorted(changes)}
        try:
            replace(kind(), **out[part])
        except AssertionError:
            raise BadValueError(f"{name}.{part}: {out[part]} do not fit together (see {kind.__name__})") from None
    return {part: {field: list(v) if isinstance(v, tuple) else v for field, v in c.items()}
            for part, c in out.items()}


def _checked(value: Any, default: Any, name: str) -> Any:
    """One field's value, of its default's kind."""
    if isinstance(default, bool):
        return check_bool(value, name)
    if isinstance(default, tuple):
        pair = list(value) if isinstance(value, Sequence) and not isinstance(value, str) else []
        if len(pair) != len(default) or not all(is_number(v) and v >= 0 for v in pair):
            raise BadValueError(f"{name} must be {len(default)} finite numbers >= 0, got {value!r}")
        return tuple(float(v) for v in pair)
    if isinstance(default, int):
        return check_int(value, name, 0)
    return check_number(value, name, 0.0)


def model_fit_settings(model_config: dict) -> tuple[ProbeFitSettings, HandFitSettings]:
    """The settings a model's fits run with: the defaults with its saved config's ``fit_settings`` changes
    (:func:`check_fit_settings`; a config without the field, as every model file before it: the defaults)."""
    from hupbench.fits import fits

    changes = check_fit_settings(model_config.get("fit_settings"), fits(model_config))
    return tuple(replace(kind(), **{f: tuple(v) if isinstance(v, list) else v
                                    for f, v in changes.get(part, {}).items()})
                 for part, kind in SETTINGS.items())
