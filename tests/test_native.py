"""Rule bases compiled to C: the same steps and fired rules as the Python function, bit for bit,
against the independent tree-walking evaluator of test_rules."""

import math
import os
import subprocess

import numpy as np
import pytest

from itg_vision import native, trajectory as traj
from itg_vision.arm import ArmSpec
from itg_vision.rules import RuleBase, load_rules
from itg_vision.shipped import rule_names
from test_rules import (_ARM_OF, PARAMETER_SETS, SPECIAL_VALUES, _assert_compiled_is_reference,
                        _exactly, _situations, markers, random_rule_base, rng_pick)


@pytest.fixture(autouse=True)
def _compiler():
    """Skip where the machine has no C compiler, except in CI (whose machines have one: there
    a missing compiler fails the tests rather than hiding them)."""
    try:
        native.compiler()
    except native.NativeUnavailable as exc:
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            raise
        pytest.skip(str(exc))


def _assert_same(fn, rb, args):
    assert _assert_compiled_is_reference(rb, args, fn) == _exactly(rb.compiled(*args))


@pytest.mark.slow
def test_shipped_rule_bases_in_c_equal_the_reference():
    """Every shipped rule base, at four parameter sets, on the situations of test_rules (poses,
    set points out of reach, on the gripper, markers missing, degenerate poses)."""
    bases, arms = [], []
    for name in rule_names():
        arm = ArmSpec.from_args(_ARM_OF.get(name, "two-link"))
        for f, S, w in PARAMETER_SETS:
            bases.append(load_rules(name, arm.n_joints, arm.links_mm, f=f, S=S, w=w))
            arms.append(arm)
    rng = np.random.default_rng(11)
    for fn, rb, arm in zip(native.build(bases), bases, arms):
        for d, m, q in _situations(arm, rng, 400):
            _assert_same(fn, rb, rb.arguments(d, m, q))


@pytest.mark.slow
def test_random_rule_bases_in_c_equal_the_reference():
    """300 random rule bases (test_rules.random_rule_base: definitions, OUT_OF_REACH, HOLD,
    several joints per rule, divisions by zero, powers) in one module, on inputs drawn from
    zeros of both signs, NaN, inf and 1e200."""
    rng = np.random.default_rng(3)
    pick = rng_pick(rng)
    bases = [random_rule_base(pick) for _ in range(300)]
    for fn, rb in zip(native.build(bases), bases):
        for _ in range(8):
            _assert_same(fn, rb, tuple(pick(SPECIAL_VALUES) for _ in rb.argument_names))


def test_powers_and_divisions_at_their_edges_equal_python():
    """x ^ y and x / y over signed zeros, infinities, NaN, overflow and negative bases to
    fractional powers (where C's pow and Python's float power could part: (-0) ^ -1 is +inf in
    the rules, -inf in C99)."""
    rb = RuleBase.from_text("RULE 1: IF 1 > 0 THEN q1 += xd ^ yd, q2 += xd / yd", 2, (100.0, 100.0))
    fn = native.native_step(rb)
    values = [0.0, -0.0, 1.0, -1.0, 0.5, -0.5, 2.0, -2.0, 3.0, -3.0, 1e300, -1e300, 1e-300,
              math.inf, -math.inf, math.nan, 1.5, -1.5]
    for x in values:
        for y in values:
            args = rb.arguments(np.array([x, y, 0.0]), markers([0, 0, 0], [0, 0, 0]), [0, 0])
            _assert_same(fn, rb, args)


def test_a_zero_minus_an_absolute_value_keeps_its_sign_as_in_python():
    """0 - |x| at x = 0 is +0, as Python computes it: GCC 12 folds it into -|x| (-0), even at
    -O0, unless told not to assume the rounding mode (-frounding-math); so does a LET's zero
    the optimiser propagates."""
    rb = RuleBase.from_text("LET z = 0\n"
                            "RULE 1: IF 1 > 0 THEN q1 += 0 - |xd|, q2 += z - |yd|, q3 -= |xd| - 0",
                            3, (100.0,) * 3)
    fn = native.native_step(rb)
    for x in (0.0, -0.0, 1.0, math.nan):
        args = rb.arguments(np.array([x, x, 0.0]), markers([0, 0, 0], [0, 0, 0]), [0, 0, 0])
        _assert_same(fn, rb, args)


