"""One tracking run from a validated configuration: what `run`, `paper` and `bench` share."""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from . import trajectory as traj
from .arm import MAX_ANGLE_DEG, MAX_ITERATIONS, ArmSpec
from .camera import MAX_SUPERSAMPLE, CAMERAS_DIR, default_rig_path, resolve_rig  # noqa: F401
from .shipped import DATA_DIR
from .errors import MAX_POINTS, ConfigError, NothingInReach, UserError
from .feedback import MAX_NOISE_MM, MAX_NOISE_PX, ModelFeedback, TruthFeedback
from .identify import measure_geometry, nominal_geometry
from .imaging import opencv_threads
from .inputs import is_whole
from .loop import Trace, distance_mm, simulate
from .provenance import code_hash
from .preview import Preview, plan
from .rules import PARAM_DEFAULTS, PARAM_FIELDS, PARAM_OF_FIELD, load_rules
from .world import World

FEEDBACKS = ("vision", "model", "truth")
CONTROLLERS = ("itg", "ik", "jacobian")
#: Most decisions (set points x iterations, laps included) a run makes: the trace keeps each
#: (~125 bytes: 1.25 GB here; ~12 min without vision), 100 iterations at MAX_POINTS set points.
MAX_DECISIONS = 10_000_000
#: A rule base's parameters: their defaults (one place) and their names in the rules.
RULE_DEFAULTS = {PARAM_FIELDS[k]: v for k, v in PARAM_DEFAULTS.items()}
#: What a run whose rule base binds S to the servo limit does instead of giving another S.
SERVO_HINT = "set the servo limit instead (max_step_deg; run's --max-step)"


