"""``TrackingEnv``: the simulator as a Gymnasium environment, for controllers of your own.

The environment runs the same :class:`itg_vision.loop.Session` as ``python -m itg_vision.run``:
one arm, one rig, one trajectory and one feedback source, built from a
:class:`itg_vision.runner.RunConfig` (validated as the command line validates it). Each
``step`` is one iteration: the action (joint increments in degrees) is clipped to the servo
limit (``info["clipped"]`` says when) and applied, the reward is minus E_i (mm) after the move, and the next observation is
what the feedback measures. The episode ends with the trajectory.

Observation (a dict of float64 arrays, mm): ``desired_mm`` (the current set point),
``gripper_mm`` and, for arms that carry one, ``elbow_mm`` (the feedback's estimates; a marker
that was not measured keeps its last estimate, as in the loop). On a planar arm the set point
lies in the joints' plane (z = 0) while the LEDs sit ``led_standoff_mm`` (12 mm) above it:
compare x and y there, as E_i (the reward) does. With ``images=True`` (vision
feedback only) it also holds ``camera_images``: both cameras' whole frames (uint8 RGB, as the
estimator saw them: distorted, noisy); the eye then renders whole frames instead of windows
around the LEDs: the same rendered pixels there, but the sensor noise is drawn over the whole
frame, so its samples, and the estimates, differ slightly from a run without images (0.03 mm
in one measured episode), and each step costs more (15-50x, by the rig's image size). The encoders' joint angles are in
``info["q_deg"]``: a model-free controller does not read them.

``reset(seed=...)`` rebuilds the world at the start pose and reseeds the feedback: the same
seed and the same actions give the same observations and rewards, bit for bit. ``reset()``
without a seed starts the next episode of a reproducible sequence: the config's ``seed`` at
the first reset, then a seed drawn from the env's generator (``np_random``, seeded by the
config's seed and again by every seed given), so that envs seeded 10 and 11 (a vector env reset
with ``seed=10``) never replay each other's episodes. Unseeded, copies of one config run the same
episodes: give the vector env's ``reset`` a seed. The lengths the
start-up measurement found (what a model-free controller may know) are in
``info["geometry"]`` (an :class:`itg_vision.identify.ArmGeometry`) after ``reset``. After each
``step``, ``info["missed"]`` names the markers the new observation could not measure (their
values in it are held from the last good estimate). At a look that missed the gripper,
``run``'s loop gives its controller the last decision's aim for the gripper
(:data:`itg_vision.loop.AIM_ON_LOST`); here the agent decides what a lost look means.

An action holds one finite increment per joint (deg); a wrong size or a NaN or infinite value
raises ``ValueError`` (a NaN joint would spoil the rest of the episode).

Example::

    from itg_vision import TrackingEnv
    env = TrackingEnv(arm="two-link", trajectory="ellipse-t1", feedback="truth")
    obs, info = env.reset(seed=0)
    done = False
    while not done:
        g, d = obs["gripper_mm"], obs["desired_mm"]
        action = my_controller(d, g)            # joint increments, deg
        obs, reward, done, _, info = env.step(action)
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np

from .arm import ArmSpec
from .loop import Session
from .contracts import Step
from .errors import ConfigError
from .runner import RunConfig, given_rule_params, prepare, session_geometry, start_up_geometry
from .world import World

#: Bounds of the observed positions (mm): none. An arm file's links and a trajectory file's
#: coordinates have bounds of their own (up to 1e6 mm); a finite box here clipped an estimate
#: beyond it without a word, and a set point beyond it left the space.
POSITION_BOUND_MM = np.inf


class TrackingEnv(gym.Env):
    """Track a trajectory with your own controller (see the module docstring).

    Parameters
    ----------
    config : a :class:`itg_vision.runner.RunConfig`; or its fields as keyword arguments
        (``arm``, ``trajectory``, ``feedback``, ``rig``, ``iterations``, ``max_step_deg``, ``laps``,
        ``noise_px``, ``true_links_mm``, ...). ``max_step_deg`` bounds the action space; unset,
        it is the arm file's servo limit (``benchmark.max_step_deg``: 20 deg per iteration for
        the one- and two-link arms, 2 for the three-link), which ``run`` applies only when
        given. Its ``controller`` is not used, and settings
        that shape a controller (``rules``, f, S, w, ``correction``, ``preview``) are refused:
        you are the controller.
    images : add both camera images to the observation (``feedback="vision"`` only).
    """

    metadata = {"render_modes": []}

    def __init__(self, config: RunConfig | None = None, *, images: bool = False, **fields):
        super().__init__()
        if config is not None and not isinstance(config, RunConfig):  # a dict: "no 'correction'"
            raise TypeError(f"config: a RunConfig expected (or its fields as keyword "
                            f"arguments), got {type(config).__name__}")
        cfg = config if config is not None else RunConfig(**fields)
        if config is not None and fields:
            cfg = dataclasses.replace(config, **fields)
        set_ = [n for n, default in (("correction", 1.0), ("preview", False), ("rules", None),
                                     ("damping_mm", None))
                if getattr(cfg, n) != default] + list(given_rule_params(cfg))
        if set_:  # (a rule setting was accepted and unused: it read as in use)
            raise ConfigError(set_[0], "sets a controller; in the environment you are the "
                                       "controller")
        cfg.validate()  # as given: the controller it names is not used, but a typo is no setting
        if cfg.max_step_deg is None:  # an action space needs bounds: the arm file's limit
            cfg = dataclasses.replace(cfg, max_step_deg=ArmSpec.from_args(cfg.arm).benchmark[
                "max_step_deg"])
        if not isinstance(images, bool):  # "no" asked for images
            raise ValueError(f"images: must be true or false, got {images!r}")
        if images:
            if cfg.feedback != "vision":
                raise ValueError(f"images: only vision feedback has camera images, "
                                 f"not {cfg.feedback!r}")
            cfg = dataclasses.replace(cfg, full_frame=True)
        self.config = cfg
        self.images = bool(images)
        # you are the controller: none is built, and the config's controller and rule settings
        # are not checked; "jacobian" (model-free) makes the start-up measure the lengths
        # whatever the config names (start_up_geometry gives "ik" the nominal ones)
        self._prep = prepare(dataclasses.replace(cfg, controller="jacobian", rules=None,
                                                 gain_deg_per_mm=None, step_deg=None,
                                                 tolerance_mm=None), with_controller=False)
        model = self._prep.model
        self.marker_names = model.marker_names
        box = gym.spaces.Box(-POSITION_BOUND_MM, POSITION_BOUND_MM, (3,), np.float64)
        spaces = {"desired_mm": box, **{f"{m}_mm": box for m in self.marker_names}}
        if not model.planar:  # the pitch axis the loop keeps (contracts.Markers.pitch_axis)
            spaces["pitch_axis"] = gym.spaces.Box(-1.0, 1.0, (3,), np.float64)
        if self.images:
            cams = self._prep.feedback_factory().render_rig.cameras
            spaces["camera_images"] = gym.spaces.Tuple(
                gym.spaces.Box(0, 255, (c.size[1], c.size[0], 3), np.uint8) for c in cams)
        self.observation_space = gym.spaces.Dict(spaces)
        self.action_space = gym.spaces.Box(-cfg.max_step_deg, cfg.max_step_deg, (model.n_joints,),
                                           np.float64)
        self._world: World | None = None
        self._session: Session | None = None
        self._feedback = None
        self._np_random, self._np_random_seed = gym.utils.seeding.np_random(int(cfg.seed))
        self._reset_before = False

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.close()
        prep = self._prep
        cfg = prep.config  # the config as given but its controller settings
        if seed is not None:
            run_seed = int(seed)
        else:
            run_seed = int(self.np_random.integers(2**31)) if self._reset_before else cfg.seed
        self._reset_before = True
        self._feedback = prep.feedback_factory()
        self._feedback.reset(run_seed)
        self._world = World(prep.true_arm)
        try:
            geometry = start_up_geometry(cfg, self._world, self._feedback, prep.model)
        except BaseException:  # a failed start-up (StartUpFailed) leaves no client open
            self.close()
            raise
        self._session = Session(self._world, self._feedback, prep.trajectory.points_mm,
                                iterations=cfg.iterations, planar=prep.model.planar,
                                max_step_deg=cfg.max_step_deg,
                                tracking_start=prep.trajectory.tracking_start,
                                **session_geometry(geometry, prep.model))
        markers = self._session.observe()
        return self._observation(markers), {
            "geometry": geometry, "q_deg": self._world.q_deg.copy(), "k": 0,
            "missed": tuple(markers.missed)}

    def step(self, action):
        if self._session is None:
            raise RuntimeError("call reset() before step()")
        if self._session.done:  # the episode terminated: a new one starts with reset()
            raise RuntimeError("the trajectory is finished (the episode terminated): call "
                               "reset() before step()")
        raw = np.asarray(action)
        if raw.shape != self.action_space.shape or raw.dtype.kind not in "iuf":
            raise ValueError(f"action: {self.action_space.shape[0]} real joint increments (deg) "
                             f"expected, got shape {raw.shape} of {raw.dtype}")
        dq = raw.astype(float)
        if not np.isfinite(dq).all():
            raise ValueError(f"action: joint increments must be finite, got {dq.tolist()}")
        k = self._session.k
        e = self._session.apply(Step(dq, (), False))
        terminated = self._session.done
        # the last observation shows where the arm ended; it is no decision's input, so the
        # trace (its estimation errors, misses, timings) does not count it, as in simulate()
        markers = self._feedback.observe(self._world) if terminated else self._session.observe()
        obs = self._observation(markers)
        info = {"e_mm": e, "k": k, "q_deg": self._world.q_deg.copy(),
                "missed": tuple(markers.missed),
                "clipped": bool(np.any(np.abs(dq) > self.config.max_step_deg))}
        if terminated:
            info["metrics"] = self._session.trace.metrics()
        return obs, -e, terminated, False, info

    def close(self) -> None:
        if self._world is not None:
            self._world.close()
        self._world = None
        self._session = None

    # ------------------------------------------------------------------ helpers
    @property
    def trace(self):
        """The run's :class:`itg_vision.loop.Trace` so far (for plots and metrics)."""
        return None if self._session is None else self._session.trace

    def _observation(self, markers) -> dict:
        obs = {"desired_mm": np.array(self._session.desired_mm, np.float64)}
        for m in self.marker_names:
            obs[f"{m}_mm"] = np.array(markers.get(m), np.float64)
        if "pitch_axis" in self.observation_space.spaces:
            obs["pitch_axis"] = np.array(markers.pitch_axis, np.float64)
        if self.images:
            obs["camera_images"] = tuple(np.ascontiguousarray(f, np.uint8)
                                         for f in self._feedback.last_observation.frames())
        return obs


#: The id ``gymnasium.make`` knows the environment by, once this module is imported (``from
#: itg_vision import TrackingEnv`` imports it), or in one call:
#: ``gymnasium.make("itg_vision.env:itg_vision/Tracking-v0", arm="two-link", ...)``; the
#: keyword arguments are the config's fields, as ``TrackingEnv`` takes them.
ENV_ID = "itg_vision/Tracking-v0"
if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="itg_vision.env:TrackingEnv")
