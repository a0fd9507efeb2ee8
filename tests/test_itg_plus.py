"""ITG+ (issue 13): the rule language's LET, and the ITG+ rule bases against independent
computations (finite-difference Jacobians of the nominal model, the forward kinematics) and the
properties the issue asks for (first step never farther, ties settled the same way whatever the
noise, no link length in the motion rules)."""

import dataclasses
import re
from dataclasses import fields, is_dataclass
from itertools import islice

import numpy as np
import pytest
from conftest import PYBULLET_RTOL, affine_eye

from itg_vision.arm import ArmSpec, forward_kinematics, model_pitch_axis
from itg_vision.errors import UserError
from itg_vision.feedback import Markers
from itg_vision.loop import DIVERGED_MM
from itg_vision.rules import Name, RuleBase, load_rules
from itg_vision.runner import RunConfig, execute, prepare

_SPECS = {n: ArmSpec.from_args(n) for n in ("one-link", "two-link", "three-link")}
#: arm -> its ITG+ rule base (the arm file's itg_plus_rules)
ARMS = {n: a.defaults["itg_plus_rules"] for n, a in _SPECS.items()}
#: The servo limit the comparisons use (deg per iteration, the arm file's), also the rules' S.
SERVO = {n: float(a.benchmark["max_step_deg"]) for n, a in _SPECS.items()}


def itg_plus(arm: ArmSpec, links=None) -> RuleBase:
    return load_rules(ARMS[arm.name], arm.n_joints, links or arm.links_mm, S=SERVO[arm.name], w=0.5)


def dls(arm: ArmSpec):
    """The DLS Jacobian tracker on the nominal geometry, under the same servo limit."""
    from itg_vision.controllers import make_controller

    return make_controller("jacobian", arm, max_step_deg=SERVO[arm.name])


def near_base(arm: ArmSpec, q) -> bool:
    """The gripper within a quarter forearm of the base (25 mm on the paper's arm)."""
    return bool(np.hypot(*forward_kinematics(arm, q)["gripper"][:2]) < arm.links_mm[-1] / 4)


def observe(arm, q, rng=None, sigma=0.0):
    """The LEDs at joints ``q`` (``sigma`` mm of noise each), and on the three-link arm the pitch
    axis the loop keeps, exact here: a start-up's measured axis turned by the commanded q1 is
    the true one (Session's own is tested against it in test_loop)."""
    m = forward_kinematics(arm, q)
    g, e = m["gripper"], m["elbow"]
    if rng is not None and sigma:
        g, e = g + rng.normal(0, sigma, 3), e + rng.normal(0, sigma, 3)
    return Markers(g, e, pitch_axis=None if arm.planar else model_pitch_axis(arm, q[0]))


def distance(arm, p, q):
    dim = 2 if arm.planar else 3
    return float(np.linalg.norm((p - forward_kinematics(arm, q)["gripper"])[:dim]))


def reachable_target(arm, rng):
    """A point the gripper LED reaches (a random pose's) that RULE 0 lets through too: on the
    three-link arm RULE 0 tests the arm's reach from the shoulder, L2 + L3, while the LED, 12 mm
    beside the arm's plane, reaches up to sqrt((L2 + L3)^2 + 12^2)."""
    while True:
        p = forward_kinematics(arm, rng.uniform(-180, 180, arm.n_joints))["gripper"]
        arm_reach = arm.planar or np.linalg.norm(p - arm.shoulder_mm()) <= arm.reach_mm()[1]
        if arm.reachable(p) and arm_reach:
            return p


def step(rb, arm, p, q, rng=None, sigma=0.0):
    dq = rb.step(p, observe(arm, q, rng, sigma), q).dq_deg
    return np.clip(dq, -SERVO[arm.name], SERVO[arm.name])  # the loop's servo limit


def poses_from_the_start(rb, arm, p):
    """The joints from the arm's start pose, one decision a step towards ``p`` (ideal sensors,
    the servo limit): the start, then each step's pose, without end."""
    q = arm.start_q_deg.astype(float)
    while True:
        yield q
        q = q + step(rb, arm, p, q)


# ----------------------------------------------------------------------------- LET
@pytest.mark.parametrize("name", ["two-link", "three-link"])
@pytest.mark.parametrize("S", [2.0, 20.0])
def test_every_step_is_clipped_to_the_servo_limit(name, S):
    """The two- and three-link files say every step is clipped to +-S (two-link: the th3 clip
    of RULE 3 is 40.4 deg at S = 40, beyond this S). Random poses and set points, a third of
    them square to the three-link arm's plane (RULES 2 and 3, whose shoulder step reached 12 S
    near the shoulder's height before its clip): no joint steps more than S."""
    arm = _SPECS[name]
    rb = load_rules(ARMS[name], arm.n_joints, arm.links_mm, S=S, w=0.5)
    rng = np.random.default_rng(2)
    for k in range(3000):
        q = rng.uniform(-180, 180, arm.n_joints)
        d = reachable_target(arm, rng)
        if k % 3 == 0 and not arm.planar:  # along the pitch axis, a few mm either side
            a = np.array([np.sin(np.radians(q[0])), -np.cos(np.radians(q[0]))])
            d[:2] = rng.uniform(20, 150) * a * rng.choice([-1, 1]) + rng.normal(0, 0.5, 2)
        step = rb.step(d, observe(arm, q), q)
        assert step.out_of_reach or np.abs(step.dq_deg).max() <= S + 1e-9, (q, d, step)


def test_let_names_a_quantity_computed_once_before_the_rules():
    rb = RuleBase.from_text("LET C = xg * ye - yg * xe\nLET D = 2 * C\n"
                            "RULE 1: IF D > 0 THEN q1 += D\nRULE 2: IF 1 > 0 THEN q2 -= C",
                            2, (100.0, 100.0))
    s = rb.step(np.zeros(3), Markers(np.array([1.0, 0, 0]), np.array([0, 1.0, 0])), [0, 0])
    assert s.fired == (1, 2) and list(s.dq_deg) == [2.0, -1.0]


@pytest.mark.parametrize("text, where, what", [
    ("LET C = 1\nLET C = 2\nRULE 1: IF 1 > 0 THEN q1 += C", ":2:5", "'C' is already LET on line 1"),
    ("LET xg = 1\nRULE 1: IF 1 > 0 THEN q1 += xg", ":1:5", "'xg' is already a built-in name"),
    ("LET q3 = 1\nRULE 1: IF 1 > 0 THEN q1 += q3", ":1:5", "'q3' is already reserved: qN names joint N's angle"),
    ("RULE 1: IF 1 > 0 THEN q1 += C\nLET C = 1", ":1:29", "unknown name 'C'"),
    ("LET C = D\nLET D = 1\nRULE 1: IF 1 > 0 THEN q1 += C", ":1:9", "unknown name 'D'"),
    ("LET C 1\nRULE 1: IF 1 > 0 THEN q1 += C", ":1:7", "expected '=' after LET C"),
    ("LET C = 1 2\nRULE 1: IF 1 > 0 THEN q1 += C", ":1:11", "expected the next 'RULE' or 'LET'"),
    ("RULE 1: IF 1 > 0 THEN q1 += 1 LET", ":1:", "expected a name after LET"),
])
def test_let_errors_name_file_line_column(text, where, what):
    with pytest.raises(UserError) as exc:
        RuleBase.from_text(text, 2, (100.0, 100.0), source="my.rules")
    msg = str(exc.value)
    assert msg.startswith("my.rules" + where), msg
    assert what in msg


# ----------------------------------------------------------------------------- model-free
#: The rules each motion may read of the link lengths: none, but for the three-link shoulder
#: height L1 (the pivot of q2, a measured point like the base axis; its rule file says so).
ALLOWED_LINKS = {"one-link": set(), "two-link": set(), "three-link": {"L1"}}


def _names(node) -> list[str]:
    """Every name a parsed rule, action, definition or expression reads. The parser's nodes
    (Num, Name, Unary, Binary) and the Rule, Action and Definition holding them are frozen
    dataclasses: walk their fields, and tuples of them (a Name's Token holds only its text)."""
    if isinstance(node, Name):
        return [node.name]
    if isinstance(node, (tuple, list)):
        return [n for x in node for n in _names(x)]
    if is_dataclass(node) and not isinstance(node, type):
        return [n for f in fields(node) for n in _names(getattr(node, f.name))]
    return []


@pytest.mark.parametrize("name", list(ARMS))
def test_motion_rules_use_no_link_length(name):
    """L1..Ln appear only in RULE 0, the reach test, except the three-link shoulder height L1:
    no definition, no condition and no step of the motion rules reads one; the one-link file
    reads none at all (its RULE 0 flags only the base). The walker is checked on the same trees:
    it finds the two- and three-link lengths in RULE 0, a name in every definition (none is a
    constant) and the markers in the rules."""
    from itg_vision.rules import RULES_DIR, resolve_rules_path

    assert {resolve_rules_path(r) for r in ARMS.values()} == set(RULES_DIR.glob("itg-plus-*.rules"))
    arm = ArmSpec.from_args(name)
    rb = itg_plus(arm)
    lengths = {"L"} | {f"L{i}" for i in range(1, arm.n_joints + 1)}
    reach = [r for r in rb.rules if r.out_of_reach]
    assert [r.number for r in reach] == [0]
    assert set(_names(reach[0])) & lengths == (set() if name == "one-link" else lengths - {"L"})
    assert rb.definitions
    motion = [(f"LET {d.name}", d) for d in rb.definitions]
    motion += [(f"RULE {r.number}", r) for r in rb.rules if not r.out_of_reach]
    read = {where: set(_names(node)) for where, node in motion}
    assert all(read[f"LET {d.name}"] for d in rb.definitions)
    assert {"xg", "yg", "xd", "yd", "S", "w"} <= set().union(*read.values())
    for where, names in read.items():
        assert not names & (lengths - ALLOWED_LINKS[name]), (where, names & lengths)


