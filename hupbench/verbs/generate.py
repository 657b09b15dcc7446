"""``hupbench generate``: render the dataset; ``hupbench verify``: re-check one."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from hupbench.config import build
from hupbench.provenance import run_info
from datagen.errors import BadValueError, MissingFileError


def run_generate(cfg: DictConfig, log=print) -> dict:
    """Validate the config, make the grasps if needed, and render (or resume) the dataset.

    Args:
        cfg: the composed ``generate`` config.

    Returns:
        :func:`datagen.dataset.writer.generate`'s dict.
    """
    from datagen.assets.backgrounds import BackgroundSet
    from datagen.dataset.writer import check_output_dir, check_workers, generate, parse_shard, run_lock
    from datagen.dataset.ray_launcher import check_launcher

    # everything that can be wrong with the config fails here, before any rendering
    spec = build(cfg.dataset)
    parse_shard(cfg.shard)
    check_launcher(cfg.launcher)
    check_workers(cfg.workers, cfg.launcher)
    ray_options = build(cfg.ray)
    if cfg.backgrounds.dir is not None:
        BackgroundSet.from_dir(cfg.backgrounds.dir)
    out_dir = Path(cfg.out_dir)
    check_output_dir(out_dir)
    grasps_path = Path(cfg.grasps_path) if cfg.grasps_path else out_dir / "grasps" / "grasps.npz"
    make_grasps = cfg.grasps_path is None and not grasps_path.is_file()
    if make_grasps:
        from hupbench.config import compose

        grasps_cfg = compose("grasps", [f"out_dir={out_dir / 'grasps'}"])
        n_grasps = grasps_cfg.generate.n_select
        if spec.splits is not None and sum(spec.splits.values()) != n_grasps:
            raise BadValueError(f"splits {spec.splits} add up to {sum(spec.splits.values())} grasps but the default "
                             f"grasps config selects {n_grasps}")
    elif grasps_path.is_dir():
        raise BadValueError(f"grasps_path {grasps_path} is a folder; expected a grasps .npz file (as `hupbench grasps` "
                         f"writes)")
    elif not grasps_path.is_file():
        raise MissingFileError(f"grasps_path {grasps_path} not found (run `hupbench grasps` or set grasps_path=null)")
    resolved = OmegaConf.to_container(cfg, resolve=True)
    resolved["_provenance"] = {k: v for k, v in run_info({}).items() if k != "config"}
    # one run per folder (or shard), from the default grasps to the manifest
    with run_lock(out_dir, cfg.shard) as lock:
        if make_grasps and not grasps_path.is_file():
            from hupbench.verbs.grasps import run_grasps

            log(f"no grasps given: generating the default {n_grasps} grasps into {grasps_path.parent}")
            run_grasps(grasps_cfg, log=log)
        return generate(spec, out_dir, grasps_path, resolved, backgrounds_dir=cfg.backgrounds.dir,
                        workers=cfg.workers, shard=cfg.shard, platform=cfg.render.platform, progress=cfg.progress,
                        log=log, launcher=cfg.launcher, ray=ray_options, lock=lock)


def run_verify(dataset: str | Path, workers: int = 2, log=print, progress: bool | None = None) -> dict:
    """Verify a dataset folder (see :mod:`datagen.dataset.verify`: what stops it, what it reports).

    Args:
        dataset: the dataset folder. workers: processes for the per-frame checks (>= 1).
        log: progress lines. progress: a progress bar with ETA (None: when stderr is a terminal).

    Returns:
        :func:`datagen.dataset.verify.verify`'s dict.
    """
    from datagen.dataset.verify import verify

    return verify(dataset, workers=workers, log=log, progress=progress)
