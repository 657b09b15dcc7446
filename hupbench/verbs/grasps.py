"""``hupbench grasps``: synthesise, score and select grasps; write grasps.npz, grasps.json and a contact sheet.

Which grasps come out depends on the CPU's floating point (the refinement's sums round differently on
another CPU, and the selection amplifies the difference): ``hupbench generate`` renders the default grasps
shipped with hupbench (:data:`hupbench.datagen.dataset.grasps_file.DEFAULT_GRASPS`), so that every machine
makes the same default dataset.
"""

from __future__ import annotations

import time
from dataclasses import InitVar, dataclass, field
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from hupbench.core.errors import BadValueError
from hupbench.datagen.grasps.refine import RefineConfig
from hupbench.datagen.grasps.synthesis import MAX_TILE_PX, MIN_TILE_PX, GraspGenConfig, check_selection
from hupbench.core.input_checks import check_int
from hupbench.core.io import OutputLock, check_writable, save_npz, write_json
from hupbench.core.processes import check_threads
from hupbench.datagen.dataset.writer import check_platform
from hupbench.datagen.assets.patient import PatientSpec
from hupbench.datagen.assets.probe_mesh import ProbeSource
from hupbench.datagen.assets.subjects import SubjectSpec
from hupbench.config import build, build_group
from hupbench.provenance import run_info


#: what a run of ``hupbench grasps`` says first
CPU_NOTE = ("the grasps selected depend on this CPU's floating point (another CPU may select others); `hupbench "
            "generate` renders the default grasps shipped with hupbench unless given grasps_path=...")


@dataclass(frozen=True)
class GraspsRun:
    """``conf/grasps.yaml`` (``_recursive_: false``: the groups are built here, their errors named by group).

    Attributes:
        out_dir: the output folder. threads: torch CPU threads (results are reproducible at a fixed count); with
            subjects, worker processes of one torch thread each (results do not depend on their count).
        generate: what to generate. refine: the refinement.
        probe: which probe (the procedural one, or your mesh: README "Your own probe").
        subjects: None for every grasp on the tables' hand (``HandSpec()``), selected from all candidates; or
            who holds the probe (``+subjects=clinic``): one grasp per subject, refined for its own hand, with a
            patient placed under it (:mod:`hupbench.datagen.grasps.subject_grasps`).
        patient: the patient placed under each subject's grasp.
        tile_px, platform: the contact sheet's tile side (pixels) and GL platform, from ``sheet``.
    """

    out_dir: str
    threads: int = 2
    generate: GraspGenConfig = GraspGenConfig()
    refine: RefineConfig = RefineConfig()
    probe: ProbeSource = ProbeSource()
    subjects: SubjectSpec | None = None
    patient: PatientSpec = PatientSpec()
    sheet: InitVar[dict] = None
    tile_px: int = field(init=False)
    platform: str | None = field(init=False)

    def __post_init__(self, sheet) -> None:
        for group in ("generate", "refine", "subjects", "patient"):
            object.__setattr__(self, group, build_group(getattr(self, group), group))
        # its messages name probe.mesh, probe.mesh_unit, probe.align themselves
        if isinstance(self.probe, (dict, DictConfig)):
            object.__setattr__(self, "probe", build(self.probe))
        # what would fail after minutes of refinement fails here
        if self.subjects is None:  # with subjects, each subject's best grasp is kept
            check_selection(self.generate)
        check_threads(self.threads)
        sheet = sheet or {"tile_px": 200, "platform": None}
        object.__setattr__(self, "tile_px", check_int(sheet["tile_px"], "sheet.tile_px", MIN_TILE_PX, MAX_TILE_PX,
                                                      hint=" (pixels)"))
        object.__setattr__(self, "platform", check_platform(sheet["platform"], "sheet.platform"))
        out_dir = check_writable(self.out_dir, "out_dir")
        if (out_dir / "manifest.json").is_file():
            raise BadValueError(f"out_dir {out_dir} holds a finished dataset, rendered with its grasps.npz: write the "
                                "grasps elsewhere (a dataset's grasps are made by `hupbench generate`)")


def run_grasps(cfg: DictConfig, log=print) -> dict:
    """Build the ``grasps`` config and run the grasp generator (:func:`make_grasps`)."""
    return make_grasps(build(cfg), cfg, log)


