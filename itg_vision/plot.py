"""Every figure of itg_vision. The only module that imports matplotlib (Agg backend)."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from . import outputs  # noqa: E402


def _save(fig, path) -> None:
    """Render the figure to PNG bytes and write them atomically."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)
    outputs.write_bytes(path, buf.getvalue())


#: Below this a log axis draws a value at the floor, as an open downward triangle (below it).
FLOOR_MM = 1e-3
#: Markers and line styles per series, so that series lying on each other stay told apart.
_MARKERS = ("o", "s", "^", "D", "P", "X", "*", "h")
_STYLES = ("-", "--", "-.", ":")


def _shown(text: str) -> str:
    """A title as it can be drawn: a file name's bytes that are not UTF-8 (Python keeps them as
    lone surrogates, which matplotlib cannot draw) become U+FFFD."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


#: Tick labels as plain decimals (0.05, 20), not powers of ten.
_PLAIN = FuncFormatter(lambda v, _: f"{v:g}")


#: Labelled ticks per decade of a log axis: 1, 2, 5; on an axis where they label fewer than
#: three values (less than about a decade shown), the denser set.
LOG_SUBS = (1.0, 2.0, 5.0)
LOG_SUBS_NARROW = (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 7.0)


class _LogTicks(LogLocator):
    """:data:`LOG_SUBS` per decade, or :data:`LOG_SUBS_NARROW` where those leave fewer than
    three ticks inside the axis (E_av from 5.7 to 42 mm was labelled at 10 and 20 alone)."""

    def tick_values(self, vmin, vmax):
        lo, hi = sorted((vmin, vmax))
        for subs in (LOG_SUBS, LOG_SUBS_NARROW):
            self.set_params(subs=subs)
            ticks = super().tick_values(vmin, vmax)
            if np.count_nonzero((ticks >= lo) & (ticks <= hi)) >= 3:
                break
        return ticks


def plain_log_ticks(axis) -> None:
    """Ticks of a log axis at 1, 2 and 5 per decade (more where that leaves fewer than three
    inside the axis), written as plain decimals (0.05, 20), not as powers of ten."""
    axis.set_major_locator(_LogTicks())
    axis.set_major_formatter(_PLAIN)
    axis.set_minor_formatter(NullFormatter())


def lap_slices(n: int, laps: int) -> list[slice]:
    """The set points of each lap of an ``n``-point run of ``laps`` equal laps."""
    laps = max(1, int(laps))
    per = n // laps
    return [slice(k * per, n if k == laps - 1 else (k + 1) * per) for k in range(laps)]


def _reach_marks(trace) -> list[tuple[np.ndarray, str, str, str]]:
    """(set points, marker, colour, label) for the set points the arm cannot reach (left out of
    the metrics) and those the controller flagged out of reach that the arm can reach."""
    gone = ~trace.in_reach
    flagged = trace.out_of_reach & ~gone
    return [(w, m, c, label) for w, m, c, label in (
        (gone, "x", "C3", "out of reach"), (flagged, "+", "C1", "flagged out of reach, reachable"))
        if w.any()]


#: Up to this many laps each gets a colour of its own and a legend entry; more share a
#: colour map (first lap to last), and only the first and the last are named.
MAX_NAMED_LAPS = 10


def lap_style(k: int, laps: int, what: str = "actual gripper") -> tuple:
    """Colour and legend label of lap ``k`` (from 0) of ``laps``: a label per lap up to
    :data:`MAX_NAMED_LAPS`, beyond them the first and the last only (matplotlib's
    "_nolegend_" for the others: no entry)."""
    if laps <= 1:
        return "C0", what
    if laps <= MAX_NAMED_LAPS:
        return f"C{k}", f"{what}, lap {k + 1}"
    color = plt.get_cmap("viridis")(k / (laps - 1))
    return color, (f"{what}, lap {k + 1} (of {laps}; laps between in the colours between)"
                   if k == 0 else f"{what}, lap {k + 1}" if k == laps - 1 else "_nolegend_")


def marked_laps(laps: int) -> range:
    """The laps after the first whose start the error figure marks: each, up to
    :data:`MAX_NAMED_LAPS`; beyond them about ten, evenly (1000 marks drew a black band)."""
    step = max(1, -(-laps // MAX_NAMED_LAPS))
    return range(step, laps, step)


def path_figure(trace, title: str, path, *, laps: int = 1) -> None:
    """Desired against actual path (x-y for planar arms, 3-D with equal scales for the
    three-link arm). The actual gripper is drawn as dots, a colour per lap; the desired path as
    a thin dark line over them, so that both stay seen; the base behind them."""
    d = np.asarray(trace.desired_mm)
    g = np.asarray(trace.gripper_mm)
    marks = _reach_marks(trace)
    if trace.planar:
        fig, ax = plt.subplots(figsize=(5.5, 5.5))
        ax.plot(0, 0, "^", color="0.55", ms=7, zorder=1, label="base")
        for k, part in enumerate(lap_slices(len(g), laps)):
            color, label = lap_style(k, laps)
            ax.plot(g[part, 0], g[part, 1], ".", ms=4, color=color, zorder=2,
                    label=label)
        ax.plot(d[:, 0], d[:, 1], "-", color="k", lw=0.7, zorder=3, label="desired")
        for which, marker, color, label in marks:
            ax.plot(d[which, 0], d[which, 1], marker, color=color, zorder=4, label=label)
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    else:
        fig = plt.figure(figsize=(6, 5.5))
        ax = fig.add_subplot(projection="3d")
        ax.plot([0], [0], [0], "^", color="0.55", ms=7, label="base")
        for k, part in enumerate(lap_slices(len(g), laps)):
            color, label = lap_style(k, laps)
            ax.plot(g[part, 0], g[part, 1], g[part, 2], ".", ms=4, color=color,
                    label=label)
        ax.plot(d[:, 0], d[:, 1], d[:, 2], "-", color="k", lw=0.7, label="desired")
        for which, marker, color, label in marks:
            ax.plot(d[which, 0], d[which, 1], d[which, 2], marker, color=color, label=label)
        pts = np.vstack([d, g, np.zeros((1, 3))])
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        mid, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, 1.0) * 1.05
        ax.set_xlim(mid[0] - half[0], mid[0] + half[0])
        ax.set_ylim(mid[1] - half[1], mid[1] + half[1])
        ax.set_zlim(mid[2] - half[2], mid[2] + half[2])
        ax.set_box_aspect(half)  # a millimetre is as long on every axis
        ax.locator_params(nbins=5)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
    ax.set_title(_shown(title), fontsize=9)
    # beside the axes, as the other figures': inside, a lap's long label (past MAX_NAMED_LAPS)
    # made the legend wider than the equal-scaled axes, over the gripper's dots and the ticks
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02 if trace.planar else 1.08, 1))
    _save(fig, path)


def error_figure(trace, title: str, path, *, laps: int = 1) -> None:
    """E_i along the trajectory: log scale above 0.01 mm, linear below (so that a zero shows);
    laps after the first and set points where a marker was missed are marked."""
    e = trace.error_mm()
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(np.where(trace.in_reach, e, np.nan), "-", color="C0", lw=1)
    marks = _reach_marks(trace)
    for which, _, color, label in marks:
        ax.plot(np.flatnonzero(which), np.zeros(which.sum()), "|", color=color, label=label)
    missed = np.array([any(f.startswith("missed:") for f in r.flags) for r in trace.records], bool)
    if missed.any():
        ax.plot(np.flatnonzero(missed), e[missed], "o", mfc="none", ms=4, color="C1",
                label=f"a marker missed ({missed.sum()} set points)")
    parts = lap_slices(len(e), laps)
    for k in marked_laps(laps):
        ax.axvline(parts[k].start - 0.5, color="0.6", ls=":", lw=0.8)
        ax.annotate(f"lap {k + 1}", (parts[k].start, 0), xycoords=("data", "axes fraction"),
                    xytext=(2, 3), textcoords="offset points", fontsize=7, color="0.4")
    m = trace.metrics()  # the summary's numbers, not a second computation of them
    tracked = m["track_max_mm"] is not None
    if tracked:
        ax.axvline(trace.tracking_start - 0.5, color="0.4", ls="--", lw=0.8,
                   label=f"tracking phase: median {m['track_median_mm']:.3g} / "
                         f"p95 {m['track_p95_mm']:.3g} / max {m['track_max_mm']:.3g} mm")
    if marks or tracked or missed.any():
        ax.legend(fontsize=8)
    ax.set_xlabel("set point i")
    ax.set_ylabel("E_i (mm)\nlog scale, linear below 0.01")
    ax.set_yscale("symlog", linthresh=0.01)  # log above 0.01 mm, so that the tracking shows
    ax.set_ylim(bottom=0)
    ax.yaxis.set_major_formatter(_PLAIN)
    ax.grid(alpha=0.3)
    ax.set_title(_shown(title), fontsize=9)
    _save(fig, path)


def _floored(y, logy: bool):
    """(drawn, below): ``y`` with values under :data:`FLOOR_MM` put at the floor on a log axis,
    and which ones were."""
    y = np.asarray(y, float)
    below = logy & np.isfinite(y) & (y < FLOOR_MM)
    return np.where(below, FLOOR_MM, y), below


def _floor_and_spread(ax, x, y, below, spread, color, logy: bool) -> None:
    """What a series of :func:`lines_figure` or :func:`grouped_dots_figure` draws besides its
    values: an open downward triangle at the floor for each value below it, and, if ``spread``
    is (q1s, q3s), the interquartile range as whiskers."""
    if below.any():
        ax.plot(x[below], y[below], "v", mfc="none", ms=6, color=color)
    if spread:
        lo, hi = (_floored(v, logy)[0] for v in spread)
        ax.vlines(x, lo, hi, color=color, lw=0.9, alpha=0.7)


def _legend_notes(ax, below: bool, spread: bool, flag_label: str = "") -> None:
    """Legend entries for the marks drawn: values below the floor, whiskers, ringed cells."""
    if below:
        ax.plot([], [], "v", mfc="none", color="0.3", label=f"below {FLOOR_MM:g} mm, drawn there")
    if spread:
        ax.plot([], [], "|", color="0.3", ms=10, label="whisker: interquartile range")
    if flag_label:
        ax.plot([], [], "o", ms=11, mfc="none", mec="C3", mew=1.3, label=flag_label)


def _log_label(label: str, log: bool) -> str:
    """An axis label that says its scale is logarithmic (ticks 5 and 10 alone read as linear)."""
    return f"{label}, log scale" if log else label


def lines_figure(series: dict, xlabel: str, ylabel: str, title: str, path, *, logx=False,
                 logy=False, marker=True, hlines=(), vlines=(), vspans=(), references=None) -> None:
    """Generic curves: ``series`` maps a label to (x, y) arrays, each with its own marker and
    line style (series lying on each other stay seen). With ``logy``, a value below
    :data:`FLOOR_MM` is drawn at the floor as an open downward triangle, not joined to the
    curve. ``hlines``: (y, label[, colour]) drawn dashed (a threshold); ``vspans``: (x0, x1,
    label) bands shaded (a tolerance; the label is shown once); ``references``: label -> (x, y)
    curves that are not measurements (e.g. a slope), thin grey lines without markers;
    ``vlines``: (x, label[, colour]) drawn dashed (a threshold along x); an hline's fourth
    item is its line style (default dashed). Log axes say so in
    their labels.
    ``marker=None`` (or False) draws the series without markers. A series given as (x, y, q1, q3) also
    draws its interquartile range (over seeds) as whiskers."""
    fig, ax = plt.subplots(figsize=(6, 3.8))
    any_below = any_spread = False
    for i, (label, (x, y, *spread)) in enumerate(series.items()):
        x = np.asarray(x, float)
        y, below = _floored(y, logy)
        mk = _MARKERS[i % len(_MARKERS)] if marker else None
        line, = ax.plot(x, np.where(below, np.nan, y), marker=mk, ms=4, lw=1.2, color=f"C{i % 10}",
                        ls=_STYLES[(i // 10) % len(_STYLES)] if len(series) > 10 else "-",
                        mfc="none" if i % 2 else None, label=label)
        _floor_and_spread(ax, x, y, below, spread, line.get_color(), logy)
        any_spread |= bool(spread)
        any_below |= bool(below.any())
    for j, (label, (x, y)) in enumerate((references or {}).items()):
        ax.plot(x, y, ls=_STYLES[1 + j % 3], color="0.45", lw=0.9, label=label)
    for y, label, *style in hlines:
        ax.axhline(y, color=style[0] if style else "k", ls=style[1] if len(style) > 1 else "--",
                   lw=0.9, label=label)
    for x, label, *color in vlines:
        ax.axvline(x, color=color[0] if color else "k", ls="--", lw=0.9, label=label)
    shown = set()
    for x0, x1, label in vspans:
        ax.axvspan(x0, x1, color="0.85", zorder=0, label=None if label in shown else label)
        shown.add(label)
    _legend_notes(ax, any_below, any_spread)
    if logx:
        ax.set_xscale("log")
        plain_log_ticks(ax.xaxis)
    if logy:
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
    ax.set_xlabel(_log_label(xlabel, logx))
    ax.set_ylabel(_log_label(ylabel, logy))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1))  # beside: curves stay seen
    ax.set_title(_shown(title), fontsize=9)
    _save(fig, path)


def paths_figure(panels: list, title: str, path, *, laps: int = 1) -> None:
    """Several planar paths side by side: ``panels`` is a list of (subtitle, trace) or
    (subtitle, trace, jumps), ``jumps`` a list of (i, j, label): the desired path is not drawn
    from set point i to j (no set point lies between them), a dashed line is, labelled. The
    actual gripper is drawn a colour per lap (``laps`` equal laps), as in :func:`path_figure`."""
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 5), squeeze=False)
    for ax, (sub, trace, *jumps) in zip(axes[0], panels):
        d, g = np.asarray(trace.desired_mm), np.asarray(trace.gripper_mm)
        for k, part in enumerate(lap_slices(len(g), laps)):
            color, label = lap_style(k, laps, "actual")
            ax.plot(g[part, 0], g[part, 1], ".", ms=4, zorder=2, color=color,
                    label=label)
        cuts = sorted(i for i, _, _ in (jumps[0] if jumps else ()))
        first = True
        for part in np.split(np.arange(len(d)), [i + 1 for i in cuts]):
            ax.plot(d[part, 0], d[part, 1], "-", color="k", lw=0.7, zorder=3,
                    label="desired" if first else None)
            first = False
        for i, j, label in (jumps[0] if jumps else ()):
            ax.plot(d[[i, j], 0], d[[i, j], 1], "--", color="C3", lw=1, zorder=3, label=label)
        ax.set_aspect("equal")
        ax.set_title(_shown(sub), fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.legend(fontsize=8)
    fig.suptitle(_shown(title), fontsize=10)
    _save(fig, path)


def grouped_dots_figure(categories: list, values: dict, ylabel: str, title: str, path, *,
                        logy=False, spread: dict | None = None, flagged: dict | None = None,
                        flag_label: str = "", empty_label: str = "no value",
                        notes: dict | None = None) -> None:
    """A dot chart: ``values`` maps a series label to one value per category (NaN: no dot), the
    series side by side in each category, each with its own marker, and the value written
    beside it. Dots, not bars: on a log axis a bar's length would mean nothing. With
    ``logy``, a value below :data:`FLOOR_MM` is drawn at the floor as an open downward
    triangle. ``spread`` maps a series label to (q1s, q3s), whiskers per category (the
    interquartile range over seeds). ``flagged`` maps a series label to booleans per category: those dots are ringed
    in red and ``flag_label`` says why (e.g. a run diverged). A category no series has a value
    in is written ``empty_label`` (e.g. no run finished), not left blank; ``notes`` maps a
    series label to a text per category ("" for none) written where that series' dot would be
    (e.g. why its cell has no value: some runs did not start)."""
    n = max(1, len(values))
    width = 0.8 / n
    x = np.arange(len(categories))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.55 * len(categories) * max(1, n / 2) + 2), 4.2))
    any_below = any_flag = False
    for i, (label, ys) in enumerate(values.items()):
        xs = x + (i - (n - 1) / 2) * width
        ys, below = _floored(ys, logy)
        dots, = ax.plot(np.where(below, np.nan, xs), ys, _MARKERS[i % len(_MARKERS)], ms=5,
                        ls="none", label=label, color=f"C{i % 10}")  # its own (not the cycle's:
        # a ring drawn below takes the cycle's next)
        _floor_and_spread(ax, xs, ys, below, (spread or {}).get(label), dots.get_color(), logy)
        any_below |= bool(below.any())
        for xv, yv, b in zip(xs, ys, below):
            if np.isfinite(yv):
                ax.annotate(f"<{FLOOR_MM:g}" if b else f"{yv:.3g}", (xv, yv), xytext=(0, 5),
                            textcoords="offset points", fontsize=6, ha="center",
                            rotation=90, va="bottom", color=dots.get_color())
        for xv, note in zip(xs, (notes or {}).get(label, ())):
            if note:  # a cell left out: say why where its dot would be, in its colour
                ax.text(xv, 0.02, note, transform=ax.get_xaxis_transform(), rotation=90,
                        ha="center", va="bottom", fontsize=6, color=dots.get_color())
        hit = np.asarray((flagged or {}).get(label, np.zeros(len(categories), bool)), bool)
        if hit.any():
            any_flag = True
            ax.plot(xs[hit], ys[hit], "o", ms=11, mfc="none", mec="C3", mew=1.3)
    for k in range(1, len(categories)):  # where one category ends
        ax.axvline(k - 0.5, color="0.85", lw=0.8, zorder=0)
    for k in range(len(categories)):  # a category without a value says so, not left blank
        if not any(np.isfinite(float(ys[k])) for ys in values.values()):
            ax.text(k, 0.5, empty_label, transform=ax.get_xaxis_transform(), rotation=90,
                    ha="center", va="center", fontsize=7, color="0.4")
    _legend_notes(ax, any_below, bool(spread), flag_label if any_flag else "")
    ax.set_xticks(x)
    ax.set_xticklabels(categories, rotation=35, ha="right", fontsize=8)
    ax.set_xlim(-0.5, len(categories) - 0.5)
    if logy:
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        lo, hi = ax.get_ylim()
        ax.set_ylim(lo, hi * 3)  # room for the values written above the dots
    ax.set_ylabel(_log_label(ylabel, logy))
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1))  # beside: dots stay seen
    ax.set_title(_shown(title), fontsize=9)
    _save(fig, path)