#: Other link lengths to tell the rules (factors of the arm's): each length changed by its own
#: factor, and a set whose reach (RULE 0) holds all of the arm's, so that near-base and full-reach
#: set points are compared too. One-link: its rules read no length, so any factor will do.
OTHER_LINKS = {"one-link": [(1.3,)], "two-link": [(0.8, 1.3), (1.3, 1.3)],
               "three-link": [(1.0, 1.3, 0.7), (1.0, 1.3, 1.3)]}
#: Rules the sample below must have fired: all the one-link steps, the singular rules of the
#: others (two-link RULES 8-12, three-link 5-9: the elbow within 1 deg of straight or folded).
SAMPLED_RULES = {"one-link": {2, 3, 4, 5, 6}, "two-link": set(range(8, 13)),
                 "three-link": set(range(5, 10))}


def _near_full_reach(arm, rng):
    """A set point the rules let through (RULE 0) within 3 mm of the arm's full reach about its
    shoulder (the planar arms: the base), in any direction the LED can reach."""
    lo, hi = arm.reach_mm()
    while True:
        v = rng.normal(size=3)
        if arm.planar:
            v[2] = 0.0
        p = arm.shoulder_mm() + rng.uniform(hi - 3.0, hi) * v / np.linalg.norm(v)
        if arm.planar:
            p[2] = arm.led_standoff_mm
        if arm.reachable(p):
            return p


@pytest.mark.parametrize("name", list(ARMS))
def test_motion_steps_do_not_change_with_the_link_lengths_the_rules_are_told(name):
    """The steps do not change when the rules are told other lengths (the shoulder height L1 of
    the three-link arm kept): random poses and set points, poses with the elbow within 1 deg of
    straight or folded (the singular rules), and set points within 3 mm of full reach (where
    RULES 8-9 of the two-link arm test the set point against the gripper's circle)."""
    arm = ArmSpec.from_args(name)
    a = itg_plus(arm)
    others = [itg_plus(arm, links=tuple(v * f for v, f in zip(arm.links_mm, fs)))
              for fs in OTHER_LINKS[name]]
    rng = np.random.default_rng(1)
    elbow = arm.n_joints - 1
    fired, compared, n = set(), [0] * len(others), 300
    for i in range(n):
        q = rng.uniform(-180, 180, arm.n_joints)
        if i % 3 and arm.n_joints > 1:
            q[elbow] = rng.choice([0.0, 180.0]) + rng.uniform(-1.0, 1.0)
        p = _near_full_reach(arm, rng) if i % 3 == 2 else reachable_target(arm, rng)
        m = observe(arm, q)
        sa = a.step(p, m, q)
        if sa.out_of_reach:
            continue
        fired |= set(sa.fired)
        for k, b in enumerate(others):
            sb = b.step(p, m, q)
            if not sb.out_of_reach:
                np.testing.assert_array_equal(sa.dq_deg, sb.dq_deg, err_msg=str((q, p, sa.fired)))
                compared[k] += 1
    assert SAMPLED_RULES[name] <= fired, fired
    assert min(compared) >= n // 2, compared


@pytest.mark.parametrize("scale", [0.95, 1.0, 1.05])
def test_one_link_tracks_through_an_eye_whose_scale_is_off(scale):
    """A scale error about the base moves no bearing, and the one-link rules step by bearings:
    the arm tracks the arc (set points 1.5 deg apart on the 100 mm circle) with the eye's L 5 %
    off, where every set point lies 5 mm off the circle the eye believes in. Table 1's ring
    test (|rd2 - L^2| <= 2 L w, 1 mm wide), which this file had, flagged all 180 and held: a
    tracking median of 191 mm. What is left is the step formula's own error: the angle to go
    is the spacing plus the residual r carried from the set point before, and one step of
    4 a b sin t / (a^2 + b^2 + 2 a b cos t + w^2) rad (a = 100 x scale, the gripper's measured
    radius; b = 100, the set point's) leaves r = t - step, iterated to its fixed point; the
    gripper then sits the chord 2 b sin(r / 2) from the set point, to the simulator's float32:
    an ulp of each coordinate and of the joint angle at 100 mm, a few times over."""
    prep = prepare(RunConfig(arm="one-link", rules=ARMS["one-link"], feedback="truth", seed=0))
    prep = dataclasses.replace(prep, feedback_factory=lambda: affine_eye(scale=scale))
    trace, s = execute(prep)
    a, b, w, spacing = 100.0 * scale, 100.0, 0.5, np.radians(1.5)
    r = 0.0
    for _ in range(200):
        t = spacing + r
        r = t - 4 * a * b * np.sin(t) / (a * a + b * b + 2 * a * b * np.cos(t) + w * w)
    expected = abs(2 * b * np.sin(r / 2))
    tracking = trace.error_mm()[s["tracking_from"]:]
    assert s["geometry"]["links_mm"][0] == pytest.approx(a, rel=PYBULLET_RTOL * 4)
    assert s["n_flagged"] == 0 and s["n_setpoints"] == 180
    np.testing.assert_allclose(tracking, expected, rtol=0, atol=4 * PYBULLET_RTOL * b)


# ----------------------------------------------------------------------------- hold
#: The tolerance w the rule bases get here (``itg_plus``; the runner's default, RULE_DEFAULTS).
W_MM = 0.5


def _set_point_at(arm, q, r_mm, v):
    """The gripper LED of the pose q + t v (v in deg, t > 0) that lies r_mm from the LED at q:
    a set point the arm reaches, from the forward kinematics (bisection on t to 1e-12 mm)."""
    def gap(t):
        return distance(arm, forward_kinematics(arm, q + t * v)["gripper"], q) - r_mm

    lo, hi = 0.0, 1.0
    while gap(hi) < 0:
        lo, hi = hi, 2 * hi
    while hi - lo > 1e-12 * hi:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if gap(mid) < 0 else (lo, mid)
    return forward_kinematics(arm, q + hi * v)["gripper"]


def _hold_poses(arm, rng, n):
    """Poses away from singular ones (J from finite differences: smallest singular value at
    least 0.3 mm/deg) where a set point 0.6 mm away is one small servo step: two-link not near
    the base, three-link forearm 10 deg or more off vertical (see the Newton test below) and the
    gripper 5 mm or more inside RULE 0's reach (the pose's own LED must pass it)."""
    out = []
    while len(out) < n:
        q = rng.uniform(-180, 180, arm.n_joints)
        if np.linalg.svd(_fd_jacobian(arm, q), compute_uv=False).min() < 0.3:
            continue
        if arm.name == "two-link" and near_base(arm, q):
            continue
        if arm.name == "three-link" and (abs((q[1] + q[2]) % 180 - 90) < 10 or np.linalg.norm(
                forward_kinematics(arm, q)["gripper"] - arm.shoulder_mm()) > arm.reach_mm()[1] - 5):
            continue
        out.append(q)
    return out


@pytest.mark.parametrize("name", list(ARMS))
def test_rule_1_holds_within_w_of_the_set_point_and_only_there(name):
    """RULE 1 of every ITG+ rule base: the gripper within w of the set point (compared on
    squares), every joint holds. A set point w - 0.1 mm from the LED (in the plane for the planar
    arms, in space for the three-link arm; reached by turning each joint alone, and all of them
    at random): the step is exactly zero and RULE 1 alone fires. At w + 0.1 mm: RULE 1 does not
    fire, the arm moves, and the step (servo-limited) lands nearer the set point."""
    arm = ArmSpec.from_args(name)
    rb = itg_plus(arm)
    rng = np.random.default_rng(9)
    for q in _hold_poses(arm, rng, 15):
        for v in [*np.eye(arm.n_joints), rng.normal(size=arm.n_joints)]:
            for sign in (1, -1):
                inside = _set_point_at(arm, q, W_MM - 0.1, sign * v)
                got = rb.step(inside, observe(arm, q), q)
                assert got.fired == (1,) and not got.out_of_reach, (q, inside, got)
                assert np.all(got.dq_deg == 0), (q, inside, got)
                outside = _set_point_at(arm, q, W_MM + 0.1, sign * v)
                got = rb.step(outside, observe(arm, q), q)
                assert 1 not in got.fired and not got.out_of_reach, (q, outside, got)
                assert np.any(got.dq_deg != 0), (q, outside, got)
                after = distance(arm, outside, q + step(rb, arm, outside, q))
                assert after < W_MM + 0.1, (q, outside, got, after)


# ----------------------------------------------------------------------------- steps
def _fd_jacobian(arm, q, h=1e-6):
    """d(gripper)/dq in mm/deg by central differences of the forward kinematics."""
    cols = []
    for j in range(arm.n_joints):
        dq = np.zeros(arm.n_joints)
        dq[j] = h
        cols.append((forward_kinematics(arm, q + dq)["gripper"]
                     - forward_kinematics(arm, q - dq)["gripper"]) / (2 * h))
    J = np.column_stack(cols)
    return J[:2] if arm.planar else J


