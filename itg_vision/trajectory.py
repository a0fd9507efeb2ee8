"""Desired trajectories: the paper's named ones, a quintic time law, and a CSV reader.

Points are in mm, shape (n, 3); planar trajectories have z = 0 (ignored by planar arms).
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import MAX_POINTS, ConfigError, UserError
from .inputs import clip, count, read_text
from .shipped import (TRAJECTORIES_DIR, TRAJECTORY_NAMES, names_a_path, not_found, or_a_path,
                      trajectory_file_names)


@dataclass(frozen=True)
class Trajectory:
    """A sequence of set points.

    Attributes
    ----------
    name : a name or the CSV path.
    points_mm : shape (n, 3).
    t_s : shape (n,) or None: the time of each set point.
    param_deg : shape (n,) or None: the ellipse's radial angle of each point (experiment 5).
    planar : True when the points carry no z.
    closed : True when the path returns to its start (the last point is followed by the
        first): such a path can be run for several laps.
    laps : how many times the points of one lap are repeated in ``points_mm``.
    file : the CSV file it was read from, absolute (the run's record and its input hash name
        it wherever the run goes on); None for a named trajectory.
    """

    name: str
    points_mm: np.ndarray = field(repr=False)
    t_s: np.ndarray | None = field(default=None, repr=False)
    param_deg: np.ndarray | None = field(default=None, repr=False)
    planar: bool = True
    closed: bool = False
    laps: int = 1
    file: Path | None = None  # the CSV read, absolute; None for a named trajectory

    def __len__(self) -> int:
        return len(self.points_mm)

    @property
    def tracking_start(self) -> int:
        """Index of the first set point of the tracking phase: the laps after the first for a
        path run for 2+ laps, else the second half (the start transient is over by then)."""
        n = len(self.points_mm)
        return n // self.laps if self.laps > 1 else n // 2

    def repeated(self, laps: int) -> "Trajectory":
        """The same closed path run ``laps`` times (set points, times and angles repeated).

        Raises
        ------
        ConfigError : ``laps`` < 1, or > 1 on a path that is not closed.
        """
        if laps < 1 or laps > 1000:
            raise ConfigError("laps", f"must be in 1..1000, got {laps}")
        if laps > 1 and not self.closed:
            raise ConfigError("laps", f"trajectory {self.name} has {len(self.points_mm)} set "
                                      "points; a path run in laps needs at least 4 (to tell "
                                      "that it closes)" if len(self.points_mm) < 4 else
                                      f"trajectory {self.name} is not a closed path (its last "
                                      "point is not next to its first): it can run only once")
        if laps == 1:
            return self
        # a path that repeats its start as its last point is not given that point twice at
        # each seam: its laps share it (one set point, once)
        p = self.points_mm
        shared = len(p) > 2 and np.array_equal(p[0], p[-1])
        total = laps * (len(p) - 1) + 1 if shared else laps * len(p)
        if total > MAX_POINTS:  # a run's memory and trace.csv grow with its set points
            most = (MAX_POINTS - 1) // (len(p) - 1) if shared else MAX_POINTS // len(p)
            raise ConfigError("laps", f"{laps} laps of the {len(p)} set points of trajectory "
                                      f"{self.name} make {total}; a run holds at most "
                                      f"{MAX_POINTS} set points (as --points): at most "
                                      f"{count(most, 'lap')} of this path")

        def tiled(v, shift=0.0):  # v per set point, one lap -> all laps
            one = v[:-1] if shared else v
            parts = [one + k * shift for k in range(laps)]
            return np.concatenate(parts + ([v[-1:] + (laps - 1) * shift] if shared else []))

        period = None
        if self.t_s is not None and len(self.t_s) > 1:
            period = float(self.t_s[-1] - self.t_s[0]) + (
                0.0 if shared else float(np.median(np.diff(self.t_s))))
        return Trajectory(self.name, tiled(p),
                          None if period is None else tiled(self.t_s, period),
                          None if self.param_deg is None else tiled(self.param_deg),
                          self.planar, self.closed, self.laps * laps, self.file)


def ellipse(name, centre_mm, major_mm, minor_mm, orientation_deg, n=180) -> Trajectory:
    """n points on an ellipse, uniformly 360/n degrees apart in the radial (parameter) angle."""
    theta = np.radians(np.arange(n) * 360.0 / n)
    c, s = math.cos(math.radians(orientation_deg)), math.sin(math.radians(orientation_deg))
    a, b = major_mm / 2.0, minor_mm / 2.0
    u, v = a * np.cos(theta), b * np.sin(theta)
    pts = np.column_stack([centre_mm[0] + c * u - s * v, centre_mm[1] + s * u + c * v,
                           np.zeros(n)])
    return Trajectory(name, pts, None, np.degrees(theta), True, closed=True)


def is_closed(points_mm: np.ndarray) -> bool:
    """Whether the last point is followed by the first (a loop sampled without repeating its
    start): their distance, the closing step, is at most 1.5 times the path's median step, or
    within a factor 1.5 of the step beside it, its first or its last; repeated points (dwells)
    are no steps. A loop sampled densely in its corners and sparsely along its sides closes with
    a side's step; a jump at either end does not close a path whose ends are far apart, unless
    the closing step matches that jump."""
    p = np.asarray(points_mm, float)
    if len(p) < 4:
        return False
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    steps = steps[steps > 0]  # a dwell (a repeated point) is no step
    gap = float(np.linalg.norm(p[-1] - p[0]))
    if not steps.size:
        return gap == 0
    return gap <= 1.5 * float(np.median(steps)) or any(
        e / 1.5 <= gap <= 1.5 * e for e in (steps[0], steps[-1]))


def quintic(s: np.ndarray) -> np.ndarray:
    """The paper's motion parameter lambda = 10 s^3 - 15 s^4 + 6 s^5, s = t / t_r in [0, 1]."""
    s = np.asarray(s, float)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def line(name, a_mm, b_mm, duration_s=10.0, n=100) -> Trajectory:
    """n points from a to b at times uniformly spread over [0, duration] along the quintic."""
    t = np.linspace(0.0, duration_s, n)
    lam = quintic(t / duration_s)[:, None]
    a, b = np.asarray(a_mm, float), np.asarray(b_mm, float)
    return Trajectory(name, a + lam * (b - a), t, None, False)