def test_powers_of_ordinary_numbers_are_libms_as_in_python():
    """Powers the C compiler could rewrite (x ^ -1 into 1 / x, a power that folds to 2 into a
    product, a constant to a constant power into its exact value) call libm's pow as Python
    does: bit for bit on 20000 doubles of every magnitude (libm's pow and the exact value part
    by an ulp about once in 400 calls here)."""
    rb = RuleBase.from_text("LET two = 1 + 1\n"
                            "RULE 1: IF 1 > 0 THEN q1 += xd ^ (-1) + yd ^ (1 + 1) * 0,"
                            " q2 += xd ^ two + 1.795840980948305 ^ 3 * yd\n"
                            "RULE 2: IF 1 > 0 THEN q3 += |xd| ^ 0.5 + xd ^ 3", 3, (100.0,) * 3)
    fn = native.native_step(rb)
    rng = np.random.default_rng(8)
    values = rng.uniform(1.0, 2.0, 20000) * 2.0 ** rng.integers(-60, 60, 20000) \
        * rng.choice([-1.0, 1.0], 20000)
    for x, y in zip(values, values[::-1]):
        args = rb.arguments(np.array([x, y, 0.0]), markers([0, 0, 0], [0, 0, 0]), [0, 0, 0])
        assert _exactly(fn(*args)) == _exactly(rb.compiled(*args)), (x, y)


def test_rule_numbers_keep_their_references():
    """The C function hands out the module's own rule-number objects: each call's result takes
    a reference and gives it back (a number too large for CPython's shared small ints)."""
    import sys

    rb = RuleBase.from_text("RULE 123456789012: IF xd > 0 THEN q1 += xd\n"
                            "RULE 98765432109876: IF xd < 0 THEN OUT_OF_REACH", 1, (100.0,))
    fn = native.native_step(rb)
    number = fn(*([1.0] + [0.0] * (len(rb.argument_names) - 1)))[1][0]
    out = fn(*([-1.0] + [0.0] * (len(rb.argument_names) - 1)))[1][0]
    before = sys.getrefcount(number), sys.getrefcount(out)
    for x in (1.0, -1.0) * 5000:
        fn(*([x] + [0.0] * (len(rb.argument_names) - 1)))
    assert (number, out) == (123456789012, 98765432109876)
    assert (sys.getrefcount(number), sys.getrefcount(out)) == before


def test_the_rule_files_name_never_reaches_the_c_source():
    """A path is not C: one that closes a comment and carries code compiles as nothing."""
    rb = RuleBase.from_text("RULE 1: IF xd > 0 THEN q1 += xd", 1, (100.0,),
                            source="*/ int injected = 1; /*\n#error injected")
    text = native.module_source([rb], "itg_native_x")
    assert "injected" not in text
    assert native.native_step(rb)(*([2.0] + [0.0] * (len(rb.argument_names) - 1))) == ([2.0], [1])


