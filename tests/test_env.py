"""TrackingEnv: Gymnasium's contract, reproducibility, and the same step code as the loop."""

import numpy as np
import pytest
from conftest import PYBULLET_RTOL, roundoff
from gymnasium.utils.env_checker import check_env

from itg_vision import TrackingEnv
from itg_vision.arm import ArmSpec, forward_kinematics
from itg_vision.controllers import JacobianTracker
from itg_vision.errors import UserError
from itg_vision.runner import RunConfig, execute, prepare


@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")  # degrees by design
@pytest.mark.filterwarnings("ignore:.*value is (-)?infinity")  # positions unbounded by design
def test_env_passes_gymnasiums_checker():
    env = TrackingEnv(feedback="truth", noise_mm=0.2, points=20)
    check_env(env, skip_render_check=True)
    env.close()


def test_observations_are_not_clipped_and_stay_in_the_space():
    """An arm file allows links of kilometres and a trajectory coordinates up to 1e6 mm. The
    space bounded positions at 1e4 mm: the three-link arm with 5 m links, straight up, had its
    gripper (z 15 m) reported at 10 m, a wrong position without a flag; now the observation is
    the estimate, and the space holds it."""
    env = TrackingEnv(arm="three-link", links_mm=(5000.0, 5000.0, 5000.0), feedback="truth",
                      points=3)
    try:
        obs, _ = env.reset(seed=0)
        assert obs["gripper_mm"][2] == pytest.approx(15000.0, abs=1e-6)
        assert env.observation_space.contains(obs)
    finally:
        env.close()


def test_reset_with_a_seed_reproduces_the_episode():
    env = TrackingEnv(feedback="truth", noise_mm=0.3, points=15)
    actions = np.random.default_rng(0).uniform(-5, 5, (15, 2))

    def episode(seed):
        obs, _ = env.reset(seed=seed)
        out = [obs["gripper_mm"]]
        for a in actions:
            obs, r, done, _, _ = env.step(a)
            out += [obs["gripper_mm"], [r]]
        assert done
        return np.concatenate(out)

    a, b, c = episode(3), episode(3), episode(4)
    env.close()
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_actions_are_clipped_to_the_servo_limit_and_reward_is_minus_e_i():
    env = TrackingEnv(feedback="truth", points=10, max_step_deg=2.0)
    env.reset(seed=0)
    q0 = env._world.q_deg.copy()
    _, reward, _, _, info = env.step(np.array([50.0, -50.0]))
    assert np.allclose(info["q_deg"] - q0, [2.0, -2.0], rtol=0, atol=roundoff(180))  # every controller's limit
    assert reward == pytest.approx(-info["e_mm"]) and info["e_mm"] > 0
    assert info["clipped"]  # said, not silent
    assert not env.step(np.array([2.0, -1.5]))[4]["clipped"]  # at the limit: applied whole
    env.close()


@pytest.mark.parametrize("arm", ["two-link", "three-link"])
def test_env_and_command_line_loop_run_the_same_steps(arm):
    """A controller driving the env through observations alone gives the trace that
    ``runner.execute`` gives with the same controller: one loop, not two."""
    cfg = RunConfig(arm=arm, controller="jacobian", feedback="truth", noise_mm=0.2,
                    max_step_deg=2.0 if arm == "three-link" else 20.0,
                    iterations=2, points=30, seed=5)
    trace, summary = execute(prepare(cfg))
    env = TrackingEnv(cfg)
    obs, info = env.reset(seed=cfg.seed)
    g = info["geometry"]  # what the start-up measurement found
    tracker = JacobianTracker(g, arm != "three-link", len(g.links_mm), max_step_deg=cfg.max_step_deg)
    done = False
    while not done:
        from itg_vision.feedback import Markers

        m = Markers(obs["gripper_mm"], obs["elbow_mm"], pitch_axis=obs.get("pitch_axis"))
        obs, _, done, _, info = env.step(tracker.step(obs["desired_mm"], m, None).dq_deg)
    assert np.array_equal(env.trace.error_mm(), trace.error_mm())
    assert info["metrics"]["e_av_mm"] == summary["e_av_mm"]
    # the same observations counted: the terminal one (no decision's input) is not, as in the
    # loop (it used to add an estimation error, and under vision a render and its misses)
    assert env.trace.est_err_mm == trace.est_err_mm
    no_timing = lambda m: {k: v for k, v in m.items() if k != "timing_ms"}  # noqa: E731
    assert no_timing(info["metrics"]) == no_timing(trace.metrics())  # the env times no rules
    env.close()


