"""``hupbench grasps``: synthesise, score and select grasps; write grasps.npz, grasps.json and a contact sheet."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from datagen.io import save_npz, write_json
from hupbench.config import build
from hupbench.provenance import run_info


def run_grasps(cfg: DictConfig, log=print) -> dict:
    """Run the grasp generator.

    Args:
        cfg: the composed ``grasps`` config.
        log: progress printer.

    Returns:
        dict with the output paths, counts and timings.
    """
    from datagen.render.draw import write_png
    from datagen.grasps.synthesis import (check_run_options, check_selection, generate_candidates, grasp_arrays,
                                          scores_json, select_grasps, take_rows)
    from datagen.grasps.sheet import contact_sheet
    from datagen.assets.hand import build_hand
    from datagen.assets.probe import build_probe

    import torch

    gen_config = build(cfg.generate)
    refine_config = build(cfg.refine)
    # what would fail after minutes of refinement fails here (also for `hupbench generate`'s default grasps)
    check_selection(gen_config)
    check_run_options(cfg.threads, cfg.sheet.tile_px, cfg.sheet.platform, cfg.out_dir)
    # CPU results are bit-reproducible only at a fixed thread count
    torch.set_num_threads(cfg.threads)
    start = time.perf_counter()
    out_dir = Path(cfg.out_dir)
    log(f"generating {len(gen_config.theta_vol_deg)} x {gen_config.starts_per_theta} candidates "
        f"({gen_config.sampler} sampler)")
    candidates = generate_candidates(gen_config, refine_config=refine_config, log=log)
    scores = candidates["scores"]
    ids = select_grasps(candidates, build_hand(), gen_config.n_select, gen_config.seed, gen_config.pinned_ids)
    all_ids = np.arange(len(candidates["grasps"]))
    candidate_arrays = grasp_arrays(candidates, all_ids, gen_config, build_probe())
    arrays = take_rows(candidate_arrays, ids)
    save_npz(out_dir / "candidates.npz", candidate_arrays)
    npz = save_npz(out_dir / "grasps.npz", arrays)
    summary = scores_json(arrays, gen_config)
    summary["candidates"] = {"total": len(all_ids), "plausible": int(scores["plausible"].sum()),
                             "refine_seconds": round(candidates["seconds"], 1)}
    js = write_json(out_dir / "grasps.json", summary)
    log(f"rendering the contact sheet of {len(ids)} grasps")
    sheet = write_png(out_dir / "contact_sheet.png", contact_sheet(arrays, cfg.sheet.tile_px, cfg.sheet.platform))
    seconds = time.perf_counter() - start
    write_json(out_dir / "run.json", run_info(cfg, verb="grasps", seconds=seconds))
    return {"grasps_npz": str(npz), "grasps_json": str(js), "contact_sheet": str(sheet),
            "candidates": len(all_ids), "plausible": int(scores["plausible"].sum()), "selected": len(ids),
            "seconds": seconds}


def run_train_grasp_sampler(cfg: DictConfig, log=print) -> dict:
    """Make the refinement corpus and train the grasp CVAE (``hupbench train-grasp-sampler``).

    Args:
        cfg: the composed ``train_grasp_sampler`` config.

    Returns:
        dict with the weights path, corpus size and timing.
    """
    import torch

    from datagen.grasps.cvae import SHIPPED_WEIGHTS
    from datagen.grasps.cvae_training import train_sampler
    from datagen.assets.hand import build_hand
    from datagen.assets.probe import build_probe

    # CPU results are bit-reproducible only at a fixed thread count
    torch.set_num_threads(cfg.threads)
    out = Path(cfg.out) if cfg.out else SHIPPED_WEIGHTS
    result = train_sampler(build(cfg.corpus), build(cfg.cvae), out, build_hand(), build_probe(), log=log)
    write_json(out.with_suffix(".run.json"), run_info(cfg, verb="train-grasp-sampler", seconds=result["seconds"],
                                                      corpus_size=result["corpus_size"],
                                                      n_refined=result["n_refined"]))
    return result
