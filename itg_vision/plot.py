"""Every figure of itg_vision. The only module that imports matplotlib (Agg backend)."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from . import outputs  # noqa: E402


def _save(fig, path) -> None:
    """Render the figure to PNG bytes and write them atomically."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)
    outputs.write_bytes(path, buf.getvalue())


def _reach_marks(trace) -> list[tuple[np.ndarray, str, str, str]]:
    """(set points, marker, colour, label) for the set points the arm cannot reach (left out of
    the metrics) and those the controller flagged out of reach that the arm can reach."""
    gone = ~trace.in_reach
    flagged = trace.out_of_reach & ~gone
    return [(w, m, c, label) for w, m, c, label in (
        (gone, "x", "C3", "out of reach"), (flagged, "+", "C1", "flagged out of reach, reachable"))
        if w.any()]


def path_figure(trace, title: str, path) -> None:
    """Desired against actual path (x-y for planar arms, 3-D for the three-link arm)."""
    d = np.asarray(trace.desired_mm)
    g = np.asarray(trace.gripper_mm)
    marks = _reach_marks(trace)
    if trace.planar:
        fig, ax = plt.subplots(figsize=(5.5, 5.5))
        ax.plot(d[:, 0], d[:, 1], "-", color="0.6", lw=2, label="desired")
        ax.plot(g[:, 0], g[:, 1], ".", ms=3, color="C0", label="actual gripper")
        for which, marker, color, label in marks:
            ax.plot(d[which, 0], d[which, 1], marker, color=color, label=label)
        ax.plot(0, 0, "k^", label="base")
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    else:
        fig = plt.figure(figsize=(6, 5.5))
        ax = fig.add_subplot(projection="3d")
        ax.plot(d[:, 0], d[:, 1], d[:, 2], "-", color="0.6", lw=2, label="desired")
        ax.plot(g[:, 0], g[:, 1], g[:, 2], ".", ms=3, color="C0", label="actual gripper")
        for which, marker, color, label in marks:
            ax.plot(d[which, 0], d[which, 1], d[which, 2], marker, color=color, label=label)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    _save(fig, path)


def error_figure(trace, title: str, path) -> None:
    """E_i along the trajectory."""
    e = trace.error_mm()
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(np.where(trace.in_reach, e, np.nan), "-", color="C0", lw=1)
    marks = _reach_marks(trace)
    for which, _, color, label in marks:
        ax.plot(np.flatnonzero(which), np.zeros(which.sum()), "|", color=color, label=label)
    m = trace.metrics()  # the summary's numbers, not a second computation of them
    tracked = m["track_max_mm"] is not None
    if tracked:
        ax.axvline(trace.tracking_start - 0.5, color="0.4", ls="--", lw=0.8,
                   label=f"tracking phase: median {m['track_median_mm']:.3g} / "
                         f"p95 {m['track_p95_mm']:.3g} / max {m['track_max_mm']:.3g} mm")
    if marks or tracked:
        ax.legend(fontsize=8)
    ax.set_xlabel("set point i")
    ax.set_ylabel("E_i (mm)")
    ax.set_yscale("symlog", linthresh=0.01)  # log above 0.01 mm, so that the tracking shows
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.set_title(title, fontsize=9)
    _save(fig, path)


def lines_figure(series: dict, xlabel: str, ylabel: str, title: str, path, *, logx=False,
                 logy=False, marker="o", hlines=(), vspans=()) -> None:
    """Generic curves: ``series`` maps a label to (x, y) arrays. ``hlines``: (y, label[, colour])
    drawn dashed (a threshold); ``vspans``: (x0, x1, label) bands shaded (a tolerance; the
    label is shown once)."""
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for label, (x, y) in series.items():
        ax.plot(x, y, marker=marker, ms=3, lw=1.2, label=label)
    for y, label, *color in hlines:
        ax.axhline(y, color=color[0] if color else "k", ls="--", lw=0.9, label=label)
    shown = set()
    for x0, x1, label in vspans:
        ax.axvspan(x0, x1, color="0.85", zorder=0, label=None if label in shown else label)
        shown.add(label)
    if logx:
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1))  # beside: curves stay seen
    ax.set_title(title, fontsize=9)
    _save(fig, path)


def paths_figure(panels: list, title: str, path) -> None:
    """Several planar paths side by side: ``panels`` is a list of (subtitle, trace)."""
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 5), squeeze=False)
    for ax, (sub, trace) in zip(axes[0], panels):
        d, g = np.asarray(trace.desired_mm), np.asarray(trace.gripper_mm)
        ax.plot(d[:, 0], d[:, 1], "-", color="0.6", lw=2, label="desired")
        ax.plot(g[:, 0], g[:, 1], ".", ms=3, label="actual")
        ax.set_aspect("equal")
        ax.set_title(sub, fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    _save(fig, path)


def grouped_bars_figure(categories: list, values: dict, ylabel: str, title: str, path, *,
                        logy=False) -> None:
    """Grouped bars: ``values`` maps a series label to one value per category (NaN: no bar).

    With ``logy``, values below 1e-3 are drawn at 1e-3 (the axis' floor)."""
    n = max(1, len(values))
    width = 0.8 / n
    x = np.arange(len(categories))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.55 * len(categories) * max(1, n / 2) + 2), 4.2))
    for i, (label, ys) in enumerate(values.items()):
        ys = np.asarray(ys, float)
        if logy:
            ys = np.where(np.isfinite(ys), np.maximum(ys, 1e-3), np.nan)
        ax.bar(x + (i - (n - 1) / 2) * width, ys, width, label=label)
    ax.set_xticks(x)
    ax.set_xticklabels(categories, rotation=35, ha="right", fontsize=8)
    if logy:
        ax.set_yscale("log")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1))  # beside: bars stay seen
    ax.set_title(title, fontsize=9)
    _save(fig, path)
