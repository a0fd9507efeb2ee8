"""The rule language and the paper's tables against hand-worked situations."""

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import roundoff
from hypothesis import example, given, settings, strategies as st

from itg_vision.arm import ArmSpec, forward_kinematics
from itg_vision.errors import UserError
from itg_vision.feedback import Markers
from itg_vision.rules import RuleBase, load_rules
from itg_vision.shipped import rule_names


def markers(g, e=(np.nan, np.nan, np.nan)):
    return Markers(np.array(g, float), np.array(e, float))


TWO = (100.0, 100.0)


def table2(f=0.5):
    return load_rules("table2", 2, TWO, f=f)


# ----------------------------------------------------------------------------- parser
@pytest.mark.parametrize("text, where, what", [
    ("RULE 1: IF xd > xg THEN q1 += f * |xd - xq|", ":1:41", "unknown name 'xq'"),
    ("RULE 1: IF xd > xg q1 += S", ":1:20", "expected 'THEN'"),
    # a condition's missing ')' is reported where it is missing, not where the reading of the
    # '(' as an expression gave up (the '>')
    ("RULE 1: IF (xd > xg THEN q1 += S", ":1:21:", "expected ')' (opened at line 1, column 12) "
     "(found 'THEN')"),
    ("RULE 1: IF (xd > xg AND (yd < yg OR xd < 0) THEN q1 += S", ":1:45:", "expected ')' (opened "
     "at line 1, column 12) (found 'THEN')"),
    ("RULE 1: IF (xd - xg) * > 1 THEN q1 += S", ":1:24:", "expected a number, a name"),
    ("RULE 1: IF xd > xg THEN q3 += S", ":1:25:", "moves q3, but the arm has 2 joint(s)"),
    ("RULE 1: IF xd > xg THEN q3 HOLD", ":1:25:", "holds q3, but the arm has 2 joint(s)"),
    ("RULE 1: IF xd > xg THEN q1 += S, q3 HOLD", ":1:34:", "holds q3"),
    ("RULE 1: IF xd > xg THEN q1 += S, OUT_OF_REACH", ":1:34:", "OUT_OF_REACH must be"),
    ("RULE 1: IF xd > xg THEN q1 += f * sin(xd - xg)", ":1:35:", "'sin(' reads as a function "
     "call, and the rule language has none"),
    ("LET r = sqrt(xd * xd)\nRULE 1: IF xd > r THEN q1 += S", ":1:9:", "'sqrt(' reads as a function call"),
    ("RULE 1: IF xd $ xg THEN q1 += S", ":1:15", "unexpected character '$'"),
    ("RULE 1 IF xd > xg THEN q1 += S", ":1:8", "expected ':'"),
    ("\n\nRULE 1: IF xd > xg THEN q1 += |xd - xg", ":3:", "closing '|' (opened at line 3, column 31)"),
    # the end of a file that ends its last line is the next line's start: the opener says where
    ("RULE 1: IF xd > xg THEN q1 += (xd - xg\n", ":2:1:", "expected ')' (opened at line 1, "
     "column 31) (found end of file)"),
    ("RULE 1: IF xd > xg THEN q1 += S\n  RULE 1: IF xd < xg THEN q1 -= S", ":2:3:", "defined twice"),
    ("# only a comment\n", "", "no rules found"),
    ("RULE 1: IF xd > xg THEN q1 = q2", ":1:30", "only 'q1 = q1'"),
    ("RULE 1: IF xd > xg THEN q1 += 1, q1 -= 2", ":1:34", "q1 has two actions in one rule"),
    ("RULE 1: IF xd > xg THEN q2 HOLD, q1 += 1, q2 += 1", ":1:43", "q2 has two actions"),
    # the likely slip, said after the error: a product without its *, '=>' for '>=', a single
    # '=' for '==', two actions without their ','
    ("RULE 1: IF xd > xg THEN q1 -= f |xd - xg|", ":1:33:", "(found '|'): two operands side by "
     "side; a product needs its * ('f * ...')"),
    ("LET a = 2 xg\nRULE 1: IF xd > a THEN q1 += S", ":1:11:", "a product needs its * ('2 * "),
    # digits are ASCII, as in trajectory files (Python's \d also takes Arabic-Indic, full-width)
    ("RULE 1: IF xd > xg THEN q1 += \u0663", ":1:31:", "unexpected character '\u0663'"),
    ("RULE \uff11: IF xd > xg THEN q1 += S", ":1:6:", "unexpected character '\uff11'"),
    # a LET's name or a rule's number, then an operand: no product was meant there
    ("LET a 2 * xg\nRULE 1: IF xd > a THEN q1 += S", ":1:7:", "expected '=' after LET a (found "
     "'2')\n"),
    ("RULE 1 2: IF xd > xg THEN q1 += S", ":1:8:", "expected ':' after the rule number (found "
     "'2')\n"),
    ("RULE 1: IF (xd => xg) THEN q1 += S", ":1:16:", "(found '='): '=>' is not an operator, '>=' is"),
    ("RULE 1: IF xd =< xg THEN q1 += S", ":1:15:", "'=<' is not an operator, '<=' is"),
    ("RULE 1: IF xd = xg THEN q1 += S", ":1:15:", "(found '='): '=' is not a comparison, '==' is"),
    ("RULE 1: IF xd > xg THEN q1 += S q2 HOLD", ":1:33:", "(found 'q2'): the next action needs a "
     "',' before it"),
    # a chained comparison (the README: 'a < b < c' is an error), bare or in parentheses; a
    # comparison after the THEN's step, in its own parentheses or after an AND is no chain
    ("RULE 1: IF xd < xg < 5 THEN q1 += S", ":1:20:", "(found '<'): comparisons do not chain; "
     "write 'a < b AND b < c'\n"),
    ("RULE 1: IF yd > 0 AND (|xd| + 1 == xg <= 5) THEN q1 += S", ":1:39:", "expected ')' "
     "(opened at line 1, column 23) (found '<='): comparisons do not chain; write 'a < b AND "
     "b < c'\n"),
    # a condition in parentheses compared again or computed with, '(a < b) < c': said at the
    # operator after its ')' (it was "expected ')'" at the '<' inside, where a ')' is not missing)
    ("RULE 1: IF (xd < xg) < 5 THEN q1 += S", ":1:22:", "a condition in parentheses (opened at "
     "line 1, column 12) is true or false, not a number to compare or compute with (found '<'): "
     "comparisons do not chain; write 'a < b AND b < c'\n"),
    ("RULE 1: IF yd > 0 AND NOT ((xd < xg)) * 2 > 5 THEN q1 += S", ":1:39:", "a condition in "
     "parentheses (opened at line 1, column 27) is true or false, not a number to compare or "
     "compute with (found '*')\n"),
    ("RULE 1: IF xd < xg THEN q1 += S < 5", ":1:33:", "(found '<')\n"),
    ("RULE 1: IF xd < (xg < 5) THEN q1 += S", ":1:21:", "(found '<')\n"),
    ("RULE 1: IF xd < xg AND < 5 THEN q1 += S", ":1:24:", "(found '<')\n"),
    # a second action for one joint, after its ',': the comma is there, so no comma hint
    ("RULE 1: IF xd > xg THEN q1 -= f * |xd - xg|, q1 HOLD", ":1:46:", "q1 has two actions in one "
     "rule (found 'q1')\n"),
    # C's '||' and '&&', Python's '**'; a name in the wrong case; a LET below its use
    ("RULE 1: IF xd > xg || yd > yg THEN q1 += S", ":1:20:", "(found '|'): '||' is not an "
     "operator here, OR is"),
    ("RULE 1: IF xd > xg && yd > yg THEN q1 += S", ":1:20:", "unexpected character '&': '&&' is "
     "not an operator here, AND is"),
    ("RULE 1: IF xd > xg THEN q1 += f ** 2", ":1:34:", "(found '*'): '**' is not an operator "
     "here, ^ is"),
    ("RULE 1: IF xd > xg THEN q1 += F", ":1:31:", "unknown name 'F' (known: L, L1, L2, S, f, h, q1, "
     "q2, rd2, re2, rg2, sL, w, xd, xe, xg, yd, ye, yg, zd, ze, zg); did you mean 'f'? names are "
     "case-sensitive\n"),
    # an action right after the condition: THEN is missing, not a ','
    ("RULE 1: IF 1 > 0 q1 += 1, q2 HOLD", ":1:18:", "(found 'q1'): is 'THEN' missing before the "
     "actions?\n"),
    # a '#!' line that is not the one declaration (it was read as a comment: S fell back to
    # --step and the servo limit went unapplied, E_av 46 -> 225 mm on itg-plus-two-link)
    ("#! S is the servo limit (deg)\nRULE 1: IF xd > xg THEN q1 += S", ":1: ", "'#! S is the "
     "servo limit (deg)' is not a declaration the parser knows (the only one: '#! S is the "
     "servo limit', a line of its own); a comment starts with '#' alone\n"),
    # a joint the arm lacks: the same words in a LET's name and in use
    ("LET q4 = xd\nRULE 1: IF xd > xg THEN q1 += S", ":1:5:", "'q4' is already reserved: qN names "
     "joint N's angle\n"),
    ("RULE 1: IF q4 > 0 THEN q1 += S", ":1:12:", "'q4' is joint 4's angle, but the arm has 2 "
     "joint(s)\n"),
    ("LET L7 = xd\nRULE 1: IF xd > xg THEN q1 += S", ":1:5:", "'L7' is already reserved: LN names "
     "link N's length\n"),
    # a LET of its own name: not "defined below" (it is the same line)
    ("LET A = xd - xg\nLET B = B + A\nRULE 1: IF B > 0 THEN q1 += S", ":2:9:", "LET B uses 'B' "
     "itself: a name has one value, from one expression, and rules keep nothing between "
     "iterations; give the new value a new name\n"),
    # a number run into other characters is named whole, not read as two operands
    ("RULE 1: IF xd > 1_000 THEN q1 += S", ":1:17:", "'1_000' is not a number: write digits"),
    ("RULE 1: IF xd > 0x10 THEN q1 += S", ":1:17:", "'0x10' is not a number"),
    ("RULE 1: IF xd > 5mm THEN q1 += S", ":1:17:", "'5mm' is not a number"),
    ("RULE 1: IF xd > 1.5.2 THEN q1 += S", ":1:17:", "'1.5.2' is not a number"),
    ("RULE 1: IF xd > 2e THEN q1 += S", ":1:17:", "'2e' is not a number"),
    ("RULE 1: IF e > 0 THEN q1 += f\nLET e = xd - xg", ":1:12:", "unknown name 'e' here: the LET "
     "on line 2 defines it below, and a LET must come before the rules and LETs that use it\n"),
])
def test_syntax_and_name_errors_name_file_line_column(text, where, what):
    with pytest.raises(UserError) as exc:
        RuleBase.from_text(text, 2, TWO, source="my.rules")
    msg = str(exc.value)
    assert msg.startswith("my.rules" + where), msg
    assert what in msg + "\n", msg  # what ends in \n: the line ends there (no hint follows)
    assert "\n" not in msg