def make_grasps(run: GraspsRun, cfg: DictConfig, log=print) -> dict:
    """Run the grasp generator of the built ``run`` (``cfg``, the composed config, goes into run.json); the
    output folder is this run's until it returns. Returns the output paths, counts and timings."""
    from hupbench.core.draw import write_png
    from hupbench.datagen.grasps.sheet import contact_sheet
    from hupbench.datagen.assets.probe import probe_of
    from hupbench.datagen.assets.probe_mesh import read_cached

    import torch

    # CPU results are bit-reproducible only at a fixed thread count
    torch.set_num_threads(run.threads)
    start = time.perf_counter()
    out_dir = Path(run.out_dir)
    log(CPU_NOTE)
    # beside the folder, which a refused or failed run does not create
    with OutputLock.for_file(out_dir, "grasps"):
        if run.probe.mesh is not None:
            # read and repaired first (a mesh over the face budget is refused here), then its signed distance
            faces = read_cached(run.probe.spec)[1]
            log(f"probe: {run.probe.mesh}: {len(faces):,} triangles; deriving its signed distance and regions "
                f"(minutes for thousands of triangles)")
        probe = probe_of(run.probe)
        if run.probe.mesh is not None:
            log(f"probe: {probe.mesh.extents[2] * 1000:.0f} mm long, marker "
                f"{'placed' if probe.marker_patch is not None else 'none: no surface at its spot'}")
        arrays, summary, counts = (_selected_grasps if run.subjects is None else _subject_grasps)(run, probe, log)
        npz = save_npz(out_dir / "grasps.npz", arrays)
        js = write_json(out_dir / "grasps.json", summary)
        log(f"rendering the contact sheet of {len(arrays['grasp_id'])} grasps")
        sheet = write_png(out_dir / "contact_sheet.png", contact_sheet(arrays, run.tile_px, run.platform, probe=probe))
        seconds = time.perf_counter() - start
        write_json(out_dir / "run.json", run_info(cfg, verb="grasps", seconds=seconds))
    return {"grasps_npz": str(npz), "grasps_json": str(js), "contact_sheet": str(sheet), **counts,
            "selected": len(arrays["grasp_id"]), "seconds": seconds}


def _selected_grasps(run: GraspsRun, probe, log) -> tuple[dict, dict, dict]:
    """N diverse plausible grasps (or the pinned ones) of all candidates, on the tables' hand; writes
    candidates.npz. Returns the grasps file's arrays, grasps.json's content and the counts."""
    from hupbench.datagen.grasps.synthesis import generate_candidates, grasp_arrays, scores_json, select_grasps, take_rows
    from hupbench.datagen.assets.hand import build_hand

    gen_config = run.generate
    log(f"generating {len(gen_config.theta_vol_deg)} x {gen_config.starts_per_theta} candidates "
        f"({gen_config.sampler} sampler)")
    candidates = generate_candidates(gen_config, refine_config=run.refine, log=log, probe=probe)
    scores = candidates["scores"]
    ids = select_grasps(candidates, build_hand(), gen_config.n_select, gen_config.seed, gen_config.pinned_ids)
    all_ids = np.arange(len(candidates["grasps"]))
    candidate_arrays = grasp_arrays(candidates, all_ids, gen_config, probe)
    arrays = take_rows(candidate_arrays, ids)
    save_npz(Path(run.out_dir) / "candidates.npz", candidate_arrays)
    summary = scores_json(arrays, gen_config)
    counts = {"candidates": len(all_ids), "plausible": int(scores["plausible"].sum())}
    summary["candidates"] = {"total": counts["candidates"], "plausible": counts["plausible"],
                             "refine_seconds": round(candidates["seconds"], 1)}
    return arrays, summary, counts


def _subject_grasps(run: GraspsRun, probe, log) -> tuple[dict, dict, dict]:
    """One grasp per subject of ``run.subjects``, each on its own hand with its patient. Returns the grasps file's
    arrays, grasps.json's content (with each grasp's subject and which subjects needed new starts) and the counts."""
    from hupbench.datagen.assets.subjects import draw_subjects
    from hupbench.datagen.grasps.subject_grasps import subject_grasps
    from hupbench.datagen.grasps.synthesis import scores_json

    subjects = draw_subjects(run.subjects)
    log(f"generating one grasp for each of {len(subjects)} subjects ({run.generate.starts_per_theta} starts each, "
        f"{run.generate.sampler} sampler)")
    made = subject_grasps(subjects, run.generate, run.refine, run.probe, run.patient, workers=run.threads, log=log)
    arrays = made["arrays"]
    summary = scores_json(arrays, run.generate)
    for row, sex, length, breadth in zip(summary["grasps"], arrays["subject_sex"], arrays["hand_length_mm"],
                                         arrays["hand_breadth_mm"]):
        row |= {"subject_sex": int(sex), "hand_length_mm": round(float(length), 2),
                "hand_breadth_mm": round(float(breadth), 2)}
    counts = {"candidates": made["candidates"], "plausible": made["plausible"], "retried": made["retried"]}
    summary["candidates"] = {"total": made["candidates"], "plausible": made["plausible"],
                             "retried_subjects": made["retried"], "refine_seconds": round(made["seconds"], 1)}
    return arrays, summary, counts


def run_train_grasp_sampler(cfg: DictConfig, log=print) -> dict:
    """Make the refinement corpus and train the grasp CVAE of a composed ``train_grasp_sampler`` config;
    returns the weights path, corpus size and timing."""
    import torch

    from hupbench.datagen.grasps.cvae import SHIPPED_WEIGHTS
    from hupbench.datagen.grasps.cvae_training import train_sampler
    from hupbench.datagen.assets.hand import build_hand
    from hupbench.datagen.assets.probe import build_probe

    corpus, cvae = build(cfg.corpus), build(cfg.cvae)
    # CPU results are bit-reproducible only at a fixed thread count
    torch.set_num_threads(check_threads(cfg.threads))
    out = Path(cfg.out) if cfg.out else SHIPPED_WEIGHTS
    result = train_sampler(corpus, cvae, out, build_hand(), build_probe(), log=log)
    write_json(out.with_suffix(".run.json"), run_info(cfg, verb="train-grasp-sampler", seconds=result["seconds"],
                                                      corpus_size=result["corpus_size"],
                                                      n_refined=result["n_refined"]))
    return result