def test_an_episode_of_laps_tracks_from_the_second_lap():
    """The env runs the laps it is given, and its tracking phase is the laps after the first,
    as in a run: 20 set points a lap, 3 laps, tracked from set point 20 of 60."""
    env = TrackingEnv(feedback="model", points=20, laps=3)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, done, _, info = env.step([0.0, 0.0])
    with pytest.raises(RuntimeError, match=r"^the trajectory is finished \(the episode "
                       r"terminated\): call reset\(\) before step\(\)$"):
        env.step([0.0, 0.0])  # after termination: says what to do, and the metrics stand
    env.close()
    assert (info["metrics"]["n_setpoints"], info["metrics"]["tracking_from"]) == (60, 20)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")
@pytest.mark.filterwarnings("ignore:.*value is (-)?infinity")  # positions unbounded by design
def test_images_on_request_are_the_frames_the_estimate_came_from():
    """With images=True the observation holds both cameras' whole frames; each shows the
    gripper LED (red) where its estimate projects (within the LED's ~5 px image radius)."""
    from itg_vision.urdf import LED_RGB

    env = TrackingEnv(feedback="vision", points=3, supersample=1, images=True)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    cams = env._feedback.estimate_rig.cameras
    assert len(obs["camera_images"]) == 2
    red = np.array(LED_RGB["gripper"]) * 255
    for img, cam in zip(obs["camera_images"], cams):
        assert img.shape == (cam.size[1], cam.size[0], 3) and img.dtype == np.uint8
        u, v = np.round(cam.project(obs["gripper_mm"])).astype(int).ravel()
        assert np.abs(img[v, u].astype(float) - red).max() < 60
    with pytest.raises(ValueError, match="images: only vision feedback"):
        TrackingEnv(feedback="truth", images=True)
    env.close()


@pytest.mark.parametrize("aim", [{"correction": 0.5}, {"preview": True},
                                 {"rules": "itg-plus-two-link"}, {"gain_deg_per_mm": 0.3},
                                 {"step_deg": 2.0}, {"tolerance_mm": 1.0},
                                 {"damping_mm": 1.0}])
def test_env_refuses_a_controller_setting_it_would_not_apply(aim):
    """A rule base or its f, S, w given to the environment was accepted and never used (it
    read as in use); the memory and the preview aim a controller the environment lacks."""
    from itg_vision.errors import ConfigError

    with pytest.raises(ConfigError, match=f"{next(iter(aim))}: sets a controller; in the "
                                          "environment you are the controller"):
        TrackingEnv(feedback="truth", max_step_deg=20, **aim)


def test_env_refuses_actions_it_cannot_apply():
    env = TrackingEnv(feedback="truth", points=5)
    env.reset(seed=0)
    for bad in ([np.nan, 0.0], [np.inf, 0.0]):
        with pytest.raises(ValueError, match="action: joint increments must be finite"):
            env.step(bad)
    for bad, got in (([1.0, 2.0, 3.0], r"shape \(3,\) of float64"),
                     ([[1.0], [2.0]], r"shape \(2, 1\) of float64"),  # not reshaped silently
                     (["1", "2"], r"shape \(2,\) of <U1"), ([True, False], r"shape \(2,\) of bool"),
                     ([1 + 1j, 2], r"shape \(2,\) of complex128")):
        with pytest.raises(ValueError, match=r"action: 2 real joint increments \(deg\) expected, "
                                             "got " + got):
            env.step(bad)
    _, _, _, _, info = env.step([1.0, -1.0])  # the refusals left the episode as it was
    assert info["k"] == 0 and np.isfinite(info["q_deg"]).all()
    env.close()