def test_a_let_before_a_rule_on_the_same_line_is_known_to_that_rule():
    """A statement ends where the next RULE or LET starts, so 'LET a = ... RULE 1: ...' on one
    line defines a before RULE 1 reads it (it was refused: 'the LET on line 1 defines it
    below'); a LET after the rule on its line is still unknown to it."""
    rb = RuleBase.from_text("LET a = xd * 2 RULE 1: IF a > 1 THEN q1 += a\n"
                            "RULE 2: IF xd > 0 THEN q2 += 1 LET b = xd + 1 RULE 3: IF b > 0 THEN q2 -= b",
                            2, TWO, source="my.rules")
    step = rb.step(np.array([3.0, 0, 0]), markers([0, 0, 0], [0, 0, 0]), [0, 0])
    assert step.fired == (1, 2) and list(step.dq_deg) == [6.0, 1.0]
    step = rb.step(np.array([-3.0, 0, 0]), markers([0, 0, 0], [0, 0, 0]), [0, 0])
    assert step.fired == () and list(step.dq_deg) == [0.0, 0.0]
    with pytest.raises(UserError, match=r"^my\.rules:1:30: unknown name 'a' here"):
        RuleBase.from_text("RULE 1: IF xd > 0 THEN q1 += a LET a = 2", 2, TWO, source="my.rules")


def test_parses_nested_conditions_and_parenthesised_expressions():
    rb = RuleBase.from_text(
        "RULE 1: IF ((xd - xg) * 2 > w OR NOT (yd >= 0)) AND (xg - xe) != 0 THEN q1 += 2 * (xd - xg)^2",
        2, TWO, w=1.0)
    step = rb.step(np.array([3.0, 1.0, 0]), markers([1.0, 0, 0], [0.5, 0, 0]), [0, 0])
    assert step.fired == (1,) and step.dq_deg[0] == 8.0  # small integers: exact
    step = rb.step(np.array([1.2, 1.0, 0]), markers([1.0, 0, 0], [0.5, 0, 0]), [0, 0])
    assert step.fired == ()


_names = st.sampled_from(["xd", "yd", "xg", "yg", "xe", "ye", "f", "w", "L1", "L2"])
_nums = st.integers(1, 9).map(str)


def _expr(depth):
    leaf = _names | _nums
    if depth == 0:
        return leaf
    sub = _expr(depth - 1)
    return leaf | st.tuples(sub, st.sampled_from(["+", "-", "*"]), sub).map(lambda t: f"({t[0]} {t[1]} {t[2]})")


@settings(max_examples=150, deadline=None)
@given(_expr(3), st.lists(st.floats(-200, 200), min_size=6, max_size=6))
def test_compiled_step_equals_reference_arithmetic(expr, vals):
    """The compiler computes the same number as Python's own arithmetic on the same text."""
    rb = RuleBase.from_text(f"RULE 1: IF 1 > 0 THEN q1 += {expr}", 2, TWO, f=0.3, w=0.7)
    xd, yd, xg, yg, xe, ye = vals
    env = dict(xd=xd, yd=yd, xg=xg, yg=yg, xe=xe, ye=ye, f=0.3, w=0.7, L1=100.0, L2=100.0)
    expected = eval(expr, {"__builtins__": {}}, env)  # reference only, on our own generated text
    got = rb.step(np.array([xd, yd, 0]), markers([xg, yg, 0], [xe, ye, 0]), [0, 0]).dq_deg[0]
    # the same operations in the same order on the same float64 numbers (integer literals and
    # their products, at most 9^8, are exact as floats): bit for bit (3000 examples: all equal)
    assert got == expected


def test_each_joint_moves_at_most_once_per_iteration_first_rule_wins():
    rb = RuleBase.from_text("RULE 1: IF 1 > 0 THEN q1 += 1\nRULE 2: IF 1 > 0 THEN q1 += 5\n"
                            "RULE 3: IF 1 > 0 THEN q2 -= 2", 2, TWO)
    step = rb.step(np.zeros(3), markers([0, 0, 0], [0, 0, 0]), [0, 0])
    assert step.fired == (1, 3) and list(step.dq_deg) == [1.0, -2.0]


def test_nan_marker_never_fires_nor_moves():
    rb = RuleBase.from_text("RULE 1: IF xe < 1 OR xe >= 1 THEN q1 += xe", 2, TWO)
    step = rb.step(np.zeros(3), markers([0, 0, 0]), [0, 0])
    assert step.fired == () and np.all(step.dq_deg == 0)


# ----------------------------------------------------------------------------- Table 2
@pytest.mark.parametrize("q1", [30.0, 120.0, 210.0, 300.0])  # gripper in each quadrant
@pytest.mark.parametrize("dx", [+5.0, -5.0])
def test_table2_q1_correction_reduces_x_error_in_each_quadrant(q1, dx):
    """Where the desired point is on the gripper's side of the x axis, the q1 correction
    has the sign that reduces |xd - xg| (dx_g/dq1 = -y_g)."""
    arm = ArmSpec.from_args("two-link")
    q = np.array([q1, 60.0])  # gripper well inside the quadrant of the elbow
    m = forward_kinematics(arm, q)
    g = m["gripper"]
    desired = np.array([g[0] + dx, g[1], 0.0])
    step = table2(f=0.05).step(desired, markers(g, m["elbow"]), q)
    # f |xd - xg|: xd = xg + 5 rounds by half an ulp of it, then the product by half an ulp
    assert step.dq_deg[0] == pytest.approx(math.copysign(0.05 * 5, step.dq_deg[0]), rel=0,
                                           abs=roundoff(0.05 * (abs(g[0]) + 5), ulps=2))
    after = forward_kinematics(arm, q + [step.dq_deg[0], 0])["gripper"]
    assert abs(desired[0] - after[0]) < abs(desired[0] - g[0])