@dataclass(frozen=True)
class RunConfig:
    """Everything that defines a run. Units: mm, deg.

    ``true_links_mm`` / ``joint_offset_deg`` make the simulated arm differ from the nominal
    model (model error). Only ``feedback="model"`` and the open-loop ``ik`` baseline know the
    model; under ``vision`` or ``truth`` feedback the lengths the rules and the Jacobian tracker
    use are measured from the LEDs at start-up (:mod:`itg_vision.identify`).

    Controller parameters (None: not given; the rules' defaults are ``RULE_DEFAULTS``): the
    gain f (``gain_deg_per_mm``), the fixed step S (``step_deg``) and the tolerance w
    (``tolerance_mm``) of a rule base. A parameter the controller does not use is refused
    (``ik`` takes no gain; ``table1`` uses S, not f), and only the parameters used are recorded.

    ``max_step_deg`` is the servo rate limit (deg per iteration), applied by the loop to every
    controller alike. ``correction`` < 1 feeds the set point's motion forward and corrects only
    that fraction of the measured error per decision (:func:`itg_vision.loop.aim_mm`), for the
    closed-loop controllers (itg, jacobian). ``preview`` asks the controller, near the base of
    a planar two-link arm, to go where a plan of the whole path under the servo limit puts the
    gripper (:mod:`itg_vision.preview`); it needs a servo limit. ``laps`` repeats a closed
    trajectory.
    ``noise_mm``: Gaussian noise (std per axis, mm) added to ``truth`` feedback.

    Every field is checked by :meth:`validate` (and :func:`prepare`); a bad one raises
    :class:`~itg_vision.errors.ConfigError` naming it.
    """

    arm: str = "two-link"
    links_mm: tuple[float, ...] | None = None
    trajectory: str | None = None
    points: int | None = None
    controller: str = "itg"
    rules: str | None = None
    gain_deg_per_mm: float | None = None
    step_deg: float | None = None
    tolerance_mm: float | None = None
    damping_mm: float | None = None  # the Jacobian tracker's lambda (None: DEFAULT_DAMPING_MM)
    iterations: int = 1
    max_step_deg: float | None = None
    laps: int = 1
    feedback: str = "vision"
    rig: str | None = None
    noise_px: float = 0.0
    noise_mm: float = 0.0
    dropout: float = 0.0
    strobe: bool = False
    supersample: int | None = None  # None: the rig file's, else DEFAULT_SUPERSAMPLE
    full_frame: bool = False  # render whole frames, not windows around the LEDs
    seed: int = 0
    true_links_mm: tuple[float, ...] | None = None
    joint_offset_deg: tuple[float, ...] | None = None
    allow_unseen: bool = False  # skip the start-up check that the cameras can see the arm
    correction: float = 1.0  # fraction of the measured error corrected per decision (loop.aim_mm)
    preview: bool = False  # aim near the base by a plan of the whole path (itg_vision.preview)

    def validate(self) -> None:
        """Check every field's range; raises `ConfigError` naming the first bad one."""
        def positive(v):
            return v is None or (math.isfinite(v) and v > 0)

        for name in ("gain_deg_per_mm", "step_deg", "tolerance_mm", "damping_mm", "max_step_deg",
                     "noise_px", "noise_mm", "dropout", "correction"):  # a number, not text
            v = getattr(self, name)
            optional = name in ("gain_deg_per_mm", "step_deg", "tolerance_mm", "damping_mm",
                                "max_step_deg")
            if not ((v is None and optional)
                    or (isinstance(v, numbers.Real) and not isinstance(v, bool))):
                raise ConfigError(name, f"must be a number, got {v!r}")
        for name in ("arm", "rules", "trajectory", "rig"):  # 3 or None: a bare TypeError
            v = getattr(self, name)
            if not ((v is None and name != "arm") or isinstance(v, (str, os.PathLike))):
                raise ConfigError(name, f"must be a name or a file's path, got {v!r}")
        for name, unit in (("links_mm", "mm"), ("true_links_mm", "mm"),
                           ("joint_offset_deg", "deg")):  # "abc" read as three lengths
            v = getattr(self, name)
            if v is not None and not (
                    (isinstance(v, (list, tuple)) or getattr(v, "ndim", None) == 1)  # an array
                    and all(isinstance(x, numbers.Real) and not isinstance(x, bool) for x in v)):
                raise ConfigError(name, f"must be a list of numbers ({unit}), one per joint, "
                                        f"got {v!r}")
        for name in ("strobe", "full_frame", "allow_unseen", "preview"):  # "no" is true
            v = getattr(self, name)
            if not isinstance(v, bool):
                raise ConfigError(name, f"must be true or false, got {v!r}")
        if not is_whole(self.laps):  # 2.5 and "2" ended in a bare TypeError
            raise ConfigError("laps", f"must be a whole number, got {self.laps!r}")
        for name, what in (("rules", "a rule base"), ("trajectory", "a trajectory"),
                           ("rig", "a rig")):  # '' is given, not the arm's default
            if getattr(self, name) == "":
                raise ConfigError(name, f"is empty: name {what} or give a file's path")
        checks = [
            ("points", self.points is None or (is_whole(self.points) and 2 <= self.points <= MAX_POINTS),
             f"must be a whole number of set points in 2..{MAX_POINTS}, got {self.points!r}"),
            ("controller", self.controller in CONTROLLERS,
             f"unknown {self.controller!r} (choose from {', '.join(CONTROLLERS)})"),
            ("feedback", self.feedback in FEEDBACKS,
             f"unknown {self.feedback!r} (choose from {', '.join(FEEDBACKS)})"),
            ("gain_deg_per_mm", positive(self.gain_deg_per_mm) and (
                self.gain_deg_per_mm is None or self.gain_deg_per_mm <= 1e6),
             f"must be in (0, 1e6] deg/mm, got {self.gain_deg_per_mm}"),
            ("step_deg", positive(self.step_deg) and (self.step_deg is None or self.step_deg <= 360),
             f"must be in (0, 360] deg, got {self.step_deg}"),
            ("tolerance_mm", self.tolerance_mm is None or (
                math.isfinite(self.tolerance_mm) and 0 <= self.tolerance_mm <= 1e4),
             f"must be in [0, 1e4] mm, got {self.tolerance_mm}"),
            ("damping_mm", positive(self.damping_mm) and (
                self.damping_mm is None or self.damping_mm <= 1e4),
             f"must be in (0, 1e4] mm, got {self.damping_mm}"),
            ("damping_mm", self.damping_mm is None or self.controller == "jacobian",
             "is the jacobian controller's lambda; the others take none"),
            ("max_step_deg", positive(self.max_step_deg) and (
                self.max_step_deg is None or self.max_step_deg <= MAX_ANGLE_DEG),
             f"must be in (0, {MAX_ANGLE_DEG:g}] deg per iteration (as an arm file's "
             f"benchmark.max_step_deg), got {self.max_step_deg}"),
            ("iterations", is_whole(self.iterations) and 1 <= self.iterations <= MAX_ITERATIONS,
             f"must be a whole number in 1..{MAX_ITERATIONS}, got {self.iterations}"),
            ("noise_px", math.isfinite(self.noise_px) and 0 <= self.noise_px <= MAX_NOISE_PX,
             f"must be in [0, {MAX_NOISE_PX:g}] px, got {self.noise_px}"),
            ("noise_mm", math.isfinite(self.noise_mm) and 0 <= self.noise_mm <= MAX_NOISE_MM,
             f"must be in [0, {MAX_NOISE_MM:g}] mm, got {self.noise_mm}"),
            ("noise_mm", self.noise_mm == 0 or self.feedback == "truth",
             "applies to truth feedback only"),
            ("noise_px", self.noise_px == 0 or self.feedback == "vision",
             "applies to vision feedback only"),
            ("dropout", self.dropout == 0 or self.feedback == "vision",
             "applies to vision feedback only"),
            ("strobe", not self.strobe or self.feedback == "vision",
             "applies to vision feedback only"),
            ("rig", self.rig is None or self.feedback == "vision",
             "applies to vision feedback only"),
            ("supersample", self.supersample is None or self.feedback == "vision",
             "applies to vision feedback only"),
            ("supersample", self.supersample is None or (
                isinstance(self.supersample, int) and 1 <= self.supersample <= MAX_SUPERSAMPLE),
             f"must be a whole number in 1..{MAX_SUPERSAMPLE}, got {self.supersample}"),
            ("full_frame", not self.full_frame or self.feedback == "vision",
             "applies to vision feedback only"),
            ("allow_unseen", not self.allow_unseen or self.feedback == "vision",
             "applies to vision feedback only"),
            ("dropout", 0 <= self.dropout <= 1,
             f"must be a probability in [0, 1], got {self.dropout}"),
            ("seed", is_whole(self.seed) and self.seed >= 0,
             f"must be a whole number >= 0, got {self.seed!r}"),
            ("correction", math.isfinite(self.correction) and 0 < self.correction <= 1,
             f"must be in (0, 1], got {self.correction}"),
            ("correction", self.correction == 1 or self.controller != "ik",
             "applies to the closed-loop controllers (itg, jacobian); ik is open loop"),
        ]
        for name, ok, msg in checks:
            if not ok:
                raise ConfigError(name, msg)

    def _default(self, what: str) -> str:
        return ArmSpec.from_args(self.arm).defaults[what]  # the arm file says

    @property
    def trajectory_name(self) -> str:
        return self.trajectory or self._default("trajectory")

    @property
    def rules_name(self) -> str:
        return self.rules or self._default("rules")

    @property
    def rig_path(self) -> Path:
        return resolve_rig(self.rig or self._default("rig"))


