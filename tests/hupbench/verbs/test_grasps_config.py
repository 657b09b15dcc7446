"""The per-field cases of `hupbench grasps`' bad-input matrix, as unit tests of ``GraspsRun`` (which builds its
``generate`` and ``refine`` groups and names them in an error): each answers with the line the CLI prints
(tests/hupbench/verbs/test_matrix_grasps.py keeps one case per field group through the whole CLI, and the files)."""

import pytest

from helpers.answers import assert_refusal
from hupbench.verbs.grasps import GraspsRun

#: tests/hupbench/verbs/test_matrix_grasps.py's SMALL config as the fields of the run
GENERATE = {"_target_": "hupbench.datagen.grasps.synthesis.GraspGenConfig", "theta_vol_deg": [[0, 0, 0], [0, 0, 180]],
            "starts_per_theta": 8, "sampler": "cvae", "short_refine_iterations": 5, "n_select": 1,
            "pinned_ids": None, "seed": 0}
REFINE = {"_target_": "hupbench.datagen.grasps.refine.RefineConfig", "iterations": 50}
SHEET = {"tile_px": 96, "platform": None}


def run(threads=2, generate=(), refine=(), sheet=()):
    return lambda tmp: GraspsRun(out_dir=str(tmp / "g"), threads=threads, generate={**GENERATE, **dict(generate)},
                                 refine={**REFINE, **dict(refine)}, sheet={**SHEET, **dict(sheet)})