def test_info_names_the_markers_each_observation_missed():
    env = TrackingEnv(feedback="vision", points=12, supersample=1, dropout=0.5)
    _, info = env.reset(seed=0)
    missed = [info["missed"]]
    done = False
    while not done:
        _, _, done, _, info = env.step([0.0, 0.0])
        missed.append(info["missed"])
    # every look the session counted as missed is reported at the step that made it; the
    # terminal look (no decision's input) is reported but not counted, as in the loop
    assert sum(map(len, missed[:-1])) == env.trace.n_missed > 0
    assert set().union(*missed) <= {"gripper", "elbow"}
    env.close()


def test_a_missed_elbow_is_observed_turned_with_the_joints_as_run_gives_it():
    """The env's session is run's: a look that misses the elbow gives its last measurement turned
    about the measured base axis by the base's commanded turn since (loop.Session's
    base_axis_mm), not the eye's held estimate. The base turns 6 deg a step, so a held elbow
    would be 100 mm x 2 sin(3 deg) = 10.5 mm off per step since it was seen; turned, it is within
    the eye's error of the true elbow (0.1 mm at 0 px; 1 mm bounds it with the start-up's axis;
    0.026-0.079 mm measured over 9 such looks)."""
    env = TrackingEnv(feedback="vision", points=24, supersample=1, dropout=0.4)
    arm = ArmSpec.from_args("two-link")
    obs, info = env.reset(seed=3)
    turned = 0
    done = False
    while not done:
        obs, _, done, _, info = env.step([6.0, -3.0])
        if "elbow" in info["missed"] and not done:
            true = forward_kinematics(arm, info["q_deg"])["elbow"]
            assert np.hypot(*(obs["elbow_mm"] - true)[:2]) < 1.0, (info["q_deg"], obs["elbow_mm"])
            turned += 1
    assert turned >= 3, turned
    env.close()


def test_reset_without_a_seed_runs_the_next_episode_of_a_reproducible_sequence():
    def firsts(seeds, seed=10):
        env = TrackingEnv(feedback="truth", noise_mm=0.3, points=5, seed=seed)
        out = [env.reset(seed=s)[0]["gripper_mm"] for s in seeds]
        env.close()
        return out

    a = firsts([None, None, None, 7, None])
    assert all(np.array_equal(x, y) for x, y in zip(a, firsts([None, None, None, 7, None])))
    assert np.array_equal(a[0], firsts([10])[0])  # the first: the config's seed
    assert np.array_equal(a[3], firsts([7])[0])
    assert all(not np.array_equal(a[i], a[j]) for i in range(5) for j in range(i))
    # envs seeded 10 and 11 (as a vector env seeds its envs) do not replay each other's episodes
    b = firsts([None, None, None], seed=11)
    assert all(not np.array_equal(x, y) for x in a[:3] for y in b)


def test_the_controller_field_is_not_used_the_env_has_no_controller():
    # ik would be given the nominal lengths; the env measures them whatever the config names
    env = TrackingEnv(feedback="truth", points=5, controller="ik")
    obs, info = env.reset(seed=0)
    assert info["geometry"].source.startswith("measured")  # a model-free user learns the lengths
    env.close()


def test_reading_the_seed_gymnasium_reports_keeps_the_sequence():
    """Gymnasium reseeds from the OS when its recorded seed is unset: the env records it."""
    def firsts(touch):
        env = TrackingEnv(feedback="truth", noise_mm=0.3, points=3, seed=10)
        if touch:
            assert env.np_random_seed == 10
        out = [env.reset()[0]["gripper_mm"] for _ in range(3)]
        env.close()
        return out

    assert all(np.array_equal(a, b) for a, b in zip(firsts(True), firsts(False)))


