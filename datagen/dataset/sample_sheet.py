"""Pictures of a dataset, read through the dataset contract.

:func:`sample_sheet` (``hupbench verify --sample-sheet``): one frame per (background, glove) with its
depth, mask and keypoints. :func:`overview`: what the dataset spans: frames from across the camera
sphere with a map of every view position, each camera distance, and every grasp. Both end in a
depth colour bar (metres) and legends for the mask labels and the keypoint colours.

Convention:
    View positions are the annotations' ``theta`` (polar angle from the sphere's pole) and ``phi``
    (azimuth about it), radians; pictures print them in degrees.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from hupbench.core.contract import SEG_LABELS, SPLITS, frame_path, read_annotations, read_manifest
from hupbench.datagen.dataset.verify_images import read_image
from hupbench.core.errors import BadValueError
from hupbench.core.draw import (
    SEG_RGB,
    beside,
    colorize_depth,
    colorize_labels,
    depth_color_bar,
    draw_keypoints,
    grid,
    keypoint_legend_entries,
    keypoint_radius_px,
    legend,
    resize_with_keypoints,
    stack,
    text_block,
    titled,
)

_KEYS = ("frame_id", "keypoints_2d", "visible", "background_id", "glove_id", "grasp_index", "grasp_id", "z_ego",
         "view_id", "theta", "phi")


def _check_modalities(manifest: dict) -> None:
    missing = {"rgb", "depth", "seg"} - set(manifest["modalities"])
    if missing:
        raise BadValueError(f"a sample sheet needs rgb, depth and seg; the dataset lacks {sorted(missing)}")


def read_frame(root: Path, split: str, manifest: dict, frame_id: int) -> dict:
    """{"rgb": (H, W, 3) uint8 RGB, "depth_m": (H, W) float64 metres, "seg": (H, W) uint8} of one stored frame."""
    images = {}
    for m in ("rgb", "depth", "seg"):
        path = frame_path(root, split, m, frame_id, manifest["rgb_format"])
        images[m], why = read_image(path, m)
        if images[m] is None:
            raise BadValueError(f"{path}: {why}")
    return {"rgb": np.ascontiguousarray(images["rgb"][..., ::-1]),
            "depth_m": images["depth"] * manifest["depth_scale_m"], "seg": images["seg"]}


def _depth_range_m(frames: list[dict]) -> tuple[float, float]:
    """Nearest and farthest rendered depth over the frames, widened to whole centimetres."""
    hits = np.concatenate([f["depth_m"][f["depth_m"] > 0] for f in frames])
    if not hits.size:
        return 0.1, 1.0
    near, far = np.floor(hits.min() * 100) / 100, np.ceil(hits.max() * 100) / 100
    return float(near), float(max(far, near + 0.01))


def _keypoint_tile(frame: dict, ann: dict, row: int, side_px: int) -> np.ndarray:
    """The RGB frame resized to ``side_px`` with its skeleton drawn at that scale."""
    rgb, uv = resize_with_keypoints(frame["rgb"], ann["keypoints_2d"][row], side_px)
    return draw_keypoints(rgb, uv, ann["visible"][row], radius=keypoint_radius_px(side_px),
                          thickness=1 if side_px < 200 else 2)


def _map_tiles(frame: dict, side_px: int, depth_range_m: tuple[float, float]) -> list[np.ndarray]:
    """Depth (coloured on the sheet's common range) and mask, resized to ``side_px``."""
    size = (side_px, side_px)
    return [cv2.resize(colorize_depth(frame["depth_m"], *depth_range_m), size, interpolation=cv2.INTER_NEAREST),
            cv2.resize(colorize_labels(frame["seg"]), size, interpolation=cv2.INTER_NEAREST)]


def legends(manifest: dict, depth_range_m: tuple[float, float], width: int) -> np.ndarray:
    """Footer of a sheet: the depth colour bar in metres, the mask labels and the keypoint colours.

    Args:
        manifest: the dataset's manifest (its ``seg_labels`` name the mask values).
        depth_range_m: (near, far) metres the sheet's depth maps were coloured with.
        width: pixels.

    Returns:
        (H, width, 3) uint8.
    """
    labels = sorted(manifest.get("seg_labels", SEG_LABELS).items(),
                    key=lambda item: item[1])
    side = width >= 900  # three columns side by side, or one under another on a narrow sheet
    part = width // 3 if side else width
    masks = legend("mask: label of each pixel", [(name, SEG_RGB[value], "square") for name, value in labels
                                                  if value < len(SEG_RGB)], part)
    bar = depth_color_bar(*depth_range_m, width=part)
    points = legend("keypoints: 21 hand joints by finger, 8 probe box corners", keypoint_legend_entries(),
                    width - 2 * (part + 6) if side else width)
    return beside([bar, masks, points]) if side else stack([bar, masks, points])


def sample_sheet(root, split: str = "train", view: int | None = None, tile_px: int = 128) -> np.ndarray:
    """One frame per (background, glove) of a dataset: RGB, depth, mask and keypoints side by side.

    Takes the split's first grasp at the first distance and the given view index (default: view
    40 of the paper protocol's sphere, where the grip and the probe's green orientation marker both
    show, or the middle view of a sphere with fewer views). Every depth map is coloured on one range,
    the one the colour bar below the tiles gives in metres.

    Returns:
        (H, W, 3) uint8 RGB: one row per background, four tiles per glove in a row, then the legends.

    Raises:
        ValueError: the dataset lacks a modality, the split or a readable image (the message names it).
    """
    root = Path(root)
    manifest = read_manifest(root, split=split)
    _check_modalities(manifest)
    ann = read_annotations(root, split, keys=_KEYS, manifest=manifest)
    n_view = manifest["layout"]["shape"][4]
    if view is None:
        view = 40 if n_view > 40 else n_view // 2
    assert 0 <= view < n_view, (view, n_view)
    first = (ann["grasp_index"] == ann["grasp_index"].min()) & (ann["z_ego"] == ann["z_ego"].min())
    names = (manifest.get("backgrounds") or {}).get("names") or []
    gloves = sorted(set(ann["glove_id"].tolist()))
    shown = []
    for b in sorted(set(ann["background_id"].tolist())):
        for glove in gloves:
            rows = np.flatnonzero(first & (ann["background_id"] == b) & (ann["glove_id"] == glove))
            if len(rows):
                i = int(rows[min(view, len(rows) - 1)])
                shown.append((b, glove, i, read_frame(root, split, manifest, int(ann["frame_id"][i]))))
    depth_range_m = _depth_range_m([frame for *_, frame in shown])
    tiles = []
    for b, glove, i, frame in shown:
        depth, mask = _map_tiles(frame, tile_px, depth_range_m)
        rgb = resize_with_keypoints(frame["rgb"], np.zeros((0, 2)), tile_px)[0]
        tiles += [titled(rgb, str(names[b]) if b < len(names) else f"background {b}"),
                  titled(depth, "depth"), titled(mask, "mask"),
                  titled(_keypoint_tile(frame, ann, i, tile_px), f"glove {glove}, #{int(ann['frame_id'][i])}")]
    sheet = grid(tiles, columns=4 * len(gloves))
    return stack([sheet, legends(manifest, depth_range_m, max(sheet.shape[1], 900))])


def _directions(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(N, 3) unit vectors of view positions given polar angle and azimuth, radians."""
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def spread_views(theta: np.ndarray, phi: np.ndarray, count: int, first: int) -> list[int]:
    """Indices of ``count`` views spread over the sphere (farthest-point order from view ``first``).

    Args:
        theta, phi: (N,) float radians, the positions of N distinct views.
        count: how many to take (at most N).
        first: index of the view to start from.

    Returns:
        ``min(count, N)`` distinct indices, sorted by (theta, phi).
    """
    d = _directions(np.asarray(theta), np.asarray(phi))
    chosen = [first]
    nearest = d @ d[first]
    while len(chosen) < min(count, len(d)):
        far = int(np.argmin(np.where(np.isin(np.arange(len(d)), chosen), np.inf, nearest)))
        chosen.append(far)
        nearest = np.maximum(nearest, d @ d[far])
    return sorted(chosen, key=lambda i: (round(float(theta[i]), 6), round(float(phi[i]), 6)))


def _nearest_view_row(ann: dict, mask: np.ndarray, direction: np.ndarray) -> int | None:
    """Row among ``mask`` whose view position is nearest ``direction`` (exact when that view is there)."""
    rows = np.flatnonzero(mask)
    if not len(rows):
        return None
    return int(rows[np.argmax(_directions(ann["theta"][rows], ann["phi"][rows]) @ direction)])


def overview_plan(root, n_views: int = 12, max_grasps: int = 12) -> dict:
    """Which frames :func:`overview` shows.

    The first split's first grasp at the nearest distance, first background and glove gives the
    sphere's views; the same view at every distance gives the distance row; every grasp of every
    split (up to ``max_grasps``) at the view nearest that one, backgrounds and gloves taken in turn,
    gives the grasp rows.

    Args:
        root: dataset folder.
        n_views: frames to show from across the sphere.
        max_grasps: grasps to show at most.

    Returns:
        {"manifest": dict, "annotations": {split: {name: (N, ...) array}},
        "views", "distances", "grasps": lists of (split, row), "sphere": (V, 3) float64 of the split's
        distinct (view_id, theta, phi) in radians, "first_view": view_id of the common view}.
    """
    root = Path(root)
    manifest = read_manifest(root)
    _check_modalities(manifest)
    splits = [s for s in SPLITS if manifest["counts"].get(s, 0) > 0]
    if not splits:
        raise BadValueError(f"{root} has no frames in any of {list(SPLITS)}")
    ann = {s: read_annotations(root, s, keys=_KEYS, manifest=manifest) for s in splits}
    main = ann[splits[0]]
    base = ((main["grasp_index"] == main["grasp_index"].min()) & (main["z_ego"] == main["z_ego"].min())
            & (main["background_id"] == main["background_id"].min()) & (main["glove_id"] == main["glove_id"].min()))
    rows = np.flatnonzero(base)
    rows = rows[np.unique(main["view_id"][rows], return_index=True)[1]]
    first = 40 if len(rows) > 40 else len(rows) // 2
    views = spread_views(main["theta"][rows], main["phi"][rows], n_views, first)
    common = _directions(main["theta"][rows[first]], main["phi"][rows[first]])
    distances = []
    for z in np.unique(main["z_ego"]):
        at_z = main["z_ego"] == z
        for key in ("grasp_index", "background_id", "glove_id"):
            at_z &= main[key] == main[key][rows[first]]
        distances.append((splits[0], _nearest_view_row(main, at_z, common)))
    grasps = []
    for s in splits:
        a = ann[s]
        n_bg, n_glove = int(a["background_id"].max()) + 1, int(a["glove_id"].max()) + 1
        for g in np.unique(a["grasp_index"]):
            if len(grasps) == max_grasps:
                break
            k = len(grasps)
            of_grasp = (a["grasp_index"] == g) & (a["z_ego"] == a["z_ego"].min())
            row = _nearest_view_row(a, of_grasp & (a["background_id"] == k % n_bg) & (a["glove_id"] == k % n_glove),
                                    common)
            grasps.append((s, row if row is not None else _nearest_view_row(a, of_grasp, common)))
    sphere = np.stack([main["view_id"][rows], main["theta"][rows], main["phi"][rows]], axis=1).astype(np.float64)
    return {"manifest": manifest, "annotations": ann, "views": [(splits[0], int(rows[i])) for i in views],
            "distances": distances, "grasps": grasps, "sphere": sphere, "first_view": int(main["view_id"][rows[first]])}


def sphere_map(sphere: np.ndarray, chosen_view_ids: list[int], width: int, height: int) -> np.ndarray:
    """Map of the camera sphere: azimuth across, polar angle down; every view a grey dot, the chosen
    ones blue and numbered 1.. in the order given.

    Args:
        sphere: (V, 3) float (view_id, theta, phi), radians.
        chosen_view_ids: view ids to number.
        width, height: pixels.

    Returns:
        (height, width, 3) uint8.
    """
    out = np.full((height, width, 3), 255, dtype=np.uint8)
    left, right, top, bottom = 44, 16, 12, 44
    plot_w, plot_h = width - left - right, height - top - bottom
    assert plot_w > 50 and plot_h > 50, (width, height)

    def at(theta_deg: float, phi_deg: float) -> tuple[int, int]:
        return left + int(np.round(phi_deg / 360.0 * plot_w)), top + int(np.round(theta_deg / 180.0 * plot_h))

    font, ink, rule = cv2.FONT_HERSHEY_SIMPLEX, (20, 20, 20), (215, 215, 215)
    for phi in range(0, 361, 45):
        cv2.line(out, at(0, phi), at(180, phi), rule, 1)
        if phi % 90 == 0:
            x, y = at(180, phi)
            cv2.putText(out, str(phi), (x - 4 * len(str(phi)), y + 16), font, 0.4, ink, 1, cv2.LINE_AA)
    for theta in range(0, 181, 45):
        cv2.line(out, at(theta, 0), at(theta, 360), rule, 1)
        x, y = at(theta, 0)
        cv2.putText(out, str(theta), (x - 8 - 8 * len(str(theta)), y + 4), font, 0.4, ink, 1, cv2.LINE_AA)
    cv2.putText(out, "azimuth phi, degrees", (left + plot_w // 2 - 80, height - 8), font, 0.45, ink, 1, cv2.LINE_AA)
    theta_deg, phi_deg = np.rad2deg(sphere[:, 1]), np.rad2deg(sphere[:, 2]) % 360.0
    for t, p in zip(theta_deg, phi_deg):
        cv2.circle(out, at(t, p), 4, (150, 150, 150), -1, cv2.LINE_AA)
    for k, view_id in enumerate(chosen_view_ids):
        (i,) = np.flatnonzero(sphere[:, 0] == view_id)
        x, y = at(theta_deg[i], phi_deg[i])
        cv2.circle(out, (x, y), 7, (40, 90, 220), -1, cv2.LINE_AA)
        label = str(k + 1)
        tx = x + 9 if x + 9 + 10 * len(label) < width else x - 9 - 10 * len(label)
        cv2.putText(out, label, (tx, y + 5), font, 0.5, (40, 90, 220), 1, cv2.LINE_AA)
    return out


def overview(root, tile_px: int = 180, columns: int = 6, n_views: int = 12, max_grasps: int = 12) -> np.ndarray:
    """One picture of what a dataset spans: views from across the camera sphere with a map of every
    view position, each camera distance (RGB with keypoints, depth, mask), every grasp, then the legends.

    Frames are resized to ``tile_px`` before the keypoints are drawn, dots sized for that tile.

    Args:
        root: dataset folder.
        tile_px: side of each frame, pixels.
        columns: frames per row.
        n_views: frames from across the sphere.
        max_grasps: grasps shown at most.

    Returns:
        (H, W, 3) uint8 RGB.

    Raises:
        ValueError: the dataset lacks a modality, a split's annotations or a readable image.
    """
    root = Path(root)
    plan = overview_plan(root, n_views, max_grasps)
    manifest, ann = plan["manifest"], plan["annotations"]
    names = (manifest.get("backgrounds") or {}).get("names") or []
    frames = {pick: read_frame(root, pick[0], manifest, int(ann[pick[0]]["frame_id"][pick[1]]))
              for pick in plan["views"] + plan["distances"] + plan["grasps"]}
    width = columns * (tile_px + 6) + 6

    def where(split: str, row: int) -> str:
        a = ann[split]
        b = int(a["background_id"][row])
        return f"{names[b] if b < len(names) else f'background {b}'} / glove {int(a['glove_id'][row])}"

    counts = manifest["counts"]
    n_grasp, n_z, n_bg, n_glove, n_view = manifest["layout"]["shape"]
    h, w = manifest["image_size"]
    header = text_block([
        f"{root.name}: {sum(counts.values())} frames of {w} x {h} px ("
        + ", ".join(f"{s} {counts[s]}" for s in SPLITS if s in counts) + f"): {n_grasp} grasps x {n_z} camera "
        f"distances x {n_bg} backgrounds x {n_glove} gloves x {n_view} views."], width, scale=0.55, line_px=22)

    split0, row0 = plan["views"][0]
    a0 = ann[split0]
    view_tiles = []
    for k, (s, r) in enumerate(plan["views"]):
        a = ann[s]
        view_tiles.append(titled(_keypoint_tile(frames[(s, r)], a, r, tile_px),
                                 f"{k + 1}: view {int(a['view_id'][r])}\n"
                                 f"polar {np.rad2deg(a['theta'][r]):.0f}, az {np.rad2deg(a['phi'][r]):.0f}"))
    views_title = text_block([
        (f"1. Around the camera sphere: grasp {int(a0['grasp_id'][row0])} at {a0['z_ego'][row0]:.2f} m, "
        f"{where(split0, row0)}, from {len(view_tiles)} of the {len(plan['sphere'])} views (numbered on the map).")],
        width)
    map_w = min(width, 620)
    sphere = sphere_map(plan["sphere"], [int(ann[s]["view_id"][r]) for s, r in plan["views"]], map_w, 300)
    polar_axis = str((manifest.get("protocol") or {}).get("polar_axis", "the sphere's axis")).split(" (")[0]
    map_note = text_block([
        ("Camera positions on the sphere around the hand, one dot per view; the camera looks at the hand "
        "from each."), f"Down: polar angle theta from the pole ({polar_axis}), degrees.",
        "Across: azimuth phi about that axis, degrees.", "Blue, numbered: the frames above."],
        width - map_w - 6, scale=0.45) if width - map_w > 120 else None

    depth_range_m = _depth_range_m([frames[p] for p in plan["distances"]])
    distance_tiles = []
    for s, r in plan["distances"]:
        z = f"{ann[s]['z_ego'][r]:.2f} m"
        depth, mask = _map_tiles(frames[(s, r)], tile_px, depth_range_m)
        distance_tiles += [titled(_keypoint_tile(frames[(s, r)], ann[s], r, tile_px), f"camera {z} away"),
                           titled(depth, f"depth at {z}"), titled(mask, f"mask at {z}")]
    distances_title = text_block([
        (f"2. Camera distances: the same frame from each of the {len(plan['distances'])} distances: RGB with "
        "keypoints, depth (one colour scale, bar below), mask.")], width)

    grasp_tiles = [titled(_keypoint_tile(frames[(s, r)], ann[s], r, tile_px),
                          f"grasp {int(ann[s]['grasp_id'][r])} ({s})\n{where(s, r)}") for s, r in plan["grasps"]]
    n_all = sum(len(np.unique(ann[s]["grasp_index"])) for s in ann)
    grasps_title = text_block([
        (f"3. Grasps: {len(grasp_tiles)} of the {n_all} grasps (their split in brackets) seen from the view nearest "
        f"view {plan['first_view']} at the nearest distance, backgrounds and gloves in turn.")], width)

    blocks = [header, views_title, grid(view_tiles, columns),
              beside([sphere, map_note]) if map_note is not None else sphere,
              distances_title, grid(distance_tiles, columns), grasps_title, grid(grasp_tiles, columns),
              legends(manifest, depth_range_m, width)]
    return stack(blocks)