@pytest.mark.parametrize("q", [(30, -60), (120, 40), (210, -100), (300, 80), (10, 170)])
@pytest.mark.parametrize("dy", [+5.0, -5.0])
def test_table2_q2_correction_reduces_y_error(q, dy):
    """dy_g/dq2 = x_g - x_e exactly, so RULE 3/4 always turn q2 the right way."""
    arm = ArmSpec.from_args("two-link")
    q = np.array(q, float)
    m = forward_kinematics(arm, q)
    g = m["gripper"]
    desired = np.array([g[0], g[1] + dy, 0.0])
    step = table2(f=0.05).step(desired, markers(g, m["elbow"]), q)
    assert set(step.fired) & {3, 4} and step.dq_deg[1] != 0
    after = forward_kinematics(arm, q + [0, step.dq_deg[1]])["gripper"]
    assert abs(desired[1] - after[1]) < abs(desired[1] - g[1])


def test_table2_hand_worked_quadrant_signs():
    rb = table2(f=0.1)
    # f |xd - xg| of whole millimetres, 0.1 x 10 = 1.0 in float64: every step below is exact
    # gripper (100, 100), elbow (100, 0): desired to the right and above the x axis -> RULE 1
    s = rb.step(np.array([110.0, 100.0, 0]), markers([100, 100, 0], [100, 0, 0]), [0, 90])
    assert s.fired == (1,) and s.dq_deg[0] == -1.0 and s.dq_deg[1] == 0
    # below the x axis, desired to the right -> RULE 2 (q1 up)
    s = rb.step(np.array([110.0, -100.0, 0]), markers([100, -100, 0], [100, 0, 0]), [0, -90])
    assert s.fired == (2,) and s.dq_deg[0] == 1.0
    # desired above, gripper right of elbow -> RULE 3 (q2 up); gripper left of elbow -> RULE 4
    s = rb.step(np.array([50.0, 60.0, 0]), markers([50, 50, 0], [0, 0, 0]), [0, 0])
    assert 3 in s.fired and s.dq_deg[1] == 1.0
    s = rb.step(np.array([-50.0, 60.0, 0]), markers([-50, 50, 0], [0, 0, 0]), [0, 0])
    assert 4 in s.fired and s.dq_deg[1] == -1.0
    # equality everywhere: nothing fires (the paper excludes equality)
    s = rb.step(np.array([50.0, 50.0, 0]), markers([50, 50, 0], [0, 0, 0]), [0, 0])
    assert s.fired == () and not s.out_of_reach


@pytest.mark.parametrize("links, r, inside", [
    ((100, 100), 200.0, True), ((100, 100), 200.001, False), ((100, 100), 0.0, True),
    ((100, 60), 40.0, True), ((100, 60), 39.999, False), ((100, 60), 160.0, True),
    ((100, 60), 160.001, False)])
def test_table2_rule0_at_its_boundaries(links, r, inside):
    rb = load_rules("table2", 2, links)
    for d in ([r, 0, 0], [0, -r, 0], [-r, 0, 0]):  # exact squares: no rounding at the boundary
        d = np.array(d)
        s = rb.step(d, markers([0, 150, 0], [0, 100, 0]), [90, 0])
        assert s.out_of_reach is (not inside)
        if not inside:
            assert s.fired == (0,) and np.all(s.dq_deg == 0)


# ----------------------------------------------------------------------------- Table 1
def test_table1_signs_hold_and_reach():
    rb = load_rules("table1", 1, (100.0,), S=2.0, w=0.5)
    # on the circle, desired anticlockwise of the gripper in the upper half -> q += S
    g = [100 * math.cos(math.radians(40)), 100 * math.sin(math.radians(40)), 0]
    d = np.array([100 * math.cos(math.radians(50)), 100 * math.sin(math.radians(50)), 0])
    s = rb.step(d, markers(g), [40])
    assert s.fired == (2,) and s.dq_deg[0] == 2.0
    s = rb.step(np.array(g), markers(g), [40])  # at the goal: RULE 1 holds
    assert s.fired == (1,) and s.dq_deg[0] == 0.0
    # lower half, desired clockwise (x smaller... mirrored): yd < 0, xd <= xg -> q -= S
    g2 = [100 * math.cos(math.radians(-40)), 100 * math.sin(math.radians(-40)), 0]
    d2 = np.array([100 * math.cos(math.radians(-50)), 100 * math.sin(math.radians(-50)), 0])
    s = rb.step(d2, markers(g2), [-40])
    assert s.fired == (3,) and s.dq_deg[0] == -2.0
    # RULE 0: 0.4 mm off the circle is in reach with w = 0.5 mm, 0.6 mm is not
    assert not rb.step(np.array([100.4, 0, 0]), markers(g), [40]).out_of_reach
    assert rb.step(np.array([100.6, 0, 0]), markers(g), [40]).out_of_reach


# ----------------------------------------------------------------------------- three-link
def test_three_link_rule0_uses_distance_from_shoulder():
    rb = load_rules("three-link", 3, (100.0, 100.0, 100.0))
    m = markers([0, 0, 300], [0, 0, 200])
    assert not rb.step(np.array([0, 0, 300.0]), m, [0, 90, 0]).out_of_reach  # 200 from shoulder
    assert rb.step(np.array([0, 0, 300.01]), m, [0, 90, 0]).out_of_reach
    assert rb.step(np.array([250.0, 200.0, 400.0]), m, [0, 90, 0]).out_of_reach  # paper's B


def test_three_link_set_point_level_with_the_shoulder_or_gripper_fires_no_pitch_rule():
    """The file's comment: RULES 4 and 5 need zd's side of L1, so zd = L1 fires neither and moves
    no q2 however far the radii differ, and zd = zg fires neither of RULES 6 and 7 (which need
    zd's side of zg); a millimetre either way fires one and moves the joint."""
    arm = ArmSpec.from_args("three-link")
    L1 = arm.links_mm[0]
    q = np.array([20.0, 40.0, -60.0])
    m = forward_kinematics(arm, q)
    g, e = m["gripper"], m["elbow"]
    rb = load_rules("three-link", 3, arm.links_mm, f=0.05)
    far = g * [1.1, 1.1, 0]  # radius 10 % larger (188 mm, in reach): rd2 > rg2
    for dz, moves in ((0.0, False), (1.0, True), (-1.0, True)):
        s = rb.step(far + [0, 0, L1 + dz], markers(g, e), q)
        assert not s.out_of_reach and bool(s.dq_deg[1] != 0) is moves, (dz, s)
        assert bool({4, 5} & set(s.fired)) is moves
    level = np.array([g[0] - 30.0, g[1], g[2]])  # 30 mm nearer the base, at the gripper's height
    for dz, moves in ((0.0, False), (1.0, True), (-1.0, True)):
        s = rb.step(level + [0, 0, dz], markers(g, e), q)
        assert not s.out_of_reach and bool(s.dq_deg[2] != 0) is moves, (dz, s)
        assert bool({6, 7} & set(s.fired)) is moves


@pytest.mark.parametrize("q", [(20, 40, -60), (60, 25, -30), (-30, 50, -90)])
def test_three_link_vertical_plane_corrections_reduce_errors(q):
    arm = ArmSpec.from_args("three-link")
    q = np.array(q, float)
    m = forward_kinematics(arm, q)
    g, e = m["gripper"], m["elbow"]
    rb = load_rules("three-link", 3, arm.links_mm, f=0.05)
    # desired 5 mm higher: q3 must raise the gripper
    d = g + [0, 0, 5.0]
    s = rb.step(d, markers(g, e), q)
    after = forward_kinematics(arm, q + [0, 0, s.dq_deg[2]])["gripper"]
    assert abs(d[2] - after[2]) < abs(d[2] - g[2])
    # desired 5 mm farther out radially: q2 must increase the radius
    r = np.hypot(g[0], g[1])
    d = g * [(r + 5) / r, (r + 5) / r, 1]
    s = rb.step(d, markers(g, e), q)
    after = forward_kinematics(arm, q + [0, s.dq_deg[1], 0])["gripper"]
    assert abs(np.hypot(*d[:2]) - np.hypot(*after[:2])) < 5.0