def segments(name, corners_mm, per_segment: int) -> Trajectory:
    """Experiment 1: set points along A-B and C-D, with a jump (no set point) from B to C."""
    A, B, C, D = (np.asarray(p, float) for p in corners_mm)
    s = np.linspace(0.0, 1.0, per_segment)[:, None]
    pts = np.vstack([A + s * (B - A), C + s * (D - C)])
    return Trajectory(name, np.column_stack([pts, np.zeros(len(pts))]), None, None, True)


#: Experiment 1's corners (mm): a 120 mm stroke at y = 120, a 100 mm jump down, and back.
ABCD_MM = ((-60.0, 120.0), (60.0, 120.0), (60.0, 20.0), (-60.0, 20.0))
#: Experiment 6: the paper's line (B is out of reach of 100/100/100 mm links) and the reachable
#: variant, the same segment scaled by 0.42 about the arm's shoulder ((0, 0, 100) for the
#: paper's arm): same direction, same quintic and duration, 134 mm long, both ends within
#: 190 mm of the shoulder.
LINE_AB_MM = ((50.0, 30.0, 220.0), (250.0, 200.0, 400.0))
REACH_SCALE = 0.42
#: The arms these trajectories are defined on, when no arm is given: the paper's.
PAPER_ARM = {"line-ab": "three-link", "line-ab-reach": "three-link", "arc": "one-link"}


def line_ab_reach_mm(shoulder_mm) -> tuple[np.ndarray, np.ndarray]:
    """A' and B': the paper's A and B scaled by ``REACH_SCALE`` about the shoulder (mm)."""
    s = np.asarray(shoulder_mm, float)
    return tuple(s + REACH_SCALE * (np.array(p) - s) for p in LINE_AB_MM)

NAMES = TRAJECTORY_NAMES
DEFAULT_POINTS = {"ellipse-t1": 180, "ellipse-t2": 180, "abcd": 200, "line-ab": 100,
                  "line-ab-reach": 100, "arc": 180}


