import numpy as np
import pytest

from hupbench.datagen.grasps.cvae import SHIPPED_WEIGHTS, load_shipped_cvae
from hupbench.datagen.grasps.cvae_sampling import sample_grasps
from hupbench.datagen.grasps.cvae_training import CorpusConfig
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import joint_limits_rad
from hupbench.datagen.assets.probe import build_probe


@pytest.fixture(scope="module")
def shipped():
    return load_shipped_cvae()


def test_shipped_weights_record_how_they_were_made(shipped):
    assert SHIPPED_WEIGHTS.is_file()
    _, config, meta = shipped
    assert config.latent_dim == 16 and config.n_bps == meta["bps_n"] == 1024
    assert meta["bps_radius_m"] == pytest.approx(0.15)
    assert meta["corpus_size"] > 100 and meta["n_refined"] >= meta["corpus_size"]


def test_samples_are_valid_and_reproducible(shipped):
    hand, probe = build_hand(), build_probe()
    a = sample_grasps(6, (0.0, 0.0, 90.0), probe, hand, np.random.default_rng(5), shipped)
    b = sample_grasps(6, (0.0, 0.0, 90.0), probe, hand, np.random.default_rng(5), shipped)
    c = sample_grasps(6, (0.0, 0.0, 90.0), probe, hand, np.random.default_rng(6), shipped)
    np.testing.assert_array_equal(a.trans, b.trans)
    assert not np.allclose(a.trans, c.trans)
    limits = joint_limits_rad()
    assert np.all(a.angles >= limits[..., 0] - 1e-9) and np.all(a.angles <= limits[..., 1] + 1e-9)
    np.testing.assert_allclose(a.R_global @ np.swapaxes(a.R_global, 1, 2), np.broadcast_to(np.eye(3), (6, 3, 3)),
                               atol=1e-9)
    # proposals land around the handle, not somewhere else in the scene
    wrist_to_axis = np.linalg.norm(a.trans[:, :2], axis=1)
    assert np.all(wrist_to_axis < 0.12) and np.all((a.trans[:, 2] > 0.0) & (a.trans[:, 2] < 0.2))


@pytest.mark.parametrize("fields, message", [
    (dict(n_orientations=0), "n_orientations must be a whole number >= 1, got 0"),
    (dict(bps_n=2.5), "bps_n must be a whole number >= 1, got 2.5"),
    (dict(bps_seed=-1), "bps_seed must be a whole number >= 0, got -1"),
    (dict(bps_radius_m=0.0), r"bps_radius_m must be a finite number > 0, got 0.0"),
    (dict(bps_radius_m=float("nan")), r"bps_radius_m must be a finite number > 0, got nan"),
])
def test_corpus_config_rejects_bad_values(fields, message):
    with pytest.raises(ValueError, match=message):
        CorpusConfig(**fields)
