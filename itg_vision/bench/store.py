"""The noise benchmark's results store: ``results.csv`` and ``sweep.json`` in ``--out``.

- ``results.csv``: one row per run, every parameter and every metric (:data:`COLUMNS`).
  Appended one row at a time (flush + fsync), so an interruption never loses a finished row; a
  restart with the same ``--out`` skips the ``run_id`` s already there; a torn (partial) last
  line or a damaged row is dropped, named, and its run redone (:class:`Results`).
- ``sweep.json``: the sweep's definition (its hash and the options that made it) and the code
  that started it (:func:`code_hash`; each row has its own in its ``code`` column). A different
  definition in the same folder is refused, no row touched (:func:`check_sweep_file`); a resume
  by other code is allowed with a warning counting the rows other code made
  (:func:`code_warning`): run ids cover the parameters and the files a run reads (rule file,
  arm file, rigs, trajectory file), not the code.
"""

from __future__ import annotations

import codecs
import contextlib
import csv
import dataclasses
import functools
import hashlib
import io
import json
import math
import os
from collections import Counter
from pathlib import Path

from .. import outputs
from ..provenance import code_hash
from ..errors import UserError
from .sweep import SCHEMA, RunSpec, input_files

#: Per-run metrics from the run's summary (see itg_vision.loop.Trace.metrics).
RUN_METRICS = ["e_av_mm", "e_max_mm", "e_rms_mm", "tracking_from", "track_median_mm",
               "track_mean_mm", "track_p95_mm", "track_max_mm", "n_setpoints", "n_missed",
               "n_missed_gripper", "n_missed_elbow", "n_elbow_turned", "n_out_of_reach",
               "n_flagged", "est_gripper_rms_mm", "est_elbow_rms_mm", "start_error_mm",
               "first_error_mm", "wall_s"]
COLUMNS = (["run_id", "controller", "condition", "trajectory", "arm", "points", "laps", "seed",
            "rc_controller", "feedback", "noise_mm", "noise_px", "dropout", "rig", "rig_sha",
            "inputs_sha", "link_error_pct", "offset_deg", "links_mm", "true_links_mm",
            "joint_offset_deg", "measured_links_mm", "measured_length_se_mm", "iterations",
            "max_step_deg", "correction", "preview", "rules", "rules_sha", "controller_params"]
           + RUN_METRICS
           + ["diverged", "no_start", "code"])


def definition_hash(specs: list[RunSpec]) -> str:
    text = json.dumps([SCHEMA, COLUMNS, sorted(s.run_id for s in specs)])
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return ";".join(_cell(float(x)) for x in v)
    return str(v)


def params_cell(params: dict) -> str:
    """The parameters a controller ran with, as ``name=value`` pairs joined by ``;`` in the
    order given (``gain_deg_per_mm=0.5;tolerance_mm=0.5``); empty when it takes none (IK)."""
    return ";".join(f"{k}={_cell(v)}" for k, v in params.items())


def make_row(spec: RunSpec, s: dict | None, no_start: str = "") -> dict:
    """A run's row: its spec and its summary ``s``; or, for a run that did not start
    (``s`` None), its spec and ``no_start``, why (its metrics empty)."""
    row = {"run_id": spec.run_id, **dataclasses.asdict(spec), "code": code_hash()}
    if s is None:
        row["no_start"] = no_start
        return {c: _cell(row.get(c)) for c in COLUMNS}
    row["points"] = s["n_setpoints"] // max(1, spec.laps)
    row.update({k: s.get(k) for k in ["links_mm", "true_links_mm", "joint_offset_deg"]
                + RUN_METRICS})
    row.update({f"n_missed_{m}": n for m, n in s["n_missed_by"].items()})
    row["controller_params"] = params_cell(s["controller_params"])
    row["measured_links_mm"] = s["geometry"]["links_mm"]
    row["measured_length_se_mm"] = s["geometry"]["length_se_mm"]  # the rules' sL
    row["diverged"] = "" if s["diverged"] is None else int(s["diverged"])  # loop.Trace.metrics
    return {c: _cell(row.get(c)) for c in COLUMNS}


