"""python -m itg_vision.bench noise: the noise-robustness benchmark.

ITG fed by vision against the baselines, on the same runs, under named conditions (centroid
noise, LED dropout, the rig the estimator believes, kinematic model error, and a few
combinations). Writes to ``--out``:

- ``results.csv``: one row per run, every parameter and every metric. Appended one row at a time
  (flush + fsync), so an interruption never loses a finished row; a restart with the same
  ``--out`` skips the ``run_id`` s already there and drops a torn (partial) last line.
- ``sweep.json``: the sweep definition (its hash and the options that made it). A different
  definition in the same folder is refused (exit 2), no row touched.
- ``report.md``: median [IQR] of E_av and E_max per controller per condition, and a conclusion
  generated from the numbers.
- plots: E_av against sigma, against dropout, against model error, by condition.
- ``rigs/``: a copy of each perturbed rig the estimator believed (for the record; the workers
  build their own, so a cluster needs no shared file system).

Runs go to a local process pool (``--workers``) or to a Dask cluster (``--scheduler``).

Choices (documented in the report too):
- The four controllers map onto :class:`itg_vision.runner.RunConfig`: ``itg-vision`` =
  (itg, vision), ``itg-model`` = (itg, model), ``ik`` = (ik, model: IK ignores the feedback,
  'model' wastes no rendering), ``jacobian-vision`` = (jacobian, vision).
- Conditions that only perturb vision (noise, dropout, rig) cannot change the model-fed
  controllers; they are run anyway (no rendering, a few ms each) so every table cell is filled
  from real runs. Likewise every controller is run for every seed.
- Three-link runs use ``max_step_deg=2.0`` (deg per iteration, a servo rate limit) and
  ``iterations=5``: the paper's three-link composition is not stable without a rate limit.
  Two-link runs use the defaults (gain 0.5 deg/mm, one iteration per set point).
- ``links+X%``: every link of the simulated arm is X % longer than the nominal model;
  ``offset-1deg``: every joint of the simulated arm sits 1 degree off its commanded angle.
- ``rig-perturbed``: the estimator believes the true rig moved as one body by 1 degree (about a
  random axis through the cameras' midpoint) and 5 mm (in a random direction), drawn from the
  run's seed: consistent stereo, wrong world frame. ``rig-perturbed-cams``: each camera
  perturbed on its own by 1 degree and 5 mm: the rays no longer meet (about 10 px apart), so
  the feedback's residual test rejects the markers. Images are rendered with the true rig.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import hashlib
import json
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .. import outputs
from ..arm import ArmSpec
from ..errors import UserError, run_main

# ---------------------------------------------------------------------------- the sweep
#: Bench controller name -> (RunConfig.controller, RunConfig.feedback, truth noise in mm).
CONTROLLERS: dict[str, tuple[str, str, float]] = {
    "itg-vision": ("itg", "vision", 0.0),
    "itg-model": ("itg", "model", 0.0),
    "ik": ("ik", "model", 0.0),
    "jacobian-vision": ("jacobian", "vision", 0.0),
}
#: Controllers only the ``start-tie`` sweep uses: ideal LED positions plus Gaussian noise of
#: about vision's size, many seeds cheaply.
TRUTH_NOISE_MM = 0.25
EXTRA_CONTROLLERS: dict[str, tuple[str, str, float]] = {
    "itg-truth-noise": ("itg", "truth", TRUTH_NOISE_MM),
    "jacobian-truth-noise": ("jacobian", "truth", TRUTH_NOISE_MM),
}
ALL_CONTROLLERS = {**CONTROLLERS, **EXTRA_CONTROLLERS}
CONTROLLER_TITLES = {
    "itg-vision": "ITG fed by vision (no model)",
    "itg-model": "ITG fed by encoders + nominal model",
    "ik": "closed-form IK of the nominal model, open loop",
    "jacobian-vision": "vision-fed Jacobian tracker (DLS, no model)",
    "itg-truth-noise": f"ITG fed by the simulator's LED positions + {TRUTH_NOISE_MM} mm noise",
    "jacobian-truth-noise": f"Jacobian tracker fed by the LED positions + {TRUTH_NOISE_MM} mm noise",
}
#: Trajectory -> arm. ``line-ab-reach`` is the reachable variant of the paper's line A-B.
TRAJECTORIES: dict[str, str] = {
    "ellipse-t1": "two-link",
    "ellipse-t2": "two-link",
    "abcd": "two-link",
    "line-ab-reach": "three-link",
}
NOISE_PX = (0.1, 0.3, 1.0, 2.0, 4.0)
DROPOUTS = (0.05, 0.2)
LINK_ERRORS = (0.02, 0.05)
RIG_ANGLE_DEG = 1.0
RIG_SHIFT_MM = 5.0
#: Closed paths run this many laps; the tracking phase is the laps after the first.
LAPS = 2
#: A run "diverged" when the median E_i of its tracking phase exceeds this (mm): 10 % of the
#: two- and three-link arms' 200 mm reach; tracking runs sit below 5 mm, diverged ones above 100.
DIVERGED_MM = 20.0
FULL_SEEDS = 5
QUICK = {"trajectories": ("ellipse-t1",), "points": 60, "seeds": 2,
         "conditions": ("clean", "noise-1px", "dropout-0.2", "rig-perturbed", "links+5%",
                        "noise-1px+links+5%")}
#: Named sweeps: ``robustness`` (the default: every condition) and ``start-tie`` (the
#: three-link arm from its straight-up start, many seeds: how often does it diverge?).
SWEEPS = {
    "robustness": {"controllers": tuple(CONTROLLERS), "trajectories": tuple(TRAJECTORIES),
                   "conditions": None, "seeds": FULL_SEEDS},
    "start-tie": {"controllers": ("itg-vision", "itg-truth-noise", "jacobian-vision",
                                  "jacobian-truth-noise"),
                  "trajectories": ("line-ab-reach",),
                  "conditions": ("clean", "links+2%", "links+5%"), "seeds": 40},
}
#: Bump when the meaning of a column or of a run's parameters changes.
SCHEMA = 2


@dataclass(frozen=True)
class Condition:
    """A named perturbation; fields combine in the ``+`` conditions."""

    name: str
    noise_px: float = 0.0
    dropout: float = 0.0
    rig: str = "true"  # true | calibrated | perturbed | perturbed-cams
    link_error: float = 0.0  # fraction: simulated links = (1 + link_error) * nominal
    offset_deg: float = 0.0  # every joint of the simulated arm

    @property
    def vision_only(self) -> bool:
        return self.link_error == 0 and self.offset_deg == 0

    def combine(self, other: "Condition") -> "Condition":
        def pick(a, b, zero):
            return b if a == zero else a

        return Condition(f"{self.name}+{other.name}", pick(self.noise_px, other.noise_px, 0.0),
                         pick(self.dropout, other.dropout, 0.0), pick(self.rig, other.rig, "true"),
                         pick(self.link_error, other.link_error, 0.0),
                         pick(self.offset_deg, other.offset_deg, 0.0))


def _all_conditions() -> dict[str, Condition]:
    single = [Condition("clean")]
    single += [Condition(f"noise-{s:g}px", noise_px=s) for s in NOISE_PX]
    single += [Condition(f"dropout-{p:g}", dropout=p) for p in DROPOUTS]
    single += [Condition("rig-calibrated", rig="calibrated"), Condition("rig-perturbed", rig="perturbed"),
               Condition("rig-perturbed-cams", rig="perturbed-cams")]
    single += [Condition(f"links+{100 * e:g}%", link_error=e) for e in LINK_ERRORS]
    single += [Condition("offset-1deg", offset_deg=1.0)]
    by = {c.name: c for c in single}
    combined = [("noise-1px", "links+5%"), ("noise-0.3px", "dropout-0.05"),
                ("noise-1px", "offset-1deg"), ("rig-perturbed", "links+2%")]
    for a, b in combined:
        c = by[a].combine(by[b])
        by[c.name] = c
    return by


CONDITIONS: dict[str, Condition] = _all_conditions()


@dataclass(frozen=True)
class RunSpec:
    """One run, every parameter resolved; ``run_id`` is a hash of them all."""

    controller: str
    condition: str
    trajectory: str
    arm: str
    points: int | None
    seed: int
    rc_controller: str
    feedback: str
    noise_mm: float
    noise_px: float
    dropout: float
    rig: str  # true | calibrated | perturbed | perturbed-cams
    rig_sha: str  # content hash of the calibrated rig file ("" otherwise)
    link_error: float
    offset_deg: float
    iterations: int
    max_step_deg: float | None
    laps: int

    @property
    def run_id(self) -> str:
        text = json.dumps([SCHEMA, dataclasses.asdict(self)], sort_keys=True)
        return hashlib.sha1(text.encode()).hexdigest()[:16]

    @property
    def vision(self) -> bool:
        return self.feedback == "vision"

    def cost_s(self) -> float:
        """A rough cost for the progress bar and the estimate (vision: ~28 ms per render)."""
        n = (self.points or _default_points(self.trajectory)) * self.iterations * self.laps
        return 0.6 + 0.03 * n if self.vision else 0.05 + 0.0002 * n


def _default_points(trajectory: str) -> int:
    from ..trajectory import DEFAULT_POINTS

    return DEFAULT_POINTS[trajectory]


def _parse_names(text: str | None, known, what: str, noun: str) -> tuple[str, ...] | None:
    if text is None:
        return None
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise UserError(f"--{what}: give at least one name (choose from {', '.join(known)})")
    for n in names:
        if n not in known:
            raise UserError(f"--{what}: unknown {noun} {n!r} (choose from {', '.join(known)})")
    return tuple(dict.fromkeys(names))


def calibrated_rig_path(arm: str) -> Path:
    from ..camera import default_rig_path

    return default_rig_path(arm, calibrated=True)


def build_sweep(*, quick: bool = False, seeds: int | None = None, conditions=None,
                controllers=None, trajectories=None, points: int | None = None,
                sweep: str = "robustness") -> list[RunSpec]:
    """The run specs of a sweep, in a stable order (trajectory, condition, seed, controller).

    Every controller of a trajectory runs under the same limits (``LIMITS`` of its arm);
    closed trajectories run ``LAPS`` laps.
    """
    base = SWEEPS[sweep]
    conds = conditions or (QUICK["conditions"] if quick else base["conditions"] or tuple(CONDITIONS))
    ctrls = controllers or base["controllers"]
    trajs = trajectories or (QUICK["trajectories"] if quick else base["trajectories"])
    n_seeds = seeds if seeds is not None else (QUICK["seeds"] if quick else base["seeds"])
    if n_seeds < 1:
        raise UserError(f"--seeds: must be >= 1, got {n_seeds}")
    if points is None and quick:
        points = QUICK["points"]
    if points is not None and points < 2:
        raise UserError(f"--points: must be >= 2, got {points}")
    from ..trajectory import named

    rig_sha: dict[str, str] = {}
    specs = []
    for traj_name in trajs:
        arm = TRAJECTORIES[traj_name]
        limits = ArmSpec.from_args(arm).benchmark  # the servo limit every controller runs under
        laps = LAPS if named(traj_name).closed else 1
        n = points
        if n is not None and traj_name == "abcd" and n % 2:
            n += 1  # abcd needs an even number of points (two segments)
        for cname in conds:
            cond = CONDITIONS[cname]
            sha = ""
            if cond.rig == "calibrated":
                if arm not in rig_sha:
                    rig_sha[arm] = _calibrated_rig_sha(arm)
                sha = rig_sha[arm]
            for seed in range(n_seeds):
                for ctrl in ctrls:
                    rc, fb, noise_mm = ALL_CONTROLLERS[ctrl]
                    specs.append(RunSpec(
                        ctrl, cname, traj_name, arm, n, seed, rc, fb, noise_mm, cond.noise_px,
                        cond.dropout, cond.rig, sha, cond.link_error, cond.offset_deg,
                        int(limits["iterations"]), float(limits["max_step_deg"]), laps))
    return specs


def _calibrated_rig_sha(arm: str) -> str:
    path = calibrated_rig_path(arm)
    if not path.exists():
        raise UserError(f"condition rig-calibrated needs {path}: make it with `python -m "
                        f"itg_vision.calibrate --rig {ArmSpec.from_args(arm).defaults['rig']} "
                        f"--out {path}`, or leave "
                        "the rig-calibrated conditions out with --conditions")
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12]


def definition_hash(specs: list[RunSpec]) -> str:
    text = json.dumps([SCHEMA, COLUMNS, sorted(s.run_id for s in specs)])
    return hashlib.sha1(text.encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------- rigs
def perturb_rig(rig, seed: int, *, angle_deg: float = RIG_ANGLE_DEG,
                shift_mm: float = RIG_SHIFT_MM, each_camera: bool = False,
                true_rig: str | Path | None = None):
    """A copy of ``rig`` whose extrinsics are off by ``angle_deg`` and ``shift_mm``.

    ``each_camera=False`` (condition ``rig-perturbed``): the rig moves as one body, turned by
    exactly ``angle_deg`` about a random axis through the midpoint of the camera centres and
    shifted by exactly ``shift_mm`` in a random direction: the stereo geometry stays consistent
    and every triangulated point lands in a wrong world frame (a badly measured base frame).
    ``each_camera=True`` (``rig-perturbed-cams``): each camera turns and moves on its own by those
    amounts (inconsistent stereo: rays no longer meet).

    The random directions come from ``numpy.random.default_rng([seed, 0x5EED])``. Intrinsics and
    distortion are unchanged. The copy's ``true_rig`` names the rig the images are rendered with
    (``true_rig``, default the original's file), so a run believing the copy renders with the
    truth and estimates with the copy.

    Returns
    -------
    `itg_vision.camera.Rig`
    """
    from ..camera import Rig

    rng = np.random.default_rng([int(seed), 0x5EED])

    def draw():
        axis, d = rng.normal(size=3), rng.normal(size=3)
        rvec = np.asarray(axis, float) / np.linalg.norm(axis) * math.radians(angle_deg)
        return cv2.Rodrigues(rvec)[0], shift_mm * d / np.linalg.norm(d)

    centres = [c.position_mm for c in rig.cameras]
    pivot = np.mean(centres, axis=0)
    dR, shift = draw()
    cams = []
    for cam, C in zip(rig.cameras, centres):
        if each_camera:
            dR, shift = draw()
            C_new = C + shift
        else:
            C_new = pivot + dR @ (C - pivot) + shift
        R = cam.R @ dR.T  # the camera's axes turn with the body: R' = R dR^T
        cams.append(dataclasses.replace(cam, rotation=tuple(tuple(float(v) for v in r) for r in R),
                                        translation_mm=tuple(float(v) for v in -R @ C_new)))
    truth = true_rig if true_rig is not None else (rig.true_rig or rig.source)
    if not truth:
        raise ValueError("perturb_rig: the rig has no source file; pass true_rig")
    record = {"perturbed": {"from": str(rig.source or truth), "seed": int(seed),
                            "angle_deg": float(angle_deg), "shift_mm": float(shift_mm),
                            "each_camera": bool(each_camera)}}
    return Rig(f"{rig.name}-perturbed", tuple(cams), "", record, str(Path(truth).resolve()))


# ---------------------------------------------------------------------------- one run
def run_config(spec: RunSpec, rig_path: str | None = None):
    """The :class:`itg_vision.runner.RunConfig` of a spec (``rig_path``: the rig believed)."""
    from ..runner import RunConfig

    nominal = ArmSpec.from_args(spec.arm).links_mm
    true_links = (tuple(round(v * (1.0 + spec.link_error), 9) for v in nominal)
                  if spec.link_error else None)
    offset = (spec.offset_deg,) * len(nominal) if spec.offset_deg else None
    # a condition's vision parameters reach vision-fed runs only (elsewhere they do nothing)
    vision = spec.feedback == "vision"
    return RunConfig(arm=spec.arm, trajectory=spec.trajectory, points=spec.points,
                     controller=spec.rc_controller, feedback=spec.feedback,
                     iterations=spec.iterations, max_step_deg=spec.max_step_deg, laps=spec.laps,
                     rig=rig_path if vision else None, noise_px=spec.noise_px if vision else 0.0,
                     noise_mm=spec.noise_mm if spec.feedback == "truth" else 0.0,
                     dropout=spec.dropout if vision else 0.0, seed=spec.seed,
                     true_links_mm=true_links, joint_offset_deg=offset)


def run_one(spec: RunSpec) -> dict:
    """Execute one spec (in a worker); return its results row, or ``{'run_id', 'error'}``.

    Builds its own World (PyBullet clients are per process) and, for ``rig-perturbed``, its own
    perturbed rig in memory: nothing is shared with the caller but the spec.
    """
    from ..camera import Rig, default_rig_path
    from ..runner import execute, prepare

    try:
        rig_path, rig = None, None
        if spec.vision and spec.rig == "calibrated":
            rig_path = str(calibrated_rig_path(spec.arm))
        elif spec.vision and spec.rig in ("perturbed", "perturbed-cams"):
            true_path = default_rig_path(spec.arm)
            rig = perturb_rig(Rig.from_yaml(true_path), spec.seed,
                              each_camera=spec.rig == "perturbed-cams", true_rig=true_path)
        prep = prepare(run_config(spec, rig_path), estimate_rig=rig)
        _, s = execute(prep)
    except Exception as exc:  # noqa: BLE001 - reported per run, the sweep goes on
        return {"run_id": spec.run_id, "error": f"{type(exc).__name__}: {exc}".splitlines()[0]}
    return make_row(spec, s)


#: Per-run metrics from the run's summary (see itg_vision.loop.Trace.metrics).
RUN_METRICS = ["e_av_mm", "e_max_mm", "e_rms_mm", "tracking_from", "track_median_mm",
               "track_mean_mm", "track_p95_mm", "track_max_mm", "n_setpoints", "n_missed",
               "n_out_of_reach", "est_gripper_rms_mm", "est_elbow_rms_mm", "wall_s"]
COLUMNS = (["run_id", "controller", "condition", "trajectory", "arm", "points", "laps", "seed",
            "rc_controller", "feedback", "noise_mm", "noise_px", "dropout", "rig", "rig_sha",
            "link_error", "offset_deg", "links_mm", "true_links_mm", "joint_offset_deg",
            "measured_links_mm", "iterations", "max_step_deg", "gain"] + RUN_METRICS
           + ["diverged"])


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return ";".join(_cell(float(x)) for x in v)
    return str(v)


def make_row(spec: RunSpec, s: dict) -> dict:
    row = {"run_id": spec.run_id, **dataclasses.asdict(spec)}
    row["points"] = s["n_setpoints"] // max(1, spec.laps)
    row.update({k: s.get(k) for k in ["links_mm", "true_links_mm", "joint_offset_deg", "gain"]
                + RUN_METRICS})
    row["measured_links_mm"] = s["geometry"]["links_mm"]
    row["max_step_deg"] = spec.max_step_deg
    med = s.get("track_median_mm")
    row["diverged"] = "" if med is None else int(med > DIVERGED_MM)
    return {c: _cell(row.get(c)) for c in COLUMNS}


# ---------------------------------------------------------------------------- results.csv
class Results:
    """``results.csv`` in ``--out``: read once, then append rows.

    Damage is reported and repaired, never silently kept: a torn last line (an interrupted
    write) and any damaged row (wrong number of fields, a run_id that is not 16 hex digits,
    bytes that are not UTF-8) are dropped, each named by its line number in :attr:`problems`;
    :meth:`repair` rewrites the file without them (atomically) before anything is appended, and
    their runs are redone. A file whose header is not this benchmark's is refused.
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
            keep.append(raw)
            row = dict(zip(COLUMNS, fields))
            self.rows.setdefault(row["run_id"], row)
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
            raise UserError(f"--out {out} holds results of a different sweep definition "
                            f"({old} [{was or 'defaults'}], now {definition}): rerun with the same "
                            "options or choose another --out")
        return
    ids = {s.run_id for s in specs}
    foreign = [r for r in results.rows if r not in ids]
    if foreign:
        raise UserError(f"--out {out} holds {len(foreign)} results of a different sweep "
                        "definition (no sweep.json): choose another --out")


def record_sweep_file(out: Path, definition: str, options: dict, specs: list[RunSpec]) -> None:
    path = out / "sweep.json"
    if not path.exists():
        outputs.write_json(path, {"definition": definition, "schema": SCHEMA,
                                  "n_runs": len(specs), "options": options})


# ---------------------------------------------------------------------------- executors
def _outcome(spec: RunSpec, future) -> dict:
    """A finished future's row, or an error row when its worker died (reported per run)."""
    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001 - a dead or lost worker
        return {"run_id": spec.run_id, "error": f"{type(exc).__name__}: {exc}"}


def _exit_with_parent() -> None:
    """Pool initializer: end this worker as soon as its parent dies, however it dies.

    A pool's workers otherwise outlive a parent killed by SIGKILL (they wait forever on the call
    queue, whose write end they hold themselves; the resource tracker lives as long as they do;
    cpython#111873). A daemon thread waits on the parent sentinel that ``spawn`` hands every
    child (a pipe closed by the kernel when the parent exits) and then ``os._exit`` s.
    """
    import multiprocessing
    import threading

    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        parent.join()
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


class _Local:
    """A process pool (or the calling process when workers == 1). Its workers exit when this
    process dies, even by SIGKILL (see :func:`_exit_with_parent`)."""

    def __init__(self, workers: int):
        self.workers = workers
        self.pool = None
        if workers > 1:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            self.pool = ProcessPoolExecutor(max_workers=workers,
                                            mp_context=multiprocessing.get_context("spawn"),
                                            initializer=_exit_with_parent)

    def results(self, specs):
        if self.pool is None:
            for spec in specs:
                yield spec, run_one(spec)
            return
        from concurrent.futures import as_completed

        futures = {self.pool.submit(run_one, s): s for s in specs}
        for fut in as_completed(futures):
            yield futures[fut], _outcome(futures[fut], fut)

    def close(self, cancel: bool = False) -> None:
        if self.pool is None:
            return
        if cancel:  # interrupted: stop the runs in flight too (their rows were not written)
            for proc in list(getattr(self.pool, "_processes", {}).values()):
                proc.terminate()
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)


