"""ITG+ in the runner and the benchmarks (issue 13): S follows the servo limit, the ITG+
controllers run in the noise benchmark under the same limits as every other controller, and
the targets table's verdicts come from its thresholds."""

from __future__ import annotations

import pytest

from itg_vision.arm import ArmSpec
from itg_vision.bench.sweep import CONTROLLERS, build_sweep
from itg_vision.errors import ConfigError
from itg_vision.runner import RULE_DEFAULTS, RunConfig, prepare


@pytest.mark.parametrize("arm", ["one-link", "two-link", "three-link"])
def test_itg_plus_step_is_the_servo_limit_of_the_arm_file_by_default(arm):
    spec = ArmSpec.from_args(arm)
    prep = prepare(RunConfig(arm=arm, rules=spec.defaults["itg_plus_rules"], feedback="model"))
    servo = float(spec.benchmark["max_step_deg"])
    assert prep.config.max_step_deg == servo  # the loop applies it too
    assert prep.controller.S == servo and prep.info["controller_params"]["step_deg"] == servo
    assert "data/arms/" in prep.info["servo_limit"]


def test_itg_plus_step_follows_a_given_servo_limit_and_refuses_another_step():
    prep = prepare(RunConfig(rules="itg-plus-two-link", feedback="model", max_step_deg=7.0))
    assert prep.controller.S == 7.0 and prep.config.max_step_deg == 7.0
    assert prepare(RunConfig(rules="itg-plus-two-link", feedback="model", max_step_deg=7.0,
                             step_deg=7.0)).controller.S == 7.0  # repeating it is fine
    with pytest.raises(ConfigError) as exc:
        prepare(RunConfig(rules="itg-plus-two-link", feedback="model", step_deg=5.0))
    assert exc.value.field == "step_deg" and "servo limit" in str(exc.value)


def test_the_paper_rules_keep_their_own_step():
    prep = prepare(RunConfig(arm="one-link", feedback="model", max_step_deg=20.0))
    assert prep.controller.S == RULE_DEFAULTS["step_deg"] and not prep.controller.servo_step


def test_run_help_lists_the_itg_plus_rule_bases(cli):
    res = cli("itg_vision.run", "--help")
    text = "".join(res.stdout.split())  # argparse wraps at hyphens
    for name in ("itg-plus-one-link", "itg-plus-two-link", "itg-plus-three-link"):
        assert name in text


def test_itg_plus_runs_in_every_table_under_the_same_limits_as_the_others():
    specs = build_sweep(seeds=1)  # the full robustness sweep's definition (nothing runs)
    assert {"itg-plus-vision", "itg-plus-model"} <= set(CONTROLLERS)
    by_traj: dict = {}
    for s in specs:
        by_traj.setdefault(s.trajectory, set()).add((s.max_step_deg, s.iterations))
        if s.controller.startswith("itg-plus"):
            assert s.rules == ArmSpec.from_args(s.arm).defaults["itg_plus_rules"]
    for traj, limits in by_traj.items():
        arm = ArmSpec.from_args(next(s.arm for s in specs if s.trajectory == traj))
        assert limits == {(float(arm.benchmark["max_step_deg"]), int(arm.benchmark["iterations"]))}
    cells = {(s.trajectory, s.condition, s.controller) for s in specs}
    for t, c, k in cells:
        if k == "itg-vision":
            assert (t, c, "itg-plus-vision") in cells and (t, c, "itg-plus-model") in cells