def test_a_world_frees_its_client_when_closed_or_dropped_and_refuses_bad_angles():
    """A World dropped without close() disconnects when collected (each client holds ~28 MB);
    close() twice is fine; a closed World, a wrong number of angles or a non-finite one is a
    clear error, never a silent NaN pose."""
    import gc

    import pybullet as p

    from itg_vision.arm import ArmSpec
    from itg_vision.world import World

    arm = ArmSpec.from_args("two-link")
    w = World(arm)
    client = w.client
    del w
    gc.collect()
    assert not p.isConnected(client)
    w = World(arm)
    for bad in ([np.nan, 0.0], [np.inf, 0.0], [10.0], [0.0, 0.0, 0.0]):
        with pytest.raises(ValueError, match=r"World.set_q: 2 finite joint angles \(deg\) expected"):
            w.set_q(bad)
    assert np.all(np.isfinite(w.true_markers()["gripper"]))  # the refusals moved nothing
    client = w.client
    w.close()
    w.close()
    assert not p.isConnected(client)
    with pytest.raises(RuntimeError, match="the World is closed"):
        w.true_markers()
    with pytest.raises(RuntimeError, match="the World is closed"):
        w.set_q([0.0, 0.0])


def test_a_failed_reset_leaves_no_client_open():
    import pybullet as p

    from itg_vision.identify import StartUpFailed

    env = TrackingEnv(points=5, dropout=1.0)
    before = sum(p.isConnected(c) for c in range(64))
    with pytest.raises(StartUpFailed, match="dropped at random"):
        env.reset(seed=0)
    assert sum(p.isConnected(c) for c in range(64)) == before
    with pytest.raises(RuntimeError, match="call reset"):
        env.step([0.0, 0.0])


@pytest.mark.parametrize("field, value", [("iterations", 2.5), ("iterations", True),
                                          ("seed", 1.5), ("seed", -1), ("seed", "3"),
                                          ("points", 2.5), ("points", True)])
def test_whole_number_fields_refuse_other_values(field, value):
    """iterations=2.5 ran 2 iterations while the config said 2.5, and points=2.5 ran 2 set
    points; a bool is not a count, nor "3" a seed (it was refused as 'got 3', which hid the
    quotes): the value is shown as given."""
    from itg_vision.errors import ConfigError

    with pytest.raises(ConfigError, match=f"{field}: must be a whole number") as exc:
        TrackingEnv(feedback="truth", **{"points": 5, field: value})
    assert str(exc.value).endswith(f"got {value!r}")
    TrackingEnv(feedback="truth", **{"points": 5, field: np.int64(2)}).close()  # numpy's ints are


@pytest.mark.parametrize("field, value", [("noise_px", "1"), ("dropout", "0.1"),
                                          ("max_step_deg", "20"), ("correction", None)])
def test_number_fields_given_text_are_refused_by_name(field, value):
    """noise_px="1" from code ended in a bare TypeError naming no field; now one ConfigError
    naming it (correction has no None: it is a number too)."""
    from itg_vision.errors import ConfigError

    with pytest.raises(ConfigError) as exc:
        RunConfig(feedback="vision", **{field: value}).validate()
    assert exc.value.field == field and str(exc.value) == f"{field}: must be a number, got {value!r}"