@pytest.mark.parametrize("name, factor", [("one-link", 1000), ("two-link", 30), ("three-link", 40)])
def test_one_step_removes_a_small_error_like_newton(name, factor):
    """A set point 1-2 mm away (above the hold band w), within one servo step, away from singular
    poses (J from finite differences well conditioned): one step shrinks the error by at least
    ``factor``, as Newton's step does (it leaves terms of order |err|^2 / lever). Three-link: the
    pitch axis is the loop's (exact here), and the forearm is kept 10 degrees off vertical, as
    when the rules read the axis from the LEDs, which cannot tell the arm's plane there.
    Two-link: not within a quarter forearm of the base, where q1's step is damped (tested below)."""
    arm = ArmSpec.from_args(name)
    rb = itg_plus(arm)
    rng = np.random.default_rng(2)
    n = 0
    while n < 100:
        q = rng.uniform(-180, 180, arm.n_joints)
        J = _fd_jacobian(arm, q)
        if np.linalg.svd(J, compute_uv=False).min() < 0.3:  # mm/deg: well away from singular
            continue
        dq = rng.normal(0, 1.0, arm.n_joints)
        dq *= rng.uniform(1.0, 2.0) / np.linalg.norm(J @ dq)
        forearm_off_vertical = abs((q[1] + q[2]) % 180 - 90) if name == "three-link" else 90
        if np.abs(dq).max() > 0.75 * SERVO[name] or forearm_off_vertical < 10:
            continue
        if name == "two-link" and near_base(arm, q):
            continue
        p = forward_kinematics(arm, q + dq)["gripper"]
        before = distance(arm, p, q)
        after = distance(arm, p, q + rb.step(p, observe(arm, q), q).dq_deg)
        assert after <= before / factor, (q, dq, before, after)
        n += 1


def _bent_three_link_poses(rng):
    """Three-link poses with the elbow bent 20-160 deg either way (far outside the elbow's
    bands: RULES 10 and 11's radial step), the forearm 10 deg or more off vertical."""
    while True:
        q = np.array([rng.uniform(-180, 180), rng.uniform(-60, 150),
                      rng.choice([-1, 1]) * rng.uniform(20, 160)])
        if abs((q[1] + q[2]) % 180 - 90) >= 10:
            yield q


def test_the_pitch_steps_turn_about_the_kept_axis():
    """The pitch joints take their axis from the loop (xa, ya), not from the LEDs: the same LEDs
    with the kept axis reversed give RULE 10's pitch steps exactly reversed (every term of them
    is odd in a but its scale), and q1's step unchanged (a ratio even in a: its sign cancels). A set point
    1-3 mm away in the arm's plane: with the true axis the step shrinks the error tenfold or more (Newton's step,
    tested above), reversed it grows it. (Before the kept axis the rules read a from P, which
    under 4 px had the wrong sign at a median 6.7 % of reach-loop's decisions.)"""
    arm = ArmSpec.from_args("three-link")
    rb = itg_plus(arm)
    rng = np.random.default_rng(7)
    poses, n = _bent_three_link_poses(rng), 0
    for _ in range(5000):  # about 600 draws give the 100 (RULE 10 fires at most)
        if n == 100:
            break
        q = next(poses)
        dq = np.array([0.0, *rng.normal(0, 1.0, 2)])  # in the arm's plane: the pitch joints'
        p = forward_kinematics(arm, q + dq * rng.uniform(0.3, 0.9) / np.abs(dq).max())["gripper"]
        seen = observe(arm, q)
        true = rb.step(p, seen, None)
        flipped = rb.step(p, dataclasses.replace(seen, pitch_axis=-seen.pitch_axis), None)
        if set(true.fired) != {4, 10} or not 1.0 <= distance(arm, p, q) <= 3.0:
            continue
        assert set(flipped.fired) == {4, 10}, (q, p, flipped)
        assert flipped.dq_deg[0] == true.dq_deg[0]
        np.testing.assert_allclose(flipped.dq_deg[1:], -true.dq_deg[1:], rtol=1e-12, atol=0)
        before = distance(arm, p, q)
        assert distance(arm, p, q + true.dq_deg) < before / 10, (q, p, true)
        assert distance(arm, p, q + flipped.dq_deg) > before, (q, p, flipped)
        n += 1
    assert n == 100, n


def test_within_the_eyes_noise_the_pitch_pair_is_scaled_as_a_whole_keeping_its_direction():
    """An error within 3 sL (sL the lengths' standard error, the eye's uncertainty; 60 mm here,
    so that 20-150 mm errors count as noise): RULE 11 scales q2's and q3's steps together so
    that the larger moves S, where the loop would clip each on its own and bend the step away
    from the error (docs/robustness.md). Set points in the arm's plane (q1's step 0 to
    round-off whatever S: the LED and the set point lie equally far along the kept axis),
    20-150 mm from the gripper, so that the pair asks for more than 4 deg: at S = 2 and at
    S = 4 the larger moves exactly S and the step at 4 is the step at 2 doubled, the same
    direction; clipped joint by joint it would not be (|d2| = 3, |d3| = 10 deg clip to (2, 2)
    and (3, 4)). And the direction is the pair's own: the same as at S = 8 wherever that step
    is scaled too. With sL = 0 (the same errors beyond the noise) RULE 10 takes them instead:
    the elbow a full step S the same way (the radial step's sign), and the shoulder's turn from
    that step, so that v = g - s (forward kinematics) ends no farther in angle from the set
    point's t = p - s than after RULE 11's scaled step, and closer by more than 0.1 deg at most
    of them (93 of the 98 draws where the elbow's step is the larger)."""
    arm = ArmSpec.from_args("three-link")
    clean = {S: load_rules(ARMS["three-link"], 3, arm.links_mm, S=S, w=0.5) for S in (2.0, 4.0, 8.0)}
    rules = {S: rb.with_links(rb.links_mm, rb.base_axis_mm, sL=60.0, h=rb.h) for S, rb in clean.items()}
    shoulder = arm.shoulder_mm()

    def off_deg(q, p):  # the angle about a from v = g - s to t = p - s, in the arm's plane
        a = model_pitch_axis(arm, q[0])
        v, t = forward_kinematics(arm, q)["gripper"] - shoulder, p - shoulder
        v, t = v - a * (a @ v), t - a * (a @ t)
        return abs(np.degrees(np.arctan2(a @ np.cross(v, t), v @ t)))

    rng = np.random.default_rng(9)
    poses, n, unequal, closer, elbow_larger = _bent_three_link_poses(rng), 0, 0, 0, 0
    for _ in range(20000):
        if n == 200:
            break
        q = next(poses)
        other = np.array([q[0], *next(poses)[1:]])  # the same plane
        p = forward_kinematics(arm, other)["gripper"]
        seen = observe(arm, q)
        if not 20.0 <= distance(arm, p, q) <= 150.0:
            continue
        steps = {S: rb.step(p, seen, None) for S, rb in rules.items()}
        if any(set(s.fired) != {4, 11} for s in steps.values()):
            continue
        two, four = steps[2.0].dq_deg, steps[4.0].dq_deg
        assert abs(two[0]) < 1e-9 and abs(four[0]) < 1e-9, (q, p, two, four)
        if np.abs(four[1:]).max() < 4.0 - 1e-9:  # the pair asked for less than 4 deg
            continue
        assert np.abs(two[1:]).max() == pytest.approx(2.0, abs=1e-12)
        beyond = clean[2.0].step(p, seen, None)
        if abs(two[2]) == pytest.approx(2.0, abs=1e-12):  # the elbow's step the larger
            assert set(beyond.fired) == {4, 10}, (q, p, beyond)
            assert beyond.dq_deg[2] == pytest.approx(two[2], abs=1e-12), (q, p, beyond, two)
            assert abs(beyond.dq_deg[1]) <= 2.0 + 1e-12, (q, p, beyond, two)
            clipped_off, scaled_off = off_deg(q + beyond.dq_deg, p), off_deg(q + two, p)
            assert clipped_off <= scaled_off + 1e-9, (q, p, beyond, two)
            closer += clipped_off < scaled_off - 0.1
            elbow_larger += 1
        np.testing.assert_allclose(four[1:], 2.0 * two[1:], rtol=1e-12, atol=1e-12)
        eight = steps[8.0].dq_deg[1:]
        if np.abs(eight).max() == pytest.approx(8.0, abs=1e-12):
            np.testing.assert_allclose(eight, 4.0 * two[1:], rtol=1e-12, atol=1e-12)
        unequal += abs(abs(two[1]) - abs(two[2])) > 0.1  # not the clip's (+-S, +-S)
        n += 1
    assert n == 200 and unequal > 100 and closer > elbow_larger / 2 > 0, (n, unequal, closer,
                                                                         elbow_larger)