# ----------------------------------------------------------------------------- total arithmetic
@pytest.mark.parametrize("expr, expected", [
    ("5 / 0", math.inf), ("-5 / 0", -math.inf), ("0 / 0", math.nan), ("0 ^ -1", math.inf),
    ("10 ^ 400", math.inf), ("(-10) ^ 401", -math.inf), ("(-4) ^ 0.5", math.nan),
    ("1e308 * 10", math.inf), ("2 ^ 10", 1024.0), ("8 / 4", 2.0),
])
def test_arithmetic_is_total_in_conditions(expr, expected):
    """Every operation yields an IEEE double; in a condition it simply compares."""
    from itg_vision.rules import _div, _pow  # noqa: F401 (the compiled code's helpers)

    rb = RuleBase.from_text(f"RULE 1: IF {expr} == {expr} THEN q1 += 1\n"
                            f"RULE 2: IF {expr} > 100 THEN q2 += 1", 2, TWO)
    step = rb.step(np.zeros(3), markers([0, 0, 0], [0, 0, 0]), [0, 0])
    assert (1 in step.fired) == (expected == expected)  # NaN == NaN is false
    assert (2 in step.fired) == (expected > 100)


@pytest.mark.parametrize("step_text, value, values", [
    ("xd / (xd - xg)", "inf", "(xd = 5, xg = 5)"), ("(xg - xd - 1) ^ 0.5", "nan", "(xg = 5, xd = 5)"),
    ("f * 1e308", "inf", "(f = 10)")])
def test_a_non_finite_step_from_finite_inputs_stops_the_run_naming_rule_and_values(step_text, value,
                                                                                  values):
    rb = RuleBase.from_text(f"RULE 0: IF rd2 > 1e9 THEN OUT_OF_REACH\n\nRULE 7: IF xd >= xg THEN q1 += {step_text}",
                            2, TWO, source="my.rules", f=10.0)
    with pytest.raises(UserError) as exc:
        rb.step(np.array([5.0, 0, 0]), markers([5.0, 1, 0], [0, 0, 0]), [0, 0])
    msg = str(exc.value)
    # the values of exactly the variables the step reads, in its order
    assert msg.startswith(f"my.rules:3: RULE 7 gives q1 a step of {value} deg {values}: ")
    assert "\n" not in msg


def test_a_non_finite_step_is_judged_by_its_own_joints_inputs():
    """One rule, two actions: q1's step reads the missing elbow (NaN: moves nothing), q2's
    divides by zero from finite inputs: the run stops naming q2 and its inputs, not q1's; the
    message quotes the rule's own line, not the next."""
    rb = RuleBase.from_text("RULE 1: IF 1 > 0 THEN q1 += xe, q2 += 1 / (xd - xg)\n"
                            "RULE 2: IF xd < 0 THEN q2 += 1", 2, TWO, source="my.rules")
    with pytest.raises(UserError) as exc:
        rb.step(np.array([50.0, 0, 0]), markers([50.0, 0, 0]), [0, 0])  # no elbow
    msg = str(exc.value)
    assert msg.startswith("my.rules:1: RULE 1 gives q2 a step of inf deg (xd = 50, xg = 50)")
    assert "'RULE 1: IF 1 > 0 THEN q1 += xe, q2 += 1 / (xd - xg)'" in msg


def test_a_non_finite_step_of_a_rule_over_several_lines_quotes_the_whole_rule():
    """A rule may span lines (the ITG+ files' do): the message quotes all of it, its comments
    left out, and nothing of the statements beside it (it quoted the first line alone,
    'RULE 1: IF xd > 0', without the step that divided by zero)."""
    rb = RuleBase.from_text("LET z = 0 RULE 1: IF xd > 0   # near\n"
                            "   THEN q1 += 1 / (xd - xg),  # the step\n"
                            "        q2 HOLD RULE 2: IF xd < 0 THEN q2 += 1\n", 2, TWO,
                            source="my.rules")
    with pytest.raises(UserError) as exc:
        rb.step(np.array([50.0, 0, 0]), markers([50.0, 0, 0], [0, 0, 0]), [0, 0])
    msg = str(exc.value)
    assert msg.startswith("my.rules:1: RULE 1 gives q1 a step of inf deg (xd = 50, xg = 50)")
    assert "in 'RULE 1: IF xd > 0 THEN q1 += 1 / (xd - xg), q2 HOLD';" in msg


@pytest.mark.parametrize("n, j", [(n, j) for n in (1, 2, 3) for j in range(1, n + 1)])
def test_a_rule_base_reading_any_joint_angle_is_given_the_encoders(n, j):
    """Reading q_j alone (the last joint too) makes the rule base ask for the encoders, and
    its rule fires on them."""
    holds = "".join(f", q{i} HOLD" for i in range(1, n + 1) if i != j)
    rb = RuleBase.from_text(f"RULE 1: IF q{j} > 10 THEN q{j} -= 1{holds}", n, (100.0,) * n)
    assert rb.uses_encoders
    step = rb.step(np.array([50.0, 0, 0]), markers([50.0, 0, 0], [25.0, 0, 0]), [20.0] * n)
    assert step.fired == (1,) and step.dq_deg[j - 1] == -1


def test_keywords_are_read_in_any_case():
    upper = "RULE 1: IF xd > xg AND NOT yd < 0 THEN q1 += S, q2 HOLD\nRULE 2: IF xd < xg THEN q1 -= S"
    lower = "rule 1: if xd > xg and not yd < 0 then q1 += S, q2 hold\nRule 2: If xd < xg Then q1 -= S"
    a, b = (RuleBase.from_text(t, 2, TWO, S=2.0) for t in (lower, upper))
    for xd, yd in ((50.0, 5.0), (50.0, -5.0), (-50.0, 5.0)):
        sa, sb = (rb.step(np.array([xd, yd, 0]), markers([0.0, 0, 0], [25.0, 0, 0]), [0, 0])
                  for rb in (a, b))
        assert sa.fired == sb.fired and sa.dq_deg.tolist() == sb.dq_deg.tolist()
    assert [r.number for r in a.rules] == [1, 2]


def test_l_is_the_first_link():
    rb = RuleBase.from_text("RULE 1: IF xd > xg THEN q1 += L, q2 += L2", 2, (107.0, 94.0))
    step = rb.step(np.array([50.0, 0, 0]), markers([0.0, 0, 0], [25.0, 0, 0]), [0, 0])
    assert step.dq_deg.tolist() == [107.0, 94.0]


def test_parameters_from_code_are_checked_as_documented():
    """f and S must be > 0, w >= 0: w = 0 (no dead band) is a rule base's to use."""
    text = "RULE 1: IF xd > xg + w THEN q1 += f * S, q2 HOLD"
    for bad in ({"f": 0.0}, {"S": 0.0}, {"w": -0.1}):
        with pytest.raises(ValueError, match=f"{next(iter(bad))} must be a finite number"):
            RuleBase.from_text(text, 2, TWO, **bad)
    assert RuleBase.from_text(text, 2, TWO, f=0.5, S=2.0, w=0.0).w == 0.0


def test_a_step_computed_from_a_missing_marker_moves_nothing():
    rb = RuleBase.from_text("RULE 1: IF xd > 0 THEN q1 += xe / 0", 2, TWO)
    step = rb.step(np.array([5.0, 0, 0]), markers([0, 0, 0]), [0, 0])  # no elbow: NaN
    assert step.fired == (1,) and np.all(step.dq_deg == 0)