def check_scheduler_address(address: str) -> None:
    """``[tcp|tls|ws|wss://]HOST:PORT``, port 1..65535, or a `UserError` naming --scheduler.

    Checked before a Dask Client is made: one built on a malformed address raises, and the
    half-made Client then prints a traceback and hangs 10 s when garbage-collected.
    """
    import re

    m = re.fullmatch(r"(?:(tcp|tls|ws|wss)://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})", address)
    if not m or not 1 <= int(m.group(3)) <= 65535:
        raise UserError(f"--scheduler {address}: expected tcp://HOST:PORT (port 1..65535)")


class _Dask:
    """The same runs on a Dask distributed cluster (workers must be able to import itg_vision)."""

    def __init__(self, address: str, timeout_s: float = 5.0):
        check_scheduler_address(address)  # a Client that fails on a bad address hangs in __del__
        try:
            from distributed import Client
        except ImportError:
            raise UserError("--scheduler needs dask.distributed: pip install 'itg_vision[cluster]'") from None
        try:
            self.client = Client(address, timeout=f"{timeout_s}s", set_as_default=False)
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError (bad address)
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise UserError(f"--scheduler {address}: cannot connect ({msg})") from None
        self.workers = max(1, sum(w.get("nthreads", 1) for w in
                                  self.client.scheduler_info().get("workers", {}).values()))

    def results(self, specs):
        from distributed import as_completed

        futures = {self.client.submit(run_one, s, key=f"itg-noise-{s.run_id}", pure=False): s
                   for s in specs}
        with self.client.as_current():  # as_completed looks for the current client
            for fut in as_completed(list(futures)):
                yield futures[fut], _outcome(futures[fut], fut)

    def close(self, cancel: bool = False) -> None:
        self.client.close()