@dataclass
class Prepared:
    """A configuration turned into objects, validated, before anything runs or is written."""

    config: RunConfig
    model: ArmSpec
    true_arm: ArmSpec
    trajectory: traj.Trajectory
    controller: object
    feedback_factory: object
    info: dict = field(default_factory=dict)
    preview: Preview | None = None  # the preview's plan (None: no preview)
    n_in_reach: int = 0  # set points the simulated arm can reach: those the metrics count
    rig_arm: str | None = None  # the arm whose LEDs tied a calibrated rig to the base (calibrate --arm)
    notes: tuple[str, ...] = ()  # what a run should tell before it starts (one line each)


def prepare(cfg: RunConfig, estimate_rig=None, *, with_controller: bool = True) -> Prepared:
    """Validate every input (files included) and build the pieces; raises ``UserError``.

    ``estimate_rig``: a :class:`itg_vision.camera.Rig` built in code to estimate with, in place
    of the file ``cfg.rig_path`` (it renders with the rig its ``true_rig`` names).
    ``with_controller=False``: no controller is built (``Prepared.controller`` is None) and its
    settings are not checked: the caller is the controller (``TrackingEnv``).
    """
    cfg.validate()
    model = ArmSpec.from_args(cfg.arm, cfg.links_mm)
    true_arm = model
    if cfg.true_links_mm is not None:
        try:
            true_arm = ArmSpec.from_args(cfg.arm, cfg.true_links_mm)
        except ConfigError as exc:
            raise ConfigError("true_links_mm", exc.message) from None
    if cfg.joint_offset_deg is not None:
        if len(cfg.joint_offset_deg) != model.n_joints or not all(
                math.isfinite(v) and abs(v) <= 180 for v in cfg.joint_offset_deg):
            raise ConfigError("joint_offset_deg", f"arm {model.name!r} needs {model.n_joints} "
                              f"finite offsets in deg within +-180, got {cfg.joint_offset_deg}")
        true_arm = true_arm.with_joint_offset(tuple(float(v) for v in cfg.joint_offset_deg))
    one_lap = traj.load(cfg.trajectory_name, cfg.points, arm=model)
    trajectory = one_lap.repeated(cfg.laps)
    n_points = len(trajectory.points_mm)
    if n_points * cfg.iterations > MAX_DECISIONS:  # the trace keeps each (~125 B; ~70 us without vision)
        raise ConfigError("iterations", f"{cfg.iterations} iterations at each of the {n_points} "
                          f"set points make {n_points * cfg.iterations} decisions; a run makes at "
                          f"most {MAX_DECISIONS}: at most {MAX_DECISIONS // n_points} iterations "
                          "here")
    # a trajectory the arm file chose is that file's field, not an option the user gave
    field = "trajectory" if cfg.trajectory else f"{model.source or model.name}: defaults.trajectory"
    if not trajectory.planar and model.planar:
        raise ConfigError(field, f"{trajectory.name} has z values, but arm {model.name} "
                                 "is planar (x_mm,y_mm)")
    if trajectory.planar and not model.planar:
        raise ConfigError(field, f"arm {model.name} needs a 3-D trajectory "
                                 f"(x_mm,y_mm,z_mm), but {trajectory.name} is planar")
    n_in_reach = sum(true_arm.reachable(p) for p in trajectory.points_mm)
    if not n_in_reach:
        lo, hi = true_arm.reach_mm()
        if cfg.true_links_mm is not None and any(model.reachable(p) for p in trajectory.points_mm):
            field = "true_links_mm"  # the model reaches them: the simulated arm's lengths do not
        elif cfg.links_mm is not None and not cfg.trajectory:
            field = "links_mm"  # the arm file's own path, for lengths the user gave
        beside = ("" if true_arm.planar else f", and at least {true_arm.led_standoff_mm:g} mm "
                  "from the base axis, the LEDs' stand-off")
        metres = ("" if traj.span_note(trajectory, hi) is None else
                  "; every point lies within 1 % of the reach of the base: written in metres?")
        raise NothingInReach(field, f"none of the {len(one_lap.points_mm)}"
                          f" set points of {trajectory.name} is in reach of {true_arm.label} "
                          f"({lo:g} to {hi:g} mm from its shoulder{beside}): nothing to "
                          f"track{metres}")
    info: dict = {}
    notes: list = []
    given = given_rule_params(cfg)
    if not with_controller:
        controller = None
    elif cfg.controller == "itg":
        controller, cfg, info = rule_controller(cfg, model)
    else:
        from .controllers import make_controller

        for k in given:
            raise ConfigError(k, f"the {cfg.controller} controller takes no {PARAM_OF_FIELD[k]} "
                                 "(a rule base's parameter)")
        if cfg.rules is not None:
            raise ConfigError("rules", f"the {cfg.controller} controller takes no rule base "
                                       "(rules are for --controller itg)")
        controller = make_controller(cfg.controller, model, max_step_deg=cfg.max_step_deg,
                                     damping_mm=cfg.damping_mm)
        info["controller_params"] = controller.params()
    planned = _preview(cfg, model, trajectory) if cfg.preview else None
    rig_arm = None

    if cfg.feedback == "model":
        def feedback_factory():
            return ModelFeedback(model)
    elif cfg.feedback == "truth":
        def feedback_factory():
            return TruthFeedback(noise_mm=cfg.noise_mm)
    else:
        from .camera import Rig, load_true_rig
        from .feedback import VisionFeedback, check_full_frames
        from .visibility import check_visible

        if estimate_rig is None:
            estimate_rig = Rig.from_yaml(cfg.rig_path)
        render_rig = estimate_rig
        if estimate_rig.true_rig:  # checked against the hash it was calibrated with
            render_rig = load_true_rig(estimate_rig, cfg.rig_path)
        if not cfg.allow_unseen:
            notes.append(check_visible(render_rig, true_arm, trajectory.points_mm,
                                       true_links=cfg.true_links_mm is not None))
        info["estimate_rig"] = estimate_rig.source or estimate_rig.name
        info["render_rig"] = str(render_rig.source)
        rig_arm = estimate_rig.tied_arm

        supersample = supersample_of(cfg, estimate_rig)
        if cfg.full_frame:  # refused with the other inputs, not when the feedback is built
            check_full_frames(render_rig, supersample)

        def feedback_factory():
            return VisionFeedback(render_rig, estimate_rig, model, noise_px=cfg.noise_px,
                                  dropout=cfg.dropout, strobe=cfg.strobe,
                                  supersample=supersample, full_frame=cfg.full_frame)
    return Prepared(cfg, model, true_arm, trajectory, controller, feedback_factory, info, planned,
                    n_in_reach, rig_arm, tuple(filter(None, notes)))