def test_a_step_through_a_definition_follows_it_to_the_inputs():
    """A step that reads a LET: NaN from a missing marker moves nothing; a division by zero
    from finite inputs stops the run naming the inputs (it raised KeyError on the LET name)."""
    rb = RuleBase.from_text("LET u = xe - xg\nLET z = xd - xd\n"
                            "RULE 1: IF xd > 0 THEN q1 += u / z", 2, TWO)
    step = rb.step(np.array([5.0, 0, 0]), markers([0, 0, 0]), [0, 0])  # no elbow: NaN
    assert step.fired == (1,) and np.all(step.dq_deg == 0)
    with pytest.raises(UserError, match=r"RULE 1 gives q1 a step of .*xe = 3, xg = 0, xd = 5"):
        rb.step(np.array([5.0, 0, 0]), markers([0, 0, 0], [3, 0, 0]), [0, 0])


def test_a_file_of_20000_chained_lets_loads_compiles_and_steps_as_written():
    """A long legal file: 20,000 LETs, each reading the one before, and a rule after every
    2,000th reading it: compiled as written, each definition computed where first needed
    (such files once loaded in time quadratic in the LETs and rules: this one in 10 s)."""
    lines = ["LET a1 = xg + 1"]
    for k in range(2, 20001):
        lines.append(f"LET a{k} = a{k - 1} + 1")  # xg + k
        if k % 2000 == 0:  # fires when xg > k, q2 first, then q1, q2, ...
            lines.append(f"RULE {k}: IF a{k} > {2 * k} THEN q{k // 2000 % 2 + 1} += a{k} - xg")
    rb = RuleBase.from_text("\n".join(lines), 2, TWO)
    steps = {}
    for xg in (1.0, 3000.0, 5000.0, 19000.0, math.nan):
        args = rb.arguments(np.array([0.0, 0, 0]), markers([xg, 0, 0], [0, 0, 0]), [0, 0])
        _assert_compiled_is_reference(rb, args)
        steps[xg] = rb.compiled(*args)
    assert steps[1.0] == steps[math.nan] == ([0.0, 0.0], [])
    assert steps[3000.0] == ([0.0, 2000.0], [2000])
    assert steps[5000.0] == steps[19000.0] == ([4000.0, 2000.0], [2000, 4000])


@pytest.mark.parametrize("text, where, what", [
    ("RULE 1: IF xd > xg THEN q1 += 1e999", ":1:31", "number 1e999 is out of range"),
    ("RULE 1: IF xd > xg THEN q1 += " + "9" * 400, ":1:31", "...(400 chars) is out of range"),
    ("RULE 1: IF " + "(" * 51 + "xd > xg" + ")" * 51 + " THEN q1 += S", ":1:62", "nested too deeply"),
    ("RULE 1: IF xd > xg THEN q1 += " + "-" * 51 + "S", ":1:81", "nested too deeply"),
    ("RULE 1: IF xd > xg THEN q1 += |" + "+".join(["S"] * 51) + "|", ":1:", "nested too deeply"),
    ("RULE 1: IF xd > xg THEN q1 += " + " + ".join(["S"] * 600), ":1:", "longer than 1000 tokens"),
])
def test_stated_limits_are_refused_at_line_and_column(text, where, what):
    with pytest.raises(UserError) as exc:
        RuleBase.from_text(text, 2, TWO, source="my.rules")
    msg = str(exc.value)
    assert msg.startswith("my.rules" + where) and what in msg and len(msg) < 400, msg


def test_limits_leave_room_for_real_rule_bases():
    deep = "(" * 40 + "xd - xg" + ")" * 40
    chain = " + ".join(["S"] * 45)
    rb = RuleBase.from_text(f"RULE 1: IF {deep} > 0 THEN q1 += {chain}", 2, TWO, S=1.0)
    assert rb.step(np.array([1.0, 0, 0]), markers([0, 0, 0], [0, 0, 0]), [0, 0]).dq_deg[0] == 45.0


def test_parsing_reads_each_token_a_bounded_number_of_times_however_long_the_file(monkeypatch):
    """A parenthesised condition is first tried as a condition, and the error that attempt makes
    is dropped; each such error used to look its token up in the whole file, so a 1 MiB rule
    file of 4054 such rules took 56 s of CPU to reach its error (15 s to parse now, on the same
    busy host). Counted, not timed: token reads per rule stay flat from 50 to 200 rules
    (quadratic would grow 4x)."""
    import itg_vision.rules as rules_module

    class Counting(list):
        reads = 0

        def __getitem__(self, k):
            got = super().__getitem__(k)
            Counting.reads += len(got) if isinstance(k, slice) else 1
            return got

        def __iter__(self):
            for t in super().__iter__():
                Counting.reads += 1
                yield t

    tokenize = rules_module.tokenize
    monkeypatch.setattr(rules_module, "tokenize", lambda *a, **k: Counting(tokenize(*a, **k)))
    per_rule = {}
    for n in (50, 200):
        text = "".join(f"RULE {i}: IF (xg + yg) > {i} AND (xd - xe) < 1 THEN q1 += S, q2 -= S\n"
                       for i in range(1, n + 1))
        Counting.reads = 0
        RuleBase.from_text(text, 2, TWO, S=1.0)
        per_rule[n] = Counting.reads / n
    assert per_rule[200] < 1.5 * per_rule[50], per_rule


def test_a_rule_base_for_another_arm_is_refused_by_load_rules():
    with pytest.raises(UserError, match="no rule moves or holds q2 of this 2-joint arm"):
        load_rules("table1", 2, TWO)
    with pytest.raises(UserError, match="no rule moves or holds q3 of this 3-joint arm"):
        load_rules("table2", 3, (100.0, 100.0, 100.0))


def test_a_name_the_arm_lacks_is_called_a_rule_base_for_another_arm_only_when_it_is_one(
        tmp_path):
    """Table 2 on the one-link arm was only told that L2 is link 2's length and 1 length was
    given, where Table 1 on the two-link arm was called a rule base for another arm: the L2,
    q2 or elbow the arm lacks says so too, with the joints the rules are for (the most any of
    its names asks). q0, or too few lengths given from code, is no other arm."""
    path = tmp_path / "x.rules"
    for text, at in (("RULE 1: IF q2 > 0 THEN q1 += S", "1:12: 'q2' is joint 2's angle"),
                     ("RULE 1: IF ye > 0 THEN q1 += S, q3 HOLD", "1:12: 'ye' reads the elbow")):
        path.write_text(text)
        with pytest.raises(UserError) as exc:
            load_rules(str(path), 1, (100.0,))
        assert str(exc.value).startswith(f"{path}:{at}"), exc.value
        assert ": a rule base for another arm? (its rules are for an arm of " in str(exc.value)
    assert "of 3 joints or more, this one has 1; shipped: table1 (one-link), " in str(exc.value)
    path.write_text("RULE 1: IF q0 > 0 THEN q1 += S")
    with pytest.raises(UserError, match=r"'q0' is joint 0's angle, but the arm has 1 joint\(s\)$"):
        load_rules(str(path), 1, (100.0,))
    with pytest.raises(UserError, match=r"only 1 link length\(s\) were given \(links_mm\)$"):
        load_rules("table2", 2, (100.0,))


def test_a_joint_held_on_purpose_counts_as_named(tmp_path):
    """`q2 HOLD` says the rule base means to keep q2 still: it is loaded and q2 never moves (it
    used to be refused as 'a rule base for another arm', and `q2 += 0` was the workaround)."""
    path = tmp_path / "hold.rules"
    path.write_text("RULE 1: IF xd > xg THEN q1 += S, q2 HOLD\nRULE 2: IF xd < xg THEN q1 -= S\n")
    rb = load_rules(str(path), 2, TWO, S=1.0)
    for g in ([0.0, 0, 0], [5.0, 0, 0]):
        dq = rb.step(np.array([1.0, 0, 0]), markers(g, [0, 0, 0]), [0, 0]).dq_deg
        assert dq[1] == 0.0 and abs(dq[0]) == 1.0
    path.write_text("RULE 1: IF xd > xg THEN q1 += S\n")
    with pytest.raises(UserError, match=r"no rule moves or holds q2 .*say so: q2 HOLD\)$"):
        load_rules(str(path), 2, TWO, S=1.0)


