"""The leaderboard's two plots: test MPJPE against inference latency, and validation MPJPE against training time.

Drawn on matplotlib's Agg canvas in its default style (the user's matplotlibrc is set aside) at a fixed size,
with a PNG ``Software`` tag naming only the versions that decide the pixels: the same rows give the same bytes.
Reported (paper) rows have no latency or training curve and are drawn as horizontal reference lines.

Convention: errors in mm, latency in ms per image at batch 1, times in seconds inside and minutes or hours on
the axes.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Sequence

from hupbench.evaluation.leaderboard_table import inference_latency_ms, plot_label, sort_key

FIGSIZE_IN = (9.0, 6.0)
DPI = 100  # FIGSIZE_IN x DPI = 900 x 600 px
#: latencies, or test errors, spread over more than this ratio (largest / smallest) are drawn on a log axis
LATENCY_LOG_RATIO = 20.0
#: validation errors spread over more than this ratio are drawn on a log axis (a first pass is often ten times the last)
TRAINING_LOG_RATIO = 5.0
#: inches of figure height per row listed under the latency plot
LIST_ROW_IN = 0.13


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the ``(x, y)`` points no other point beats (no worse on both, better on one; lower is
    better), ordered by x, then y, then index; identical points do not dominate each other."""
    front = []
    for i, (xi, yi) in enumerate(points):
        dominated = any(xj <= xi and yj <= yi and (xj < xi or yj < yi) for j, (xj, yj) in enumerate(points) if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (points[i][0], points[i][1], i))


@contextlib.contextmanager
def _figure(rows: list[dict], extra_height_in: float = 0.0):
    """(figure, axes, reported rows) on the Agg canvas (no pyplot, no global backend switch) in matplotlib's
    default style, the reported rows drawn as reference lines; ``extra_height_in`` inches are added below
    the axes (for a list of the points)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    with matplotlib.rc_context():
        matplotlib.rcdefaults()  # the user's matplotlibrc must not change the committed bytes
        fig = Figure(figsize=(FIGSIZE_IN[0], FIGSIZE_IN[1] + extra_height_in), dpi=DPI)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        reported = [row for row in rows if row["kind"] == "reported"]
        _draw_references(ax, reported)
        yield fig, ax, reported


def _png_bytes(fig, ax, xlabel: str, ylabel: str, title: str, legend_loc: str, bottom_in: float = 0.0) -> bytes:
    """The figure as PNG bytes, labelled; ``bottom_in`` inches at the bottom are kept clear of the axes."""
    import matplotlib
    import PIL

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc=legend_loc, fontsize=8)
    height_in = fig.get_size_inches()[1]
    fig.tight_layout(rect=(0.0, bottom_in / height_in, 1.0, 1.0))
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI,
                metadata={"Software": f"hupbench leaderboard; matplotlib {matplotlib.__version__}; "
                                      f"Pillow {PIL.__version__}"})
    return buffer.getvalue()


def _plain_log_ticks(axis) -> None:
    """Ticks at 1, 2, 5 x 10^k labelled as plain numbers (``20``, not ``2 x 10^1``)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axis.set_minor_formatter(NullFormatter())


def _reference_label(row: dict) -> str:
    return f"{row['dataset']['name']}: {row['model']['name']} {row['metrics']['mpjpe_mm']['all']:.2f} mm"


_REFERENCE_STYLES = ("--", ":", "-.", (0, (5, 1, 1, 1)))


def _draw_references(ax, reported: list[dict]) -> None:
    for k, row in enumerate(reported):
        y = row["metrics"]["mpjpe_mm"]["all"]
        ax.axhline(y, color="0.35", linestyle=_REFERENCE_STYLES[k % len(_REFERENCE_STYLES)], linewidth=1.2,
                   label=_reference_label(row) + " (test, reported)")
    # in order of height, labels go alternately below and above their line, so two close lines keep
    # readable labels
    by_height = sorted(reported, key=sort_key)
    for k, row in enumerate(by_height):
        ax.text(0.01, row["metrics"]["mpjpe_mm"]["all"], " " + _reference_label(row),
                transform=ax.get_yaxis_transform(), ha="left", va="top" if k % 2 == 0 else "bottom",
                fontsize=8, color="0.25")


def _error_axis(ax, values: list[float], log_ratio: float) -> None:
    """The y axis of errors (mm) ``values``: from 0, linear; a log axis where they span more than ``log_ratio``
    times (a row whose fit diverged to metres beside rows of millimetres, a first validation beside the last)."""
    positive = [v for v in values if v > 0]
    if positive and max(positive) / min(positive) > log_ratio:
        ax.set_yscale("log")
        ax.set_ylim(min(positive) / 1.3, max(positive) * 1.3)
        _plain_log_ticks(ax.yaxis)
    else:
        ax.set_ylim(0, max(values) * 1.2 if values else 1.0)


def latency_axis(latencies_ms: Sequence[float]) -> tuple[str, float, float]:
    """("linear" | "log", low, high) x limits of the latency plot: from 0 on a linear axis, so that a few
    hundredths of a millisecond between rows look as small as they are; a log axis (a factor 2 beyond the
    extremes) where the latencies span more than ``LATENCY_LOG_RATIO`` times; 1 to 1000 ms with none."""
    if not latencies_ms:
        return "log", 1.0, 1000.0
    low, high = min(latencies_ms), max(latencies_ms)
    if high / max(low, 1e-9) > LATENCY_LOG_RATIO:
        return "log", low / 2, high * 2
    return "linear", 0.0, high * 1.15 if high > 0 else 1.0