def test_from_the_straight_start_a_still_set_point_is_reached_in_the_servos_time():
    """From the straight-up start to a still, reachable set point, exact markers, one decision a
    step under the servo limit S: the gripper comes within 1 mm in at most ceil(n*) + 2 steps,
    n* the servo's bound, the steps that bring the slowest joint to an IK pose at its limit
    (over the closed-form IK solutions, the largest joint travel over S; 1 mm may come a step
    or two sooner). The last steps are Newton's, which shrink the few mm left as the slowest
    joint arrives (the worst of these 200: 5.8, 2.3, then 0.0 mm), so 1 mm comes up to two
    steps after ceil(n*); measured, 78 of the 200 arrive before ceil(n*), 117 at it, 3 one step
    after and 2 two steps after. RULE 10 gives it: beyond the eye's noise (3 sL, 0 here) each
    joint runs at its own limit, q2's turn computed from q3's clipped step. With the pair
    scaled as a whole there too (RULE 11's step), the turn waited on the radial step, which
    near the straight pose is many times the bend the set point needs: 128 of the 200 came
    late, a median of 15 steps beyond n* and up to 55, and line-ab-reach at one iteration per
    set point reached a tracking max of 25.3 mm."""
    from itg_vision.arm import wrap_deg
    from itg_vision.controllers import three_link_ik

    arm = ArmSpec.from_args("three-link")
    S, rb = SERVO["three-link"], itg_plus(arm)
    rng = np.random.default_rng(5)
    late = []
    for _ in range(200):
        p = reachable_target(arm, rng)
        bound = min(np.abs(wrap_deg(np.array(sol) - arm.start_q_deg)).max() / S
                    for sol in three_link_ik(p, arm.links_mm, arm.led_standoff_mm))
        for n, q in zip(range(400), poses_from_the_start(rb, arm, p)):
            if distance(arm, p, q) <= 1.0:
                break
        if n > np.ceil(bound) + 2:
            late.append((np.round(p, 1).tolist(), n, round(bound, 1)))
    assert not late, late


def _around_base(rng, lo_mm, hi_mm):
    """A set point lo_mm..hi_mm from the base in a random direction (the plane, z = 0)."""
    a = rng.uniform(-np.pi, np.pi)
    return np.array([*(rng.uniform(lo_mm, hi_mm) * np.array([np.cos(a), np.sin(a)])), 0.0])


def _near_base_poses(arm, rng):
    """Poses with the gripper within a quarter forearm of the base, folded either way."""
    while True:
        q = np.array([rng.uniform(-180, 180), rng.choice([-1, 1]) * rng.uniform(152, 180)])
        if near_base(arm, q):
            yield q


@pytest.mark.parametrize("links, damping_mm, gate_mm", [
    ((100.0, 100.0), 5.0, 2.0),                            # the floors: 5 mm and 4 w
    ((300.0, 300.0), 300 / np.sqrt(500), 5.0),             # |u| / 22.4 and |u| / 60
    ((60.0, 60.0), 5.0, 2.0)])                             # a shorter arm: the floors
def test_near_the_base_with_the_set_point_at_it_the_step_is_the_dls_trackers_step(
        links, damping_mm, gate_mm):
    """Gripper within a quarter forearm of the base and the set point within the gate of it
    (max(4 w, |u| / 60)): the rules' step (RULE 2: Cramer's rule on the levers' dot and cross
    products, scaled down as a whole beyond S) equals the DLS Jacobian tracker's (numpy's solve
    on the marker-built Jacobian, the same direction-preserving servo limit) with its damping
    lambda = max(5 mm, |u| / sqrt(500)), at the arm's servo limit (20 deg: steps within it) and
    at 2 deg (steps scaled down to it). On the 300/300 arm both lengths scale with the forearm:
    with the fixed 5 and 2 mm the step differed and RULE 2 did not fire from 2 to 5 mm."""
    from itg_vision.controllers import make_controller

    arm = ArmSpec.from_args("two-link").with_links(links)
    rng = np.random.default_rng(7)
    scaled = []
    for servo in (SERVO["two-link"], 2.0):
        rb = load_rules(ARMS["two-link"], 2, arm.links_mm, S=servo, w=0.5)
        tracker = make_controller("jacobian", arm, max_step_deg=servo, damping_mm=damping_mm)
        for q, _ in zip(_near_base_poses(arm, rng), range(150)):
            p = _around_base(rng, 0.9 * gate_mm if len(scaled) % 2 else 0.0, gate_mm)
            if distance(arm, p, q) <= 0.5:  # the hold band w
                continue
            got = rb.step(p, observe(arm, q), q)
            assert got.fired == (2,), (q, got.fired)
            scaled.append(np.isclose(np.abs(got.dq_deg).max(), servo))
            # rtol: the rules convert with 57.29578 deg/rad, 8.5e-9 above 180 / pi
            np.testing.assert_allclose(got.dq_deg, tracker.step(p, observe(arm, q), q).dq_deg,
                                       rtol=2e-8, atol=1e-9)
    assert 30 < sum(scaled) < len(scaled) - 30  # steps within the servo limit and scaled to it


def test_on_forearms_up_to_111_mm_the_near_base_lengths_are_their_floors_to_the_bit():
    """lambda^2 = max(25, |u|^2 / 500) and the gate^2 = max(16 w^2, |u|^2 / 3600), written as
    a + (|b - a| + (b - a)) / 2, are exactly 25 and 16 w^2 wherever b < a: forearms measured
    up to 111.8 and 120 mm. So on the paper's 100 mm forearm every step is the same to the last
    bit as the rules with the fixed lengths they replaced, here a copy with the two LETs
    written as 25 and 16 w^2: near-base poses of arms with forearms of 40-111 mm, markers
    0.5 mm off, set points 0 to 30 % of the forearm from the base, both servo limits."""
    from itg_vision.rules import resolve_rules_path

    text = resolve_rules_path(ARMS["two-link"]).read_text()
    fixed = re.sub(r"^LET lam2 = .*$", "LET lam2 = 25", text, count=1, flags=re.M)
    fixed = re.sub(r"^LET gate2 = .*$", "LET gate2 = 16 * w * w", fixed, count=1, flags=re.M)
    assert fixed.count("LET lam2 = 25\n") == fixed.count("LET gate2 = 16 * w * w\n") == 1
    rng = np.random.default_rng(11)
    fired, n = set(), 0
    for servo in (SERVO["two-link"], 2.0):
        for _ in range(8):
            L = rng.uniform(40.0, 111.0)
            arm = ArmSpec.from_args("two-link").with_links((L, L))
            new = load_rules(ARMS["two-link"], 2, arm.links_mm, S=servo, w=0.5)
            old = RuleBase.from_text(fixed, 2, arm.links_mm, S=servo, w=0.5)
            for q, _ in zip(_near_base_poses(arm, rng), range(60)):
                p, m = _around_base(rng, 0.0, 0.3 * L), observe(arm, q, rng, 0.5)
                a, b = new.step(p, m, q), old.step(p, m, q)
                np.testing.assert_array_equal(a.dq_deg, b.dq_deg, err_msg=str((L, q, p)))
                assert a.fired == b.fired
                fired |= set(a.fired)
                n += 1
    assert {2, 3, 4, 5, 6, 7} <= fired, fired  # every near-base rule compared
    assert n == 960


def test_near_the_base_the_step_never_ends_farther_and_beats_the_dls_step():
    """Gripper within 25 mm of the base, set point 2-30 mm from it in any direction (RULES 3-7:
    the gripper's line through the base turned towards the set point the shorter way, or the
    damped step, whichever lands nearer by the levers' prediction, or the slide line turned to
    the line through g and d, the line of travel when err is the path's step): one step never
    ends farther from the set point than it started, and lands nearer the best servo-limited
    step (the exact model's, by grid search) than the DLS step does, in median over 400 cases;
    every kind of step is taken."""
    from itg_vision.bench.itg_plus import greedy_step_deg

    arm = ArmSpec.from_args("two-link")
    rb, tracker = itg_plus(arm), dls(arm)
    rng = np.random.default_rng(5)
    excess, excess_dls, fired = [], [], set()
    for q, _ in zip(_near_base_poses(arm, rng), range(400)):
        p = _around_base(rng, 2.0, 30.0)
        before = distance(arm, p, q)
        got = rb.step(p, observe(arm, q), q)
        fired |= set(got.fired)
        after = distance(arm, p, q + got.dq_deg)
        assert after < before, (q, p, before, after)
        best = greedy_step_deg(q, p, arm.links_mm, SERVO["two-link"])[1]
        step_dls = step(tracker, arm, p, q)
        excess.append(after - best)
        excess_dls.append(distance(arm, p, q + step_dls) - best)
    assert fired == {3, 4, 5, 6, 7}
    assert np.median(excess) < np.median(excess_dls), (np.median(excess), np.median(excess_dls))


def test_near_the_base_a_set_point_25_to_100_mm_away_is_never_left_farther():
    """Gripper within 25 mm of the base and the set point 25-100 mm from the base in any
    direction, a jump rather than a path passing by (RULES 3-7 as above, or RULE 2's damped step
    alone): no step of 5000 ends farther from the set point than it started. (100-200 mm away
    some do: docs/itg-plus.md, "Passing by the base".)"""
    arm = ArmSpec.from_args("two-link")
    rb = itg_plus(arm)
    rng = np.random.default_rng(11)
    farther = []
    for q, _ in zip(_near_base_poses(arm, rng), range(5000)):
        p = _around_base(rng, 25.0, 100.0)
        before = distance(arm, p, q)
        got = rb.step(p, observe(arm, q), q)
        if distance(arm, p, q + got.dq_deg) > before:
            farther.append((q, p, got.fired))
    assert not farther, farther[:3]