def given_rule_params(cfg: RunConfig) -> dict[str, float]:
    """The rule parameters ``cfg`` gives (f, S, w by field name; those not given are None)."""
    return {k: getattr(cfg, k) for k in RULE_DEFAULTS if getattr(cfg, k) is not None}


def rule_controller(cfg: RunConfig, model: ArmSpec, servo_hint: str = SERVO_HINT
                    ) -> tuple[object, RunConfig, dict]:
    """The rule base of an ``itg`` run with its parameters (those ``cfg`` gives, the others
    ``RULE_DEFAULTS``), the configuration it runs under (a rule base whose S is the servo limit
    sets it: :func:`servo_limit_for_rules`, whose refusal ends with ``servo_hint``) and what the
    summary records of it (``info``: the file, the parameters its rules use, where each came
    from). A given parameter the rules never use raises `ConfigError` naming it."""
    given = given_rule_params(cfg)
    params = {**RULE_DEFAULTS, **given}
    try:
        controller = load_rules(cfg.rules_name, model.n_joints, model.links_mm,
                                **{PARAM_OF_FIELD[k]: v for k, v in params.items()})
    except UserError as exc:  # a rule base the arm file chose is that file's field
        if cfg.rules or isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{model.source or model.name}: defaults.rules", str(exc)) from None
    info = {}
    if controller.servo_step:  # the rules' S is the loop's servo limit (#! in the file)
        cfg, servo_note = servo_limit_for_rules(cfg, model, controller.source, servo_hint)
        controller = dataclasses.replace(controller, S=cfg.max_step_deg)
        info["servo_limit"] = servo_note
    used = controller.params()  # the parameters its rules read, by field name
    for k in given:
        if k not in used:
            raise ConfigError(k, f"{controller.source} never uses {PARAM_OF_FIELD[k]}")
    info["rules"] = str(controller.source)
    info["controller_params"] = used
    # where each came from: a rule base that lost its '#! S is the servo limit' line runs
    # with S = run's default and says so, not silently
    info["controller_params_from"] = {
        k: "given" if k in given else
        "the servo limit" if controller.servo_step and k == "step_deg" else "default"
        for k in used}
    return controller, cfg, info