def test_binary_and_oversized_rule_files_are_one_line(tmp_path):
    f = tmp_path / "x.rules"
    f.write_bytes(b"RULE 1: IF xd > xg\n  THEN \xe9 q1 += S")
    with pytest.raises(UserError, match=r"x.rules:2:8: not UTF-8 text \(byte 0xe9\)"):
        RuleBase.from_file(f, 2, TWO)
    f.write_bytes(b"# " + b"x" * (1 << 20))
    with pytest.raises(UserError, match="larger than 1024 KiB"):
        RuleBase.from_file(f, 2, TWO)


@settings(max_examples=100, deadline=None)
@given(st.floats(-1e200, 1e200), st.floats(-50, 50))
@example(5.573621533931981e+16, 0.0)  # pow(x, 2.0) != x * x by an ulp here (CI, 2026-11)
def test_squares_and_powers_equal_python_floats(x, y):
    """Squares compile to a product (no call), other powers to a checked pow: the same numbers
    as Python's product and pow. (A square is the correctly rounded IEEE product; libm's
    pow(x, 2) may differ from it by an ulp, so the reference squares by multiplying too.)"""
    rb = RuleBase.from_text("RULE 1: IF 1 > 0 THEN q1 += ((xd - yd)^2)^2 + |xd|^1.5 + 2^yd\n"
                            "RULE 2: IF 1 > 0 THEN q2 += xd^2", 2, TWO)
    d = np.array([x, y, 0.0])
    try:
        s = (x - y) * (x - y)
        expected = [s * s + abs(x) ** 1.5 + 2.0 ** y, x * x]
    except OverflowError:  # Python raises; the rules give inf, and then a UserError (above)
        return
    if not all(map(math.isfinite, expected)):
        return
    got = rb.step(d, markers([0, 0, 0], [0, 0, 0]), [0, 0]).dq_deg
    assert list(got) == expected


# ----------------------------------------------------------------------------- the compiled function
# An independent evaluator: it walks the parsed tree with the module docstring's semantics
# (definitions first, in file order; OUT_OF_REACH rules first; then each rule in file order
# fires when its condition holds and none of its joints is set yet). The compiled function must
# return exactly what it returns: the same fired rules and bit for bit the same steps (a NaN
# as any NaN).
def _reference_div(a, b):
    if b == 0:  # IEEE 754: x / 0 is +-inf with the signs' product, 0 / 0 and NaN / 0 NaN
        if a == 0 or a != a:
            return math.nan
        return math.inf if (a > 0) == (math.copysign(1.0, b) > 0) else -math.inf
    return a / b


def _reference_pow(a, b):
    if a < 0 and abs(a) != math.inf and b == b and abs(b) != math.inf and b != int(b):
        return math.nan  # a complex number, even one too large for a double
    try:
        r = a ** b
    except ZeroDivisionError:  # 0 ^ -1
        return math.inf
    except OverflowError:
        return -math.inf if a < 0 and b == int(b) and int(b) % 2 == 1 else math.inf
    return math.nan if isinstance(r, complex) else r


_REFERENCE_OPS = {"+": lambda a, b: a + b, "-": lambda a, b: a - b, "*": lambda a, b: a * b,
                  "/": _reference_div, "^": _reference_pow,
                  "<": lambda a, b: a < b, "<=": lambda a, b: a <= b, ">": lambda a, b: a > b,
                  ">=": lambda a, b: a >= b, "==": lambda a, b: a == b, "!=": lambda a, b: a != b}


def _reference_value(node, env):
    from itg_vision.rules import Binary, Name, Num, Unary

    if isinstance(node, Num):
        return node.value
    if isinstance(node, Name):
        return env[node.name]
    if isinstance(node, Unary):
        x = _reference_value(node.arg, env)
        return {"-": lambda: -x, "abs": lambda: abs(x), "not": lambda: not x}[node.op]()
    if node.op == "and":
        return _reference_value(node.left, env) and _reference_value(node.right, env)
    if node.op == "or":
        return _reference_value(node.left, env) or _reference_value(node.right, env)
    a = _reference_value(node.left, env)
    if node.op == "^" and node.right == Num(2.0):  # a square is the (correctly rounded) product
        return a * a
    return _REFERENCE_OPS[node.op](a, _reference_value(node.right, env))


def _reference_step(rb, args):
    env = dict(zip(rb.argument_names, args))
    for d in rb.definitions:
        env[d.name] = _reference_value(d.expr, env)
    for r in (r for r in rb.rules if r.out_of_reach):
        if _reference_value(r.condition, env):
            return None, (r.number,)
    dq, done, fired = [0.0] * rb.n_joints, set(), []
    for r in (r for r in rb.rules if not r.out_of_reach):
        joints = {a.joint for a in r.actions}
        if joints & done or not _reference_value(r.condition, env):
            continue
        for a in r.actions:
            if a.kind in ("inc", "dec"):
                v = _reference_value(a.step, env)
                dq[a.joint - 1] = v if a.kind == "inc" else -v
        done |= joints
        fired.append(r.number)
    return dq, fired


def _exactly(result):
    """(dq, fired) with every step as its type and its 8 bytes: equal means bit for bit equal,
    but for a NaN's sign and payload, which CPython itself does not keep: once specialised,
    ``a * b`` of two NaNs may return the other operand's NaN (and RuleBase.step treats every
    NaN alike)."""
    import struct

    dq, fired = result
    steps = None if dq is None else [(type(v), "nan" if v != v else struct.pack("<d", v)) for v in dq]
    return type(dq), steps, type(fired), list(fired)


def _assert_compiled_is_reference(rb, args, fn=None):
    """``fn`` (default: the rule base's compiled function) returns what the reference does;
    returns that result (as :func:`_exactly` gives it)."""
    fn = fn or rb.compiled
    got, want = _exactly(fn(*args)), _exactly(_reference_step(rb, args))
    assert got == want, (rb.source, args, fn(*args), _reference_step(rb, args))
    return got


#: (f, S, w) the shipped rule bases are compared at: defaults, the servo-limit S, a wide band.
PARAMETER_SETS = ((0.06, 0.5, 0.5), (0.5, 20.0, 0.5), (0.05, 2.0, 3.0), (0.1, 20, 0.5))


def rng_pick(rng):
    """``pick(options)`` drawing from a numpy Generator (for the random rule bases)."""
    def pick(options):
        options = list(options)
        return options[rng.integers(len(options))]

    return pick


_ARM_OF = {"table1": "one-link", "itg-plus-one-link": "one-link", "three-link": "three-link",
           "itg-plus-three-link": "three-link"}  # the others: two-link


def _situations(arm, rng, n):
    """(desired, markers, q): poses of the arm with set points within reach, anywhere (often
    out of reach), exactly at the gripper, within a few w of it, a small step away; markers
    missing (NaN); degenerate poses (markers at the base or on top of each other)."""
    k, reach = arm.n_joints, sum(arm.links_mm)
    for i in range(n):
        q = rng.uniform(-180.0, 180.0, k)
        m = forward_kinematics(arm, q)
        g, e = m["gripper"].copy(), m["elbow"].copy()
        kind = i % 8
        if kind == 0:
            d = forward_kinematics(arm, rng.uniform(-180.0, 180.0, k))["gripper"]
        elif kind == 1:
            d = rng.uniform(-1.3 * reach, 1.3 * reach, 3)
        elif kind == 2:
            d = g.copy()
        elif kind == 3:
            d = g + rng.normal(0.0, 1.0, 3)
        elif kind == 4:
            d = forward_kinematics(arm, q + rng.normal(0.0, 2.0, k))["gripper"]
        elif kind == 5:  # a marker not measured
            d = forward_kinematics(arm, rng.uniform(-180.0, 180.0, k))["gripper"]
            if rng.random() < 0.5:
                e[:] = np.nan
            else:
                g[rng.integers(3)] = np.nan
        elif kind == 6:  # gripper on the elbow, or at the base
            d = rng.uniform(-reach, reach, 3)
            g = e.copy() if rng.random() < 0.5 or np.isnan(e[0]) else np.zeros(3)
        else:  # whole numbers: exact ties and zeros
            d, g, e = (np.round(rng.uniform(-2, 2, 3)) * 50.0 for _ in range(3))
        yield d, markers(g, e), (None if i % 5 == 4 else q)


