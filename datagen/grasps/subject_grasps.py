"""One grasp per subject, each refined for the subject's own hand and kept only when a patient fits under it.

For subject ``i`` the candidates come from one probe orientation, ``theta_vol_deg[i % len(theta_vol_deg)]``,
and ``starts_per_theta`` starts on the subject's hand (:func:`hupbench.datagen.grasps.synthesis.generate_candidates`),
scored with the same plausibility scores; the plausible ones are tried in order of their refinement energy, and
the first that admits a patient placement (:func:`hupbench.datagen.assets.patient.place_patient`: the lens on
the skin, no hand or forearm vertex deep in the body) is the subject's grasp. A subject with none gets new starts
(another seed), up to :data:`MAX_ATTEMPTS` rounds.

Each subject is made with one torch thread, in one of ``workers`` processes: a subject's grasp does not depend
on how many workers share the subjects (torch's CPU results depend on its thread count).

Convention:
    Probe frame (the renderer's world), metres, as :mod:`hupbench.datagen.grasps.synthesis`.
"""

from __future__ import annotations

import multiprocessing
import time
from dataclasses import replace

import numpy as np

from hupbench.core.errors import BadValueError
from hupbench.core.geometry import axis_angle_to_matrix, matrix_to_axis_angle
from hupbench.datagen.assets.arm import forearm_mesh
from hupbench.datagen.assets.hand_anatomy import anatomical_to_pose
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.patient import PatientSpec, place_patient, placement_arrays
from hupbench.datagen.assets.subjects import Subject
from hupbench.datagen.grasps.synthesis import MAX_SEED, GraspGenConfig, generate_candidates, grasp_arrays
from hupbench.datagen.assets.probe_mesh import PROBE_MESH_FIELDS
from hupbench.datagen.grasps.refine import RefineConfig
from hupbench.datagen.render.scene import models_of

#: rounds of new starts for a subject before giving up
MAX_ATTEMPTS = 4
#: how many of a round's plausible candidates, lowest energy first, are offered a patient
MAX_PLACEMENT_TRIES = 4
#: the seed stream of the patient placements (with the run's seed, the subject and the round)
PATIENT_STREAM = 7


def subject_config(config: GraspGenConfig, subject: Subject, attempt: int) -> GraspGenConfig:
    """The candidates of ``subject``'s round ``attempt``: one orientation (the subject's index cycling over
    ``config.theta_vol_deg``), ``config.starts_per_theta`` starts, a seed of its own."""
    theta = config.theta_vol_deg[subject.index % len(config.theta_vol_deg)]
    seed = int(np.random.default_rng([config.seed, subject.index, attempt]).integers(MAX_SEED))
    return replace(config, theta_vol_deg=(theta,), seed=seed, n_select=1, pinned_ids=None)


def _placed(candidates: dict, hand, probe, patient: PatientSpec, rng: np.random.Generator):
    """(candidate id, placement) of the lowest-energy plausible candidate that admits a patient, or None. The
    forearm is the one rendered with the hand (:func:`hupbench.datagen.render.scene.models_of`)."""
    g = candidates["grasps"]
    plausible = np.flatnonzero(candidates["scores"]["plausible"])
    for i in plausible[np.argsort(g.energy[plausible], kind="stable")][:MAX_PLACEMENT_TRIES]:
        hand_pose = anatomical_to_pose(g.angles[i], matrix_to_axis_angle(g.R_global[i]))
        hand_vertices = hand.vertices(hand_pose, g.trans[i], clamp=False)
        arm = forearm_mesh(axis_angle_to_matrix(hand_pose[:3]), g.trans[i], spec=models_of(hand.spec).arm)
        placement = place_patient(patient, probe, hand_vertices, np.asarray(arm.vertices), rng)
        if placement is not None:
            return int(i), placement
    return None