@pytest.mark.parametrize("field, value, said", [
    ("arm", 3, "must be a name or a file's path, got 3"),
    ("arm", None, "must be a name or a file's path, got None"),
    ("trajectory", 5, "must be a name or a file's path, got 5"),
    ("rig", 1.0, "must be a name or a file's path, got 1.0"),
    ("laps", 2.5, "must be a whole number, got 2.5"),
    ("laps", "2", "must be a whole number, got '2'"),
    ("laps", True, "must be a whole number, got True"),
    ("links_mm", 100, "must be a list of numbers (mm), one per joint, got 100"),
    ("true_links_mm", "abc", "must be a list of numbers (mm), one per joint, got 'abc'"),
    ("joint_offset_deg", ("1", "2"), "must be a list of numbers (deg), one per joint, "
                                     "got ('1', '2')"),
    ("joint_offset_deg", 5, "must be a list of numbers (deg), one per joint, got 5"),
])
def test_fields_of_the_wrong_type_are_refused_by_name(field, value, said):
    """arm=3 or trajectory=5 ended in Python's "expected str, bytes or os.PathLike object",
    laps=2.5 in "'float' object cannot be interpreted as an integer" (and laps=True ran one
    lap), true_links_mm="abc" in "could not convert string to float": errors naming no field.
    Now one ConfigError naming it; paths, lists and arrays are taken as before."""
    from pathlib import Path

    from itg_vision.errors import ConfigError

    with pytest.raises(ConfigError) as exc:
        TrackingEnv(feedback="truth", **{"points": 5, field: value})
    assert exc.value.field == field and str(exc.value) == f"{field}: {said}"
    RunConfig(arm=Path("data/arms/two-link.yaml"), links_mm=[100, 100.0],
              true_links_mm=np.array([100.0, 100.0]), joint_offset_deg=(np.float64(1), 0),
              laps=np.int64(2)).validate()



@pytest.mark.parametrize("field, value", [("allow_unseen", "no"), ("strobe", 1),
                                          ("full_frame", "yes"), ("images", "no")])
def test_switches_are_true_or_false(field, value):
    """allow_unseen="no" was read as true: the check that the cameras see the arm was skipped
    without a word, as were strobe=1 and full_frame="yes" taken; images="no" added images.
    Each is refused in one line naming it, as preview was."""
    with pytest.raises(ValueError if field == "images" else UserError) as exc:
        TrackingEnv(feedback="vision", points=5, **{field: value})
    assert str(exc.value) == f"{field}: must be true or false, got {value!r}"


def test_an_unknown_controller_is_refused_though_the_env_uses_none():
    """The env ignores a known controller (a run's config may be passed as it is), but
    controller="foo" was accepted without a word."""
    from itg_vision.errors import ConfigError

    with pytest.raises(ConfigError, match="controller: unknown 'foo' \\(choose from itg, "):
        TrackingEnv(feedback="model", points=5, controller="foo")
    TrackingEnv(feedback="model", points=5, controller="jacobian").close()


@pytest.mark.parametrize("field, value, said", [
    ("true_links_mm", (1.0, 2.0, 3.0), "true_links_mm: arm 'two-link' needs 2 link lengths"),
    ("links_mm", (100.0, -5.0), "links_mm: link 2 must be a length in mm"),
    ("joint_offset_deg", (1.0,), "joint_offset_deg: arm 'two-link' needs 2 finite offsets"),
    ("laps", 0, "laps: must be in 1..1000"),
    ("trajectory", "line-ab-reach", "trajectory: line-ab-reach has z values, but arm two-link"),
])
def test_the_library_names_its_fields_not_the_command_lines_options(field, value, said):
    """From code, a bad field is named as the code names it (`true_links_mm`), not as `run`'s
    option (`--true-links`, which the command line still says: tests/test_bad_inputs.py)."""
    from itg_vision.errors import ConfigError

    with pytest.raises(ConfigError) as caught:
        TrackingEnv(**{field: value})
    assert caught.value.field == field and str(caught.value).startswith(said)
    assert "--" not in str(caught.value)


