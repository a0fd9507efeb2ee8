"""Property test: the rule language's logical precedence (NOT over AND over OR, parentheses
first) against Python's own, on generated conditions."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from itg_vision.feedback import Markers
from itg_vision.rules import RuleBase

NAN = float("nan")  # the pitch axis's xa, ya on an arm without one

_atoms = st.sampled_from(["xd", "yd", "xg", "yg", "1", "2", "-3"])
_ops = st.sampled_from(["<", "<=", ">", ">=", "==", "!="])
_cmp = st.tuples(_atoms, _ops, _atoms).map(" ".join)


def _cond(depth):
    if depth == 0:
        return _cmp
    sub = _cond(depth - 1)
    return (_cmp
            | st.tuples(sub, st.sampled_from(["AND", "OR"]), sub).map(" ".join)
            | sub.map(lambda c: f"NOT {c}")
            | sub.map(lambda c: f"({c})"))


@settings(max_examples=300, deadline=None)
@given(_cond(4), st.lists(st.integers(-3, 3).map(float), min_size=4, max_size=4))
def test_conditions_follow_not_and_or_precedence(cond, vals):
    xd, yd, xg, yg = vals
    rb = RuleBase.from_text(f"RULE 1: IF {cond} THEN q1 += 1", 1, (100.0,))
    fired = rb.step(np.array([xd, yd, 0.0]), Markers(np.array([xg, yg, 0.0]), np.full(3, np.nan)),
                    [0.0]).fired == (1,)
    # Python's not/and/or have the same precedence; our generated text only, as a reference
    py = cond.replace("AND", "and").replace("OR", "or").replace("NOT", "not")
    expected = bool(eval(py, {"__builtins__": {}}, dict(xd=xd, yd=yd, xg=xg, yg=yg)))
    assert fired == expected, (cond, vals)


def test_python_source_is_what_runs():
    """RuleBase.python_source is the exact function that runs: the same text every time it is
    compiled, and executing it gives the compiled function's decisions."""
    from itg_vision import rules
    from itg_vision.rules import load_rules

    a = load_rules("table2", 2, (100.0, 100.0), f=0.5)
    b = load_rules("table2", 2, (100.0, 100.0), f=0.5)
    assert a.python_source == b.python_source and "def _itg_step(" in a.python_source
    ns = dict(rules._HELPERS)
    exec(a.python_source, ns)  # noqa: S102 - our own generated source, as the library does
    rng = np.random.default_rng(0)
    for _ in range(200):
        d, g, e = rng.uniform(-150, 150, (3, 3))
        args = a.arguments(d, Markers(g, e), [10.0, 20.0])
        assert ns["_itg_step"](*args) == a.compiled(*args)


def test_definitions_a_condition_reads_after_its_first_operand_wait_for_it():
    """``IF a AND b``: the definitions only ``b`` reads are computed where ``a`` holds (inside
    ``if a:``), and a rule that returns computes its steps' definitions in its body; the
    results are the tree-walking reference's (test_rules)."""
    rb = RuleBase.from_text("LET E = xd * 2\nLET F = yd * 3\n"
                            "RULE 1: IF xg > 0 AND E > 1 THEN q1 += F\n"
                            "RULE 2: IF 1 > 0 THEN q1 += 2", 1, (100.0,))
    lines = rb.python_source.splitlines()
    depth = {name: next(len(l) - len(l.lstrip()) for l in lines if l.strip().startswith(name))
             for name in ("if v_xg > 0.0:", "v_E =", "v_F =")}
    assert depth["v_E ="] > depth["if v_xg > 0.0:"] and depth["v_F ="] > depth["v_E ="]
    for xg, xd, want in ((1.0, 1.0, [6.0]), (1.0, 0.0, [2.0]), (-1.0, 1.0, [2.0])):
        args = (xd, 2.0, 0.0, xg, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, NAN, NAN,  # no pitch axis
                0.0, 0.06, 0.5, 0.5, 100.0, 100.0, 0.0, 0.0)
        assert rb.compiled(*args)[0] == want


@pytest.mark.parametrize("first", ["", "RULE 0: IF yg > 0 AND D > 5 THEN q3 += 1\n"])
def test_a_definition_the_steps_share_with_later_rules_is_computed_with_what_it_reads(first):
    """``IF a AND b`` where b reads D, the rule's step reads E = D + 1 and a later rule reads E
    too: E is computed before the test, so D is too (found in review: E was computed before D,
    an UnboundLocalError, always or only where an earlier rule's first operand failed)."""
    from test_rules import _assert_compiled_is_reference

    rb = RuleBase.from_text("LET D = xd * 2\nLET E = D + 1\n" + first
                            + "RULE 1: IF xg > 0 AND D > 1 THEN q1 += E\n"
                            "RULE 2: IF yd > 0 THEN q2 += E", 3, (100.0,) * 3)
    for xd, xg, yg in ((1.0, 1.0, 1.0), (1.0, 1.0, -1.0), (0.2, -1.0, -1.0), (5.0, 1.0, 1.0)):
        args = (xd, 1.0, 0.0, xg, yg, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, NAN, NAN, 0.0, 0.0, 0.0,
                0.06, 0.5, 0.5, 100.0, 100.0, 100.0, 100.0, 0.0, 0.0)
        _assert_compiled_is_reference(rb, args)
