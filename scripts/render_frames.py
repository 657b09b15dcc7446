"""Render a few frames of the default dataset with this checkout's generator, and set two such renders side by side.

  python3 scripts/render_frames.py render GRASPS_NPZ OUT.npz [--shading pbr] [--frames 5 1450]   # in each checkout
  python3 scripts/render_frames.py compare BEFORE.npz AFTER.npz OUT.png [--titles before after]

``render`` draws frames of the default dataset spec (the paper protocol) through the generator's own chunk
renderer: different grasps, distances, backgrounds, gloves and views. ``compare`` writes one column per frame:
the two renders and their absolute difference (x3), and prints the mean difference per frame.
docs/rendering.md shows the result for two versions of the renderer.
"""

from __future__ import annotations

import argparse
import inspect

import cv2
import numpy as np

#: frame indices of the default layout (11 grasps x 2 distances x 8 backgrounds x 2 gloves x 90 views)
FRAMES = (5, 1450, 3000 + 90 + 40, 9000 + 180 * 3 + 60, 16000 + 33, 28990)


def render(grasps: str, out: str, shading: str | None, frames: tuple[int, ...] = FRAMES) -> None:
    """Render ``frames`` (indices of the default layout) of the default spec with the grasps file ``grasps`` into
    ``out`` (an .npz of encoded images by frame index)."""
    from hupbench.datagen.dataset.chunks import ChunkRenderer
    from hupbench.datagen.dataset.spec import DatasetSpec, Layout

    spec = DatasetSpec()
    layout = Layout(11, 2, 8, 2, 90)
    renderer = ChunkRenderer(spec, grasps, None, None)
    if shading is not None:  # the same frames through another colour shader
        from hupbench.datagen.render.renderer import Renderer

        renderer.renderer.close()
        renderer.renderer = Renderer(spec.intrinsics, shading=shading)
    takes_frames = "frames" in inspect.signature(renderer.render).parameters
    images = {}
    for index in frames:
        chunk = index // layout.chunk_size
        # the split only names the output folder; the frames are rendered alike in any split
        output = (renderer.render(chunk, "train", (index,), layout) if takes_frames
                  else renderer.render(chunk, "train", layout))
        data = next(d for m, f, d in output.files if m == "rgb" and f == index)
        images[str(index)] = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    np.savez_compressed(out, **images)
    print(f"{len(images)} frames -> {out}")


def compare(before: str, after: str, out: str, titles: tuple[str, str]) -> None:
    with np.load(before) as a, np.load(after) as b:
        keys = sorted(set(a.files) & set(b.files), key=int)
        columns = []
        for key in keys:
            diff = cv2.absdiff(a[key], b[key])
            print(f"frame {int(key):6d}: mean |difference| {diff.mean():.1f} levels, "
                  f"{100 * np.mean(diff.max(axis=2) > 24):.0f}% of pixels more than 24 levels apart")
            columns.append(np.concatenate([a[key], b[key], np.clip(3 * diff.astype(np.int32), 0, 255).astype(np.uint8)]))
    sheet = np.concatenate(columns, axis=1)
    label = np.full((sheet.shape[0], 170, 3), 255, np.uint8)
    h = a_h = sheet.shape[0] // 3
    for row, text in enumerate((*titles, "|difference| x3")):
        cv2.putText(label, text, (6, row * h + a_h // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.imwrite(out, np.concatenate([label, sheet], axis=1))
    print(f"-> {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="verb", required=True)
    r = sub.add_parser("render")
    r.add_argument("grasps")
    r.add_argument("out")
    r.add_argument("--shading", choices=("blinn_phong", "pbr"), help="colour shader (default: the generator's)")
    r.add_argument("--frames", type=int, nargs="+", default=FRAMES, help="frame indices of the default layout")
    c = sub.add_parser("compare")
    c.add_argument("before")
    c.add_argument("after")
    c.add_argument("out")
    c.add_argument("--titles", nargs=2, default=("before", "after"))
    args = parser.parse_args()
    if args.verb == "render":
        render(args.grasps, args.out, args.shading, tuple(args.frames))
    else:
        compare(args.before, args.after, args.out, tuple(args.titles))


if __name__ == "__main__":
    main()