def _preview(cfg: RunConfig, model: ArmSpec, trajectory) -> Preview:
    """The preview's plan (:mod:`itg_vision.preview`), the line through the base turning at
    most q1's servo limit per iteration."""
    if not (model.planar and model.n_joints == 2):
        raise ConfigError("preview", f"plans for a planar two-link arm (its gripper slides "
                                     f"along a line through the base); {model.label} is not")
    if cfg.max_step_deg is None:
        raise ConfigError("preview", "plans under the servo limit: set max_step_deg "
                                     "(--max-step)")
    try:
        return plan(trajectory.points_mm, cfg.max_step_deg * cfg.iterations)
    except ValueError as exc:  # a turn too fine, or too many set points, for the plan's grid
        raise ConfigError("preview", f"with a servo limit of {cfg.max_step_deg:g} deg x "
                                     f"{cfg.iterations} iteration(s): {exc}") from None


def supersample_of(cfg: RunConfig, rig) -> int:
    """The vision loop's supersampling: the run's option, else the rig file's, else the
    default (:data:`itg_vision.feedback.DEFAULT_SUPERSAMPLE`)."""
    from .feedback import DEFAULT_SUPERSAMPLE

    if cfg.supersample is not None:
        return int(cfg.supersample)
    return int(rig.supersample or DEFAULT_SUPERSAMPLE)