@pytest.mark.parametrize("controller", ["itg-plus", "dls"])
def test_under_estimate_noise_one_step_lands_the_estimate_error_away(controller):
    """Why 1 px of centroid noise costs ITG+ and the DLS tracker the same millimetres: a one-step
    controller moves the gripper by the error it measures, d - (g + n), so it lands where the
    noise n of the gripper's estimate puts it, |d - g'| = |n| to first order, whatever its clean
    accuracy. Two-link, non-singular poses, set points 1-3 mm away, sigma = 0.5 mm on every
    axis of both LEDs: the landing distance differs from |n_xy| by the second-order terms only
    (|err|^2 / lever and the lever's own error sigma / |u| times |err|, each below 0.1 mm; DLS
    also keeps lambda^2 / s_min^2 < 1 % of the step)."""
    arm = ArmSpec.from_args("two-link")
    ctrl = itg_plus(arm) if controller == "itg-plus" else dls(arm)
    rng = np.random.default_rng(11)
    gaps, noise = [], []
    while len(gaps) < 200:
        q = rng.uniform(-180, 180, 2)
        if np.linalg.svd(_fd_jacobian(arm, q), compute_uv=False).min() < 0.3 or near_base(arm, q):
            continue
        m = forward_kinematics(arm, q)
        err = rng.normal(0, 1.0, 2)
        p = m["gripper"] + np.array([*(err * rng.uniform(1.0, 3.0) / np.linalg.norm(err)), 0.0])
        n_g, n_e = rng.normal(0, 0.5, 3), rng.normal(0, 0.5, 3)
        seen = Markers(m["gripper"] + n_g, m["elbow"] + n_e)
        if np.sum((p - seen.gripper_mm)[:2] ** 2) <= 0.25:  # ITG+ holds within w: not this case
            continue
        landed = distance(arm, p, q + ctrl.step(p, seen, q).dq_deg)
        gaps.append(abs(landed - np.hypot(*n_g[:2])))
        noise.append(np.hypot(*n_g[:2]))
    assert np.median(gaps) < 0.1 < 0.5 * np.median(noise), (np.median(gaps), np.median(noise))
    assert np.percentile(gaps, 95) < 0.2


@pytest.mark.parametrize("name", list(ARMS))
@pytest.mark.parametrize("sigma", [0.0, 0.25])
def test_first_step_from_the_start_never_moves_the_gripper_away(name, sigma):
    """From the paper's start pose, any reachable set point, truth or 0.25 mm noise per axis,
    under the servo limit: the first step never ends farther from the set point. (Three-link, set
    point square to the arm's plane: the plane turns and the shoulder cancels the stand-off
    LED's swing to first order; the arc's second order, h dq1^2 / 2 < 0.01 mm, remains.)"""
    arm = ArmSpec.from_args(name)
    rb = itg_plus(arm)
    rng = np.random.default_rng(3)
    q0 = arm.start_q_deg
    for _ in range(300):
        p = reachable_target(arm, rng)
        q1 = q0 + step(rb, arm, p, q0, rng, sigma)
        assert distance(arm, p, q1) <= distance(arm, p, q0) + (0.01 if name == "three-link" else 1e-9), p


@pytest.mark.parametrize("name", ["two-link", "three-link"])
def test_the_straight_start_tie_is_settled_the_same_way_whatever_the_noise(name):
    """At the straight start the elbow's radial lever is zero and its sign is noise; the rules'
    dead band makes noisy observations give the bend of the noise-free one. Noise 0.15 mm per
    axis: the gripper's distance from the base-elbow line has 0.34 mm std (its own 0.15 and the
    elbow's doubled by the lever, sqrt(0.15^2 + 0.3^2)); without the band about half the draws
    would bend the other way. (That the band reaches 4 w = 2 mm, 6 sigma, 600 draws cannot show:
    the test below places observations at its edge. At 0.25 mm per axis about one observation in
    10^4 falls outside and bends the other way; the run still converges: both bends reach.) (Set
    points more than 3 mm, the dead band's 4 w plus the noise, from the plane through the base
    axis square to the arm: nearer, the three-link elbow's choice is between bending and
    waiting.)"""
    arm = ArmSpec.from_args(name)
    rb = itg_plus(arm)
    rng = np.random.default_rng(4)
    q0 = arm.start_q_deg
    elbow = arm.n_joints - 1
    for _ in range(30):
        p = reachable_target(arm, rng)
        while name == "three-link" and abs(p[0]) <= 3.0:  # the arm's plane at the start is x-z
            p = reachable_target(arm, rng)
        clean = step(rb, arm, p, q0)[elbow]
        for _ in range(20):
            noisy = step(rb, arm, p, q0, rng, 0.15)[elbow]
            assert np.sign(noisy) == np.sign(clean), p


#: The elbow's rules at a singular pose (the dead band) and elsewhere (the radial step).
SINGULAR_RULES = {"two-link": set(range(8, 13)), "three-link": set(range(5, 10))}
RADIAL_RULES = {"two-link": {13, 14, 15}, "three-link": {10, 11}}


@pytest.mark.parametrize("name, sL", [("two-link", 0.0), ("three-link", 0.0), ("three-link", 1.0),
                                      ("three-link", 5.0)])
def test_the_straight_start_dead_band_ends_at_its_width_from_the_arms_line(name, sL):
    """The dead band of the singular rules, (a . (u x v))^2 <= B^2 |e - s|^2 (two-link:
    C^2 <= 16 w^2 re2, B = 4 w; three-link: B = max(4 w, S |u|, 2 sL), one servo step S in rad,
    sL the lengths' measured standard error (the eye's uncertainty); a the
    joint axis, z for the planar arm; s the base or the shoulder; u = g - e, v = g - s; w the
    tolerance), at the straight start, where a . (u x v) = 0. The gripper observed moved by
    delta along n = a x (e - s) / |a x (e - s)| (in the arm's plane, square to the
    base/shoulder-elbow line) makes a . (u x v) = delta |a x (e - s)|, so the band ends at
    delta* = B |e - s| / |a x (e - s)|: 4 w = 2 mm on the two-link arm (e - s in the plane of
    motion); on the three-link arm S |u| = 3.491 mm (2 deg, |u| = 100 mm), and the stand-off
    h = 12 mm along a lengthens |e - s| but not the lever, delta* = 3.491 sqrt(100^2 + 12^2) / 100
    = 3.516 mm (a bend of 2.014 deg). Observed 0.01 mm inside the edge
    (either side of the line): the singular rule of the noise-free observation fires and the
    elbow bends the same way; 0.01 mm outside: the radial step (g . err over the vanishing lever)
    takes over and its sign follows the side, opposite on the two sides. Set points more than
    10 mm from the plane through the base axis containing the arm (x = 0 at both starts):
    moving the gripper 2 mm tilts the forearm's line by up to 3 x 2 mm at a set point behind
    the base, and within 4 w of that line the elbow's side is a tie of its own. With sL = 1 mm
    (2 sL inside the servo step's band) the edge is the same; with sL = 5 mm, 2 sL = 10 mm sets
    it, 10 sqrt(100^2 + 12^2) / 100 = 10.07 mm, and the set points keep the same margin in
    proportion (the forearm's line tilts with the observed gripper's move)."""
    arm = ArmSpec.from_args(name)
    rb = dataclasses.replace(itg_plus(arm), sL=sL)
    q0 = arm.start_q_deg
    elbow = arm.n_joints - 1
    m = forward_kinematics(arm, q0)
    g, e = m["gripper"], m["elbow"]
    if arm.planar:
        a, s, flat = np.array([0.0, 0.0, 1.0]), np.zeros(3), np.array([1.0, 1.0, 0.0])
    else:  # the pitch axis (sin q1, -cos q1, 0), along which the LEDs stand off
        q1 = np.radians(q0[0])
        a, s, flat = np.array([np.sin(q1), -np.cos(q1), 0.0]), arm.shoulder_mm(), np.ones(3)
    axis = None if arm.planar else a  # the loop's kept axis: the true one here
    lever = np.cross(a, (e - s) * flat)
    assert abs(a @ np.cross(g - e, (g - s) * flat)) < 1e-9  # straight: on the band's centre
    step_band = 4 * W_MM if arm.planar else max(4 * W_MM,
                                                np.radians(SERVO[name]) * np.linalg.norm(g - e))
    band = max(step_band, 2 * sL)
    edge = band * np.linalg.norm((e - s) * flat) / np.linalg.norm(lever)
    n = lever / np.linalg.norm(lever)
    L2, L3, h = arm.links_mm[1], arm.links_mm[-1], arm.led_standoff_mm
    assert edge == pytest.approx(4 * W_MM if arm.planar else
                                 max(np.radians(SERVO[name]) * L3, 2 * sL) * np.hypot(L2, h) / L2)
    rng = np.random.default_rng(4)
    bends = set()
    for _ in range(30):
        p = reachable_target(arm, rng)
        while abs(p[0]) <= 10.0 * band / step_band:
            p = reachable_target(arm, rng)
        clean = rb.step(p, Markers(g, e, pitch_axis=axis), q0)
        assert set(clean.fired) & SINGULAR_RULES[name], (p, clean)
        bends.add(np.sign(clean.dq_deg[elbow]))
        outside = []
        for side in (1, -1):
            seen = rb.step(p, Markers(g + side * (edge - 0.01) * n, e, pitch_axis=axis), q0)
            assert seen.fired == clean.fired, (p, side, seen, clean)
            assert np.sign(seen.dq_deg[elbow]) == np.sign(clean.dq_deg[elbow]) != 0, (p, side, seen)
            seen = rb.step(p, Markers(g + side * (edge + 0.01) * n, e, pitch_axis=axis), q0)
            assert set(seen.fired) & RADIAL_RULES[name], (p, side, seen)
            outside.append(np.sign(seen.dq_deg[elbow]))
        assert outside[0] == -outside[1] != 0, (p, outside)
    assert bends == {1.0, -1.0}  # set points on either side of the arm


