"""The leaderboard's README.md: a table per track, what the numbers mean, and each row's details.

Generated from validated results rows (:mod:`hupbench.evaluation.results`), with every number formatted
explicitly and nothing read from the clock: the same rows give the same bytes.

Convention: errors in mm, latency in ms per image, times in seconds.
"""

from __future__ import annotations

from hupbench.core.contract import TRACKS
from hupbench.datagen.dataset.floors import FLOOR_KINDS
from hupbench.evaluation.leaderboard_robustness import robustness_section
from hupbench.evaluation.leaderboard_sequences import sequence_section
from hupbench.evaluation.leaderboard_table import (
    GRASP_COLUMNS,
    MISSING,
    RECORDED,
    SPREAD_AXES,
    SPREAD_RATIO_WARN,
    TABLE_ALIGN,
    TABLE_COLUMNS,
    TRACK_TITLES,
    code_cell,
    grasp_rows,
    interval_triplet_cell,
    markdown_table,
    natural_key,
    number_cell,
    row_intervals,
    row_track,
    sha_cell,
    spread_cell,
    table_row,
    text_cell,
    triplet_cell,
)
from hupbench.evaluation.results import (
    FLOOR_NAMES,
    GRASP_FIELDS_VERSION,
    INTERVALS_VERSION,
    SCHEMA_VERSION,
    WEIGHTED_MEAN_TOLERANCE_MM,
    keypoint_weighted_all_mm,
)

#: the plots the README shows, by file name
LATENCY_PLOT = "mpjpe_vs_latency.png"
TRAINING_PLOT = "val_mpjpe_vs_training_time.png"