def shown_path(path: str) -> str:
    """A path for a summary: a file in the project's shipped folders (``data/``, ``cameras/``)
    relative to the project (``data/arms/...``), the same on every machine; any other file
    absolute (a user's, wherever it lies, the project folder included), so that the summary
    finds it from anywhere; anything else (a shipped trajectory's name) as given."""
    if not path or not Path(path).is_file():
        return path
    full = Path(path).resolve()
    for shipped in (DATA_DIR, CAMERAS_DIR):
        if shipped.resolve() in full.parents:
            return str(full.relative_to(shipped.resolve().parent))
    return str(full)


def servo_limit_for_rules(cfg: RunConfig, model: ArmSpec, source: str,
                          hint: str = SERVO_HINT) -> tuple[RunConfig, str]:
    """The configuration of a rule base whose S is the servo limit, and where the limit came
    from: the run's ``max_step_deg``, else the arm file's benchmark limit (which the loop then
    applies too; the arm file checked it, :func:`itg_vision.arm.load_arm`). ``step_deg`` may
    only repeat it (`ConfigError` otherwise, ending with ``hint``: what to do instead)."""
    servo, note = cfg.max_step_deg, "the run's max_step_deg"
    if servo is None:
        servo = model.benchmark["max_step_deg"]
        note = f"the arm file's benchmark limit ({shown_path(model.source) or model.name})"
        cfg = dataclasses.replace(cfg, max_step_deg=servo)
    if cfg.step_deg is not None and cfg.step_deg != servo:
        raise ConfigError("step_deg", f"{source}: S is the servo limit ({servo:g} deg per "
                                      f"iteration): {hint}")
    return cfg, f"S = servo limit = {servo:g} deg/iteration, from {note}"


