"""The per-field cases of `hupbench generate`'s bad-input matrix, as unit tests of its config classes
(``GenerateRun``, its ``RenderJob``, ``DatasetSpec`` and ``SphereSpec``): each answers with the line the CLI
prints (tests/hupbench/verbs/test_matrix_generate.py keeps one case per field group through the whole CLI)."""

import pytest

from hupbench.datagen.dataset.spec import DatasetSpec
from hupbench.datagen.dataset.sphere import SphereSpec
from helpers.answers import assert_refusal
from hupbench.datagen.dataset.writer import GenerateRun

from helpers.datasets import TINY_SPEC  # noqa: E402  (tests/ is on sys.path)


def run(**fields):
    return lambda tmp: GenerateRun(**{"dataset": DatasetSpec(**TINY_SPEC), "out_dir": str(tmp / "ds"), "workers": 1,
                                      "progress": False, **fields})


def dataset(**fields):
    return lambda tmp: DatasetSpec(**{**TINY_SPEC, **fields})


def sphere(**fields):
    return lambda tmp: SphereSpec(**{"r_circ_m": 0.4, "exclude": ["poles"], **fields})


# id -> (make(tmp), the override a user types, needles); the values are what Hydra makes of the override
CASES = {
    "workers-negative": (run(workers=-1), "workers=-1", ["workers", ">= 1"]),
    "workers-word": (run(workers="two"), "workers=two", ["workers", ">= 1", "two"]),
    "workers-fraction": (run(workers=1.5), "workers=1.5", ["workers", ">= 1"]),
    "workers-huge": (run(workers=100000), "workers=100000", ["workers", "100000"]),
    "shard-1-of-0": (run(shard="1/0"), "shard=1/0", ["shard", "0 <= k < n"]),
    "shard-x-of-y": (run(shard="x/y"), "shard=x/y", ["shard", "k/n"]),
    "shard-negative": (run(shard="-1/2"), "shard=-1/2", ["shard", "0 <= k < n"]),
    "shard-three-parts": (run(shard="1/2/3"), "shard=1/2/3", ["shard", "k/n"]),
    "launcher-unknown": (run(launcher="slurm"), "launcher=slurm", ["launcher", "slurm"]),
    "platform-unknown": (run(render={"platform": "vulkan"}), "render.platform=vulkan", ["platform", "vulkan"]),
    "progress-not-a-bool": (run(progress="maybe"), "progress=maybe", ["progress", "maybe"]),
    "z-ego-zero": (dataset(z_ego_m=[0.0]), "dataset.z_ego_m=[0.0]", ["z_ego_m"]),
    "z-ego-nan": (dataset(z_ego_m=[float("nan")]), "dataset.z_ego_m=[nan]", ["z_ego_m"]),
    "z-ego-inf": (dataset(z_ego_m=[float("inf")]), "dataset.z_ego_m=[inf]", ["z_ego_m"]),
    "z-ego-huge": (dataset(z_ego_m=[1e9]), "dataset.z_ego_m=[1e9]", ["z_ego_m", "10"]),
    "z-ego-tiny": (dataset(z_ego_m=[0.001]), "dataset.z_ego_m=[0.001]", ["z_ego_m", "0.1"]),
    "z-ego-word": (dataset(z_ego_m=["far"]), "dataset.z_ego_m=[far]", ["z_ego_m", "far"]),
    "z-ego-empty": (dataset(z_ego_m=[]), "dataset.z_ego_m=[]", ["z_ego_m"]),
    "z-ego-not-a-list": (dataset(z_ego_m=0.5), "dataset.z_ego_m=0.5", ["z_ego_m"]),
    "jpeg-quality-101": (dataset(jpeg_quality=101), "dataset.jpeg_quality=101", ["jpeg_quality", "from 0 to 100"]),
    "jpeg-quality-negative": (dataset(jpeg_quality=-1), "dataset.jpeg_quality=-1", ["jpeg_quality", "from 0 to 100"]),
    "jpeg-quality-word": (dataset(jpeg_quality="high"), "dataset.jpeg_quality=high", ["jpeg_quality", "high"]),
    "width-huge": (dataset(width=100000, cx=50000.0), "dataset.width=100000 dataset.cx=50000.0", ["width", "100000"]),
    "width-word": (dataset(width="wide"), "dataset.width=wide", ["width", "wide"]),
    "height-negative": (dataset(height=-64), "dataset.height=-64", ["height", "from 16 to 8192"]),
    "fx-zero": (dataset(fx=0.0), "dataset.fx=0.0", ["fx", "positive"]),
    "fx-nan": (dataset(fx=float("nan")), "dataset.fx=nan", ["fx", "finite"]),
    "cx-inf": (dataset(cx=float("inf")), "dataset.cx=inf", ["cx", "finite"]),
    "cx-outside-the-image": (dataset(cx=-5000.0), "dataset.cx=-5000", ["dataset.cx", "inside the image", "-5000"]),
    "rgb-format-bmp": (dataset(rgb_format="bmp"), "dataset.rgb_format=bmp", ["rgb_format", "bmp"]),
    "modalities-unknown": (dataset(modalities=["rgb", "thermal"]), "dataset.modalities=[rgb,thermal]",
                           ["modality", "thermal"]),
    "modalities-empty": (dataset(modalities=[]), "dataset.modalities=[]", ["modality"]),
    "seed-negative": (dataset(seed=-1), "dataset.seed=-1", ["seed", "-1"]),
    "seed-word": (dataset(seed="abc"), "dataset.seed=abc", ["seed", "abc"]),
    "look-at-unknown": (dataset(look_at="elbow"), "dataset.look_at=elbow", ["look_at", "elbow"]),
    "sphere-variant-unknown": (sphere(variant="round"), "dataset.sphere.variant=round", ["variant", "round"]),
    "sphere-exclude-unknown": (sphere(exclude=["knees"]), "dataset.sphere.exclude=[knees]", ["exclude", "knees"]),
    "n-backgrounds-zero": (dataset(n_backgrounds=0), "dataset.n_backgrounds=0", ["n_backgrounds", ">= 1"]),
    "n-gloves-three": (dataset(n_gloves=3), "dataset.n_gloves=3", ["n_gloves", "3"]),
    "splits-negative": (dataset(splits={"train": 3, "val": -1, "test": 0}), "dataset.splits={train:3,val:-1,test:0}",
                        ["splits", ">= 0"]),
}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_generate(case, tmp_path):
    make, given, needles = CASES[case]
    assert_refusal(lambda: make(tmp_path), *needles, prog="hupbench generate", given=given)
    assert list(tmp_path.iterdir()) == []  # nothing created