def plot_latency(rows: list[dict]) -> bytes:
    """PNG of MPJPE all against inference latency: measured rows with a batch-1 latency as numbered points
    (the numbers listed under the plot), their Pareto frontier where it joins two or more rows, reported
    rows as horizontal reference lines."""
    points, labels, runtimes = [], [], []
    for row in rows:
        ms, runtime = inference_latency_ms(row)
        if row["kind"] == "measured" and ms is not None:
            points.append((ms, row["metrics"]["mpjpe_mm"]["all"]))
            labels.append(plot_label(row))
            runtimes.append(runtime)
    list_in = LIST_ROW_IN * (len(points) + 1) if points else 0.0  # the numbered list under the axes
    with _figure(rows, extra_height_in=list_in) as (fig, ax, reported):
        for runtime, marker in (("ONNX Runtime", "o"), ("PyTorch", "s")):
            chosen = [p for p, r in zip(points, runtimes) if r == runtime]
            if chosen:
                ax.scatter([p[0] for p in chosen], [p[1] for p in chosen], marker=marker, s=45, zorder=3,
                           color="tab:blue" if runtime == "ONNX Runtime" else "tab:orange",
                           label=f"measured, {runtime} latency (numbered as listed below)")
        for k, (x, y) in enumerate(points, start=1):
            ax.annotate(str(k), (x, y), xytext=(5, 3), textcoords="offset points", fontsize=8)
        front = [points[i] for i in pareto_front(points)]
        if len(front) > 1:  # one row alone is no frontier: a legend entry for it would name an invisible line
            ax.plot([p[0] for p in front], [p[1] for p in front], color="tab:green", linewidth=1.5, zorder=2,
                    drawstyle="steps-post", label=f"Pareto frontier ({len(front)} of {len(points)} rows)")
        scale, low, high = latency_axis([p[0] for p in points])
        ax.set_xscale(scale)
        ax.set_xlim(low, high)
        if scale == "log":
            _plain_log_ticks(ax.xaxis)
        if not points:
            ax.text(0.5, 0.5, "no measured rows with a latency yet\n(hupbench eval writes them)",
                    transform=ax.transAxes, ha="center", va="center", color="0.4")
        _error_axis(ax, [p[1] for p in points] + [r["metrics"]["mpjpe_mm"]["all"] for r in reported],
                    LATENCY_LOG_RATIO)
        if points:
            listing = "\n".join(f"{k}: {label} ({x:.2f} ms, {y:.2f} mm)"
                                 for k, (label, (x, y)) in enumerate(zip(labels, points), start=1))
            fig.text(0.01, 0.01, listing, ha="left", va="bottom", fontsize=7.5, family="monospace")
        log_scale = ", log scale" if scale == "log" else ""
        y_log = ", log scale" if ax.get_yscale() == "log" else ""
        return _png_bytes(fig, ax, f"inference latency (ms per image, batch 1{log_scale})",
                          f"test MPJPE, all 29 keypoints (mm){y_log}",
                          "Error against inference latency (lower left is better)", "best", bottom_in=list_in)


def plot_training(rows: list[dict], curves: list[tuple[dict, list[tuple[float, float]]]]) -> bytes:
    """PNG of validation MPJPE against training wall time: one line per ``(row, curve)`` of ``curves`` (a
    measured row and its training log's ``(train_wall_s, val_mpjpe_all_mm)`` points), the reported ``rows`` as
    horizontal reference lines."""
    import matplotlib

    longest_s = max((s for _, curve in curves for s, _ in curve), default=0.0)
    hours = longest_s > 2 * 3600
    scale, unit = (3600.0, "h") if hours else (60.0, "min")

    with _figure(rows) as (fig, ax, reported):
        colours = matplotlib.colormaps["tab10"].colors
        for k, (row, curve) in enumerate(curves):
            hardware = f", {row['training']['hardware']}" if row["training"]["hardware"] else ""
            ax.plot([s / scale for s, _ in curve], [m for _, m in curve], marker="o", markersize=3, linewidth=1.5,
                    color=colours[k % len(colours)], label=f"{plot_label(row)}{hardware}")
        if curves:
            ax.set_xlim(0, longest_s / scale * 1.05 if longest_s > 0 else 1.0)
        else:
            ax.set_xlim(0, 1)
            ax.text(0.5, 0.5, "no measured rows with a training log yet", transform=ax.transAxes,
                    ha="center", va="center", color="0.4")
        _error_axis(ax, [m for _, c in curves for _, m in c] + [r["metrics"]["mpjpe_mm"]["all"] for r in reported],
                    TRAINING_LOG_RATIO)
        log_scale = ", log scale" if ax.get_yscale() == "log" else ""
        return _png_bytes(fig, ax, f"training wall time ({unit}, validation passes excluded)",
                          f"validation MPJPE, all 29 keypoints (mm){log_scale}",
                          "Validation error against training time (paper lines: test split)", "upper right")