NAN, INF = float("nan"), float("inf")
# id -> (make(tmp), the override a user types, needles); the values are what Hydra makes of the override
CASES = {
    "threads-negative": (run(threads=-2), "threads=-2", ["threads", "whole number from 1"]),
    "threads-word": (run(threads="two"), "threads=two", ["threads", "'two'"]),
    "threads-fraction": (run(threads=1.5), "threads=1.5", ["threads", "1.5"]),
    "threads-nan": (run(threads=NAN), "threads=nan", ["threads", "nan"]),
    "threads-huge": (run(threads=100000), "threads=100000", ["threads", "100000", "cpu core"]),
    "starts-per-theta-negative": (run(generate={"starts_per_theta": -4}), "generate.starts_per_theta=-4",
                                  ["starts_per_theta", "whole number >= 1"]),
    "starts-per-theta-word": (run(generate={"starts_per_theta": "many"}), "generate.starts_per_theta=many",
                              ["starts_per_theta", "'many'"]),
    "starts-per-theta-nan": (run(generate={"starts_per_theta": NAN}), "generate.starts_per_theta=nan",
                             ["starts_per_theta", "nan"]),
    "starts-per-theta-fraction": (run(generate={"starts_per_theta": 2.5}), "generate.starts_per_theta=2.5",
                                  ["starts_per_theta", "2.5"]),
    "starts-per-theta-huge": (run(generate={"starts_per_theta": 1000000000}), "generate.starts_per_theta=1000000000",
                              ["starts_per_theta", "4,096", "1,000,000,000"]),
    "n-select-zero": (run(generate={"n_select": 0}), "generate.n_select=0", ["n_select", "whole number >= 1"]),
    "n-select-negative": (run(generate={"n_select": -1}), "generate.n_select=-1", ["n_select", "whole number >= 1"]),
    "n-select-word": (run(generate={"n_select": "five"}), "generate.n_select=five", ["n_select", "'five'"]),
    "n-select-nan": (run(generate={"n_select": NAN}), "generate.n_select=nan", ["n_select", "nan"]),
    "n-select-more-than-candidates": (run(generate={"n_select": 500}), "generate.n_select=500",
                                      ["n_select", "500", "16 candidates"]),
    "short-refine-iterations-negative": (run(generate={"short_refine_iterations": -1}),
                                         "generate.short_refine_iterations=-1", ["short_refine_iterations", ">= 0"]),
    "short-refine-iterations-word": (run(generate={"short_refine_iterations": "ten"}),
                                     "generate.short_refine_iterations=ten", ["short_refine_iterations", "'ten'"]),
    "short-refine-iterations-huge": (run(generate={"short_refine_iterations": 1000000000}),
                                     "generate.short_refine_iterations=1000000000",
                                     ["short_refine_iterations", "100,000"]),
    "refine-iterations-word": (run(refine={"iterations": "lots"}), "refine.iterations=lots", ["iterations", "'lots'"]),
    "refine-iterations-nan": (run(refine={"iterations": NAN}), "refine.iterations=nan", ["iterations", "nan"]),
    "refine-iterations-bool": (run(refine={"iterations": True}), "refine.iterations=true", ["iterations", "true"]),
    "refine-iterations-huge": (run(refine={"iterations": 1000000000}, generate={"sampler": "random"}),
                               "refine.iterations=1000000000 generate.sampler=random", ["iterations", "100,000"]),
    "refine-weight-negative": (run(refine={"w_contact": -1.0}), "+refine.w_contact=-1.0", ["w_contact", ">= 0"]),
    "refine-weight-nan": (run(refine={"w_prior": NAN}), "+refine.w_prior=nan", ["w_prior", "finite"]),
    "refine-weight-inf": (run(refine={"w_penetration_end": INF}), "+refine.w_penetration_end=inf",
                          ["w_penetration_end", "finite"]),
    "refine-weight-word": (run(refine={"w_self": "heavy"}), "+refine.w_self=heavy", ["w_self", "'heavy'"]),
    "refine-lr-zero": (run(refine={"lr_joints": 0.0}), "+refine.lr_joints=0.0", ["lr_joints", "positive"]),
    "refine-clip-norm-nan": (run(refine={"clip_norm": NAN}), "+refine.clip_norm=nan", ["clip_norm", "finite"]),
    "refine-min-contact-z-nan": (run(refine={"min_contact_z_m": NAN}), "+refine.min_contact_z_m=nan",
                                 ["min_contact_z_m", "finite"]),
    "refine-min-contact-z-word": (run(refine={"min_contact_z_m": "low"}), "+refine.min_contact_z_m=low",
                                  ["min_contact_z_m", "'low'"]),
    "seed-negative": (run(generate={"seed": -1}), "generate.seed=-1", ["seed", "-1"]),
    "seed-word": (run(generate={"seed": "abc"}), "generate.seed=abc", ["seed", "'abc'"]),
    "seed-nan": (run(generate={"seed": NAN}), "generate.seed=nan", ["seed", "nan"]),
    "seed-fraction": (run(generate={"seed": 0.5}), "generate.seed=0.5", ["seed", "0.5"]),
    "seed-huge": (run(generate={"seed": 100000000000000000000000}), "generate.seed=100000000000000000000000",
                  ["seed", "4294967295"]),
    "theta-empty": (run(generate={"theta_vol_deg": []}), "generate.theta_vol_deg=[]",
                    ["theta_vol_deg", "alpha, beta, gamma"]),
    "theta-two-angles": (run(generate={"theta_vol_deg": [[0, 0]]}), "generate.theta_vol_deg=[[0,0]]",
                         ["theta_vol_deg", "(1, 2)"]),
    "theta-word": (run(generate={"theta_vol_deg": [[0, 0, "up"]]}), "generate.theta_vol_deg=[[0,0,up]]",
                   ["theta_vol_deg", "'up'"]),
    "theta-nan": (run(generate={"theta_vol_deg": [[0, 0, NAN]]}), "generate.theta_vol_deg=[[0,0,nan]]",
                  ["theta_vol_deg", "finite"]),
    "theta-not-nested": (run(generate={"theta_vol_deg": [0, 0, 0]}), "generate.theta_vol_deg=[0,0,0]",
                         ["theta_vol_deg", "list of"]),
    "theta-huge": (run(generate={"theta_vol_deg": [[0, 0, 1e9]]}), "generate.theta_vol_deg=[[0,0,1e9]]",
                   ["theta_vol_deg", "[-360, 360]"]),
    "sampler-unknown": (run(generate={"sampler": "diffusion"}), "generate.sampler=diffusion", ["sampler", "diffusion"]),
    "pinned-ids-out-of-range": (run(generate={"pinned_ids": [0, 999]}), "generate.pinned_ids=[0,999]",
                                ["pinned_ids", "[999]", "0..15"]),
    "pinned-ids-negative": (run(generate={"pinned_ids": [-1]}), "generate.pinned_ids=[-1]",
                            ["pinned_ids", "[-1]", "0..15"]),
    "pinned-ids-empty": (run(generate={"pinned_ids": []}), "generate.pinned_ids=[]", ["pinned_ids", "non-empty"]),
    "pinned-ids-word": (run(generate={"pinned_ids": ["a"]}), "generate.pinned_ids=[a]", ["pinned_ids", "'a'"]),
    "pinned-ids-duplicate": (run(generate={"pinned_ids": [1, 1]}), "generate.pinned_ids=[1,1]",
                             ["pinned_ids", "unique"]),
    "pinned-ids-not-a-list": (run(generate={"pinned_ids": 3}), "generate.pinned_ids=3", ["pinned_ids", "list"]),
    "sheet-tile-negative": (run(sheet={"tile_px": -10}), "sheet.tile_px=-10", ["sheet.tile_px", "32 to 4096"]),
    "sheet-tile-huge": (run(sheet={"tile_px": 100000}), "sheet.tile_px=100000", ["sheet.tile_px", "100000"]),
    "sheet-tile-word": (run(sheet={"tile_px": "big"}), "sheet.tile_px=big", ["sheet.tile_px", "'big'"]),
    "sheet-platform-unknown": (run(sheet={"platform": "vulkan"}), "sheet.platform=vulkan",
                               ["sheet.platform", "vulkan"]),
}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_grasps(case, tmp_path):
    make, given, needles = CASES[case]
    assert_refusal(lambda: make(tmp_path), *needles, prog="hupbench grasps", given=given)
    assert list(tmp_path.iterdir()) == []  # nothing created


def test_the_run_builds_its_groups(tmp_path):
    built = run()(tmp_path)
    assert (built.generate.n_select, built.refine.iterations, built.tile_px, built.platform) == (1, 50, 96, None)