#: The upper arm's lean from vertical (deg) below which the elbow's band widens to 2 sL: the elbow
#: LED within tan(20 deg) of its height above the shoulder, xe^2 + ye^2 <= 0.1325 (ze - L1)^2, which
#: its stand-off h along the pitch axis brings to asin(sqrt((0.1325 - (h / L2)^2) / 1.1325)).
SCOPE_DEG = 18.84


@pytest.mark.parametrize("lean_deg, widened", [(0.0, True), (15.0, True), (SCOPE_DEG - 0.05, True),
                                               (SCOPE_DEG + 0.05, False), (25.0, False),
                                               (60.0, False)])
def test_the_elbows_band_widens_to_2_sL_only_near_the_straight_up_pose(lean_deg, widened):
    """The 2 sL clause decides the start's bend (the straight-up start and the walk of its first
    set points); elsewhere a near-straight elbow is left to the servo step's band, as clean (on
    reach-loop, which straightens the elbow to 10.6 deg far from the vertical, the unscoped clause
    raised the 4 px tracking max). The straight arm leaned by lean_deg in its plane (q2 = 90 -
    lean, q1 = 0) with sL = 5 mm: the gripper observed 6 mm off the upper arm's line, between
    the servo step's band (3.52 mm there) and 2 sL (10.07 mm), on either side. Within the scope
    the singular rules fire (the elbow a full step or the forearm towards the set point), beyond
    it the radial step. The scope's edge: (L2 sin t)^2 + h^2 = 0.1325 (L2 cos t)^2 at t = 18.84
    deg (L2 = 100, h = 12 mm). Set points more than 10 mm from the plane x = 0 through the base
    axis, square to the arm's plane at q1 = 0, as above."""
    arm = ArmSpec.from_args("three-link")
    L2, h = arm.links_mm[1], arm.led_standoff_mm
    assert np.degrees(np.arcsin(np.sqrt((0.1325 - (h / L2) ** 2) / 1.1325))) == pytest.approx(
        SCOPE_DEG, abs=0.005)
    rb = dataclasses.replace(itg_plus(arm), sL=5.0)
    q0 = np.array([0.0, 90.0 - lean_deg, 0.0])
    m = forward_kinematics(arm, q0)
    g, e, s = m["gripper"], m["elbow"], arm.shoulder_mm()
    a = np.array([0.0, -1.0, 0.0])  # the pitch axis at q1 = 0
    n = np.cross(a, e - s)
    n /= np.linalg.norm(n)  # in the arm's plane, square to the upper arm
    rng = np.random.default_rng(4)
    for _ in range(30):
        p = reachable_target(arm, rng)
        while abs(p[0]) <= 10.0:
            p = reachable_target(arm, rng)
        for side in (1, -1):
            seen = rb.step(p, Markers(g + side * 6.0 * n, e, pitch_axis=a), q0)
            fired = set(seen.fired)
            if widened:
                assert fired & SINGULAR_RULES["three-link"], (p, side, seen)
            else:
                assert fired & RADIAL_RULES["three-link"] and not fired & SINGULAR_RULES[
                    "three-link"], (p, side, seen)


#: The three-link start bent by a forearm offset (deg) within one servo step of straight (2.014
#: deg), past the band of 4 w alone (1.154 deg with the nominal links; the itg-plus-three-link
#: sweep's eye measured 1.08-1.11 deg at its 1 deg offset and 5 % long links), and the other way.
BENT_STARTS_DEG = (1.25, 1.5, 1.95, -1.95)


@pytest.mark.parametrize("trajectory", ["helix", "line-ab-reach"])
@pytest.mark.parametrize("bend", BENT_STARTS_DEG)
def test_a_start_bent_less_than_one_servo_step_tracks_in_the_straight_starts_branch(trajectory,
                                                                                  bend):
    """The three-link elbow's dead band reaches one servo step S (2 deg) from straight, not only
    4 w (the gripper 2 mm off the upper arm's line, a 1.10 deg bend). Outside the band the radial
    step bends on the way the arm is bent; from a start bent past 4 w the first steps took that
    branch (the elbow below the shoulder-gripper line), in which line-ab-reach and the helix turn
    the forearm through the vertical with the upper arm near horizontal: there the markers cannot
    tell the arm's plane, and with the pitch axis read from them (before the kept axis) and exact
    markers the tracking max grew to 3.84 mm (line-ab-reach) and 5.64 mm (helix) at each of these
    bends, as in 12 of 40 seeds of the
    benchmark's links +5 % and 1 deg offset under the eye (5.25-35.2 mm). Exact markers (the
    simulator's LED positions), the benchmark's servo limit and iterations, the forearm offset by
    ``bend``: the first set point bends the elbow the straight start's way (q3 -= S at each of
    its 5 iterations), and the tracking max stays within 2 w: with exact markers every set point
    is reached to within the hold band w (0.023 mm on the helix, 0.497 on line-ab-reach)."""
    cfg = RunConfig(arm="three-link", trajectory=trajectory, rules=ARMS["three-link"],
                    feedback="truth", max_step_deg=SERVO["three-link"], iterations=5,
                    joint_offset_deg=(0.0, 0.0, bend))
    trace, s = execute(prepare(cfg))
    assert trace.q_deg[0][2] == pytest.approx(-5 * SERVO["three-link"])
    assert s["track_max_mm"] < 2 * W_MM, s["track_max_mm"]


@pytest.mark.parametrize("trajectory", ["helix", "line-ab-reach"])
@pytest.mark.parametrize("bend", [2.05, 10.0])
def test_a_start_bent_past_one_servo_step_keeps_its_branch_and_tracks_it(trajectory, bend):
    """A start bent by more than a servo step keeps its own elbow branch (the radial step bends
    on the way the arm is bent: q3 += S at the first set point's iterations), in which both paths
    turn the forearm through the vertical with the upper arm near horizontal, where the LEDs
    cannot tell the arm's plane. With the pitch axis read from the LEDs the rules flailed there
    (exact markers, these bends: tracking max 3.84 mm on line-ab-reach, 7.31 on the helix, at
    b1da674); the axis the loop keeps knows the plane, and every set point is reached to within
    2 w, as from the straight start (0.50 and 0.023 mm measured). Exact markers, the benchmark's
    servo limit and iterations."""
    cfg = RunConfig(arm="three-link", trajectory=trajectory, rules=ARMS["three-link"],
                    feedback="truth", max_step_deg=SERVO["three-link"], iterations=5,
                    joint_offset_deg=(0.0, 0.0, bend))
    trace, s = execute(prepare(cfg))
    assert trace.q_deg[0][2] == pytest.approx(5 * SERVO["three-link"])  # its own branch
    assert s["track_max_mm"] < 2 * W_MM, s["track_max_mm"]


@pytest.mark.slow
def test_the_sweeps_flailing_seed_tracks_through_the_eye():
    """The itg-plus-three-link sweep's worst run before the band reached a servo step: helix,
    links 5 % long, every joint 1 deg off, seed 20, through the rendered eye. Its first look put
    the gripper 2.006 mm off the upper arm's line, just past 4 w; the elbow bent +2 deg and the
    helix's tracking max was 35.2 mm (median 0.373). Now it bends the usual way and tracks below
    issue 13's 3 mm (0.558 mm measured)."""
    cfg = RunConfig(arm="three-link", trajectory="helix", rules=ARMS["three-link"],
                    feedback="vision", max_step_deg=SERVO["three-link"], iterations=5, seed=20,
                    true_links_mm=(105.0, 105.0, 105.0), joint_offset_deg=(1.0, 1.0, 1.0))
    trace, s = execute(prepare(cfg))
    assert trace.q_deg[0][2] == pytest.approx(-5 * SERVO["three-link"])
    assert s["track_max_mm"] < 3.0, s["track_max_mm"]


@pytest.mark.parametrize("links_pct, offset_deg", [(-5, 0.0), (5, 1.0)])
def test_through_the_clean_eye_the_start_band_is_the_servo_steps(links_pct, offset_deg):
    """The 2 sL clause can only add a decision where 2 sL exceeds the servo step's band, which is
    at least 4 w = 2 mm: through the clean rendered eye (centroids within ~0.03 px, a few um at
    the arm) the start-up's sL is some forty times below w, so the clean runs (issue 13's
    three-link sweep: links -5/0/+5 %, joint offsets 0/1 deg) are the rules' without it. Asserted
    with a tenfold margin (sL 0.009-0.013 mm over that sweep's 240 start-ups, 2 sL <= 0.026 mm)."""
    from itg_vision.imaging import opencv_threads
    from itg_vision.runner import start_up_geometry
    from itg_vision.world import World

    links = tuple(100.0 * (1 + links_pct / 100) for _ in range(3))
    cfg = RunConfig(arm="three-link", trajectory="line-ab-reach", rules=ARMS["three-link"],
                    feedback="vision", max_step_deg=SERVO["three-link"], iterations=5, seed=0,
                    true_links_mm=links, joint_offset_deg=(offset_deg,) * 3)
    prep = prepare(cfg)
    eye = prep.feedback_factory()
    eye.reset(cfg.seed)
    with World(prep.true_arm) as world, opencv_threads(1):
        sL = start_up_geometry(cfg, world, eye, prep.model).length_se_mm
    assert 0 < 2 * sL < 4 * W_MM / 10, sL