@pytest.mark.parametrize("name", rule_names())
def test_compiled_shipped_rule_bases_equal_the_tree_walking_reference(name):
    arm = ArmSpec.from_args(_ARM_OF.get(name, "two-link"))
    rng = np.random.default_rng(7)
    for f, S, w in PARAMETER_SETS:
        rb = load_rules(name, arm.n_joints, arm.links_mm, f=f, S=S, w=w)
        for d, m, q in _situations(arm, rng, 400):
            _assert_compiled_is_reference(rb, rb.arguments(d, m, q))


SPECIAL_VALUES = [0.0, -0.0, 1.0, -1.0, 2.0, 0.5, -3.0, 100.0, 1e200, math.nan, math.inf]
_VALUES = st.sampled_from(SPECIAL_VALUES)
_NUMBERS = ["0", "2", "0.5", "3", "16"]


def _random_expr(pick, names, depth):
    """A random expression; ``pick(options)`` chooses one (hypothesis here, an RNG in
    test_native)."""
    if depth == 0 or pick([0, 1, 2]) == 0:
        return pick(names + _NUMBERS)
    kind = pick(["+", "-", "*", "/", "/", "^", "abs", "neg"])
    a = _random_expr(pick, names, depth - 1)
    if kind == "abs":
        return f"|{a}|"
    if kind == "neg":
        return f"-{a}"
    if kind == "^":
        return f"{a}^{pick(['2', '2', '0.5', '3', '(-1)'])}"
    return f"({a} {kind} {_random_expr(pick, names, depth - 1)})"


def _random_condition(pick, pool, depth):
    kind = pick(["cmp", "cmp", "AND", "OR", "NOT"] if depth else ["cmp"])
    if kind == "cmp":
        return f"{pick(pool)} {pick(['<', '<=', '>', '>=', '==', '!='])} {pick(pool)}"
    if kind == "NOT":
        return f"NOT ({_random_condition(pick, pool, depth - 1)})"
    return f"({_random_condition(pick, pool, depth - 1)}) {kind} ({_random_condition(pick, pool, depth - 1)})"


def random_rule_base(pick) -> RuleBase:
    """A random rule base (definitions between rules, shared subexpressions, rules moving one
    or several joints, HOLD, OUT_OF_REACH) for 1 to 3 joints."""
    n = pick([1, 2, 3])
    names = ["xd", "yd", "xg", "yg", *(["xe", "ye"] if n > 1 else []), "rd2", "f", "S", "w", "L1"]
    lines, numbers = [], iter(range(1, 100))
    pool = ["xd", "0", *(_random_expr(pick, names, 2) for _ in range(2))]  # used again and again
    for _ in range(pick(range(1, 8))):
        statement = pick(["LET", "RULE", "RULE", "RULE", "OUT"])
        a, b = pick(pool), pick(pool)
        pool += [_random_expr(pick, names, 2), f"({a} {pick(list('+-*/'))} {b})"]
        if statement == "LET":
            names.append(f"D{len(lines)}")
            lines.append(f"LET {names[-1]} = {pick(pool)}")
            continue
        cond = _random_condition(pick, pool, 2)
        if statement == "OUT":
            lines.append(f"RULE {next(numbers)}: IF {cond} THEN OUT_OF_REACH")
            continue
        actions, free = [], list(range(1, n + 1))
        for _ in range(pick(range(1, n + 1))):  # one action per joint
            j = free.pop(pick(range(len(free))))
            kind = pick(["+=", "-=", "HOLD"])
            actions.append(f"q{j} HOLD" if kind == "HOLD" else f"q{j} {kind} {pick(pool)}")
        lines.append(f"RULE {next(numbers)}: IF {cond} THEN {', '.join(actions)}")
    lines.append(f"RULE {next(numbers)}: IF xd > 0 THEN q1 += xd")  # at least one rule moves a joint
    return RuleBase.from_text("\n".join(lines), n, (100.0,) * n)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(st.data())
def test_compiled_random_rule_bases_equal_the_tree_walking_reference(data):
    """Random rule bases (:func:`random_rule_base`) on random inputs (zeros, NaN, inf)."""
    rb = random_rule_base(lambda options: data.draw(st.sampled_from(list(options))))
    for _ in range(4):
        args = data.draw(st.lists(_VALUES, min_size=len(rb.argument_names),
                                  max_size=len(rb.argument_names)))
        _assert_compiled_is_reference(rb, tuple(args))


def test_a_long_chain_of_rules_on_one_joint_compiles_and_equals_the_reference():
    """250 rules on q1 (an if/elif chain is cut every MAX_ELIF rules: Python's compiler recurses
    on each elif); the first whose condition holds fires, however far down the file."""
    text = "\n".join(f"RULE {k}: IF xd > {250 - k} THEN q1 += {k}" for k in range(1, 251))
    rb = RuleBase.from_text(text + "\nRULE 999: IF 1 > 0 THEN q2 -= 1", 2, TWO)
    for xd in (300.0, 3.0, 0.5, -1.0, math.nan):
        args = rb.arguments(np.array([xd, 0.0, 0.0]), markers([0, 0, 0], [0, 0, 0]), [0, 0])
        _assert_compiled_is_reference(rb, args)
    assert rb.compiled(*args)[1] == [999]
    args = rb.arguments(np.array([3.0, 0.0, 0.0]), markers([0, 0, 0], [0, 0, 0]), [0, 0])
    assert rb.compiled(*args) == ([248.0, -1.0], [248, 999])


def random_layered_rule_base(pick, rng) -> RuleBase:
    """A random rule base of the shape where a compiler places definitions wrongly: definitions
    built on definitions, conditions that are AND chains reading them late, steps that read
    definitions other rules read too, rules that set one joint of two or three."""
    n = pick([2, 3])
    names, lets, lines = ["xd", "yd", "xg", "yg", "w"], [], []
    for number in range(1, pick(range(4, 16))):
        if rng.random() < 0.4:
            lines.append(f"LET D{len(lets)} = {_random_expr(pick, names + lets * 3, 2)}")
            lets.append(f"D{len(lets)}")
            continue
        pool = names + lets * 2
        terms = [f"{_random_expr(pick, pool, 1)} {pick(['<', '<=', '>', '!='])} {pick(pool)}"
                 for _ in range(pick([1, 2, 3]))]
        j = pick(range(1, n + 1))
        step = pick(lets) if lets and rng.random() < 0.7 else _random_expr(pick, pool, 1)
        lines.append(f"RULE {number}: IF {' AND '.join(terms)} THEN q{j} {pick(['+=', '-='])} {step}")
    lines.append("RULE 99: IF xd > 0 THEN q1 += xd")
    return RuleBase.from_text("\n".join(lines), n, (100.0,) * n)


@pytest.mark.slow
def test_compiled_layered_rule_bases_equal_the_tree_walking_reference():
    """2000 random rule bases of that shape (random_layered_rule_base) on inputs mixing the
    special values with ordinary numbers: the compiled function raises nothing and returns
    the reference's steps and fired rules."""
    rng = np.random.default_rng(21)
    pick = rng_pick(rng)
    for _ in range(2000):
        rb = random_layered_rule_base(pick, rng)
        for _ in range(6):
            args = tuple(pick(SPECIAL_VALUES) if rng.random() < 0.3 else float(rng.normal(0, 3))
                         for _ in rb.argument_names)
            _assert_compiled_is_reference(rb, args)


def test_a_rule_base_whose_s_is_the_servo_limit_needs_s_given():
    with pytest.raises(UserError, match="itg-plus-two-link.rules: S is the servo limit here"):
        load_rules("itg-plus-two-link", 2, TWO)
    rb = load_rules("itg-plus-two-link", 2, TWO, S=20.0)
    assert rb.servo_step and rb.S == 20.0
    assert load_rules("table2", 2, TWO).S == RuleBase.S  # a fixed S keeps its default
    text = "#! S is the servo limit\nRULE 1: IF xd > xg THEN q1 += S"  # every entry point
    with pytest.raises(UserError, match="my.rules: S is the servo limit here"):
        RuleBase.from_text(text, 2, TWO, source="my.rules")
    assert RuleBase.from_text(text, 2, TWO, S=5.0).S == 5.0
    # an indented line declares it too (it was read as a plain comment: the file loaded with
    # the default S, silently not the servo limit)
    with pytest.raises(UserError, match="my.rules: S is the servo limit here"):
        RuleBase.from_text("  " + text, 2, TWO, source="my.rules")