def test_an_unusable_cache_builds_for_the_process_and_says_so(tmp_path, monkeypatch, capsys):
    """A cache folder that cannot be made, or a cached module that cannot be loaded, used to be
    NativeUnavailable: bench speed then timed the Python step alone and printed the C target
    NOT met. The module is now built in a temporary folder of the process's own, and a note
    says which cache could not be used and why."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("ITG_VISION_CACHE", str(blocker / "cache"))
    monkeypatch.setattr(native, "_loaded", {})
    rb = RuleBase.from_text("RULE 1: IF xd > 0 THEN q1 += 5 * xd", 1, (100.0,))
    args = [2.0] + [0.0] * (len(rb.argument_names) - 1)
    assert native.native_step(rb)(*args) == rb.compiled(*args)
    err = capsys.readouterr().err
    assert f"note: the compiled-rules cache {blocker / 'cache' / 'native'} cannot be used" in err
    assert f"building in {native._scratch_dir()} for this run" in err
    monkeypatch.setenv("ITG_VISION_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(native, "_loaded", {})
    native.native_step(rb)
    (built,) = (tmp_path / "cache" / "native").glob("itg_native_*")
    broken = tmp_path / "broken" / "native" / built.name
    broken.parent.mkdir(parents=True)
    broken.write_bytes(b"not a shared object")
    monkeypatch.setenv("ITG_VISION_CACHE", str(tmp_path / "broken"))
    monkeypatch.setattr(native, "_loaded", {})
    assert native.native_step(rb)(*args) == rb.compiled(*args)
    assert "cannot be used" in capsys.readouterr().err


def test_the_c_function_is_plain_c99_of_doubles():
    """The portable part (what a microcontroller port takes) names no Python API."""
    arm = ArmSpec.from_args("two-link")
    rb = load_rules(arm.defaults["itg_plus_rules"], 2, arm.links_mm, S=20.0)
    text = native.c_function(rb)
    assert text.startswith("static int itg_rules(const double *in, double *dq, int *fired, int *n_fired)")
    assert "Py" not in text and "sqrt" not in text and "atan" not in text and "sin(" not in text


def test_the_c_source_compiles_alone_as_c99(tmp_path):
    """c_source is a whole C99 file: the function and the helpers it calls, nothing implicit."""
    arm = ArmSpec.from_args("two-link")
    rb = load_rules(arm.defaults["itg_plus_rules"], 2, arm.links_mm, S=20.0)
    (tmp_path / "rules.c").write_text(native.c_source(rb))
    res = subprocess.run([*native.compiler(), "-std=c99", "-pedantic-errors",
                          "-Werror=implicit-function-declaration", "-c", "rules.c", "-o", "rules.o"],
                         cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert native.c_source(rb).endswith(native.c_function(rb))


def test_bad_arguments_are_refused_like_a_python_function():
    rb = RuleBase.from_text("RULE 1: IF xd > 0 THEN q1 += xd", 1, (100.0,))
    fn = native.native_step(rb)
    with pytest.raises(TypeError, match=f"takes {len(rb.argument_names)} arguments"):
        fn(1.0)
    with pytest.raises(TypeError):
        fn(*(["a"] + [0.0] * (len(rb.argument_names) - 1)))
    assert fn(*([2.0] + [0.0] * (len(rb.argument_names) - 1))) == ([2.0], [1])
    assert fn(*([2] + [0] * (len(rb.argument_names) - 1))) == ([2.0], [1])  # ints are numbers, as in Python

    class Reading:  # not a float: read through its __float__
        def __float__(self):
            return 2.5

    # floats are read directly, the rest converted: each kind gives its own value
    assert fn(*([np.float64(2.25)] + [0.0] * (len(rb.argument_names) - 1))) == ([2.25], [1])
    assert fn(*([Reading()] + [0.0] * (len(rb.argument_names) - 1))) == ([2.5], [1])


def test_modules_are_cached_by_source_and_a_failed_build_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("ITG_VISION_CACHE", str(tmp_path))
    monkeypatch.setattr(native, "_loaded", {})
    rb = RuleBase.from_text("RULE 1: IF xd > 0 THEN q1 += 2 * xd", 1, (100.0,))
    fn = native.native_step(rb)
    built = sorted((tmp_path / "native").iterdir())
    assert len(built) == 1 and fn(*([2.0] + [0.0] * (len(rb.argument_names) - 1))) == ([4.0], [1])

    monkeypatch.setattr(native, "_loaded", {})  # a new process: the module comes from the cache
    monkeypatch.setattr(native, "_compile", lambda *a: pytest.fail("compiled again"))
    assert native.native_step(rb)(*([2.0] + [0.0] * (len(rb.argument_names) - 1))) == ([4.0], [1])

    monkeypatch.undo()
    monkeypatch.setenv("ITG_VISION_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", "false")  # a compiler that fails
    other = RuleBase.from_text("RULE 1: IF xd > 0 THEN q1 += 3 * xd", 1, (100.0,))
    with pytest.raises(native.NativeUnavailable, match=r"C compiler false failed \(exit 1\)"):
        native.native_step(other)
    assert sorted((tmp_path / "native").iterdir()) == built  # no partial module, no build folder

    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    with pytest.raises(native.NativeUnavailable, match="no C compiler: .*no-such-cc.* not found"):
        native.native_step(other)


def test_bench_speed_times_the_steps_compiled_to_c():
    """`bench speed` times the C functions tested above, beside the Python ones."""
    from itg_vision.bench.speed import decision_costs

    c = decision_costs(n_points=30, repeat=1)
    assert c["native_error"] is None
    assert all(c[k] > 0 for k in ("rules_native_us", "itg_plus_native_us", "call_native_us",
                                  "itg_plus_compiled_us", "ik_pybullet_us"))
    # each IK call starts at the previous set point's solution and lands nearer its own set
    # point than that start (the spacing of the 30 set points)
    pts = traj.named("ellipse-t1", 30).points_mm
    spacing = np.linalg.norm(pts - np.roll(pts, 1, axis=0), axis=1)
    assert c["ik_pybullet_miss_mm"].shape == (30,) and np.all(c["ik_pybullet_miss_mm"] < spacing)


def test_bench_speed_names_the_machine_its_timings_ran_on():
    import os

    from itg_vision.bench.speed import machine_line

    line = machine_line()
    assert line.startswith("machine: ") and f", {os.cpu_count()} cores, load average " in line
    assert "; Python " in line and "; C compiler " in line