@pytest.mark.slow
@pytest.mark.parametrize("seed", [8, 13, 18])
def test_under_4px_the_start_bends_the_straight_way_and_tracks(seed):
    """The three runs of the 20-seed `bench noise` run on line-ab-reach (the rendered eye under
    4 px, its servo limit and iterations) that diverged with the elbow's band of one servo step:
    the first looks' noise put the gripper past that band, the elbow bent positive (q3 +40 to +51
    deg by set point 15) into the branch whose forearm tracks near vertical, where the pitch axis
    read from it is far off, and the tracking medians were 45.1, 22.1 and 25.4 mm. With the band
    widened to 2 sL (sL 11-22 mm at these seeds) the elbow bends the straight start's way and
    the run does not diverge (tracking median below the benchmark's 20 mm; 4.9-6.2 mm measured
    since the kept pitch axis, 6.7-7.5 before)."""
    cfg = RunConfig(arm="three-link", trajectory="line-ab-reach", rules=ARMS["three-link"],
                    feedback="vision", max_step_deg=SERVO["three-link"], iterations=5,
                    noise_px=4.0, seed=seed)
    trace, s = execute(prepare(cfg))
    assert trace.q_deg[15][2] < 0, trace.q_deg[15]
    assert s["track_median_mm"] < DIVERGED_MM, s["track_median_mm"]


@pytest.mark.slow
def test_the_reach_loop_keeps_the_starts_elbow_branch_through_the_clean_eye():
    """reach-loop.csv takes the gripper from 144.5 to 199.5 mm from the shoulder, so the elbow
    straightens to a 10.6 deg bend (0.9 mm short of full reach in the arm's plane; the LED stands
    12 mm off it), where either branch reaches the
    set point and the rules choose by the measured bend alone. Through the clean rendered eye
    (a few um at the arm) the bend stays far outside every band and noise, so the elbow keeps the
    straight start's branch (q3 < 0) over both laps and tracks below issue 13's 3 mm (0.199 mm
    measured at seed 0, 0.164 before the kept pitch axis; DLS, which the straight start sends
    the other way, 0.240)."""
    cfg = RunConfig(arm="three-link", trajectory="reach-loop", rules=ARMS["three-link"],
                    feedback="vision", max_step_deg=SERVO["three-link"], iterations=5, laps=2,
                    seed=0)
    trace, s = execute(prepare(cfg))
    q3 = np.array(trace.q_deg)[:, 2]
    assert q3.max() < 0, q3.max()
    assert s["track_max_mm"] < 3.0, s["track_max_mm"]


@pytest.mark.parametrize("name, iterations", [("one-link", 12), ("two-link", 15), ("three-link", 250)])
def test_converges_to_any_reachable_set_point_from_the_start(name, iterations):
    """Closed loop on the forward kinematics (ideal sensors), servo-limited: every reachable set
    point is reached from the paper's start pose, to within the hold band w. (Not set points
    within 5 mm of the base axis of the planar arm: folded flat over the base, with the set point
    along the forearm, neither joint can move the gripper towards it to first order.)"""
    arm = ArmSpec.from_args(name)
    rb = itg_plus(arm)
    rng = np.random.default_rng(5)
    for _ in range(40 if name == "three-link" else 100):
        p = reachable_target(arm, rng)
        while arm.planar and np.hypot(*p[:2]) < 5.0:
            p = reachable_target(arm, rng)
        q = next(islice(poses_from_the_start(rb, arm, p), iterations, None))
        assert distance(arm, p, q) <= 0.5, (p, q)


def test_near_the_base_the_predicted_landings_are_the_forward_kinematics():
    """The two-link rules choose near the base by where each step would land, predicted from the
    levers alone (P0: the damped step, P1 and P2: the line turned one way or the other, P3: the
    slide line turned to the line of travel, each a squared distance to the set point). The file's definitions, probed by rules of our own,
    against the forward kinematics of the model after each step: within 0.01 mm (the half-angle
    tangent's series is within 1e-4 rad of the turn up to 40 deg; the forearm is 100 mm)."""
    from itg_vision.rules import resolve_rules_path

    arm = ArmSpec.from_args("two-link")
    text = resolve_rules_path(ARMS["two-link"]).read_text().split("\nRULE 1:")[0]
    probes = {k: RuleBase.from_text(f"{text}\nRULE 1: IF 1 > 0 THEN q1 += {a}, q2 += {b}\n"
                                    f"RULE 2: IF 1 > 0 THEN q3 += P{k}", 3, arm.links_mm,
                                    S=SERVO["two-link"], w=0.5)
              for k, (a, b) in enumerate((("a0", "b0"), ("th1", "s1"), ("th2", "s2"),
                                          ("th3", "s3")))}
    rng = np.random.default_rng(12)
    for q, _ in zip(_near_base_poses(arm, rng), range(200)):
        p = _around_base(rng, 2.0, 30.0)
        for rb in probes.values():
            dq = rb.step(p, observe(arm, q), [*q, 0.0]).dq_deg
            assert np.all(np.abs(dq[:2]) <= SERVO["two-link"] + 1e-9)
            assert abs(np.sqrt(dq[2]) - distance(arm, p, q + dq[:2])) < 0.01, (q, p, dq)


def test_passing_by_turns_the_slide_line_to_the_line_of_travel():
    """RULE 3 of the two-link rules, against a computation of our own. th3 is the angle from the
    forearm's normal n (the way q2 slides the gripper) to the line through g and d, the shorter
    way (mod 180 deg), clipped to +-S: within 2e-4 deg of atan2's (the rules' tan and atan
    series: 1.5e-6 rad). The rule fires exactly where no earlier rule does (the gripper within w
    of d, d within 4 w of the base), the gripper is within 25 mm of the base, the line through g
    and d passes within 4 w = 2 mm of the base, d's bearing turns by more than S were d - g the
    path's step (|d x (d - g)| / |d|^2 > S in rad), and the step lands nearer d than the gripper
    is, by the forward kinematics (cases within 0.01 mm of that, the predictions' accuracy, left
    out). Set points near a point c 0-4 mm from the base, on the line from g through c or (with
    the gripper within 2.1 mm of the base) on one 60-90 deg off n, or anywhere 2-30 mm from the
    base, so that both sides of the gate, of the rate and of the landing are sampled."""
    from itg_vision.rules import resolve_rules_path

    arm = ArmSpec.from_args("two-link")
    S, w = SERVO["two-link"], 0.5
    rb = itg_plus(arm)
    text = resolve_rules_path(ARMS["two-link"]).read_text().split("\nRULE 1:")[0]
    probe = RuleBase.from_text(f"{text}\nRULE 1: IF 1 > 0 THEN q1 += th3, q2 += s3", 2,
                               arm.links_mm, S=S, w=w)
    rng = np.random.default_rng(21)
    fired, counted = {True: 0, False: 0}, {"gate, slow bearing": 0, "gate, lands farther": 0}
    for q, k in zip(_near_base_poses(arm, rng), range(1500)):
        if k % 3 == 1:  # the gripper within 2.1 mm of the base, where a clipped turn may not do
            q = np.array([q[0], np.sign(q[1]) * rng.uniform(178.8, 180.0)])
        m = forward_kinematics(arm, q)
        g, e = m["gripper"][:2], m["elbow"][:2]
        a = rng.uniform(-np.pi, np.pi)
        c = rng.uniform(0.0, 4.0) * np.array([np.cos(a), np.sin(a)])  # the line passes c
        v = (c - g) / np.linalg.norm(c - g)
        u = g - e
        n = np.array([-u[1], u[0]])
        if k % 3 == 1:  # or on a line through c 60-90 deg off n (the turn clipped to S)
            b = np.radians(rng.uniform(60.0, 90.0)) * rng.choice([-1, 1])
            v = np.array([[np.cos(b), -np.sin(b)], [np.sin(b), np.cos(b)]]) @ (n / np.linalg.norm(n))
        d = c + rng.uniform(-8.0, 8.0) * v + rng.normal(0.0, 0.3, 2)  # near c, on g's line
        if k % 3 == 2:  # or anywhere 2-30 mm from the base (the line of travel rarely passes by)
            d = rng.uniform(2.0, 30.0) * np.array([np.cos(a), np.sin(a)])
        err = d - g
        angle = np.degrees(np.arctan2(n[0] * err[1] - n[1] * err[0], n @ err))
        angle = (angle + 90.0) % 180.0 - 90.0  # to the line, the shorter way
        p = np.array([*d, 0.0])
        th3 = probe.step(p, observe(arm, q), q).dq_deg
        assert th3[0] == pytest.approx(np.clip(angle, -S, S), abs=2e-4), (q, d, angle)
        cross = abs(d[0] * err[1] - d[1] * err[0])
        gate = cross / np.linalg.norm(err) < 4 * w
        fast = cross / (d @ d) > np.radians(S)
        nearer = distance(arm, p, q + th3) - np.linalg.norm(err)
        if (abs(cross / np.linalg.norm(err) - 4 * w) < 1e-6 or abs(nearer) < 0.01
                or abs(cross / (d @ d) - np.radians(S)) < 1e-9):
            continue
        earlier = np.linalg.norm(err) <= w or np.linalg.norm(d) < 4 * w
        expect = bool(not earlier and 16 * (g @ g) < u @ u and gate and fast and nearer < 0)
        got = rb.step(p, observe(arm, q), q)
        assert (got.fired[:1] == (3,)) is expect, (q, d, got.fired, gate, fast, nearer)
        fired[expect] += 1
        if gate and not earlier and not fast:
            counted["gate, slow bearing"] += 1
        if gate and fast and not earlier and nearer > 0:
            counted["gate, lands farther"] += 1
    assert min(fired.values()) >= 50 and min(counted.values()) >= 3, (fired, counted)