#: ``no_start`` of a stand-in row for a run of the sweep that has no row (:func:`missing_rows`).
NO_RESULT = "no result: the run failed (see failures.log) or has not run; the same command runs it"


def missing_rows(specs, rows: list[dict]) -> list[dict]:
    """Stand-in rows (never written) for the runs of ``specs`` that have no row in ``rows``:
    ``no_start`` says :data:`NO_RESULT`, the metrics are empty, so what reads them counts the
    run as one that did not start rather than leave it out unsaid."""
    have = {r["run_id"] for r in rows}
    return [make_row(s, None, no_start=NO_RESULT) for s in specs if s.run_id not in have]


#: The file a sweep holds locked while it writes into its --out.
LOCK = ".itg_vision-lock"


@contextlib.contextmanager
def sweep_lock(out: Path):
    """Hold ``out``'s lock while a sweep writes there: a second sweep into the same folder at
    once (each appending every run to results.csv, each rewriting it at its end) is refused
    with one line. An advisory lock (``fcntl.flock``), released when the sweep ends however it
    ends; where there is no ``fcntl`` (Windows) there is no lock (:func:`outputs.flocked`)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / LOCK).touch()
    with outputs.flocked(out / LOCK, wait=False) as held:
        if not held:
            raise UserError(f"--out {out}: another sweep is writing into it now; wait for it to "
                            "end, or choose another --out")
        yield


def started(rows: list[dict]) -> list[dict]:
    """The rows of runs that started (a run whose start-up measurement failed has ``no_start``,
    why, and no metrics)."""
    return [r for r in rows if not r["no_start"]]


class Results:
    """``results.csv`` in ``--out``: read once, then append rows.

    Damage is reported and repaired, never silently kept: a torn last line (an interrupted
    write) and any damaged row (wrong number of fields, a run_id that is not 16 hex digits,
    bytes that are not UTF-8) are dropped, each named by its line number in :attr:`problems`;
    :meth:`repair` rewrites the file without them (atomically) before anything is appended, and
    their runs are redone. A byte-order mark before the header is dropped the same way. A file
    whose header is not this benchmark's is refused.
    """

    def __init__(self, path: Path):
        self.path = path
        self.rows: dict[str, dict] = {}
        self.problems: list[str] = []
        self._repaired: str | None = None
        if path.exists():
            self._load()

    def _load(self) -> None:
        import re

        try:
            data = self.path.read_bytes()
        except OSError as exc:
            raise UserError(f"{self.path}: cannot read ({exc.strerror})") from None
        if data.startswith(codecs.BOM_UTF8):  # a spreadsheet's "CSV UTF-8" save puts one first
            data = data[len(codecs.BOM_UTF8):]
            self.problems.append(f"{self.path}:1: a byte-order mark (the file saved by a "
                                 "spreadsheet): dropped")
            self._repaired = data.decode("utf-8", errors="replace")
        if not data:
            return
        lines = data.split(b"\n")
        last = lines.pop()  # b"" when the file ends with a newline
        if not lines and ",".join(COLUMNS).encode().startswith(last):
            self.problems.append(f"{self.path}:1: torn header (an interrupted first write): "
                                 "dropped")
            self._repaired = ""
            return
        header = lines[0] if lines else last
        if next(csv.reader([header.decode("utf-8", errors="replace")]), None) != COLUMNS:
            raise UserError(f"{self.path}: its columns are not this benchmark's (another tool's "
                            "or another version's results): choose another --out")
        keep = [header]
        for lineno, raw in enumerate(lines[1:], 2):
            try:
                fields = next(csv.reader([raw.decode("utf-8")]), [])
            except (UnicodeDecodeError, csv.Error):
                fields = None
            if fields is None or len(fields) != len(COLUMNS) or not re.fullmatch(r"[0-9a-f]{16}", fields[0]):
                got = "not UTF-8" if fields is None else f"{len(fields)} fields"
                self.problems.append(f"{self.path}:{lineno}: damaged row ({got}, expected "
                                     f"{len(COLUMNS)}): dropped, its run will be redone")
                continue
            row = dict(zip(COLUMNS, fields))
            if row["run_id"] in self.rows:  # two sweeps wrote into the same --out at once
                self.problems.append(f"{self.path}:{lineno}: a second row of run "
                                     f"{row['run_id']}: dropped, the first kept")
                continue
            keep.append(raw)
            self.rows[row["run_id"]] = row
        if last and lines:
            self.problems.append(f"{self.path}:{len(lines) + 1}: torn last line (an interrupted "
                                 "write): dropped, its run will be redone")
        if self.problems:
            self._repaired = b"".join(line + b"\n" for line in keep).decode("utf-8", errors="replace")

    def repair(self) -> None:
        """Rewrite the file without its damaged rows (atomically), before any append."""
        if self._repaired is not None:
            outputs.write_text(self.path, self._repaired)
            self._repaired = None

    def reorder(self, run_ids: list[str]) -> None:
        """Rewrite the file (atomically) with the rows of ``run_ids`` first, in that order, then
        any others in their file order: parallel runs finish in any order, and the same sweep
        must give the same file."""
        order = {r: i for i, r in enumerate(run_ids)}
        rows = sorted(self.rows.values(), key=lambda r: order.get(r["run_id"], len(order)))
        if [r["run_id"] for r in rows] == list(self.rows):
            return
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(COLUMNS)
        w.writerows([r[c] for c in COLUMNS] for r in rows)
        outputs.write_text(self.path, buf.getvalue())
        self.rows = {r["run_id"]: r for r in rows}

    def append(self, row: dict) -> None:
        """Append one row and make it durable (flush + fsync) before returning."""
        new = not self.path.exists() or self.path.stat().st_size == 0
        with open(self.path, "a", newline="", encoding="utf-8") as f:
            w = csv.writer(f, lineterminator="\n")
            if new:
                w.writerow(COLUMNS)
            w.writerow([row[c] for c in COLUMNS])
            f.flush()
            os.fsync(f.fileno())
        self.rows[row["run_id"]] = row


def check_sweep_file(out: Path, definition: str, specs: list[RunSpec], results: Results) -> None:
    """Refuse an ``--out`` holding another sweep's results (writes nothing)."""
    path = out / "sweep.json"
    if path.exists():
        try:
            stored = json.loads(path.read_text())
            old = stored["definition"]
        except (OSError, ValueError, KeyError, TypeError):
            raise UserError(f"{path}: unreadable sweep definition: choose another --out") from None
        if old != definition:
            was = " ".join(f"{k}={v}" for k, v in stored.get("options", {}).items() if v not in (None, False))
            recorded = stored.get("files") if isinstance(stored.get("files"), dict) else {}
            edited = [p for p, h in input_files(specs).items() if recorded.get(p, h) != h]
            why = (f"edited since: {', '.join(edited)}" if edited else "other options, or an "
                   "edited rule, arm, rig or trajectory file, or a new calibrated rig")
            raise UserError(f"--out {out} holds results of a different sweep definition "
                            f"({old} [{was or 'defaults'}], now {definition}; {why}): rerun "
                            "with the same options or choose another --out")
        return
    ids = {s.run_id for s in specs}
    foreign = [r for r in results.rows if r not in ids]
    if foreign:
        raise UserError(f"--out {out} holds {len(foreign)} results of a different sweep "
                        "definition (no sweep.json): choose another --out")


def code_warning(results: Results) -> str | None:
    """A one-line warning when rows of ``results`` were made by other code than this (each
    row's ``code`` column), else None."""
    now = code_hash()
    other = Counter(r["code"] for r in results.rows.values() if r["code"] != now)
    if not other:
        return None
    n = sum(other.values())
    return (f"--out {results.path.parent}: {n} of its {len(results.rows)} earlier rows were "
            f"computed by other code ({', '.join(sorted(other))}; now {now}); they are kept "
            "and reported beside the new ones: rerun into a new --out for rows of this code "
            "alone")


def record_sweep_file(out: Path, definition: str, options: dict, specs: list[RunSpec]) -> None:
    path = out / "sweep.json"
    if not path.exists():
        outputs.write_json(path, {"definition": definition, "schema": SCHEMA, "code": code_hash(),
                                  "n_runs": len(specs), "options": options,
                                  "files": input_files(specs)})

