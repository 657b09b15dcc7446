"""``hupbench generate``: render the dataset."""

from __future__ import annotations

import re
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from hupbench.datagen.dataset.writer import GenerateRun
from hupbench.core.errors import BadValueError
from hupbench.config import build
from hupbench.provenance import run_provenance


def resolved_config(cfg: DictConfig) -> dict:
    """The config a dataset records in its manifest: the composed one, resolved, with the run's provenance."""
    resolved = OmegaConf.to_container(cfg, resolve=True)
    del resolved["_target_"]
    resolved["_provenance"] = run_provenance()
    return resolved


def quoted(path) -> str:
    """``path`` as a Hydra override's value, which may hold '=', ',', brackets, quotes or spaces: quoted as the
    override grammar reads a quoted value (a quote escaped, a backslash doubled only where it precedes a quote
    or the closing one; other backslashes are taken as they stand); None as null."""
    return "null" if path is None else "'" + re.sub(r"(\\+)(?='|$)", r"\1\1", str(path)).replace("'", "\\'") + "'"


def probe_overrides(mesh, mesh_unit: str = "m", align: bool = False) -> list[str]:
    """The overrides that name a probe in a config with a ``probe`` node (``conf/grasps.yaml``,
    ``conf/generate.yaml``): ``mesh`` a path or None (null, the procedural probe)."""
    return [f"probe.mesh={quoted(mesh)}", f"probe.mesh_unit={mesh_unit}", f"probe.align={str(align).lower()}"]


def run_generate(cfg: DictConfig, log=print) -> dict:
    """Build the ``generate`` config and render (or resume) its dataset (:func:`generate_dataset`)."""
    return generate_dataset(build(cfg), resolved_config(cfg), log)


def generate_dataset(run: GenerateRun, resolved: dict, log=print) -> dict:
    """Render (or resume) the dataset of the built ``run`` from its grasps file (:attr:`GenerateRun.grasps_file`):
    the one given, the default grasps shipped with hupbench, or, for a probe mesh without ``grasps_path``,
    grasps made for the mesh into ``OUT_DIR/grasps`` first (``conf/grasps.yaml`` with the run's probe).
    ``resolved`` (:func:`resolved_config`) goes into the manifest. Returns
    :func:`hupbench.datagen.dataset.writer.generate`'s dict."""
    from hupbench.datagen.assets.backgrounds import BackgroundSet
    from hupbench.datagen.dataset.writer import check_grasps_file, generate, run_lock

    # a bad photographs' folder fails before the folder is taken (and the grasps take minutes)
    if run.job.backgrounds_dir is not None:
        BackgroundSet.from_dir(run.job.backgrounds_dir)
    grasps_path = run.grasps_file
    make_grasps = run.makes_grasps and not grasps_path.is_file()
    if make_grasps:
        from hupbench.config import compose

        probe = run.probe
        grasps_cfg = compose("grasps", [f"out_dir={quoted(grasps_path.parent)}",
                                        *probe_overrides(probe.mesh, probe.mesh_unit, probe.align)])
        n_grasps = grasps_cfg.generate.n_select
        splits = run.dataset.splits
        if splits is not None and sum(splits.values()) != n_grasps:
            raise BadValueError(f"splits {splits} add up to {sum(splits.values())} grasps but the default grasps "
                                f"config selects {n_grasps}")
    else:
        # a bad file, grasps made for another probe or splits that count other grasps fail before the folder is taken
        check_grasps_file(run)
    # one run per folder (or shard), from the grasps to the manifest
    with run_lock(Path(run.out_dir), run.job.shard) as lock:
        if make_grasps and not grasps_path.is_file():
            from hupbench.verbs.grasps import run_grasps

            log(f"no grasps given for probe.mesh: generating {n_grasps} grasps for it into {grasps_path.parent}")
            run_grasps(grasps_cfg, log=log)
        return generate(run, resolved, log, lock)
