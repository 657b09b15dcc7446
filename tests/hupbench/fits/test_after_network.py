"""hupbench.fits: what a model asks to run after its network, the probe the fits know, and the settings each fit
takes as an argument (a variant without touching module state)."""

import re
import types
from dataclasses import FrozenInstanceError, replace

import numpy as np
import pytest

from hupbench.core import keypoints as kp
from hupbench.core.errors import BadValueError
from hupbench.fits import (
    FITTED_PROBE,
    HandFitSettings,
    ProbeFitSettings,
    after_network,
    check_fitted_probe,
    fits,
    track_fits,
)

MESH_PROBE = {"kind": "mesh", "path": "/data/probes/linear.stl", "unit": "m", "align": False, "sha256": "0" * 64,
              "geometry_sha256": "0" * 64}


@pytest.mark.parametrize(("config", "asked"), [
    ({"name": "hupnet"}, ()), ({"probe_fit": "none", "hand_fit": "none"}, ()), ({"hand_fit": "depth"}, ("hand",)),
    ({"hand_fit": "depth", "probe_fit": "depth"}, ("probe", "hand"))])
def test_what_a_model_asks_for_in_the_order_it_runs(config, asked):
    assert fits(config) == asked


@pytest.mark.parametrize("record", [None, FITTED_PROBE, {"kind": "procedural"}])
def test_the_default_probe_is_the_fits_probe(record):
    check_fitted_probe({"probe_fit": "depth", "hand_fit": "depth"}, record, "DATASET/manifest.json")


@pytest.mark.parametrize(("record", "shown"), [
    (MESH_PROBE, "'/data/probes/linear.stl' (mesh)"),
    ({"kind": "procedural", "spec": {"length_m": 0.2}}, "{'length_m': 0.2} (procedural)")])
def test_another_probe_is_refused_for_a_model_that_fits_and_accepted_for_one_that_does_not(record, shown):
    with pytest.raises(BadValueError) as info:
        check_fitted_probe({"hand_fit": "depth"}, record, "DATASET/manifest.json")
    assert str(info.value) == (f"DATASET/manifest.json: the data shows the probe {shown}, but the model's hand fit "
                               "(probe_fit/hand_fit: depth) knows only the default procedural probe; use a model "
                               "without the fits on this data")
    check_fitted_probe({"name": "hupnet"}, record, "DATASET/manifest.json")


def test_a_model_file_s_own_probe_is_the_one_its_fits_accept():
    """A model whose file carries a mesh probe fits that probe's data and refuses the default probe's."""
    from dataclasses import replace as changed

    from hupbench.fits.known_probe import default_fit_probe

    own = changed(default_fit_probe(), record=MESH_PROBE)
    check_fitted_probe({"probe_fit": "depth"}, MESH_PROBE, "DATASET/manifest.json", own)
    with pytest.raises(BadValueError) as info:
        check_fitted_probe({"probe_fit": "depth"}, None, "DATASET/manifest.json", own)
    assert str(info.value) == ("DATASET/manifest.json: the data shows the probe 'procedural' (procedural), but the "
                               "model's probe fit (probe_fit/hand_fit: depth) knows only the probe "
                               "'/data/probes/linear.stl' (mesh) of its model file; use a model without the fits on "
                               "this data")


def test_settings_are_frozen_values_with_the_defaults_every_model_runs_with():
    with pytest.raises(FrozenInstanceError):
        HandFitSettings().free_weight = 0.0
    variant = replace(HandFitSettings(), free_weight=0.0)
    assert variant.free_weight == 0.0 and HandFitSettings().free_weight == 0.3
    assert ProbeFitSettings().hypotheses == 12 and ProbeFitSettings() == ProbeFitSettings()


def test_after_network_passes_each_fit_its_settings(monkeypatch):
    from hupbench.fits import hand_fit, probe_fit

    seen = []

    def stand_in(part):
        def fit(points2d, points3d, images, K_input, settings, probe, pixels, **start):
            seen.append((part, settings, probe, *start.values()))
            return points2d, points3d + 1.0, types.SimpleNamespace(pose=None)
        return fit

    monkeypatch.setattr(probe_fit, "fit_probe", stand_in("probe"))
    monkeypatch.setattr(hand_fit, "fit_hand", stand_in("hand"))
    probe, hand = ProbeFitSettings(min_inliers=5), HandFitSettings(iterations=3)
    points2d, points3d = np.zeros((1, kp.NUM_KEYPOINTS, 2), np.float32), np.zeros((1, kp.NUM_KEYPOINTS, 3))
    # the hand's fit gets the model's training hands (its start), where the model file has them
    config = {"probe_fit": "depth", "hand_fit": "depth", "hand_templates": "the file's hands"}
    out2d, out3d = after_network(config, points2d, points3d, np.zeros((1, 4, 8, 8), np.float32), np.eye(3), probe,
                                 hand, fitted="the file's")
    assert seen == [("probe", probe, "the file's", None), ("hand", hand, "the file's", "the file's hands")]
    assert out2d.dtype == out3d.dtype == np.float64 and (out3d == 2.0).all()
    # tracking: the probe's fit gets the start, the hand's its tracking steps
    seen.clear()
    track_fits({"probe_fit": "depth", "hand_fit": "depth"}, points2d, points3d, np.zeros((1, 4, 8, 8), np.float32),
               np.eye(3), "the start", probe, hand, fitted="the file's")
    assert seen == [("probe", probe, "the file's", "the start"),
                    ("hand", replace(hand, iterations=hand.tracking_iterations), "the file's", None)]
    assert hand.iterations != hand.tracking_iterations