@pytest.mark.parametrize("arm", ["one-link", "two-link", "three-link"])
def test_without_a_servo_limit_the_action_space_is_the_arm_files(arm):
    """An action space needs bounds: unset, the servo limit is the arm file's own
    (benchmark.max_step_deg: 2 deg/iteration for the three-link arm), not 20 for every arm (the
    three-link env clipped at 10x its arm's limit)."""
    from itg_vision.arm import ArmSpec

    limit = ArmSpec.from_args(arm).benchmark["max_step_deg"]
    assert limit == (2.0 if arm == "three-link" else 20.0)
    env = TrackingEnv(arm=arm, feedback="model", points=4)
    try:
        n = ArmSpec.from_args(arm).n_joints
        assert env.config.max_step_deg == limit
        np.testing.assert_array_equal(env.action_space.high, np.full(n, limit))
        np.testing.assert_array_equal(env.action_space.low, np.full(n, -limit))
    finally:
        env.close()


def test_the_action_space_is_the_servo_limit_both_ways():
    """Every action in the space is applied whole, the most negative one included."""
    env = TrackingEnv(feedback="truth", points=5, max_step_deg=3.0)
    try:
        _, info0 = env.reset(seed=0)
        assert env.action_space.contains(np.array([-3.0, -3.0], dtype=env.action_space.dtype))
        _, _, _, _, info = env.step(env.action_space.low)
        assert not info["clipped"]
        np.testing.assert_allclose(info["q_deg"] - info0["q_deg"], [-3.0, -3.0], rtol=0,
                                   atol=roundoff(180))
    finally:
        env.close()


def test_the_env_simulates_the_true_arm_not_the_model():
    """true_links_mm 110/110: straight up (q 90, 0 deg) the gripper stands 220 mm above the
    base, where ideal sensors see it; the model's 100/100 would put it at 200."""
    env = TrackingEnv(feedback="truth", points=5, true_links_mm=(110.0, 110.0))
    try:
        obs, info = env.reset(seed=0)
        true = forward_kinematics(ArmSpec.from_args("two-link", (110.0, 110.0)),
                                  info["q_deg"])["gripper"]
        np.testing.assert_allclose(obs["gripper_mm"], true, rtol=PYBULLET_RTOL, atol=roundoff(220))
        assert obs["gripper_mm"][1] == pytest.approx(220.0, abs=1e-3)
    finally:
        env.close()


def test_gymnasium_make_builds_the_env_by_its_id():
    """`gymnasium.make("itg_vision.env:itg_vision/Tracking-v0", ...)` gives the env that
    TrackingEnv(...) gives, with the same episode for the same seed and actions (there was no
    id to make it by)."""
    import gymnasium as gym

    made = gym.make("itg_vision.env:itg_vision/Tracking-v0", feedback="truth", noise_mm=0.2,
                    points=6, seed=3)
    direct = TrackingEnv(feedback="truth", noise_mm=0.2, points=6, seed=3)
    try:
        assert isinstance(made.unwrapped, TrackingEnv)
        rewards = []
        for env in (made, direct):
            env.reset(seed=7)
            rewards.append([env.step(np.array([1.0, -2.0]))[1] for _ in range(6)])
        assert rewards[0] == rewards[1]
    finally:
        made.close()
        direct.close()


def test_a_config_that_is_not_a_run_config_is_refused_by_name():
    """TrackingEnv({"feedback": "truth"}) failed as "'dict' object has no attribute
    'correction'"; the fields go as keyword arguments."""
    with pytest.raises(TypeError, match=r"^config: a RunConfig expected \(or its fields as "
                                        r"keyword arguments\), got dict$"):
        TrackingEnv({"feedback": "truth", "points": 5})
    TrackingEnv(**{"feedback": "truth", "points": 5}).close()


def test_whole_frames_too_large_to_render_are_refused_when_the_env_is_built():
    """full_frame at supersample 8 renders the shipped 640 x 480 rig's frames (with their lens
    margin) at 5504 x 4224 px, over the 16.8 Mpx limit: refused when the environment is built,
    as `run --full-frame --supersample 8` is before its run; it was refused only at the first
    reset (with images=True it already was at construction, as images build a feedback)."""
    with pytest.raises(UserError, match=r"supersample 8 renders 5504 x 4224 px.*supersample 6 "
                                        r"at most"):
        TrackingEnv(full_frame=True, supersample=8)