def test_the_run_builds_its_render_job():
    built = GenerateRun(DatasetSpec(**TINY_SPEC), "ds", workers=2, shard="1/2", render={"platform": "osmesa"},
                        backgrounds={"dir": "photos"})
    job = built.job
    assert (job.workers, job.k, job.n, job.platform, job.backgrounds_dir) == (2, 1, 2, "osmesa", "photos")
    assert built.grasps_path is None and built.progress is True


def test_grasps_for_a_probe_mesh_are_made_where_the_run_names(tmp_path, monkeypatch):
    """generate hands out_dir and probe.mesh to the grasps it makes for a mesh as given, in a folder whose name
    holds a quote, '=', ',', a backslash and a space (unquoted, '=' or ',' broke the override)."""
    from hupbench.datagen.assets.probe_mesh import ProbeSource, linear_probe_mesh
    from hupbench.verbs.generate import generate_dataset

    folder = tmp_path / "it's a=b,c\\d"
    folder.mkdir()
    stl = folder / "linear.stl"
    linear_probe_mesh().export(stl)
    asked = []

    class Stop(Exception):
        """Stops generate where it would make the grasps: only the grasps run's config is looked at."""

    def grasps_run(cfg, log=print):
        asked.append((cfg.out_dir, cfg.probe.mesh))
        raise Stop

    monkeypatch.setattr("hupbench.verbs.grasps.run_grasps", grasps_run)
    run = GenerateRun(DatasetSpec(**{**TINY_SPEC, "splits": {"train": 7, "val": 2, "test": 2}}), str(folder / "ds"),
                      probe=ProbeSource(str(stl)), workers=1, progress=False)
    with pytest.raises(Stop):
        generate_dataset(run, {"test": "quoted"}, log=lambda *_: None)
    assert asked == [(str(folder / "ds" / "grasps"), str(stl))]