def named(name: str, n_points: int | None = None, arm=None) -> Trajectory:
    """A trajectory of the paper by name (see ``NAMES``); ``n_points`` overrides the default.

    ``arm`` (an `itg_vision.arm.ArmSpec`, default the paper's arm of the trajectory) places the
    trajectories defined on it: ``line-ab-reach`` about its shoulder, ``arc`` on its reach.
    """
    if name not in NAMES:
        raise UserError(f"unknown trajectory {name!r} (choose from {', '.join(NAMES)}; the "
                        f"shipped files {', '.join(trajectory_file_names())}; "
                        f"{or_a_path(name, 'a CSV file', '.csv')})")
    n = DEFAULT_POINTS[name] if n_points is None else int(n_points)
    if n < 2 or (name == "abcd" and n % 2):
        raise ConfigError("points", f"{name} needs {'an even number of' if name == 'abcd' else 'at least 2'} "
                                    f"points, got {n}")
    if name == "ellipse-t1":
        return ellipse(name, (20.0, -30.0), 130.0, 80.0, -45.0, n)
    if name == "ellipse-t2":
        return ellipse(name, (-30.0, 40.0), 125.0, 100.0, -45.0, n)
    if name == "abcd":
        return segments(name, ABCD_MM, n // 2)
    if name == "line-ab":
        return line(name, *LINE_AB_MM, 10.0, n)
    if arm is None and name in PAPER_ARM:
        from .arm import ArmSpec

        arm = ArmSpec.from_args(PAPER_ARM[name])
    if name == "line-ab-reach":
        return line(name, *line_ab_reach_mm(arm.shoulder_mm()), 10.0, n)
    # arc: 270 degrees of the one-link arm's circle, from +y clockwise
    radius = arm.reach_mm()[1]
    theta = np.radians(90.0 - np.arange(n) * 270.0 / (n - 1))
    pts = np.column_stack([radius * np.cos(theta), radius * np.sin(theta), np.zeros(n)])
    return Trajectory(name, pts, None, None, True)


#: The largest coordinate a trajectory file may give (mm): a kilometre, far beyond any arm here.
MAX_COORD_MM = 1e6
#: The largest time a trajectory file may give (s): an epoch time even in nanoseconds, and far
#: from where 1000 laps' times, going on by a period each, would overflow to inf.
MAX_TIME_S = 1e18
#: A number as a trajectory file may write it: ASCII digits, an optional sign, point and
#: exponent (Python's float() also takes 1_000, full-width and Arabic-Indic digits).
DECIMAL = re.compile(r"[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")


#: The largest trajectory CSV read (bytes): room for MAX_POINTS rows of x, y, z and t_s written
#: at numpy's full precision (~100 bytes a row), not the 1 MiB of a rule or rig file, which
#: refused a 12000-row robot log with times.
MAX_CSV_BYTES = 16 << 20


def _header_hint(header: list[str], allowed) -> str:
    """What a refused header probably means, where that is clear ('' where it is not)."""
    line = ",".join(header)
    if line.lstrip().startswith("#"):
        return ": a comment line is not read; the header comes first"
    for sep, name in ((";", "semicolons"), ("\t", "tabs")):
        if len(header) == 1 and sep in line:
            return f": fields are separated by commas, not {name}"
    if any(sorted(header) == sorted(a) for a in allowed):
        return ": the columns in that order"
    if all(h.split("_")[0].lower() in ("x", "y", "z", "t") for h in header):
        return ": the columns are named x_mm, y_mm, z_mm (in mm) and t_s (in s)"
    return ""


def read_csv(path: str | Path) -> Trajectory:
    """A user trajectory: header ``x_mm,y_mm`` or ``x_mm,y_mm,z_mm``, optional ``t_s`` column.

    UTF-8 text of at most :data:`MAX_CSV_BYTES` (a spreadsheet's byte-order mark is dropped)
    and :data:`itg_vision.errors.MAX_POINTS` set points; every problem is one `UserError`
    naming the file, line and field.
    """
    path = Path(path)
    text = read_text(path, "trajectory CSV", limit=MAX_CSV_BYTES)
    reader = csv.reader(re.split(r"\r\n|\r|\n", text), strict=True)  # \f is no line end
    rows, starts = [], []  # each row, and the line it starts on (a quoted field may go on)
    while True:
        start = reader.line_num + 1
        try:
            rows.append(next(reader))
        except StopIteration:
            break
        except csv.Error as exc:  # a stray or unclosed quote, a field beyond csv's limit (128 KiB)
            raise UserError(f"{path}:{start}: not CSV ({exc})") from None
        starts.append(start)
    blank = [not any(cell.strip() for cell in row) for row in rows]
    if all(blank):
        raise UserError(f"{path}: empty file (expected a header x_mm,y_mm[,z_mm][,t_s])")
    if blank[0]:
        raise UserError(f"{path}:1: blank; the first line must be the header "
                        "x_mm,y_mm[,z_mm][,t_s]")
    header = [h.strip() for h in rows[0]]
    allowed = (["x_mm", "y_mm"], ["x_mm", "y_mm", "z_mm"], ["x_mm", "y_mm", "t_s"],
               ["x_mm", "y_mm", "z_mm", "t_s"])
    if header not in allowed:
        raise UserError(f"{path}:1: header must be x_mm,y_mm[,z_mm][,t_s], got "
                        f"{clip(','.join(header), 60)!r}{_header_hint(header, allowed)}")
    values, linenos = [], []
    for lineno, row, empty in zip(starts[1:], rows[1:], blank[1:]):
        if empty:
            continue
        if len(row) != len(header):
            raise UserError(f"{path}:{lineno}: expected {len(header)} fields, got {len(row)}")
        vals = []
        for col, cell in zip(header, row):
            try:
                v = float(cell)
            except ValueError:
                v = None
            if v is None or math.isfinite(v) and not DECIMAL.fullmatch(cell.strip()):
                raise UserError(f"{path}:{lineno}: field {col}: not a number: "
                                f"{clip(cell.strip())!r}")
            if not math.isfinite(v):
                raise UserError(f"{path}:{lineno}: field {col}: must be finite, got "
                                f"{clip(cell.strip())}")
            limit, unit = (MAX_TIME_S, "s") if col == "t_s" else (MAX_COORD_MM, "mm")
            if abs(v) > limit:
                raise UserError(f"{path}:{lineno}: field {col}: {clip(cell.strip())} is beyond "
                                f"+-{limit:.0e} {unit}")
            vals.append(v)
        values.append(vals)
        linenos.append(lineno)
    if len(values) < 2:
        raise UserError(f"{path}: {len(values) or 'no'} set point{'' if len(values) == 1 else 's'} "
                        "after the header; a trajectory needs at least 2 (as --points)")
    if len(values) > MAX_POINTS:
        raise UserError(f"{path}: {len(values)} set points; a trajectory holds at most "
                        f"{MAX_POINTS} (as --points)")
    arr = np.array(values)
    cols = {h: arr[:, i] for i, h in enumerate(header)}
    planar = "z_mm" not in cols
    pts = np.column_stack([cols["x_mm"], cols["y_mm"], cols.get("z_mm", np.zeros(len(arr)))])
    t = cols.get("t_s")
    if t is not None and np.any(np.diff(t) < 0):
        bad = linenos[int(np.argmax(np.diff(t) < 0)) + 1]
        raise UserError(f"{path}:{bad}: field t_s: times must not decrease")
    return Trajectory(str(path), pts, t, None, planar, closed=is_closed(pts),
                      file=Path(path).resolve())


#: A path all of whose set points lie within this fraction of the arm's outer reach of its
#: base is likely written in other units (metres under an ``x_mm`` header): :func:`span_note`.
SMALL_SPAN_FRACTION = 0.01


def span_note(trajectory: Trajectory, reach_mm: float) -> str | None:
    """A one-line note when every set point of ``trajectory`` lies within
    :data:`SMALL_SPAN_FRACTION` of ``reach_mm`` of the base (the world origin), else None: such
    a path is run as written, but a file in metres reads as a path 1000 times too small. (A
    small path elsewhere, or one set point held, is in millimetres: no note.)"""
    p = np.asarray(trajectory.points_mm, float)
    far = float(np.max(np.linalg.norm(p, axis=1)))
    if far >= SMALL_SPAN_FRACTION * reach_mm or np.all(p == p[0]):  # held: no scale to judge
        return None
    return (f"note: trajectory {trajectory.name} lies within {far:.3g} mm of the base, under "
            f"{100 * SMALL_SPAN_FRACTION:g} % of the arm's {reach_mm:g} mm reach: its "
            "coordinates are read as millimetres, not metres")


def names_a_csv_file(name: str) -> bool:
    """Whether a trajectory's name is a path to a CSV file, not a shipped or named trajectory:
    it ends in .csv (any case: .CSV too) or holds a folder separator."""
    return names_a_path(name.lower(), (".csv",))


def load(name_or_path: str, n_points: int | None = None, arm=None) -> Trajectory:
    """A named trajectory (placed on ``arm``, see :func:`named`), a CSV file's, or a shipped
    file's by its name (``peanut``: data/trajectories/peanut.csv, as the benchmark names it)."""
    if name_or_path in NAMES:
        return named(name_or_path, n_points, arm)
    p = Path(name_or_path)
    if name_or_path in trajectory_file_names():
        p = TRAJECTORIES_DIR / f"{name_or_path}.csv"
    if names_a_csv_file(name_or_path) or p.exists():
        if not p.exists():
            raise UserError(not_found(p, "trajectory", trajectory_file_names()))
        if n_points is not None:
            raise ConfigError("points", "applies to named trajectories only, not to a CSV file")
        return read_csv(p)
    return named(name_or_path, n_points)  # raises the 'unknown trajectory' error