def subject_grasp(subject: Subject, config: GraspGenConfig, refine_config: RefineConfig, probe,
                  patient: PatientSpec, log=print) -> dict:
    """The grasp of one subject on its own hand, with its patient.

    Returns:
        dict: "arrays" (:func:`~hupbench.datagen.grasps.synthesis.grasp_arrays` of the one grasp, its
        ``grasp_id`` the subject's index), "placement", "attempts" (rounds used, 1 = no retry), "candidates" and
        "plausible" (counts over the rounds), "hand" (its HandSpec) and its measured "length_mm", "breadth_mm".

    Raises:
        BadValueError: no round gave a plausible grasp that admits a patient (more starts may).
    """
    spec = subject.hand_spec()
    hand = build_hand(spec)
    counts = {"candidates": 0, "plausible": 0}
    for attempt in range(MAX_ATTEMPTS):
        sub_config = subject_config(config, subject, attempt)
        candidates = generate_candidates(sub_config, spec, refine_config=refine_config, log=lambda *_: None,
                                         probe=probe)
        counts["candidates"] += len(candidates["grasps"])
        counts["plausible"] += int(candidates["scores"]["plausible"].sum())
        rng = np.random.default_rng([config.seed, PATIENT_STREAM, subject.index, attempt])
        found = _placed(candidates, hand, probe, patient, rng)
        if found is not None:
            i, placement = found
            arrays = grasp_arrays(candidates, np.array([i]), sub_config, probe, spec)
            arrays["grasp_id"] = np.array([subject.index], dtype=np.int64)
            return {"arrays": arrays, "placement": placement, "attempts": attempt + 1, "hand": spec,
                    "length_mm": hand.length_mm, "breadth_mm": hand.breadth_mm, **counts}
        log(f"  subject {subject.index}: no plausible grasp with a patient in round {attempt + 1}; new starts")
    raise BadValueError(f"subject {subject.index} ({subject.length_mm:.0f} x {subject.breadth_mm:.0f} mm hand): no "
                        f"plausible grasp admits a patient after {MAX_ATTEMPTS} rounds of {config.starts_per_theta} "
                        "starts; raise generate.starts_per_theta")


def _subject_in_worker(job: tuple) -> dict:
    """:func:`subject_grasp` in a worker process, on one torch thread, its log lines returned."""
    import torch

    from hupbench.datagen.assets.probe import probe_of

    subject, config, refine_config, probe_source, patient = job
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    lines = []
    try:
        result = subject_grasp(subject, config, refine_config, probe_of(probe_source), patient, log=lines.append)
    finally:  # in this process (one worker), its caller's threads again
        torch.set_num_threads(threads)
    return result | {"log": lines}


def subject_grasps(subjects: list[Subject], config: GraspGenConfig, refine_config: RefineConfig, probe_source,
                   patient: PatientSpec, workers: int = 1, log=print) -> dict:
    """One grasp per subject (:func:`subject_grasp`), as the arrays of a grasps file.

    Args:
        probe_source: :class:`hupbench.datagen.assets.probe_mesh.ProbeSource`, the probe each worker builds.
        workers: processes sharing the subjects (1: in this process).

    Returns:
        dict: "arrays" (the grasps file's arrays, one row per subject in order, with :data:`hupbench.datagen.dataset.
        grasps_file.SUBJECT_FIELDS` and the ``patient_*`` arrays), "retried" (indices of subjects that needed more
        than one round), "candidates", "plausible", "seconds".
    """
    from hupbench.core.processes import workers_ignore_ctrl_c

    start = time.perf_counter()
    jobs = [(subject, config, refine_config, probe_source, patient) for subject in subjects]
    if workers == 1:
        done = map(_subject_in_worker, jobs)
    else:
        with workers_ignore_ctrl_c():
            pool = multiprocessing.get_context("spawn").Pool(min(workers, len(jobs)))
        done = pool.imap(_subject_in_worker, jobs)
    results = []
    try:
        for subject, result in zip(subjects, done):
            results.append(result)
            for line in result["log"]:
                log(line)
            log(f"  subject {subject.index} ({'man' if subject.sex else 'woman'}, {subject.length_mm:.0f} x "
                f"{subject.breadth_mm:.0f} mm): {result['attempts']} round(s), "
                f"{time.perf_counter() - start:.0f} s so far")
    finally:
        if workers > 1:
            pool.terminate()
    rows = [r["arrays"] for r in results]
    # each result holds one grasp: its per-grasp arrays have a leading axis of 1; the probe's are shared
    arrays = {k: (np.concatenate([r[k] for r in rows]) if v.ndim and len(v) == 1 and k not in PROBE_MESH_FIELDS
                  else v)
              for k, v in rows[0].items()}
    arrays |= {"subject_sex": np.array([s.sex for s in subjects], dtype=np.int8),
               "subject_hand": np.array([r["hand"].proportions for r in results], dtype=np.float64),
               "hand_length_mm": np.array([r["length_mm"] for r in results]),
               "hand_breadth_mm": np.array([r["breadth_mm"] for r in results])}
    arrays |= placement_arrays([r["placement"] for r in results])
    return {"arrays": arrays, "retried": [s.index for s, r in zip(subjects, results) if r["attempts"] > 1],
            "candidates": sum(r["candidates"] for r in results), "plausible": sum(r["plausible"] for r in results),
            "seconds": time.perf_counter() - start}