def _details(row: dict) -> list[str]:
    model, dataset, training = row["model"], row["dataset"], row["training"]
    mpjpe = row["metrics"]["mpjpe_mm"]
    lines = [f"### {text_cell(model['label'])} (`{row['run_name']}`)", ""]
    kind = "measured here" if row["kind"] == "measured" else "reported in a paper, not measured here"
    lines.append(f"- kind: {kind}; results file [`results/{row['run_name']}.json`](results/{row['run_name']}.json)")
    data = f"- test data: {text_cell(dataset['name'])}, split `{dataset['split']}`"
    if dataset["frames"] is not None:
        data += f", {dataset['frames']} frames"
    if dataset["manifest_sha256"] is not None:
        data += f", manifest sha256 {sha_cell(dataset['manifest_sha256'])}"
    lines.append(data + f", grasps sha256 {sha_cell(dataset['grasps_sha256'])}")
    lines.append(f"- MPJPE all {mpjpe['all']:.2f} mm, averaged: {text_cell(mpjpe['all_averaging'])}")
    lines.append(_interval_line(row))
    weighted = keypoint_weighted_all_mm(mpjpe)
    if weighted is not None:
        check = (f"- keypoint-weighted mean of hand and probe: (21 × {mpjpe['hand']:.2f} + 8 × {mpjpe['probe']:.2f})"
                 f" / 29 = {weighted:.2f} mm")
        if abs(weighted - mpjpe["all"]) > WEIGHTED_MEAN_TOLERANCE_MM:
            check += f", which is not the row's all ({mpjpe['all']:.2f} mm)"
        lines.append(check)
    symmetric = row["metrics"]["probe_symmetric_mpjpe_mm"]
    if symmetric is not None:
        lines.append(f"- probe MPJPE with the corners matched under the half turn about the probe's long axis where "
                     f"closer: {symmetric:.2f} mm (plain: {number_cell(mpjpe['probe'])} mm)")
    ratios = row["metrics"]["spread_ratio"]
    if any(ratios[a] is not None for a in SPREAD_AXES):
        low = [a for a in SPREAD_AXES if ratios[a] is not None and ratios[a] < SPREAD_RATIO_WARN]
        line = f"- spread ratio of predicted to true 3D keypoints across the test frames, x / y / z: {spread_cell(row)}"
        if low:
            line += (f"; below {SPREAD_RATIO_WARN} on {', '.join(low)}: the predictions barely vary along "
                     f"{'that axis' if len(low) == 1 else 'those axes'} (collapsed)")
        lines.append(line)
    if row["metrics"]["root_relative_hand_mpjpe_mm"] is not None or row["metrics"]["pixel_error_px"] is not None:
        middle = row["metrics"].get("middle_mcp_relative_hand_mpjpe_mm")  # absent in files written before it
        lines.append(f"- root-relative hand MPJPE {number_cell(row['metrics']['root_relative_hand_mpjpe_mm'])} mm"
                     + ("" if middle is None else f" (relative to the middle-finger MCP: {middle:.2f} mm)")
                     + f"; 2D error {number_cell(row['metrics']['pixel_error_px'])} px")
    if model["flops"] is not None or model["format"] is not None:
        flops = MISSING if model["flops"] is None else f"{model['flops'] / 1e9:.2f}"
        lines.append(f"- GFLOPs per image {flops}; evaluated from {model['format'] or MISSING}")
    latency = row["latency_ms_per_image"]
    if any(v is not None for runtime in latency.values() for v in runtime.values()):
        onnx, torch = latency["onnxruntime"], latency["pytorch"]
        lines.append(f"- latency ms/image, batch 1 / batch 32: ONNX Runtime {number_cell(onnx['batch1'])} / "
                     f"{number_cell(onnx['batch32'])}, PyTorch {number_cell(torch['batch1'])} / "
                     f"{number_cell(torch['batch32'])}; device: {text_cell(row['device'] or MISSING)}")
    if training["samples_seen"] is not None or training["epochs"] is not None:
        lines.append(f"- training: {training['samples_seen'] if training['samples_seen'] is not None else MISSING}"
                     f" samples, {number_cell(training['epochs'], 1)} epochs")
    if training["command"] is not None:
        lines.append(f"- reproduce: `{text_cell(training['command'])}`")
    if training["log"] is not None:
        lines.append(f"- training log: [`{training['log']}`]({training['log']})")
    if row["git_commit"] is not None:
        lines.append(f"- git commit `{row['git_commit']}`"
                     + (f", evaluated {row['created_utc']}" if row["created_utc"] else ""))
    if row["source"] is not None:
        lines.append(f"- source: {text_cell(row['source'])}")
    return lines + [""] + _grasp_details(row)

def _floor_name(kind: str) -> str:
    """What a floor kind is, in words (its name where hupbench has no words for it)."""
    return FLOOR_NAMES.get(kind, kind)


def _interval_line(row: dict) -> str:
    """The row's 95 % intervals over the test grasps, how they were drawn and whence, or why it has none."""
    intervals = row["intervals"]
    if intervals is None:
        return (f"- 95 % CI over the test grasps: {MISSING} (" + ("a paper's number" if row["kind"] != "measured" else
                "the results file records neither intervals nor a per-grasp breakdown to recompute them from: it was "
                f"written before results schema version {GRASP_FIELDS_VERSION}; `hupbench eval` adds them") + ")")
    mpjpe, floor = row["metrics"]["mpjpe_mm"], row["split_floor"]
    whence = ("" if row["intervals_from"] == RECORDED else "; recomputed from the results file's per-grasp breakdown, "
              "each grasp's mean error and frames, with `hupbench eval`'s draws")
    line = (f"- {100 * intervals['confidence']:g} % CI over the {intervals['grasps']} test grasps "
            f"({intervals['resamples']:,} bootstrap resamples of the grasps, seed {intervals['seed']}{whence}), "
            f"hand / probe / all (mm): MPJPE {interval_triplet_cell(mpjpe, intervals['mpjpe_mm'])}")
    if floor is not None:
        line += f"; split floor {interval_triplet_cell(floor['floor_mm'], intervals['split_floor_mm'])}"
    return line