# ---------------------------------------------------------------------------- report
def _float(v: str) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _stats(values) -> tuple[float, float, float]:
    v = np.asarray([x for x in values if math.isfinite(x)], float)
    if not v.size:
        return (float("nan"),) * 3
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return float(med), float(q1), float(q3)


def _fmt_mm(v: float) -> str:
    if not math.isfinite(v):
        return "n/a"
    if v == 0:
        return "0"
    if abs(v) < 0.01:
        return f"{v:.0e}"
    return f"{v:.3g}" if abs(v) < 100 else f"{v:.0f}"


def _ratio(a: float, b: float) -> str:
    """How many times ``a`` is ``b`` (both errors in mm), for prose."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return "n/a"
    if b < 1e-3:
        return "> 1000x" if a >= 1.0 else f"{a / max(b, 1e-9):.3g}x"
    return f"{a / b:.2g}x"


#: Per-run statistics summarised over seeds: (column, short label).
STATS = (("e_av_mm", "E_av"), ("e_max_mm", "E_max"), ("track_median_mm", "median"),
         ("track_mean_mm", "mean"), ("track_p95_mm", "p95"), ("track_max_mm", "max"))
#: What the plots can show (``--plot-metrics``).
PLOT_METRICS = {"e_av": "E_av", "track_median": "tracking median E_i",
                "track_mean": "tracking mean E_i", "track_p95": "tracking p95 E_i",
                "track_max": "tracking max E_i"}


def summarize(rows: list[dict]) -> dict:
    """(trajectory, condition, controller) -> per-run statistics over seeds.

    ``s["track_max"] = (median, q1, q3)`` over seeds of each run's statistic (keys: the
    ``STATS`` columns without ``_mm``), ``worst_max`` the largest tracking-phase E_i of any
    seed, ``diverged`` and ``n`` the number of diverged runs and of runs.
    """
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["trajectory"], r["condition"], r["controller"]), []).append(r)
    out = {}
    for key, rs in groups.items():
        s = {col.removesuffix("_mm"): _stats(_float(r[col]) for r in rs) for col, _ in STATS}
        worst = [_float(r["track_max_mm"]) for r in rs]
        s.update({"worst_max": max((w for w in worst if math.isfinite(w)), default=float("nan")),
                  "diverged": sum(r["diverged"] == "1" for r in rs),
                  "missed": float(np.mean([_float(r["n_missed"]) for r in rs])),
                  "wall": float(np.sum([_float(r["wall_s"]) for r in rs])), "n": len(rs)})
        out[key] = s
    return out


def _limits_line(specs: list[RunSpec], traj: str) -> str:
    s = next(s for s in specs if s.trajectory == traj)
    phase = (f"{s.laps} laps, tracking phase = laps 2..{s.laps}" if s.laps > 1
             else "tracking phase = second half of the set points")
    limit = ("no servo limit" if s.max_step_deg is None
             else f"servo limit {s.max_step_deg:g} deg/iteration")
    return (f"Every controller: {limit} (each joint), {s.iterations} iteration(s) per set point, "
            f"{phase}.")


def _grid(summary, traj, conds, ctrls, cell) -> list[str]:
    """A markdown table, a row per condition and a column per controller: ``cell(s)``."""
    lines = ["| condition | " + " | ".join(ctrls) + " |", "|---|" + "---|" * len(ctrls)]
    for c in conds:
        cells = [cell(summary[(traj, c, k)]) if (traj, c, k) in summary else "-" for k in ctrls]
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    return lines


def _table(summary, traj, conds, ctrls, metric) -> list[str]:
    """Median [IQR] over seeds of one per-run statistic."""
    def cell(s):
        med, q1, q3 = s[metric]
        return f"{_fmt_mm(med)} [{_fmt_mm(q1)}, {_fmt_mm(q3)}]"

    return _grid(summary, traj, conds, ctrls, cell)


def _tail_table(summary, traj, conds, ctrls) -> list[str]:
    """Tracking phase per cell: median / mean / p95 / max of E_i (medians over seeds), the
    worst max of any seed, and the diverged runs."""
    def cell(s):
        text = " / ".join(_fmt_mm(s[m][0]) for m in ("track_median", "track_mean", "track_p95",
                                                     "track_max"))
        text += f" ({_fmt_mm(s['worst_max'])})"
        return text + (f" **{s['diverged']}/{s['n']} diverged**" if s["diverged"] else "")

    return _grid(summary, traj, conds, ctrls, cell)


def _compare(med, trajs, conds, a_ctrl, b_ctrl):
    wins, losses, ties = [], [], []
    for t in trajs:
        for c in conds:
            a, b = med.get((t, c, a_ctrl)), med.get((t, c, b_ctrl))
            if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)):
                continue
            item = (t, c, a, b)
            if abs(a - b) <= 0.05 * max(a, b) + 0.01:
                ties.append(item)
            elif a < b:
                wins.append(item)
            else:
                losses.append(item)
    return wins, losses, ties


def conclusion(summary, trajs, conds, ctrls, subject: str = "itg-vision") -> list[str]:
    """Plain-words findings computed from the medians over seeds (thresholds stated inline)."""
    out = []
    if subject not in ctrls:
        return [f"({subject} not in this sweep: no comparison.)"]
    for metric, label in (("e_av", "E_av (the paper's metric, start transient included)"),
                          ("track_mean", "tracking-phase mean E_i"),
                          ("track_max", "tracking-phase max E_i (the tail)")):
        med = {k: v[metric][0] for k, v in summary.items()}
        parts = []
        for other in [c for c in ctrls if c != subject]:
            wins, losses, ties = _compare(med, trajs, conds, subject, other)
            n = len(wins) + len(losses) + len(ties)
            if not n:
                continue
            text = (f"vs `{other}`: lower in {len(wins)} of {n} cells, higher in "
                    f"{len(losses)}, within 5 % + 0.01 mm in {len(ties)}")
            if losses:
                t, c, a, b = max(losses, key=lambda w: w[2] / max(w[3], 1e-9))
                text += (f" (largest loss: {c} on {t}, {_fmt_mm(a)} against {_fmt_mm(b)} mm, "
                         f"{_ratio(a, b)})")
            parts.append(text)
        if parts:
            out.append(f"- **{label}**, median over seeds, `{subject}`: " + "; ".join(parts) + ".")
    if "clean" in conds:
        model_conds = [c for c in conds if not CONDITIONS[c].vision_only]
        for t in trajs:
            parts = []
            for k in ctrls:
                base = summary.get((t, "clean", k))
                if base is None:
                    continue
                deltas = [f"{c} {summary[(t, c, k)]['track_median'][0] - base['track_median'][0]:+.2f}"
                          for c in model_conds if (t, c, k) in summary
                          and math.isfinite(summary[(t, c, k)]["track_median"][0])]
                if deltas:
                    parts.append(f"{k}: " + ", ".join(deltas))
            if parts:
                out.append(f"- **Model error on {t}** (change of the median tracking E_i from "
                           "clean, mm): " + "; ".join(parts) + ".")
    div = [(key, s) for key, s in summary.items() if s["diverged"]]
    if div:
        out.append(f"- **Diverged runs** (tracking-phase median E_i > {DIVERGED_MM:g} mm): "
                   + "; ".join(f"{k} {c} on {t}: {s['diverged']} of {s['n']}"
                               for (t, c, k), s in sorted(div)) + ".")
    elif summary:
        out.append(f"- No run diverged (tracking-phase median E_i > {DIVERGED_MM:g} mm).")
    return out


def write_report(out: Path, rows: list[dict], specs: list[RunSpec], command: str,
                 failures: dict[str, str], plot_metrics=("e_av", "track_median", "track_max")
                 ) -> list[Path]:
    """report.md and the plots from the rows of this sweep; returns the plot paths."""
    from .. import plot

    ids = {s.run_id for s in specs}
    rows = [r for r in rows if r["run_id"] in ids]
    trajs = list(dict.fromkeys(s.trajectory for s in specs))
    conds = list(dict.fromkeys(s.condition for s in specs))
    ctrls = list(dict.fromkeys(s.controller for s in specs))
    summary = summarize(rows)
    seeds = sorted({s.seed for s in specs})
    pts = {t: sorted({int(_float(r["points"])) for r in rows if r["trajectory"] == t}) for t in trajs}
    wall = sum(_float(r["wall_s"]) for r in rows)
    L = ["# Noise-robustness benchmark", "",
         f"Produced by `{command}`.", "",
         f"{len(rows)} of {len(specs)} runs in `results.csv`"
         + (" (partial sweep: rerun the command to finish it)" if len(rows) < len(specs) else "")
         + f"; {len(seeds)} seeds per cell; simulated time in runs {wall:.0f} s.", ""]
    if failures:
        L += [f"**{len(failures)} runs failed** this time (rerun to retry): "
              + "; ".join(f"{k}: {v}" for k, v in list(failures.items())[:3]), ""]
    L += ["## Setup", "",
          "Controllers, on the same runs (same trajectory, condition, seed, servo limit):", ""]
    L += [f"- `{k}`: {CONTROLLER_TITLES[k]} (RunConfig controller={ALL_CONTROLLERS[k][0]}, "
          f"feedback={ALL_CONTROLLERS[k][1]})" for k in ctrls]
    L += ["", "Trajectories: " + ", ".join(
        f"`{t}` ({TRAJECTORIES[t]}, {'/'.join(map(str, pts[t])) or '?'} set points per lap)"
        for t in trajs) + ".", ""]
    L += [f"- `{t}`: {_limits_line(specs, t)}" for t in trajs]
    L += ["", "Under vision (or truth) feedback the rules' link lengths and the Jacobian "
          "tracker's shoulder and LED stand-off are measured from the LEDs at start-up "
          "(`measured_links_mm` in results.csv); only `itg-model` and `ik` use the nominal model. "
          "The Jacobian tracker scales a step whose largest joint increment exceeds the servo "
          "limit as a whole (keeping its direction); the loop clips every controller's joints "
          "to the same limit.", "",
          "Conditions: `noise-Spx` adds Gaussian noise of S px std to each centroid coordinate; "
          "`dropout-P` drops each LED detection with probability P; `rig-calibrated` estimates "
          "with the calibrated rig (`cameras/<rig>.calib.yaml`); `rig-perturbed` with the true "
          "rig moved as one body by 1 degree and 5 mm (a wrong world frame, consistent stereo); "
          "`rig-perturbed-cams` with each camera turned by 1 degree and moved by 5 mm on its own "
          "(inconsistent stereo); random directions drawn from the seed; `links+X%` makes every "
          "link of the simulated arm X % longer than the nominal model; `offset-1deg` puts every "
          "simulated joint 1 degree off its command; `a+b` combines both. Images are always "
          "rendered with the true rig.", "",
          "Vision-only conditions (noise, dropout, rig) cannot affect `itg-model` and `ik` "
          "(no rendering): they are run anyway, a few ms each, so every cell comes from real "
          "runs (their numbers equal clean). `ik` is deterministic: its IQR is zero.", "",
          "E_i = distance from the set point to the true gripper after the set point's "
          "iterations (x-y for planar arms). E_av and E_max: mean and maximum over all set "
          "points in reach (the paper's definition, start transient included). Tracking phase: "
          "the laps after the first on closed paths, else the second half; per run its median, "
          "mean, 95th percentile and max of E_i. Tables give the median over seeds of each "
          f"run's statistic, mm; a run diverged when its tracking median exceeds {DIVERGED_MM:g} mm.",
          ""]
    L += ["## Conclusion", ""] + conclusion(summary, trajs, conds, ctrls) + [""]
    for t in trajs:
        lim = _limits_line(specs, t)
        L += [f"## {t}: E_av (mm), median [IQR] over seeds", "", lim, ""] \
            + _table(summary, t, conds, ctrls, "e_av") + [""]
        L += [f"## {t}: tracking phase (mm): median / mean / p95 / max of E_i (worst seed's max)",
              "", lim, ""] + _tail_table(summary, t, conds, ctrls) + [""]
    plots = _plots(out, summary, trajs, conds, ctrls, plot, plot_metrics)
    if plots:
        L += ["## Plots", ""] + [f"![{p.stem}]({p.name})" for p in plots] + [""]
    outputs.write_text(out / "report.md", "\n".join(L))
    return plots


def _plots(out: Path, summary, trajs, conds, ctrls, plot, metrics) -> list[Path]:
    made = []

    def med(t, c, k, metric):
        s = summary.get((t, c, k))
        return s[metric][0] if s else float("nan")

    def curve(t, k, pairs, metric):
        xs, ys = [], []
        for x, c in pairs:
            y = med(t, c, k, metric)
            if math.isfinite(y):
                xs.append(x)
                ys.append(max(y, 1e-3))  # exact IK: drawn at the floor
        return xs, ys

    for t in trajs:
        for name, field_, xlabel in (("sigma", "noise_px", "centroid noise sigma (px)"),
                                     ("dropout", "dropout", "LED dropout probability"),
                                     ("model_error", "link_error", "link length error (%)")):
            pairs = [(0.0, "clean")] if "clean" in conds else []
            for c in conds:
                cd = CONDITIONS[c]
                others = dataclasses.replace(cd, name="", **{field_: Condition.__dataclass_fields__[field_].default})
                if getattr(cd, field_) and others == Condition(""):  # this factor alone
                    x = getattr(cd, field_) * (100 if field_ == "link_error" else 1)
                    pairs.append((x, c))
            if len(pairs) < 2:
                continue
            pairs.sort()
            for metric in metrics:
                label = PLOT_METRICS[metric]
                series = {k: curve(t, k, pairs, metric) for k in ctrls}
                series = {k: v for k, v in series.items() if v[0]}
                path = out / f"{metric}_vs_{name}-{t}.png"
                plot.lines_figure(series, xlabel, f"median over seeds of {label} (mm; < 0.001 "
                                  "drawn at 0.001)", f"{t}: {label} against {xlabel}", path,
                                  logy=True)
                made.append(path)
        for metric in metrics:
            values = {k: [med(t, c, k, metric) for c in conds] for k in ctrls}
            path = out / f"{metric}_by_condition-{t}.png"
            plot.grouped_bars_figure(conds, values, f"median over seeds of {PLOT_METRICS[metric]} (mm)",
                                     f"{t}: {PLOT_METRICS[metric]} per controller and condition",
                                     path, logy=True)
            made.append(path)
    return made


# ---------------------------------------------------------------------------- command line
#: The name this benchmark writes into its output folder's manifest.
COMMAND = "bench noise"


def check_out(out: Path) -> None:
    """Refuse an ``--out`` this benchmark must not write into (`UserError`, writes nothing).

    Allowed: a new path, an empty folder, or a folder this benchmark made (its manifest, or a
    ``sweep.json`` written by an earlier version): it resumes there. Anything else (a file, a
    folder of other things, another command's output) is refused: report.md and the plots
    would be written over whatever is there. The folder must be writable.
    """
    path = outputs.check_path(out)
    if path.exists() and not path.is_dir():
        raise UserError(f"--out {out}: exists and is not a folder")
    if path.is_dir() and any(path.iterdir()):
        made = outputs.read_manifest(path)
        if made is not None and made.get("command") != COMMAND:
            raise UserError(f"--out {out}: holds the output of `{made.get('command')}`; choose "
                            "another --out")
        if made is None and not (path / "sweep.json").is_file():
            raise UserError(f"--out {out}: is a folder this benchmark did not make; choose "
                            "another --out")
    outputs.probe_folder(path)


def build_parser() -> argparse.ArgumentParser:
    from ..errors import ArgumentParser  # one-line option errors

    ap = ArgumentParser(
        prog="python -m itg_vision.bench noise",
        description="Noise-robustness benchmark: ITG fed by vision against ITG + nominal model, "
                    "open-loop IK and a vision-fed Jacobian tracker, under centroid noise, LED "
                    "dropout, rig errors and kinematic model errors. Writes results.csv, "
                    "report.md and plots to --out; rerun with the same --out to resume. "
                    "Pool workers exit when this process dies, however it dies.")
    ap.add_argument("--out", default="runs/bench-noise", metavar="DIR",
                    help="output folder (default %(default)s; --quick: runs/bench-noise-quick; "
                         "--sweep start-tie: runs/bench-start-tie); a folder this benchmark made "
                         "(rerun to resume), an empty or a new one")
    ap.add_argument("--sweep", default="robustness", choices=tuple(SWEEPS),
                    help="robustness (default: every condition, 4 trajectories, "
                         f"{FULL_SEEDS} seeds) or start-tie (the three-link arm from its "
                         "straight-up start, links +0/2/5 %%, 40 seeds: how often it diverges)")
    ap.add_argument("--plot-metrics", metavar="A,B,...", default="e_av,track_median,track_max",
                    help="what the plots show, any of " + ", ".join(PLOT_METRICS)
                         + " (default %(default)s)")
    ap.add_argument("--quick", action="store_true",
                    help=f"reduced sweep (< 2 min on 2 cores): {QUICK['trajectories'][0]} with "
                         f"{QUICK['points']} points, {QUICK['seeds']} seeds, conditions "
                         + ", ".join(QUICK["conditions"]).replace("%", "%%"))
    ap.add_argument("--seeds", type=int, metavar="K",
                    help=f"seeds per cell (default {FULL_SEEDS}; --quick {QUICK['seeds']})")
    ap.add_argument("--workers", type=int, metavar="N",
                    help="local worker processes (default: the number of CPUs; 1 = this process)")
    ap.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                    help="run on this Dask distributed scheduler instead of a local pool "
                         "(pip install 'itg_vision[cluster]')")
    ap.add_argument("--conditions", metavar="A,B,...",
                    help="only these conditions (see --list)")
    ap.add_argument("--controllers", metavar="A,B,...",
                    help="only these controllers: " + ", ".join(ALL_CONTROLLERS))
    ap.add_argument("--trajectories", metavar="A,B,...",
                    help="only these trajectories: " + ", ".join(TRAJECTORIES))
    ap.add_argument("--points", type=int, metavar="N",
                    help="set points per trajectory (default: the trajectory's; --quick "
                         f"{QUICK['points']})")
    ap.add_argument("--limit", type=int, metavar="N",
                    help="run at most N of the remaining runs this time (the rest on a rerun)")
    ap.add_argument("--list", action="store_true",
                    help="list the conditions and controllers, and the sweep's size; run nothing")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)

    def body() -> int:
        args = build_parser().parse_args(argv)
        conds = _parse_names(args.conditions, CONDITIONS, "conditions", "condition")
        ctrls = _parse_names(args.controllers, ALL_CONTROLLERS, "controllers", "controller")
        plot_metrics = _parse_names(args.plot_metrics, PLOT_METRICS, "plot-metrics", "metric")
        trajs = _parse_names(args.trajectories, TRAJECTORIES, "trajectories", "trajectory")
        if args.workers is not None and args.workers < 1:
            raise UserError(f"--workers: must be >= 1, got {args.workers}")
        if args.limit is not None and args.limit < 0:
            raise UserError(f"--limit: must be >= 0, got {args.limit}")
        if args.list:
            print("controllers: " + ", ".join(ALL_CONTROLLERS))
            print("conditions:  " + ", ".join(CONDITIONS))
            print("trajectories: " + ", ".join(TRAJECTORIES))
        specs = build_sweep(quick=args.quick, seeds=args.seeds, conditions=conds,
                            controllers=ctrls, trajectories=trajs, points=args.points,
                            sweep=args.sweep)
        n_vision = sum(s.vision for s in specs)
        cost = sum(s.cost_s() for s in specs)
        if args.list:
            print(f"sweep: {len(specs)} runs ({n_vision} with rendering), ~{cost / 60:.1f} "
                  "min of work")
            return 0
        out = Path(args.out)
        if args.out == build_parser().get_default("out"):
            out = Path("runs/bench-noise-quick" if args.quick else
                       "runs/bench-noise" if args.sweep == "robustness" else f"runs/bench-{args.sweep}")
        check_out(out)
        options = {"sweep": args.sweep, "quick": args.quick, "seeds": args.seeds,
                   "conditions": args.conditions,
                   "controllers": args.controllers, "trajectories": args.trajectories,
                   "points": args.points}
        definition = definition_hash(specs)
        results = Results(out / "results.csv")
        # every refusal comes before any write: a foreign --out keeps every row
        check_sweep_file(out, definition, specs, results)
        executor = _Dask(args.scheduler) if args.scheduler else _Local(
            args.workers or os.cpu_count() or 1)
        outputs.write_json(out / outputs.MANIFEST, outputs.manifest(COMMAND))
        record_sweep_file(out, definition, options, specs)
        results.repair()
        for msg in results.problems:
            print(f"warning: {msg}", file=sys.stderr)
        todo = [s for s in specs if s.run_id not in results.rows]
        if args.limit is not None:
            todo = todo[: args.limit]
        todo_cost = sum(s.cost_s() for s in todo)
        n_workers = executor.workers
        where = f"Dask at {args.scheduler}" if args.scheduler else f"{n_workers} local worker(s)"
        print(f"noise sweep {definition}: {len(specs)} runs ({n_vision} with rendering), "
              f"{len(results.rows)} already done, {len(todo)} to run on {where}: "
              f"estimated {todo_cost / n_workers / 60:.1f} min", file=sys.stderr)
        failures: dict[str, str] = {}
        command = "python -m itg_vision.bench noise " + " ".join(
            a for a in argv if a not in ("--quiet",))
        try:
            _run_all(executor, todo, results, failures, args.quiet)
        except BaseException:
            executor.close(cancel=True)
            raise
        executor.close()
        rows = list(results.rows.values())
        plots = write_report(out, rows, specs, command.strip(), failures, plot_metrics)
        if failures:
            outputs.write_text(out / "failures.log",
                               "".join(f"{k}\t{v}\n" for k, v in failures.items()))
        done = sum(1 for s in specs if s.run_id in results.rows)
        print(f"{done} of {len(specs)} runs in {out / 'results.csv'}; report {out / 'report.md'}; "
              f"{len(plots)} plots", file=sys.stderr)
        if failures:
            print(f"error: {len(failures)} runs failed (see {out / 'failures.log'}); rerun the "
                  "same command to retry them", file=sys.stderr)
            return 1
        return 0

    return run_main(body)


def _run_all(executor, todo: list[RunSpec], results: Results, failures: dict, quiet: bool) -> None:
    from ..progress import progress

    weight = {s.run_id: max(1, round(100 * s.cost_s())) for s in todo}  # estimated cost, 10 ms
    bar = progress(sum(weight.values()), "noise sweep", quiet=quiet or not todo, unit="",
                   bar_format="{desc}: {percentage:3.0f}%|{bar}| {postfix} [{elapsed}<{remaining}]")
    n_done = 0
    bar.set_postfix_str(f"0/{len(todo)} runs")
    try:
        for spec, res in executor.results(todo):
            if "error" in res:
                failures[spec.run_id] = f"{spec.controller} {spec.condition} {spec.trajectory} " \
                                        f"seed {spec.seed}: {res['error']}"
                bar.write(f"run failed: {failures[spec.run_id]}", file=sys.stderr)
            else:
                results.append(res)
            n_done += 1
            bar.update(weight[spec.run_id])
            bar.set_postfix_str(f"{n_done}/{len(todo)} runs")
    finally:
        bar.close()


if __name__ == "__main__":
    sys.exit(main())