def test_a_model_s_own_fit_settings_run_unless_a_caller_passes_others(monkeypatch):
    """A config's ``fit_settings`` (chosen on its track's val split, saved in its model file) are what eval, predict and
    tracking run; a script's variant passed as an argument replaces them; a config without them runs the defaults."""
    from hupbench.fits import hand_fit, model_fit_settings, probe_fit

    seen = []

    def stand_in(part):
        def fit(points2d, points3d, images, K_input, settings, probe, pixels, **start):
            seen.append((part, settings))
            return points2d, points3d, types.SimpleNamespace(pose=None)
        return fit

    monkeypatch.setattr(probe_fit, "fit_probe", stand_in("probe"))
    monkeypatch.setattr(hand_fit, "fit_hand", stand_in("hand"))
    config = {"probe_fit": "depth", "hand_fit": "depth",
              "fit_settings": {"hand": {"iterations": 16, "bone_prior_m": 0.02, "trim_m": [0.01, 0.005]}}}
    own = replace(HandFitSettings(), iterations=16, bone_prior_m=0.02, trim_m=(0.01, 0.005))
    assert model_fit_settings(config) == (ProbeFitSettings(), own)
    frame = (np.zeros((1, kp.NUM_KEYPOINTS, 2)), np.zeros((1, kp.NUM_KEYPOINTS, 3)), np.zeros((1, 4, 8, 8)),
             np.eye(3))
    after_network(config, *frame)
    assert seen == [("probe", ProbeFitSettings()), ("hand", own)]
    seen.clear()
    track_fits(config, *frame, None)
    assert seen == [("probe", ProbeFitSettings()), ("hand", replace(own, iterations=own.tracking_iterations))]
    seen.clear()
    after_network(config, *frame, hand=HandFitSettings(iterations=3))
    after_network({"probe_fit": "depth", "hand_fit": "depth"}, *frame)
    assert seen == [("probe", ProbeFitSettings()), ("hand", HandFitSettings(iterations=3)),
                    ("probe", ProbeFitSettings()), ("hand", HandFitSettings())]


@pytest.mark.parametrize(("settings", "message"), [
    ({"probe": {"iterations": 3}}, "model.fit_settings must map a fit the model runs (hand) to the settings it changes, "
                                   "got {'probe': {'iterations': 3}}"),
    ({"hand": {"iterationz": 3}}, "model.fit_settings.hand must map fields of HandFitSettings (palm_radius_m, "),
    ({"hand": {"iterations": 2.5}}, "model.fit_settings.hand.iterations must be a whole number >= 0, got 2.5"),
    ({"hand": {"bone_prior_m": -0.1}}, "model.fit_settings.hand.bone_prior_m must be a finite number >= 0, got -0.1"),
    ({"hand": {"trim_m": [0.01]}}, "model.fit_settings.hand.trim_m must be 2 finite numbers >= 0, got [0.01]"),
    ({"hand": {"bone_prior_m": float("nan")}}, "model.fit_settings.hand.bone_prior_m must be a finite number >= 0"),
    ({"hand": {"templates": 1}}, "model.fit_settings.hand.templates must be true or false, got 1"),
    ("16", "model.fit_settings must map a fit the model runs (hand) to the settings it changes, got '16'")])
def test_a_model_config_s_fit_settings_are_checked_where_the_config_is_built(settings, message, tmp_path):
    """A training config's, when it is built (the run folder is not made), and a saved config's, when the fits read
    it (a model file edited by hand)."""
    from omegaconf import OmegaConf, open_dict

    from hupbench.config import compose
    from hupbench.fits import model_fit_settings
    from hupbench.training.run_config import train_config

    cfg = compose("train", ["model=hupnet_handfit", "model.probe_fit=none", f"run_dir={tmp_path / 'run'}"])
    OmegaConf.set_readonly(cfg, False)
    with open_dict(cfg):
        cfg.model.fit_settings = settings
    with pytest.raises(BadValueError, match="^" + re.escape(message)):
        train_config(cfg)
    assert not (tmp_path / "run").exists()
    with pytest.raises(BadValueError, match="^" + re.escape(message)):
        model_fit_settings({"hand_fit": "depth", "fit_settings": settings})