def _grasp_details(row: dict) -> list[str]:
    """The row's per-grasp table and its MPJPE by probe orientation, or a line saying they are not recorded."""
    table = grasp_rows(row)
    if not table:
        if row["kind"] != "measured":
            return []
        return [f"Per grasp: {MISSING} (the results file records no grasp breakdown: it was written before results "
                f"schema version {GRASP_FIELDS_VERSION}; `hupbench eval` adds it).", ""]
    floor = row["split_floor"]
    lines = ["Per test grasp" + ("" if floor is None else f" (floor: {_floor_name(floor['floor_kind'])})") + ":", ""]
    lines += markdown_table(GRASP_COLUMNS, ["---:"] * len(GRASP_COLUMNS), table)
    by_theta = row["breakdowns"].get("theta_vol")
    if by_theta:
        shown = "; ".join(f"{text_cell(label)} {triplet_cell(by_theta[label]['mpjpe_mm'])} "
                          f"({by_theta[label]['frames']} frames)" for label in sorted(by_theta, key=natural_key))
        lines += [f"MPJPE by probe orientation Theta_Vol, hand / probe / all (mm): {shown}.", ""]
    return lines


def _floor_lines(rows: list[dict]) -> list[str]:
    """The test split's floor of each dataset the rows were evaluated on, named by what it is, with its 95 %
    interval over the test grasps where a row records one (rows of one dataset share the floor; the first row
    with an interval gives it)."""
    # floor kind -> (dataset name, manifest sha256) -> (floor_mm, its intervals or None)
    floors: dict[str, dict[tuple, tuple[dict, dict | None]]] = {}
    for row in rows:
        if row["split_floor"] is not None:
            key = (row["dataset"]["name"], row["dataset"]["manifest_sha256"] or "")
            by_dataset = floors.setdefault(row["split_floor"]["floor_kind"], {})
            if by_dataset.get(key, (None, None))[1] is None:
                by_dataset[key] = (row["split_floor"]["floor_mm"], row_intervals(row, "split_floor_mm"))
    if not floors:
        return [f"Split floor: {MISSING} for every row here (results files written before results schema version "
                f"{GRASP_FIELDS_VERSION}, datasets made before split floors, and the paper record none).", ""]
    lines = []
    for kind in sorted(floors, key=lambda k: (FLOOR_KINDS + (k,)).index(k)):
        lines += [f"Split floor, hand / probe / all (mm; column *split floor*) [95 % CI over the test grasps]: "
                  f"{_floor_name(kind)}.", ""]
        for (name, sha), (mm, bounds) in sorted(floors[kind].items()):
            lines.append(f"- {text_cell(name)}" + (f" (manifest sha256 {sha_cell(sha)})" if sha else "")
                         + f", test split: {interval_triplet_cell(mm, bounds)}")
        lines.append("")
    return lines

def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _track_section(track: str, rows: list[dict]) -> list[str]:
    """One track's heading, what it holds out, its floors and its table (rows already sorted)."""
    title, holds_out = TRACK_TITLES[track]
    n_measured = sum(row["kind"] == "measured" for row in rows)
    out = [f"## Track: {title} (`{track}`)", "", f"{title}: {holds_out}", ""]
    out += _floor_lines(rows)
    out += [f"{_count(len(rows), 'row')} ({n_measured} measured, {len(rows) - n_measured} reported), sorted by MPJPE "
            f"all, then run name. {MISSING} means not measured or not reported.", ""]
    return out + markdown_table(TABLE_COLUMNS, TABLE_ALIGN, [table_row(row) for row in rows])