def execute(prep: Prepared, progress=None, recorder=None) -> tuple[Trace, dict]:
    """Run the prepared configuration; return the trace and the summary dict."""
    cfg = prep.config
    feedback = prep.feedback_factory()
    feedback.reset(cfg.seed)
    t0 = time.perf_counter()
    with World(prep.true_arm) as world, opencv_threads(1):
        geometry = start_up_geometry(cfg, world, feedback, prep.model)
        controller = bind_geometry(prep.controller, geometry, prep.model, cfg.max_step_deg)
        start_gripper_mm = world.true_markers()["gripper"]
        trace = simulate(world, controller, feedback, prep.trajectory.points_mm,
                         iterations=cfg.iterations, planar=prep.model.planar,
                         max_step_deg=cfg.max_step_deg,
                         tracking_start=prep.trajectory.tracking_start,
                         correction=cfg.correction,
                         aims_mm=None if prep.preview is None else prep.preview.aims_mm,
                         **session_geometry(geometry, prep.model),
                         progress=progress, recorder=recorder)
    wall_s = time.perf_counter() - t0
    summary = {
        **trace.metrics(),
        # the first set point: its distance from the gripper at the start, and E_i after its
        # iterations (a first step that moves the gripper away shows as first > start)
        "start_error_mm": distance_mm(prep.trajectory.points_mm[0], start_gripper_mm,
                                      prep.model.planar),
        "first_error_mm": float(trace.error_mm()[0]),
        "arm": prep.model.name,
        "arm_file": shown_path(prep.model.source),
        "links_mm": list(prep.model.links_mm),
        "true_links_mm": list(prep.true_arm.links_mm),
        "joint_offset_deg": list(prep.true_arm.joint_offset_deg),
        "trajectory": prep.trajectory.name if prep.trajectory.file is None
        else shown_path(str(prep.trajectory.file)),
        "controller": cfg.controller,
        "feedback": cfg.feedback,
        "iterations": cfg.iterations,
        "max_step_deg": cfg.max_step_deg,
        "correction": cfg.correction,
        "preview": False if prep.preview is None else prep.preview.record(),  # as the config: off
        "laps": prep.trajectory.laps,
        "geometry": geometry.record(),
        "feedback_params": feedback_params(
            cfg, feedback.supersample if cfg.feedback == "vision" else None),
        "seed": cfg.seed,
        "wall_s": wall_s,
        "code": code_hash(),  # the package's sources and data files that made these numbers
        **prep.info,
        **{k: shown_path(prep.info[k]) for k in ("rules", "estimate_rig", "render_rig")
           if k in prep.info},
        "controller_params": controller.params(),  # the controller that ran (bound at start-up)
    }
    return trace, summary


def feedback_params(cfg: RunConfig, supersample: int | None = None) -> dict:
    """The parameters the run's feedback source uses (only those: nothing unused is recorded);
    vision: ``supersample``, the factor it renders with (the option's, the rig's or the
    default)."""
    if cfg.feedback == "vision":
        return {"noise_px": cfg.noise_px, "dropout": cfg.dropout, "strobe": cfg.strobe,
                "supersample": supersample, "full_frame": cfg.full_frame}
    if cfg.feedback == "truth":
        return {"noise_mm": cfg.noise_mm}
    return {}


def start_up_geometry(cfg: RunConfig, world, feedback, model):
    """The lengths the controller may use: the nominal model's under ``model`` feedback and for
    open-loop IK (the nominal model by definition), else measured from the LEDs at start-up. A
    run the user let go on with a rig that cannot see the arm (``allow_unseen``) falls back to
    the nominal lengths, and says so."""
    if cfg.feedback == "model" or cfg.controller == "ik":
        return nominal_geometry(model)
    try:
        return measure_geometry(world, feedback, model)
    except UserError as exc:
        if not cfg.allow_unseen:
            raise
        return dataclasses.replace(nominal_geometry(model),
                                   source=f"nominal model ({exc}; --allow-unseen)")


def session_geometry(geometry, model) -> dict:
    """What the loop's :class:`~itg_vision.loop.Session` takes of the start-up's geometry: the
    base axis (planar arms) or the shoulder's axis (three-link), which turn a lost elbow with
    the joints and give each look the kept pitch axis, and where the start-up saw the elbow."""
    return {"base_axis_mm": geometry.base_axis_mm if model.planar else None,
            "pitch_axis_mm": None if geometry.pitch_axis is None
            else (geometry.shoulder_mm, geometry.pitch_axis),
            "elbow_seen": geometry.elbow_seen}


def bind_geometry(controller, geometry, model, max_step_deg=None):
    """The controller with the lengths it may use: the rules' L1..Ln and base axis and the
    Jacobian tracker's shoulder and stand-off come from ``geometry`` (measured, or the nominal
    model's)."""
    from .controllers import JacobianTracker, make_controller
    from .rules import RuleBase

    if isinstance(controller, RuleBase):
        return controller.with_links(geometry.links_mm, geometry.base_axis_mm,
                                     geometry.length_se_mm, geometry.standoff_mm)
    if isinstance(controller, JacobianTracker):
        return make_controller("jacobian", model, geometry, max_step_deg, controller.damping)
    return controller  # open-loop IK: the nominal model by definition


def config_dict(cfg: RunConfig) -> dict:
    return asdict(cfg)
