"""The noise benchmark's sweep: controllers, conditions, trajectories and one run's spec.

A sweep is a list of :class:`RunSpec` (:func:`build_sweep`), each a run with every parameter
resolved and a ``run_id`` hashed from them; :func:`run_config` turns a spec into the
:class:`itg_vision.runner.RunConfig` a worker runs. Nothing here runs, writes or prints.

Choices (documented in the report too):
- The controllers map onto :class:`itg_vision.runner.RunConfig`: ``itg-vision`` =
  (itg, vision), ``itg-model`` = (itg, model), ``ik`` = (ik, model: IK ignores the feedback,
  'model' wastes no rendering), ``jacobian-vision`` = (jacobian, vision); ``itg-plus-vision``
  and ``itg-plus-model``: the arm file's ITG+ rule base (issue 13) fed by vision or by the
  model, its S bound to the same servo limit as every other controller.
- Conditions that only perturb vision (noise, dropout, rig) cannot change the model-fed
  controllers; they are run anyway (no rendering, a few ms each) so every table cell is filled
  from real runs. Likewise every controller is run for every seed.
- Every controller of a trajectory runs under its arm's ``benchmark`` limits
  (``data/arms/*.yaml``: the servo limit ``max_step_deg`` per iteration and ``iterations`` per
  set point), recorded in every row.
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
import dataclasses
import functools
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from ..arm import ArmSpec, arm_names, names_a_file
from ..errors import ConfigError, UserError, at_least_one
from ..inputs import file_sha256
from ..rules import PARAM_FIELDS, RULES_DIR, resolve_rules_path
from ..trajectory import names_a_csv_file

#: Bench controller name -> (RunConfig.controller, RunConfig.feedback, truth noise in mm, the
#: arm file's ``defaults`` entry naming the rule base: ``rules`` (the paper's) or
#: ``itg_plus_rules`` (issue 13's ITG+); None for the baselines).
CONTROLLERS: dict[str, tuple[str, str, float, str | None]] = {
    "itg-vision": ("itg", "vision", 0.0, "rules"),
    "itg-model": ("itg", "model", 0.0, "rules"),
    "ik": ("ik", "model", 0.0, None),
    "jacobian-vision": ("jacobian", "vision", 0.0, None),
    "itg-plus-vision": ("itg", "vision", 0.0, "itg_plus_rules"),
    "itg-plus-model": ("itg", "model", 0.0, "itg_plus_rules"),
}
#: Controllers with memory (``bench itg-plus``: is the eye's noise the floor of both trackers?):
#: the controller named, with the set point's motion fed forward and this fraction of the
#: measured error corrected per decision (``run --correction``; :func:`itg_vision.loop.aim_mm`).
#: Every other controller: 1.
FF_CORRECTION = 0.5
WITH_MEMORY = {"itg-plus-vision-ff": "itg-plus-vision", "jacobian-vision-ff": "jacobian-vision"}
CORRECTIONS = dict.fromkeys(WITH_MEMORY, FF_CORRECTION)
#: Controllers with preview (``bench itg-plus``): the controller named, aiming near the base
#: where a plan of the whole path puts the gripper (``run --preview``; :mod:`itg_vision.preview`).
WITH_PREVIEW = {"itg-plus-vision-preview": "itg-plus-vision",
                "jacobian-vision-preview": "jacobian-vision"}
#: Controllers only named sweeps use (``start-tie``, ``itg-plus``; any sweep given
#: ``--controllers``): ideal LED positions plus Gaussian noise of about vision's size, many seeds
#: cheaply; and those with memory or preview.
TRUTH_NOISE_MM = 0.25
EXTRA_CONTROLLERS: dict[str, tuple[str, str, float, str | None]] = {
    "itg-truth-noise": ("itg", "truth", TRUTH_NOISE_MM, "rules"),
    "jacobian-truth-noise": ("jacobian", "truth", TRUTH_NOISE_MM, None),
    "itg-plus-truth-noise": ("itg", "truth", TRUTH_NOISE_MM, "itg_plus_rules"),
    **{ff: CONTROLLERS[base] for ff, base in WITH_MEMORY.items()},
    **{pv: CONTROLLERS[base] for pv, base in WITH_PREVIEW.items()},
}
ALL_CONTROLLERS = {**CONTROLLERS, **EXTRA_CONTROLLERS}
CONTROLLER_TITLES = {
    "itg-vision": "ITG (the paper's rules) fed by vision (no model)",
    "itg-model": "ITG (the paper's rules) fed by encoders + nominal model",
    "ik": "closed-form IK of the nominal model, open loop",
    "jacobian-vision": "vision-fed Jacobian tracker (DLS, no model)",
    "itg-plus-vision": "ITG+ rules (issue 13) fed by vision (no model); S = the servo limit",
    "itg-plus-model": "ITG+ rules fed by encoders + nominal model; S = the servo limit",
    "itg-truth-noise": f"ITG fed by the simulator's LED positions + {TRUTH_NOISE_MM} mm noise",
    "jacobian-truth-noise": f"Jacobian tracker fed by the LED positions + {TRUTH_NOISE_MM} mm noise",
    "itg-plus-truth-noise": f"ITG+ fed by the LED positions + {TRUTH_NOISE_MM} mm noise",
    "itg-plus-vision-ff": f"ITG+ fed by vision, with memory: correction {FF_CORRECTION} "
                          "(run --correction)",
    "jacobian-vision-ff": f"Jacobian tracker fed by vision, with memory: correction "
                          f"{FF_CORRECTION}",
    "itg-plus-vision-preview": "ITG+ fed by vision, with preview (run --preview)",
    "jacobian-vision-preview": "Jacobian tracker fed by vision, with preview",
}
#: Trajectory -> arm. ``line-ab-reach`` is the reachable variant of the paper's line A-B;
#: ``peanut``, ``limacon``, ``rose``, ``lemniscate``, ``ellipse-by-base``, ``trefoil``,
#: ``gerono``, ``lemniscate-2``, ``limacon-2``, ``thin-ellipse`` (closed, two-link) and
#: ``helix`` (three-link) are files in data/trajectories; the README says which of them each
#: ITG+ form was measured on unseen.
TRAJECTORIES: dict[str, str] = {
    "ellipse-t1": "two-link",
    "ellipse-t2": "two-link",
    "abcd": "two-link",
    "line-ab-reach": "three-link",
    "peanut": "two-link",
    "helix": "three-link",
    "limacon": "two-link",
    "rose": "two-link",
    "lemniscate": "two-link",
    "ellipse-by-base": "two-link",
    "trefoil": "two-link",
    "gerono": "two-link",
    "lemniscate-2": "two-link",
    "limacon-2": "two-link",
    "thin-ellipse": "two-link",
}
TRAJECTORY_FILES = {"peanut": "peanut.csv", "helix": "helix.csv", "limacon": "limacon.csv",
                    "rose": "rose.csv", "lemniscate": "lemniscate.csv",
                    "ellipse-by-base": "ellipse-by-base.csv", "trefoil": "trefoil.csv",
                    "gerono": "gerono.csv", "lemniscate-2": "lemniscate-2.csv",
                    "limacon-2": "limacon-2.csv", "thin-ellipse": "thin-ellipse.csv"}
NOISE_PX = (0.1, 0.3, 1.0, 2.0, 4.0)
DROPOUTS = (0.05, 0.2)
LINK_ERRORS = (0.02, 0.05)
#: Conditions of the itg-plus-three-link sweep only (links 5 % short, and with a joint offset).
EXTRA_LINK_ERRORS = (-0.05,)
RIG_ANGLE_DEG = 1.0
RIG_SHIFT_MM = 5.0
#: Closed paths run this many laps; the tracking phase is the laps after the first.
LAPS = 2
FULL_SEEDS = 5
#: The most seeds a sweep takes: 1000 seeds of the full sweep are 432 000 runs, about 75 h of
#: work on one core; 100 000 spent minutes only listing its 43 million runs.
MAX_SEEDS = 1000
QUICK = {"trajectories": ("ellipse-t1",), "points": 60, "seeds": 2,
         "conditions": ("clean", "noise-1px", "dropout-0.2", "rig-perturbed", "links+5%",
                        "noise-1px+links+5%")}
#: Bump when the meaning of a column or of a run's parameters changes.
SCHEMA = 11  # 3: the gain column (always empty) became controller_params; 4: rules_sha;
#            5: inputs_sha, and the no_start column; 6: correction; 7: n_out_of_reach counts the
#            set points the simulated arm cannot reach (was: those the controller flagged, now
#            n_flagged), and the metrics leave out those, the same for every controller;
#            8: preview; 9: link_error (a fraction) became link_error_pct (in %);
#            10: n_missed_gripper, n_missed_elbow (n_missed by LED), n_elbow_turned;
#            11: measured_length_se_mm (the start-up's sL)


def seed_count(text: str) -> int:
    """An argparse ``type``: a whole number of seeds in 1..:data:`MAX_SEEDS` (the option's
    one-line error otherwise, ``argument --seeds: must be in 1..1000, got 0``)."""
    n = at_least_one(text)
    if n > MAX_SEEDS:
        raise argparse.ArgumentTypeError(f"must be in 1..{MAX_SEEDS}, got {n}")
    return n


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


def _extra_conditions(by: dict[str, Condition]) -> dict[str, Condition]:
    """Conditions only named sweeps use: links shorter than the model, and with an offset."""
    extra = {f"links{100 * e:+g}%": Condition(f"links{100 * e:+g}%", link_error=e)
             for e in EXTRA_LINK_ERRORS}
    every = {**by, **extra}
    for a in ("links-5%", "links+5%"):
        c = every[a].combine(every["offset-1deg"])
        extra[c.name] = c
    return extra


#: The robustness sweep's conditions (its default: every one of them).
_ROBUSTNESS = _all_conditions()
ROBUSTNESS_CONDITIONS: tuple[str, ...] = tuple(_ROBUSTNESS)
CONDITIONS: dict[str, Condition] = {**_ROBUSTNESS, **_extra_conditions(_ROBUSTNESS)}

#: Named sweeps: ``robustness`` (the default: every robustness condition), ``start-tie`` (the
#: three-link arm from its straight-up start, many seeds: how often does it diverge?), and
#: ``itg-plus`` / ``itg-plus-three-link`` (issue 13's targets, see ``bench itg-plus``).
SWEEPS = {
    "robustness": {"controllers": tuple(CONTROLLERS),
                   "trajectories": ("ellipse-t1", "ellipse-t2", "abcd", "line-ab-reach"),
                   "conditions": ROBUSTNESS_CONDITIONS, "seeds": FULL_SEEDS},
    "start-tie": {"controllers": ("itg-vision", "itg-truth-noise", "jacobian-vision",
                                  "jacobian-truth-noise"),
                  "trajectories": ("line-ab-reach",),
                  "conditions": ("clean", "links+2%", "links+5%"), "seeds": 40},
    # issue 13's targets (bench itg-plus): two-link tracking under vision, clean and 1 px
    # and both trackers with memory (the mechanism behind the 1 px target) and with preview
    "itg-plus": {"controllers": ("itg-plus-vision", "jacobian-vision", "itg-vision",
                                 "itg-plus-vision-ff", "jacobian-vision-ff",
                                 *WITH_PREVIEW),
                 "trajectories": ("ellipse-t1", "ellipse-t2", "abcd", "peanut", "limacon",
                                  "rose", "lemniscate", "ellipse-by-base", "trefoil",
                                  "gerono", "lemniscate-2", "limacon-2", "thin-ellipse"),
                 "conditions": ("clean", "noise-1px"), "seeds": 3},
    # three-link from the straight-up start: links -5/0/+5 % x joint offset 0/1 deg
    "itg-plus-three-link": {"controllers": ("itg-plus-vision", "jacobian-vision"),
                            "trajectories": ("line-ab-reach", "helix"),
                            "conditions": ("clean", "links-5%", "links+5%", "offset-1deg",
                                           "links-5%+offset-1deg", "links+5%+offset-1deg"),
                            "seeds": 40},
}


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
    rules: str  # the rule base of an itg controller ("" for the baselines)
    rules_sha: str  # content hash of its rule file: an edited rule base is a new run
    noise_mm: float
    noise_px: float
    dropout: float
    rig: str  # true | calibrated | perturbed | perturbed-cams
    rig_sha: str  # content hash of the calibrated rig file ("" otherwise)
    inputs_sha: str  # content hash of the arm file, the trajectory file (if any), the true rig (vision)
    link_error_pct: float  # the simulated links are this many % longer than the nominal model
    offset_deg: float
    iterations: int
    max_step_deg: float | None
    laps: int
    correction: float  # the loop's correction (1: aim at the set point; CORRECTIONS)
    preview: bool  # the loop aims by a plan of the path (WITH_PREVIEW)
    # the rule parameters given (bench noise --gain, --step, --tolerance: a user's rule bases
    # only); None: the rule base's own (run's defaults, S the servo limit if the file says so)
    gain_deg_per_mm: float | None = None
    step_deg: float | None = None
    tolerance_mm: float | None = None

    @functools.cached_property  # asked several times per run by a sweep's planning
    def run_id(self) -> str:
        # a rule parameter not given is left out: the ids of runs without any are those they
        # had before the parameters were added (a sweep resumes)
        fields = {k: v for k, v in dataclasses.asdict(self).items()
                  if not (k in PARAM_FIELDS.values() and v is None)}
        text = json.dumps([SCHEMA, fields], sort_keys=True)
        return hashlib.sha1(text.encode()).hexdigest()[:16]

    @property
    def rule_params(self) -> dict[str, float]:
        """The rule parameters given to this run (RunConfig fields), none for the shipped
        controllers."""
        return {k: getattr(self, k) for k in PARAM_FIELDS.values() if getattr(self, k) is not None}

    @property
    def vision(self) -> bool:
        return self.feedback == "vision"

    def cost_s(self) -> float:
        """A rough cost (CPU s) for the progress bar and the estimate. Vision: ~0.35 s to set up
        and measure the arm, ~2.2 ms per look of the windowed eye at supersample 3 (the full
        sweep measured 1286 CPU s for 2160 runs on 2026-12-01)."""
        n = (self.points or _default_points(self.trajectory)) * self.iterations * self.laps
        return 0.35 + 0.0022 * n if self.vision else 0.05 + 0.0002 * n


@functools.lru_cache(maxsize=None)
def _default_points(trajectory: str) -> int:
    """Set points of one lap (a file's own count: read once per process)."""
    from ..trajectory import DEFAULT_POINTS

    if trajectory in TRAJECTORY_FILES or names_a_csv_file(trajectory):
        return len(load_trajectory(trajectory))
    return DEFAULT_POINTS[trajectory]


def trajectory_label(trajectory: str) -> str:
    """What the report, the plots' file names and the progress call a trajectory: a user's
    file by its stem (:func:`user_trajectory` keeps stems apart from the shipped names)."""
    return Path(trajectory).stem if names_a_csv_file(trajectory) else trajectory


def user_trajectory(given: str, arm: str, taken) -> str:
    """A user's trajectory file (``--trajectories FILE``) for the sweep, on ``arm``: its
    absolute path (the same runs wherever the command is started), read and checked now (a
    `UserError` naming it: not found, malformed at a line, no set point in the arm's reach, a
    stem that ``taken`` (the shipped names and other files' stems) already has)."""
    from ..trajectory import load

    path = Path(given)
    try:
        traj = load(str(path))
    except UserError as exc:
        raise UserError(f"--trajectories {given}: {exc}") from None
    spec = ArmSpec.from_args(arm)
    if traj.planar != spec.planar:  # as a run refuses it, but before the sweep starts
        has = ("has z values, but the {} arm is planar (x_mm,y_mm)" if spec.planar else
               "is planar, but the {} arm needs a 3-D trajectory (x_mm,y_mm,z_mm)")
        raise UserError(f"--trajectories {given}: {has.format(spec.name)}; --arm names the "
                        "arm of trajectory files")
    if not any(spec.reachable(p) for p in traj.points_mm):
        lo, hi = spec.reach_mm()
        raise UserError(f"--trajectories {given}: none of its {len(traj.points_mm)} set points "
                        f"is in reach of the {spec.name} arm ({lo:g} to {hi:g} mm from its "
                        "shoulder; --arm names the arm of trajectory files)")
    if path.stem in taken:
        raise UserError(f"--trajectories {given}: the report and plots would call it "
                        f"{path.stem!r}, a name already taken (a benchmark trajectory or "
                        "another file): rename the file")
    return str(path.resolve())


#: The arm that tracks a sweep's trajectory files when ``--arm`` does not name one.
FILES_ARM = "two-link"


def files_arm(given: str) -> str:
    """The arm of a sweep's trajectory files (``--arm``): a shipped arm's name, or an arm
    file's absolute path (the same runs wherever the command is started), read and checked now
    (a `UserError` naming ``--arm``); its ``benchmark`` limits are the runs'."""
    try:
        ArmSpec.from_args(given)
    except UserError as exc:
        raise UserError(f"--arm {given}: {exc}") from None
    return str(Path(given).resolve()) if names_a_file(given) else given


def trajectory_source(name: str) -> str:
    """What :class:`~itg_vision.runner.RunConfig` takes: the name, or the path of its file."""
    from ..trajectory import TRAJECTORIES_DIR

    return str(TRAJECTORIES_DIR / TRAJECTORY_FILES[name]) if name in TRAJECTORY_FILES else name


def load_trajectory(name: str, points: int | None = None):
    """A benchmark trajectory (one lap, ``points`` set points of a named one), placed on its
    arm; or a user's file (:func:`user_trajectory`), as it is."""
    from ..trajectory import load

    arm = None if names_a_csv_file(name) else ArmSpec.from_args(TRAJECTORIES[name])
    return load(trajectory_source(name), points, arm=arm)


def span_notes(specs) -> list[str]:
    """The note `run` prints for a trajectory file that lies within 1 % of its arm's reach of
    the base (:func:`itg_vision.trajectory.span_note`: likely written in metres), one per
    such file the sweep ``specs`` tracks."""
    from ..trajectory import span_note

    files = dict.fromkeys((s.trajectory, s.arm) for s in specs if names_a_csv_file(s.trajectory))
    notes = (span_note(load_trajectory(t), ArmSpec.from_args(arm).reach_mm()[1])
             for t, arm in files)
    return [n for n in notes if n]


def _parse_names(text: str | None, known, what: str, noun: str,
                 files=lambda name: False) -> tuple[str, ...] | None:
    """The names of a comma-separated option, each ``known`` (or a file, by ``files``)."""
    if text is None:
        return None
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise UserError(f"--{what}: give at least one name (choose from {', '.join(known)})")
    for n in names:
        if n not in known and not files(n):
            raise UserError(f"--{what}: unknown {noun} {n!r} (choose from {', '.join(known)})")
    return tuple(dict.fromkeys(names))


def calibrated_rig_path(arm: str) -> Path:
    from ..camera import default_rig_path

    return default_rig_path(arm, calibrated=True)


@dataclass(frozen=True)
class UserRules:
    """A user's rule base in the sweep (``bench noise --rules``): two controllers,
    ``STEM-vision`` and ``STEM-model`` (:func:`rules_controllers`), run on the trajectories of
    the arms it fits (it moves or holds every joint of those and names no other), beside the
    shipped controllers. Its parameters are those given (``params``, as ``run --gain``,
    ``--step``, ``--tolerance`` give them), the others ``run``'s defaults; S is the servo limit
    if the file says so (``#! S is the servo limit``), as for the shipped ITG+ rules."""

    rules: str  # a shipped rule base's name, or the file's absolute path (the same runs
    #             wherever the command is started)
    arms: tuple[str, ...]  # the arms it fits
    params: tuple[tuple[str, float], ...] = ()  # (RunConfig field, value) of those given

    @property
    def controllers(self) -> dict[str, tuple[str, str, float, str | None]]:
        """Its controllers, as :data:`ALL_CONTROLLERS` gives the shipped ones."""
        vision, model = rules_controllers(self.rules)
        return {vision: ("itg", "vision", 0.0, None), model: ("itg", "model", 0.0, None)}


def rules_controllers(given: str) -> tuple[str, str]:
    """The names of a ``--rules`` file's controllers: its stem with ``-vision`` and ``-model``."""
    stem = Path(given).stem
    return f"{stem}-vision", f"{stem}-model"


def _load_for(path: Path, arm: str):
    """The rule file at ``path`` loaded for ``arm`` under the arm's benchmark servo limit as S,
    or why it does not load (a string)."""
    from ..rules import load_rules

    spec = ArmSpec.from_args(arm)
    try:
        return load_rules(str(path), spec.n_joints, spec.links_mm,
                          S=float(spec.benchmark["max_step_deg"]))
    except UserError as exc:
        return str(exc)


def _check_params(given: str, path: Path, arm: str, params: dict[str, float]) -> None:
    """Refuse the rule parameters ``params`` for the rule file at ``path`` on ``arm`` as ``run``
    refuses them (one the rules never use; an S other than the servo limit the file binds S
    to, here the arm's benchmark limit): a `UserError` naming ``--rules given`` and the
    option."""
    from ..options import OPTIONS
    from ..runner import RunConfig, rule_controller

    spec = ArmSpec.from_args(arm)
    servo = float(spec.benchmark["max_step_deg"])
    cfg = RunConfig(arm=arm, rules=str(path), max_step_deg=servo, **params)
    hint = (f"the benchmark runs every controller of the {arm} arm under its arm file's servo "
            "limit: give no --step")
    try:
        rule_controller(cfg, spec, servo_hint=hint)
    except ConfigError as exc:
        raise UserError(f"--rules {given}: {exc.as_option(OPTIONS)}") from None


def user_rules(given_rules, arms, params: dict[str, float] | None = None
               ) -> tuple[UserRules, ...]:
    """The rule bases ``given_rules`` (``--rules``: shipped names or files, as ``run --rules``
    reads them) as :class:`UserRules`, each tried on the sweep's ``arms`` with the rule
    parameters ``params`` (RunConfig fields: ``bench noise --gain``, ...); a
    `UserError` naming the file when it fits none of them (the file's own error: unreadable,
    a syntax error, a rule base for another arm), when it was given before (the same file),
    when its controllers' names are taken (a shipped controller's, or another file's with the
    same stem) or hold a comma (``--controllers`` could not name them), or when ``run`` would refuse ``params`` for it (:func:`_check_params`)."""
    params = dict(params or {})
    out, taken, seen = [], set(ALL_CONTROLLERS), {}
    for given in given_rules:
        try:
            path = resolve_rules_path(given)
        except UserError as exc:
            raise UserError(f"--rules {given}: {exc}") from None
        if path.resolve() in seen:
            first = seen[path.resolve()]
            also = "" if first == given else f" (as --rules {first} too: the same file)"
            raise UserError(f"--rules {given}: given twice{also}; give each rule base once")
        seen[path.resolve()] = given
        loaded = {arm: _load_for(path, arm) for arm in arms}
        why = {arm: v for arm, v in loaded.items() if isinstance(v, str)}
        fits = [arm for arm in arms if arm not in why]
        if not fits:
            its = [a for a in arm_names()
                   if a not in arms and not isinstance(_load_for(path, a), str)]
            reasons = set(why.values())  # one: the file's own error, whatever the arm
            raise UserError(f"--rules {given}: " + (
                f"fits the {' and '.join(its)} arm, not the sweep's ({', '.join(arms)}): give "
                f"--trajectories of its arm, or files of your own with --arm {its[0]}" if its else
                next(iter(reasons)) if len(reasons) == 1 else
                f"fits none of the sweep's arms ({', '.join(arms)}; choose trajectories of its "
                f"arm with --trajectories); on the {arms[0]} arm: {why[arms[0]]}"))
        for arm in fits if params else ():
            _check_params(given, path, arm, params)
        own = dict(params)
        if "step_deg" in own and loaded[fits[0]].servo_step:
            del own["step_deg"]  # checked equal to the servo limit S is bound to: the same runs
        shipped = path.parent.resolve() == RULES_DIR.resolve() and path.stem == given
        u = UserRules(given if shipped else str(path.resolve()), tuple(fits),
                      tuple(own.items()))
        if "," in path.stem:
            raise UserError(f"--rules {given}: its controllers would be called "
                            f"{' and '.join(u.controllers)}, which --controllers (a list "
                            "separated by commas) cannot name: rename the file")
        clash = sorted(taken & set(u.controllers))
        if clash:
            raise UserError(f"--rules {given}: its controllers would be called "
                            f"{' and '.join(u.controllers)}, but {clash[0]} is taken (a shipped "
                            "controller or another --rules file): rename the file")
        taken |= set(u.controllers)
        out.append(u)
    return tuple(out)


@functools.cache
def _shipped_defaults(key: str) -> frozenset[str]:
    """The rule bases the shipped arm files name in ``defaults[key]`` (read once)."""
    return frozenset(ArmSpec.from_args(a).defaults[key] for a in arm_names())


def controller_title(spec: RunSpec) -> str:
    """What a controller of the sweep is, for the report. A rule-based controller's title names
    the shipped arms' rule base (the paper's, or ITG+); an arm file of yours may name another
    in its ``defaults``, and the title then says which."""
    if spec.controller in CONTROLLER_TITLES:
        title = CONTROLLER_TITLES[spec.controller]
        key = ALL_CONTROLLERS[spec.controller][3]
        if key and spec.rules not in _shipped_defaults(key):
            title += f"; here the rule base your arm file names instead (defaults.{key}: {spec.rules})"
        return title
    fed = ("vision (no model)" if spec.feedback == "vision"
           else "encoders + nominal model")
    return f"your rule base {spec.rules} (--rules) fed by {fed}"


def build_sweep(*, quick: bool = False, seeds: int | None = None, conditions=None,
                controllers=None, trajectories=None, points: int | None = None,
                sweep: str = "robustness", rules=(), arm: str = FILES_ARM,
                rule_params: dict[str, float] | None = None) -> list[RunSpec]:
    """The run specs of a sweep, in a stable order (trajectory, condition, seed, controller).

    Every controller of a trajectory runs under the same limits (``LIMITS`` of its arm);
    closed trajectories run ``LAPS`` laps. ``rules``: a user's rule bases (``--rules``, as
    given: :func:`user_rules`), their controllers run beside the sweep's (or as ``controllers``
    says, which may name them), on the trajectories of the arms each fits. ``trajectories``
    may name a user's CSV files (:func:`names_a_csv_file`), tracked by the arm ``arm`` (a
    shipped arm or an arm file: :func:`files_arm`).
    ``rule_params``: the rule parameters of those rule bases (RunConfig fields, checked values:
    :func:`itg_vision.options.rule_params`); the shipped controllers keep theirs, so
    they need ``rules``.
    """
    if rule_params and not rules:
        from ..options import OPTIONS

        given = ", ".join(OPTIONS[k] for k in rule_params)
        raise UserError(f"{given}: applies to your rule bases (--rules), and none is given "
                        "(the shipped controllers keep their own parameters)")
    base = SWEEPS[sweep]
    conds = conditions or (QUICK["conditions"] if quick else base["conditions"])
    trajs = list(trajectories or (QUICK["trajectories"] if quick else base["trajectories"]))
    arm_of = {t: TRAJECTORIES[t] for t in trajs if not names_a_csv_file(t)}
    arm = files_arm(arm)
    taken = set(TRAJECTORIES)
    for i, t in enumerate(trajs):
        if names_a_csv_file(t):
            trajs[i] = user_trajectory(t, arm, taken)
            arm_of[trajs[i]] = arm
            taken.add(Path(t).stem)
    mine = {name: (u, entry)
            for u in user_rules(rules, list(dict.fromkeys(arm_of.values())), rule_params)
            for name, entry in u.controllers.items()}
    ctrls = controllers or (*base["controllers"], *mine)
    n_seeds = seeds if seeds is not None else (QUICK["seeds"] if quick else base["seeds"])
    if not 1 <= n_seeds <= MAX_SEEDS:
        raise UserError(f"--seeds: must be in 1..{MAX_SEEDS}, got {n_seeds}")
    if points is None and quick:
        points = QUICK["points"]
    if points is not None and points < 2:
        raise UserError(f"--points: must be >= 2, got {points}")
    rig_sha: dict[str, str] = {}
    rules_sha: dict[str, str] = {"": ""}
    fitted: set[tuple[str, str]] = set()  # (arm, rule base) checked to fit
    specs = []
    for traj_name in trajs:
        arm = arm_of[traj_name]
        spec_arm = ArmSpec.from_args(arm)
        inputs = {v: inputs_sha(traj_name, vision=v, arm=arm) for v in (False, True)}
        limits = spec_arm.benchmark  # the servo limit every controller runs under
        laps = LAPS if load_trajectory(traj_name).closed else 1
        file = traj_name in TRAJECTORY_FILES or names_a_csv_file(traj_name)
        n = None if file else points  # a file has its own points
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
                    params = {}
                    if ctrl in mine:
                        user, (rc, fb, noise_mm, _) = mine[ctrl]
                        if arm not in user.arms:
                            continue  # a rule base for another arm
                        rule_base, params = user.rules, dict(user.params)
                    else:
                        rc, fb, noise_mm, rules_key = ALL_CONTROLLERS[ctrl]
                        rule_base = spec_arm.defaults[rules_key] if rules_key else ""
                    if rule_base not in rules_sha:
                        rules_sha[rule_base] = _file_sha(resolve_rules_path(rule_base))
                    if ctrl not in mine and rule_base and (arm, rule_base) not in fitted:
                        _check_fits(spec_arm, rules_key, arm)  # before any run, not in each
                        fitted.add((arm, rule_base))
                    specs.append(RunSpec(
                        controller=ctrl, condition=cname, trajectory=traj_name, arm=arm,
                        points=n, seed=seed, rc_controller=rc, feedback=fb,
                        rules=rule_base, rules_sha=rules_sha[rule_base],
                        noise_mm=noise_mm, noise_px=cond.noise_px, dropout=cond.dropout,
                        rig=cond.rig, rig_sha=sha, inputs_sha=inputs[fb == "vision"],
                        link_error_pct=round(100 * cond.link_error, 9),
                        offset_deg=cond.offset_deg, iterations=int(limits["iterations"]),
                        max_step_deg=float(limits["max_step_deg"]), laps=laps,
                        correction=CORRECTIONS.get(ctrl, 1.0), preview=ctrl in WITH_PREVIEW,
                        **params))
    return specs


def _check_fits(spec_arm: ArmSpec, key: str, arm: str) -> None:
    """Refuse, naming the arm file's field, a rule base its ``defaults[key]`` names that does
    not load for it (a rule base for another arm, a syntax error in a file of yours): every run
    of its controllers would fail."""
    why = _load_for(resolve_rules_path(spec_arm.defaults[key]), arm)
    if isinstance(why, str):
        raise UserError(f"{spec_arm.source or spec_arm.name}: defaults.{key}: {why}")


def _calibrated_rig_sha(arm: str) -> str:
    path = calibrated_rig_path(arm)
    if not path.exists():  # shown without the '..' of an arm file's ../rigs/x.yaml
        shown, rig = (os.path.normpath(p) for p in (path, ArmSpec.from_args(arm).defaults["rig"]))
        raise UserError(f"condition rig-calibrated needs {shown}: make it with `python -m "
                        f"itg_vision.calibrate --rig {rig} --arm {arm} --out {shown}`, or leave "
                        "the rig-calibrated conditions out with --conditions")
    from ..camera import Rig, load_true_rig

    load_true_rig(Rig.from_yaml(path), path)  # a stale calibration: refused before any run
    return _file_sha(path)


def _file_sha(path: Path) -> str:
    return file_sha256(path)[:12]


def _read_files(trajectory: str, vision: bool, arm: str) -> list[Path]:
    """The files a run of ``trajectory`` reads besides its rule base and calibrated rig: its
    arm file, for a run fed by vision the arm's true rig (what renders the images), and the
    trajectory's file (a named trajectory is code)."""
    from ..arm import arm_path
    from ..camera import default_rig_path

    files = [arm_path(arm)] + ([default_rig_path(arm)] if vision else [])
    if trajectory in TRAJECTORY_FILES or names_a_csv_file(trajectory):
        files.append(Path(trajectory_source(trajectory)))
    return files


def inputs_sha(trajectory: str, vision: bool, arm: str | None = None) -> str:
    """A hash of :func:`_read_files`: an edited file is a new run of exactly the runs that
    read it."""
    files = _read_files(trajectory, vision, arm or TRAJECTORIES[trajectory])
    return hashlib.sha256("".join(_file_sha(f) for f in files).encode()).hexdigest()[:12]


def input_files(specs) -> dict[str, str]:
    """Every file the runs of ``specs`` read (arm files, rule bases, the rigs that render,
    trajectory files, calibrated rigs), by absolute path -> the start of its SHA-256: what
    sweep.json records, so that a resume refused for an edited file can name it."""
    files: dict[Path, None] = {}
    for arm, rules, vision, traj, rig in {(s.arm, s.rules, s.vision, s.trajectory, s.rig)
                                          for s in specs}:
        files.update(dict.fromkeys(_read_files(traj, vision, arm)))
        if rules:
            files[resolve_rules_path(rules)] = None
        if rig == "calibrated":
            files[calibrated_rig_path(arm)] = None
    return {str(p.resolve()): _file_sha(p) for p in sorted(files)}


def run_config(spec: RunSpec, rig_path: str | None = None):
    """The :class:`itg_vision.runner.RunConfig` of a spec (``rig_path``: the rig believed)."""
    from ..runner import RunConfig

    nominal = ArmSpec.from_args(spec.arm).links_mm
    true_links = (tuple(round(v * (1.0 + spec.link_error_pct / 100), 9) for v in nominal)
                  if spec.link_error_pct else None)
    offset = (spec.offset_deg,) * len(nominal) if spec.offset_deg else None
    # a condition's vision parameters reach vision-fed runs only (elsewhere they do nothing)
    vision = spec.feedback == "vision"
    return RunConfig(arm=spec.arm, trajectory=trajectory_source(spec.trajectory),
                     points=spec.points, controller=spec.rc_controller,
                     rules=spec.rules or None, feedback=spec.feedback,
                     iterations=spec.iterations, max_step_deg=spec.max_step_deg, laps=spec.laps,
                     rig=rig_path if vision else None, noise_px=spec.noise_px if vision else 0.0,
                     noise_mm=spec.noise_mm if spec.feedback == "truth" else 0.0,
                     dropout=spec.dropout if vision else 0.0, seed=spec.seed,
                     true_links_mm=true_links, joint_offset_deg=offset,
                     correction=spec.correction, preview=spec.preview, **spec.rule_params)