def render_readme(rows: list[dict], robust: list[dict] = ()) -> str:
    """The leaderboard README (Markdown ending in one newline) of validated rows sorted by :func:`sort_key`, with the
    depth sensor table of the ``robust`` rows (:mod:`~hupbench.evaluation.leaderboard_robustness`)."""
    n_measured = sum(row["kind"] == "measured" for row in rows)
    tracks = [t for t in TRACKS if any(row_track(row) == t for row in rows)]
    out = [
        "# hupbench leaderboard",
        "",
        ("<!-- Generated by `hupbench leaderboard` from results/*.json. Do not edit by hand: edit or add a results "
         "file and rebuild. -->"),
        "",
        ("3D hand and ultrasound-probe pose estimation from one RGB image: how far the predicted keypoints are "
         "from the truth (MPJPE, mm) against what the model costs to train and to run. One row per results "
         f"file in [`results/`](results/) (schema version {SCHEMA_VERSION}, validated on load; files written in "
         f"earlier versions are read with the fields added since unknown, {MISSING}), in one table per track: "
         "what the test split holds out from training."),
        "",
        ("- **measured** rows were evaluated here by `hupbench eval` on the test split of the dataset they name. "
         "Every measured row names the committed command that reproduces its training (last column), and its "
         "results file records the model config, the dataset's manifest and grasps hashes, the git commit and the "
         "device."),
        ("- **reported in paper** rows quote a paper's numbers on that paper's data. They were not measured "
         "here, have no latency or training time, and their test data differ from the measured rows'."),
        "",
        ("Rebuild the table and both plots from the repository root with `hupbench leaderboard --dir leaderboard`; "
         "the same results files give the same bytes. To add a row, evaluate a model with "
         "`hupbench eval MODEL DATASET` into `leaderboard/results/<run_name>.json`, copy its training log to "
         "`leaderboard/logs/<run_name>.jsonl`, and rebuild."),
        "",
        (f"{_count(len(rows), 'row')} ({n_measured} measured, {len(rows) - n_measured} reported) in "
         f"{_count(len(tracks), 'track')}: " + ", ".join(f"{TRACK_TITLES[t][0]} (`{t}`)" for t in tracks) + "."),
        "",
    ]
    by_track = {track: [row for row in rows if row_track(row) == track] for track in tracks}
    for track in tracks:
        out += _track_section(track, by_track[track])
    out += robustness_section(list(robust), rows)
    out += sequence_section(rows)
    out += _meaning() + _plots() + ["## Row details", "", "By track, in the tables' order.", ""]
    for track in tracks:
        for row in by_track[track]:
            out += _details(row)
    return "\n".join(out).rstrip("\n") + "\n"