def test_passing_by_slides_by_the_error_across_the_turned_forearm():
    """RULE 3's slide b3 (before its clip): q2's first-order step after q1 turns th3, the error
    across the forearm over |u|^2, as it will be after the turn. The turn carries u and g
    alike, so u x err becomes u x (R(-th3) d - g) exactly; the rules take it to first order in
    th3 (T - th3 (u . d)), which leaves at most th3^2 / 2 |u| |d| / |u|^2 rad of the exact
    value (the rotation's second-order term). The fifth form's derivation error, T - th (g . u),
    or no correction at all (T alone) is off by th3 (u . d) / |u|^2: up to 2 / th3 times the
    bound (5.7 at th3 = 20 deg), and more than twice it in the median case here."""
    from itg_vision.rules import resolve_rules_path

    arm = ArmSpec.from_args("two-link")
    S, w = SERVO["two-link"], 0.5
    text = resolve_rules_path(ARMS["two-link"]).read_text().split("\nRULE 1:")[0]
    probe = RuleBase.from_text(f"{text}\nRULE 1: IF 1 > 0 THEN q1 += th3, q2 += b3", 2,
                               arm.links_mm, S=S, w=w)
    rng = np.random.default_rng(8)
    off = []
    for q, _ in zip(_near_base_poses(arm, rng), range(300)):
        m = forward_kinematics(arm, q)
        g, e = m["gripper"][:2], m["elbow"][:2]
        d = _around_base(rng, 2.0, 30.0)[:2]
        th, b = probe.step(np.array([*d, 0.0]), observe(arm, q), q).dq_deg
        t = np.radians(th)
        u = g - e
        back = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]]) @ d  # R(-th) d
        err = back - g
        exact = np.degrees((u[0] * err[1] - u[1] * err[0]) / (u @ u))
        bound = np.degrees(t * t / 2 * np.linalg.norm(d) / np.linalg.norm(u)) + 1e-6
        assert abs(b - exact) <= bound, (q, d, th, b, exact, bound)
        off.append(abs(np.degrees(t * (u @ d) / (u @ u))) / bound)
    assert np.median(off) > 2  # the cases tell the first-order correction from none


def test_passing_by_is_left_to_the_other_rules_beyond_the_series_range():
    """th3's tan and atan series serve S up to about 30 deg (at S = 40 deg the clip is 40.4 deg,
    at 60 meaningless): RULE 3 fires at S = 20 on set points where the line of travel passes
    by the base, and never at S = 40 on the same cases."""
    arm = ArmSpec.from_args("two-link")
    rules = {S: load_rules(ARMS["two-link"], 2, arm.links_mm, S=S, w=0.5) for S in (20.0, 40.0)}
    rng = np.random.default_rng(4)
    fired = {20.0: 0, 40.0: 0}
    for q, _ in zip(_near_base_poses(arm, rng), range(600)):
        m = forward_kinematics(arm, q)
        g = m["gripper"][:2]
        a = rng.uniform(-np.pi, np.pi)
        c = rng.uniform(0.0, 2.0) * np.array([np.cos(a), np.sin(a)])
        d = c + rng.uniform(-8.0, 8.0) * (c - g) / np.linalg.norm(c - g)
        for S, rb in rules.items():
            fired[S] += 3 in rb.step(np.array([*d, 0.0]), observe(arm, q), q).fired
    assert fired[20.0] >= 50 and fired[40.0] == 0, fired


# ----------------------------------------------------------------------------- RULE 0
#: RULE 0's margin beyond what the told lengths reach: w plus three standard errors of the
#: lengths' sum or difference, each length's at most sL (two lengths; three-link three).
REACH_MARGIN_SL = {"two-link": 6.0, "three-link": 9.0}


@pytest.mark.parametrize("sL", [0.0, 0.9])
@pytest.mark.parametrize("name, links, h", [("two-link", (150.0, 50.0), 0.0),
                                            ("three-link", (100.0, 150.0, 50.0), 0.0),
                                            ("three-link", (100.0, 150.0, 50.0), 12.0)])
def test_rule_0_flags_a_set_point_only_beyond_its_margin(name, links, h, sL):
    """A set point within m = w + k sL of the ring (two-link, about the base) or the shell
    (three-link, about the shoulder) that the told lengths reach is left to the steps, which take
    the gripper to its nearest point; one beyond m is flagged: 0.1 mm either side of m, outside
    the outer rim and inside the hole (100 mm, the links 150 and 50 mm), in 8 directions. The
    three-link LED stands h off the arm's plane: its outer shell is r = sqrt(outer^2 + h^2), and
    RULE 0's edge B = sqrt((outer + m)^2 + h (h + 2 m)) lies at or beyond r + m (equal at h = 0):
    0.1 mm either side of B, and r + m - 0.1 never flagged."""
    arm = ArmSpec.from_args(name).with_links(links)
    rb = load_rules(ARMS[name], arm.n_joints, links, S=SERVO[name], w=0.5).with_links(
        links, sL=sL, h=h)
    m = 0.5 + REACH_MARGIN_SL[name] * sL
    centre = np.array([0.0, 0.0, 0.0 if arm.planar else links[0]])
    inner, outer = abs(links[-2] - links[-1]), links[-2] + links[-1]
    r, edge = np.hypot(outer, h), np.sqrt((outer + m) ** 2 + h * (h + 2 * m))
    assert edge >= r + m - 1e-12 and (h > 0 or edge == r + m)
    markers = observe(arm, arm.start_q_deg.astype(float))
    for a in np.radians(np.arange(0, 360, 45)):
        u = np.array([np.cos(a), 0.0, np.sin(a)]) if not arm.planar and a % np.pi else \
            np.array([np.cos(a), np.sin(a), 0.0])
        cases = [(r + m - 0.1, False), (edge - 0.1, False), (edge + 0.1, True),
                 (inner - m + 0.1, False), (inner - m - 0.1, True)]
        for radius, flagged in cases:
            got = rb.step(centre + radius * u, markers, arm.start_q_deg).out_of_reach
            assert got == flagged, (u, radius, edge, m)


def test_a_ring_the_three_link_led_reaches_at_full_stretch_is_tracked_not_held(tmp_path):
    """A horizontal ring at shoulder height, 200.75 mm from the base axis: beyond L2 + L3 + m
    (200.5 mm) but within m of the LED's reach sqrt(200^2 + 12^2) = 200.36 mm. The old RULE 0
    (without h) flagged all 90 set points and held the arm at its start (E_av 284 mm); now none
    is flagged and the LED tracks the shell, as near as it gets: 0.39 mm off, within w more."""
    t = np.linspace(0.0, 2 * np.pi, 91)[:-1]
    path = tmp_path / "ring.csv"
    np.savetxt(path, np.c_[200.75 * np.cos(t), 200.75 * np.sin(t), np.full_like(t, 100.0)],
               delimiter=",", header="x_mm,y_mm,z_mm", comments="", fmt="%.4f")
    cfg = RunConfig(arm="three-link", trajectory=str(path), rules=ARMS["three-link"],
                    feedback="model", iterations=5)
    _, s = execute(prepare(cfg))
    nearest = 200.75 - np.hypot(200.0, 12.0)
    assert s["n_flagged"] == 0 and s["n_out_of_reach"] == 0
    assert nearest <= s["track_median_mm"] <= s["track_max_mm"] <= nearest + 0.5, s


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_under_1px_only_the_set_points_out_of_reach_are_flagged(seed, tmp_path):
    """Through the eye under 1 px, the lengths measured at start-up are off by up to a few mm
    (seed 1: L1 99.45, L2 100.85 mm, a 1.4 mm "hole" the 100/100 arm does not have; the old
    RULE 0 flagged 4 set points of lemniscate, which pass 0.6 mm from the base, and held the
    arm). Lemniscate with three set points 30 mm beyond reach put after its first half: exactly
    those three are flagged (the margin under 1 px, w + 6 sL, is 2.4-12 mm over 60 seeds)."""
    xy = np.loadtxt("data/trajectories/lemniscate.csv", delimiter=",", skiprows=1)
    far = [[230.0, 0.0], [0.0, 230.0], [-230.0, 0.0]]
    path = tmp_path / "lemniscate-and-far.csv"
    np.savetxt(path, np.vstack([xy[:100], far, xy[100:]]), delimiter=",", header="x_mm,y_mm",
               comments="", fmt="%.3f")
    cfg = RunConfig(trajectory=str(path), rules=ARMS["two-link"], feedback="vision", noise_px=1.0,
                    max_step_deg=SERVO["two-link"], seed=seed)
    _, s = execute(prepare(cfg))
    assert s["n_out_of_reach"] == 3 and s["n_flagged"] == 3, s