def test_a_rule_base_for_another_arm_names_every_shipped_one_for_each_arm():
    with pytest.raises(UserError) as exc:
        load_rules("table2", 3, (100.0, 100.0, 100.0))
    msg = str(exc.value)
    assert "no rule moves or holds q3 of this 3-joint arm" in msg
    assert "three-link (three-link)" in msg and "itg-plus-three-link (three-link)" in msg


@pytest.mark.parametrize("args, kw, what", [
    ((0, ()), {}, "n_joints must be a whole number >= 1"),
    ((2, ()), {}, r"links_mm must be finite lengths > 0 \(mm\)"),
    ((2, (float("nan"), 100.0)), {}, "links_mm must be finite lengths"),
    ((2, (-100.0, 100.0)), {}, "links_mm must be finite lengths"),
    ((2, (100.0, 100.0)), {"f": float("nan")}, "f must be a finite number > 0"),
    ((2, (100.0, 100.0)), {"f": -1.0}, "f must be a finite number > 0"),
    ((2, (100.0, 100.0)), {"S": "2"}, "S must be a finite number > 0"),
    ((2, (100.0, 100.0)), {"w": -0.5}, "w must be a finite number >= 0"),
])
def test_a_rule_base_from_code_refuses_arguments_no_arm_has(args, kw, what):
    """Files and options are checked by their readers; from code, f = NaN gave zero steps for
    ever, f = -1 stepped away from the target and n_joints 0 said "unknown name 'L1'"."""
    with pytest.raises(ValueError, match=what):
        load_rules("table2", *args, **kw)


def test_a_file_or_folder_named_like_a_shipped_rule_base_does_not_replace_it(tmp_path,
                                                                              monkeypatch):
    """A name is a path only if it ends in .rules or holds a folder: a folder called `table2`
    in the current folder used to make the default run fail ("table2: is a folder"), and an
    empty file `table1` to replace the shipped Table 1 ("no rules found")."""
    from itg_vision.rules import RULES_DIR, resolve_rules_path

    monkeypatch.chdir(tmp_path)
    (tmp_path / "table2").mkdir()
    (tmp_path / "table1").write_text("")
    assert resolve_rules_path("table2") == RULES_DIR / "table2.rules"
    assert resolve_rules_path("table1") == RULES_DIR / "table1.rules"
    # the file itself is still reachable, as a path
    (tmp_path / "mine.rules").write_text("")
    assert resolve_rules_path("./table1") == Path("./table1")
    assert resolve_rules_path("mine.rules") == Path("mine.rules")
    with pytest.raises(UserError, match=r"unknown rule base 'mine' .*; \./mine\.rules is in this "
                                        r"folder: give it as a path, \./mine\.rules\)$"):
        resolve_rules_path("mine")


def test_the_library_run_and_paper_share_one_set_of_rule_defaults():
    """A rule base loaded from code without f, S, w gets `run`'s parameters (the library's
    defaults used to be f 0.06, S 0.5: a gain 8x smaller than run's, said only in a
    docstring)."""
    from itg_vision.rules import PARAM_DEFAULTS
    from itg_vision.runner import RULE_DEFAULTS, RunConfig, prepare

    lib = load_rules("table2", 2, TWO)
    assert (lib.f, lib.S, lib.w) == (0.5, 2.0, 0.5) == tuple(PARAM_DEFAULTS.values())
    ran = prepare(RunConfig(feedback="model")).controller
    assert (ran.f, ran.S, ran.w) == (lib.f, lib.S, lib.w)
    assert RULE_DEFAULTS == {"gain_deg_per_mm": 0.5, "step_deg": 2.0, "tolerance_mm": 0.5}


def test_a_rule_base_built_from_code_names_what_its_arguments_lack():
    """Too few link lengths used to read as an unknown name in the rule text, and a misspelt
    parameter as a TypeError from the dataclass."""
    text = "RULE 0: IF rd2 > (L1 + L2)^2 THEN OUT_OF_REACH\nRULE 1: IF xd > xg THEN q1 -= S, q2 HOLD\n"
    with pytest.raises(UserError, match=r"<rules>:1:24: 'L2' is link 2's length, but only 1 link "
                                        r"length\(s\) were given \(links_mm\)"):
        RuleBase.from_text(text, 2, (100.0,))
    with pytest.raises(ValueError, match=r"unknown rule parameter\(s\) g \(the rules' are f, S, w\)"):
        load_rules("table2", 2, TWO, g=0.5)


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_a_rule_file_reads_alike_whatever_its_line_ends(tmp_path, newline):
    """Saved with CRs alone (old Macs), Table 2 used to read as one comment line: 'no rules
    found'. Every line end gives the same rules, at the same lines."""
    from itg_vision.rules import RULES_DIR, RuleBase

    text = (RULES_DIR / "table2.rules").read_text()
    path = tmp_path / "t.rules"
    path.write_bytes(text.replace("\n", newline).encode())
    rb = RuleBase.from_file(path, 2, TWO)
    ref = RuleBase.from_text(text, 2, TWO)
    assert [(r.number, r.line, r.text) for r in rb.rules] == [(r.number, r.line, r.text) for r in ref.rules]


def test_the_servo_limit_declaration_is_read_indented_and_spaced_but_not_misspelt():
    """'#! S is the servo limit' is read with spaces around it, on a line of its own; a
    misspelt one is an error (the previous test's table), never a silent comment."""
    for line in ("#! S is the servo limit", "   #!   S is the servo limit   ",
                 "#!\tS is the servo limit\r"):
        rb = RuleBase.from_text(line + "\nRULE 1: IF xd > xg THEN q1 += S", 2, TWO, S=20.0)
        assert rb.servo_step, line
    assert not RuleBase.from_text("# S is the servo limit\nRULE 1: IF xd > xg THEN q1 += S", 2,
                                  TWO, S=2.0).servo_step


def test_the_did_you_mean_hint_is_the_same_whatever_the_hash_seed():
    """Two LETs that differ from a misspelt name only in case: the hint names the same one
    (the first in sorted order) in every process, whatever Python's string hash seed (a set's
    order). Eight processes with different seeds: with the set's order, two names came out
    in either order."""
    import os
    import subprocess
    import sys

    code = ("from itg_vision.errors import UserError\n"
            "from itg_vision.rules import RuleBase\n"
            "try:\n"
            "    RuleBase.from_text('LET Ab = xd\\nLET AB = yd\\nRULE 1: IF ab > 0 THEN q1 += S',"
            " 2, (100.0, 100.0), source='r')\n"
            "except UserError as e:\n"
            "    print(str(e).rsplit(';', 1)[-1])\n")
    hints = set()
    for seed in range(8):
        env = {**os.environ, "PYTHONHASHSEED": str(seed)}
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, check=True).stdout.strip()
        hints.add(out)
    assert hints == {"did you mean 'AB'? names are case-sensitive"}, hints


@pytest.mark.parametrize("n_lets", [40, 41])
def test_an_unknown_name_s_error_counts_the_lets_of_a_long_file(n_lets):
    """Up to MAX_LETS_LISTED (40) LETs the error lists every known name, LETs included; beyond,
    the built-in names and how many LETs: one line, not one name per LET of the file."""
    from itg_vision.rules import MAX_LETS_LISTED

    text = "".join(f"LET a{k} = xd + {k}\n" for k in range(n_lets)) + "RULE 1: IF b > 0 THEN q1 += S"
    with pytest.raises(UserError) as err:
        RuleBase.from_text(text, 2, (100.0, 100.0), source="r")
    message = str(err.value)
    builtins = "L, L1, L2, S, f, h, q1, q2, rd2, re2, rg2, sL, w, xd, xe, xg, yd, ye, yg, zd, ze, zg"
    assert f"r:{n_lets + 1}:12: unknown name 'b' (known: " in message
    if n_lets <= MAX_LETS_LISTED:
        assert "a39" in message and "a0, a1, a10" in message and "LETs above" not in message
    else:
        assert message.endswith(f"(known: {builtins}, and the {n_lets} LETs above it)")