def _meaning() -> list[str]:
    """The section that says what each column means."""
    return [
        "## What the numbers mean",
        "",
        ("- MPJPE: mean Euclidean distance between predicted and true 3D keypoints in the camera frame, in mm, "
         "with no root or scale alignment. *hand* averages the 21 hand joints, *probe* the 8 corners of the "
         "probe's box, *all* the 29 keypoints together."),
        ("- How *all* is averaged matters when hand and probe errors differ: the mean over all 29 keypoints is "
         "(21 × hand + 8 × probe) / 29. Each row below states how its *all* was averaged. The HUP-3D paper's "
         "8.65 mm is not the keypoint-weighted mean of its 5.33 mm (hand) and 17.05 mm (probe), which is "
         "(21 × 5.33 + 8 × 17.05) / 29 = 8.56 mm; the paper does not say how its total is averaged."),
        ("- MPJPE probe, half-turn symmetric: the probe MPJPE with each frame's predicted corners compared with "
         "the true corners both as labelled and relabelled by the half turn about the probe's long axis (corner "
         "(ix, iy, iz) of the box becomes (1 − ix, 1 − iy, iz)), whichever is closer, as the BOP benchmark scores "
         "symmetric objects. It never exceeds the plain probe MPJPE; the gap is the error of confusing the two ends "
         "of the probe's transducer array. The probe carries an orientation marker on the +x end of its head "
         "(`datagen/assets/probe.py`), so the two ends can be told apart in the image and the plain probe MPJPE is the "
         "benchmark number; datasets rendered before the marker was added do not show it."),
        ("- Spread ratio x / y / z: for each camera axis, the standard deviation across the test frames of a "
         "predicted 3D coordinate, averaged over the 29 keypoints, divided by the same for the truth. 1 means the "
         "predictions vary as much as the truth; near 0 means the model gives about the same value for every "
         f"image (a collapsed model). `hupbench eval` warns below {SPREAD_RATIO_WARN}."),
        ("- Split floor (hand / probe / all, mm, mean distance per keypoint as in MPJPE), from the dataset's "
         "manifest: what a model that only recalls training labels scores on the test split. Unseen grasps: each "
         f"test grasp replaced by the {FLOOR_NAMES['nearest_train_grasp']}. Unseen views: each test frame replaced "
         f"by the {FLOOR_NAMES['nearest_train_view']}. Clinic: each test frame replaced by the "
         f"{_floor_name('nearest_train_frame')}. A row near or above its floor has learnt little beyond the "
         "training labels. Each measured row's details list its MPJPE and floor per test grasp, with the grasp's "
         "probe orientation Theta_Vol (Euler angles x, y, z of the probe in the grasp generator, degrees)."),
        ("- 95 % CI, in brackets beside each MPJPE and floor (one decimal): the percentile bootstrap interval over "
         "the test grasps (Efron & Tibshirani 1993, *An Introduction to the Bootstrap*, ch. 13). The frames of a "
         "grasp share its hand and probe pose, so the grasp is what is resampled: the test grasps are drawn with "
         "replacement as many times as there are, the mean error is recomputed over the drawn grasps' frames (a "
         "grasp drawn twice counts twice), and the interval holds the middle 95 % of those means over the "
         "resamples (10,000 by default; each results file records the number and the seed). It says how far the "
         "number could move with other test grasps of the same kind: with two test grasps it is wide, with one it "
         f"has zero width and says nothing. Results files written before results schema version "
         f"{INTERVALS_VERSION} record no interval: theirs is recomputed from the file's per-grasp breakdown (each "
         "grasp's mean error and frames, and each grasp's floor, are all the bootstrap needs) with the same "
         f"resamples, seed and draws, so it is the interval `hupbench eval` writes. [{MISSING}] where there is no "
         "breakdown to recompute it from (a paper's number)."),
        ("- PA-MPJPE hand: hand MPJPE after a Procrustes alignment (scale, rotation, translation) of the 21 "
         "predicted joints to the true ones. AUC 0-50 mm: area under the 3D PCK curve (fraction of keypoints "
         "within a threshold) for thresholds from 0 to 50 mm, normalised to [0, 1]."),
        ("- Training time is the training run's whole wall time (validation passes included) on the named hardware; "
         "the training-time plot counts training steps only. "
         "Latency is wall time per image at batch 1 on the row's device (see its details), ONNX Runtime and "
         "PyTorch measured separately."),
        ("- Grasps sha256: the first 12 hexadecimal digits of the sha256 of the grasps file the test data were "
         "rendered from (the dataset manifest's `grasps_sha256`). Rows with the same value saw the same hands and "
         f"probe poses; {MISSING} where the results file or the dataset's manifest predates the record."),
        "",
    ]


def _plots() -> list[str]:
    """The section that shows and explains both plots."""
    return [
        "## Plots",
        "",
        f"![MPJPE against inference latency]({LATENCY_PLOT})",
        "",
        ("MPJPE (all) against inference latency per image at batch 1 (ONNX Runtime where measured, else PyTorch). "
         "The line joins the Pareto frontier: the rows no other row beats on both error and latency. Paper rows "
         "have no latency and are drawn as horizontal reference lines."),
        "",
        f"![Validation MPJPE against training wall time]({TRAINING_PLOT})",
        "",
        ("Validation MPJPE (all) against training wall time, one line per measured row with a training log; the "
         "paper's test numbers are dashed reference lines."),
        "",
    ]
