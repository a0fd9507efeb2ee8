"""Every bad input: exit 2, one line on stderr naming the file, line and column or the field or
option, no traceback, nothing touched. Table-driven, each command called in-process."""

import copy
import json
import os
import random
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from itg_vision import calibrate, paper, run
from itg_vision.arm import ARMS_DIR, ArmSpec, load_arm
from itg_vision.bench import __main__ as bench
from itg_vision.bench import noise
from itg_vision.camera import CAMERAS_DIR
from itg_vision.errors import UserError
from itg_vision.inputs import read_yaml
from itg_vision.rules import RULES_DIR

COMMANDS = {"run": run.main, "paper": paper.main, "calibrate": calibrate.main,
            "noise": noise.main, "bench": bench.main}

TWO_LINK_Q2 = "\nRULE 9: IF yd > yg THEN q2 += S\n"  # so the rule base moves both joints


def _rig(tmp, name, change):
    doc = yaml.safe_load((CAMERAS_DIR / "planar.yaml").read_text())
    doc = copy.deepcopy(doc)
    change(doc)
    path = tmp / f"rig-{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _set(cam, **kw):
    def change(doc):
        doc["cameras"][cam].update(kw)
    return change


def _pose(cam, **kw):
    def change(doc):
        doc["cameras"][cam]["pose"].update(kw)
    return change


def _fx(value):
    def change(doc):
        doc["cameras"][1]["camera_matrix"]["data"][0] = value
    return change


def _tiny(doc):
    for c in doc["cameras"]:
        c.update(image_width=4, image_height=3)
        c["camera_matrix"]["data"] = [3.75, 0, 1.5, 0, 3.75, 1.0, 0, 0, 1]


def _below(doc):
    for c in doc["cameras"]:
        c["pose"]["position_mm"][2] = -620.0


#: Bad arm files: (name, a line of data/arms/two-link.yaml (regex), what replaces it).
ARM_EDITS = [
    ("last-link-5", r"^links_mm:.*$", "links_mm: [100, 5]"),
    ("ranges-5", r"^pose_ranges_deg:.*$", "pose_ranges_deg: 5"),
    ("ranges-empty", r"^pose_ranges_deg:.*$", "pose_ranges_deg:"),
    ("ranges-reversed", r"^pose_ranges_deg:.*$", "pose_ranges_deg: [[-180, 180], [150, -150]]"),
    ("start-1-angle", r"^start_pose_deg:.*$", "start_pose_deg: [90]"),
    ("rules-5", r"^defaults:.*$", "defaults: {rules: 5, rig: planar, trajectory: ellipse-t1}"),
    ("trajectory-7", r"^defaults:.*$", "defaults: {rules: table2, rig: planar, trajectory: 7}"),
    ("rules-unknown", r"^defaults:.*$", "defaults: {rules: nosuch, rig: planar, trajectory: ellipse-t1}"),
    ("rig-unknown", r"^defaults:.*$", "defaults: {rules: table2, rig: nosuch, trajectory: ellipse-t1}"),
    ("trajectory-unknown", r"^defaults:.*$", "defaults: {rules: table2, rig: planar, trajectory: circle}"),
    ("trajectory-3d", r"^defaults:.*$", "defaults: {rules: table2, rig: planar, trajectory: line-ab-reach}"),
    ("rules-one-link", r"^defaults:.*$", "defaults: {rules: table1, itg_plus_rules: itg-plus-one-link, rig: planar, trajectory: ellipse-t1}"),
    ("rig-list", r"^defaults:.*$", "defaults: {rules: table2, rig: [a], trajectory: ellipse-t1}"),
    ("servo-abc", r"^benchmark:.*$", "benchmark: {max_step_deg: abc, iterations: 1}"),
    ("servo-quoted", r"^benchmark:.*$", "benchmark: {max_step_deg: '1e1', iterations: 1}"),
    ("duplicate-key", r"^name:.*$", "name: two-link\nname: other"),
    ("duplicate-flow-key", r"^benchmark:.*$", "benchmark: {max_step_deg: 20, max_step_deg: 5, iterations: 1}"),
    ("servo-negative", r"^benchmark:.*$", "benchmark: {max_step_deg: -5, iterations: 1}"),
    ("servo-zero", r"^benchmark:.*$", "benchmark: {max_step_deg: 0, iterations: 1}"),
    ("servo-nan", r"^benchmark:.*$", "benchmark: {max_step_deg: .nan, iterations: 1}"),
    ("iterations-0", r"^benchmark:.*$", "benchmark: {max_step_deg: 20, iterations: 0}"),
    ("iterations-half", r"^benchmark:.*$", "benchmark: {max_step_deg: 20, iterations: 1.5}"),
    ("name-newline", r"^name:.*$", "name: \"two\\nlines\""),
    ("unknown-field", r"^kind:.*$", "kind: planar\ncolour: red"),
    ("sweep-poses-0", r"poses: 23, pose_deg: \[90, null\]", "poses: 0, pose_deg: [90, null]"),
    ("standoff-5000-digits", r"^led_standoff_mm:.*$", "led_standoff_mm: " + "9" * 5000),
    ("standoff-nested", r"^led_standoff_mm:.*$", "led_standoff_mm: " + "[" * 2000 + "]" * 2000),
    ("standoff-true", r"^led_standoff_mm:.*$", "led_standoff_mm: true"),
    ("standoff-5001", r"^led_standoff_mm:.*$", "led_standoff_mm: 5001"),
    ("kind-typo", r"^kind:.*$", "kind: planer"),
    ("planar-3-links", r"^links_mm:.*$", "links_mm: [100, 100, 100]"),
    ("no-base-sweep", r"^    - \{joint: 1,.*\n", ""),
    ("base-swept-twice", r"\{joint: 2, from_deg", "{joint: 1, from_deg"),
    ("elbow-on-the-last-joint", r"pose_deg: \[90, null\], markers: \[gripper\]",
     "pose_deg: [90, null], markers: [elbow, gripper]"),
]


def make_inputs(tmp):
    """The bad files of the table, by name."""
    f = {}

    def text(name, body, encoding="utf-8"):
        f[name] = tmp / name
        f[name].write_text(body, encoding=encoding)

    f["binary.rules"] = tmp / "binary.rules"
    f["binary.rules"].write_bytes(b"RULE 1: IF xd > xg THEN q1 += S\n\x86\xff\x00garbage")
    text("deep.rules", "RULE 1: IF " + "(" * 300 + "xd > xg" + ")" * 300 + " THEN q1 += S" + TWO_LINK_Q2)
    text("nots.rules", "RULE 1: IF " + "NOT " * 3000 + "xd > xg THEN q1 += S" + TWO_LINK_Q2)
    text("minus.rules", "RULE 1: IF xd > xg THEN q1 += " + "-" * 60 + "S" + TWO_LINK_Q2)
    text("powers.rules", "RULE 1: IF xd > xg THEN q1 += " + "1^" * 60 + "1" + TWO_LINK_Q2)
    text("sum.rules", "RULE 1: IF xd > xg THEN q1 += " + " + ".join(["S"] * 200) + TWO_LINK_Q2)
    text("digits.rules", "RULE 1: IF xd > xg THEN q1 += " + "9" * 5000 + TWO_LINK_Q2)
    text("inf.rules", "RULE 1: IF xd > xg THEN q1 += 1e999" + TWO_LINK_Q2)
    for name, step in (("div0", "f / 0"), ("zero-pow", "0 ^ -1"), ("big-pow", "10 ^ 400"),
                       ("overflow", "1e308 * 10")):
        text(f"{name}.rules", f"RULE 1: IF 1 > 0 THEN q1 += {step}" + TWO_LINK_Q2)
    text("complex.rules", "RULE 1: IF 1 > 0 THEN q1 -= (xg - xd - 1000) ^ 0.5" + TWO_LINK_Q2)
    f["binary.yaml"] = tmp / "binary.yaml"
    f["binary.yaml"].write_bytes(bytes(range(256)) * 4)
    text("syntax.yaml", "name: x\ncameras:\n  - name: [left\n")
    text("digits.yaml", "name: x\ncameras: " + "7" * 5000 + "\n")
    text("nested.yaml", "[" * 3000 + "]" * 3000)
    f["rig-fx-huge"] = _rig(tmp, "fx-huge", _fx(1e300))

    def shape(key, **kw):
        def change(doc):
            doc["cameras"][0][key].update(kw)
        return change
    f["rig-km-2x3"] = _rig(tmp, "km-2x3", shape("camera_matrix", rows=2))
    f["rig-dist-1x4"] = _rig(tmp, "dist-1x4", shape("distortion_coefficients", cols=4))
    f["rig-rows-text"] = _rig(tmp, "rows-text", shape("camera_matrix", rows="three"))
    f["rig-km-9x1"] = _rig(tmp, "km-9x1", shape("camera_matrix", rows=9, cols=1))
    f["rig-km-colls"] = _rig(tmp, "km-colls", shape("camera_matrix", colls=3))
    f["rig-same-place"] = _rig(tmp, "same-place", _pose(1, position_mm=[-180.0, -60.0, 620.0]))
    f["rig-40000x30000"] = _rig(tmp, "40000x30000", _set(0, image_width=40000, image_height=30000))
    f["rig-away"] = _rig(tmp, "away", _pose(0, look_at_mm=[-180.0, -60.0, 1620.0]))

    def two_line_name(doc):  # a block scalar (name: |) keeps its newline
        doc["cameras"][0]["name"] = "left\n"
        doc["cameras"][0]["pose"]["look_at_mm"] = [-180.0, -60.0, 1620.0]
    f["rig-name-newline"] = _rig(tmp, "name-newline", two_line_name)
    f["rig-rig-name-newline"] = _rig(tmp, "rig-name-newline",
                                     lambda doc: doc.update(name="planar\nrig"))
    f["rig-below"] = _rig(tmp, "below", _below)
    f["rig-4x3"] = _rig(tmp, "4x3", _tiny)
    f["rig-fx-tiny"] = _rig(tmp, "fx-tiny", _fx(1e-12))
    f["rig-dark"] = _rig(tmp, "dark", _set(0, sensor={"noise_sigma_gray": 2.0, "exposure": 1e-9}))
    f["rig-bright"] = _rig(tmp, "bright", _set(0, sensor={"noise_sigma_gray": 2.0, "exposure": 1e300}))
    f["rig-noisy"] = _rig(tmp, "noisy", _set(0, sensor={"noise_sigma_gray": 1e300}))
    f["rig-fold"] = _rig(tmp, "fold", _set(0, distortion_coefficients=[-5.0, 0, 0, 0, 0]))
    f["rig-spin"] = _rig(tmp, "spin", _set(1, pose={"position_mm": [180, -60, 620],
                                                     "rotation_deg": [1e300, 0, 0]}))
    f["bom-bad.csv"] = tmp / "bom-bad.csv"
    f["bom-bad.csv"].write_text("x_mm,y_mm\n10,twenty\n", encoding="utf-8-sig")
    text("elbow.rules", "RULE 1: IF xg > xd THEN q1 -= S\nRULE 2: IF re2 > xd THEN q1 += S\n")
    text("q2.rules", "RULE 1: IF xg > xd THEN q1 -= S, q2 HOLD\n")
    text("unreachable.csv", "x_mm,y_mm\n500,500\n510,500\n")
    text("digits.csv", "x_mm,y_mm\n" + "1" * 5000 + ",20\n30,40\n")
    f["binary.csv"] = tmp / "binary.csv"
    f["binary.csv"].write_bytes(b"x_mm,y_mm\n1,2\n\xc3\x28,4\n")
    text("path-3d.csv", "x_mm,y_mm,z_mm\n95,40,160\n94.9,42.2,160.4\n")
    text("path-2d.csv", "x_mm,y_mm\n100,5\n120,50\n")  # in the three-link arm's reach too
    text("helix-in-m.csv", "x_mm,y_mm,z_mm\n0.095,0.04,0.16\n0.0949,0.0422,0.1604\n")
    text("arm-two-fields.yaml", "name: mine\nkind: planar\n")
    text("not-rig.yaml", "just: text\n")
    text("rig-duplicate-key.yaml", "name: x\ncameras: []\ncameras: []\n")
    text("negative-standoff.yaml", re.sub(r"(?m)^led_standoff_mm: .*$", "led_standoff_mm: -3",
                                          (ARMS_DIR / "two-link.yaml").read_text()))
    text("lost-true-rig.yaml", (ARMS_DIR.parent.parent / "cameras" / "planar.yaml").read_text()
         + "true_rig: nosuch.yaml\n")
    (tmp / "held").mkdir()  # an output folder of one's own, an input kept in it
    text("held/rig.yaml", (ARMS_DIR.parent.parent / "cameras" / "planar.yaml").read_text())
    two_link = (ARMS_DIR / "two-link.yaml").read_text()
    for name, line, bad in ARM_EDITS:
        body, n = re.subn(line, lambda m: bad, two_link, flags=re.M)
        assert n == 1, name  # the shipped file changed: mend the edit
        text(f"arm-{name}.yaml", body)
    f["folder"] = tmp / "a-folder"
    f["folder"].mkdir()
    (f["folder"] / "thesis.tex").write_text("keep me")
    f["file"] = tmp / "notes.txt"
    f["file"].write_text("keep me")
    f["paper-out"] = tmp / "paper-made"
    f["paper-out"].mkdir()
    (f["paper-out"] / ".itg_vision-output.json").write_text(
        '{"made_by": "itg_vision", "command": "paper", "version": "0"}')
    return {k: str(v) for k, v in f.items()}


RUN = ["--quiet", "--feedback", "model"]
# (id, command, argv with {file} placeholders, what the one line must contain; an expect
# ending in a newline is the line's end, and from its file's name on, the whole message)
CASES = [
    # rule files
    ("rules-binary", "run", RUN + ["--rules", "{binary.rules}"], "binary.rules:2:1: not UTF-8"),
    ("rules-deep", "run", RUN + ["--rules", "{deep.rules}"], "deep.rules:1:62: nested too deeply"),
    ("rules-not-chain", "run", RUN + ["--rules", "{nots.rules}"], "nots.rules:1:4000: RULE is longer than 1000 tokens"),
    ("rules-minus-chain", "run", RUN + ["--rules", "{minus.rules}"], "minus.rules:1:81: nested too deeply"),
    ("rules-power-chain", "run", RUN + ["--rules", "{powers.rules}"], "powers.rules:1:132: nested too deeply"),
    ("rules-long-sum", "run", RUN + ["--rules", "{sum.rules}"], "sum.rules:1:229: nested too deeply"),
    ("rules-5000-digits", "run", RUN + ["--rules", "{digits.rules}"], "digits.rules:1:31: number 99999"),
    ("rules-1e999", "run", RUN + ["--rules", "{inf.rules}"], "inf.rules:1:31: number 1e999 is out of range"),
    ("rules-div-zero", "run", RUN + ["--rules", "{div0.rules}"], "div0.rules:1: RULE 1 gives q1 a step of inf deg (f = 0.5)"),
    ("rules-0^-1", "run", RUN + ["--rules", "{zero-pow.rules}"], "RULE 1 gives q1 a step of inf deg (constants only)"),
    ("rules-10^400", "run", RUN + ["--rules", "{big-pow.rules}"], "RULE 1 gives q1 a step of inf deg"),
    ("rules-overflow", "run", RUN + ["--rules", "{overflow.rules}"], "RULE 1 gives q1 a step of inf deg"),
    ("rules-complex", "run", RUN + ["--rules", "{complex.rules}"], "RULE 1 gives q1 a step of nan deg (xg = "),
    ("gain-1e308", "run", RUN + ["--gain", "1e308"], "--gain: must be in (0, 1e6] deg/mm, got 1e+308"),
    ("correction-0", "run", RUN + ["--correction", "0"], "--correction: must be in (0, 1], got 0.0"),
    ("correction-nan", "run", RUN + ["--correction", "nan"], "--correction: must be in (0, 1], got nan"),
    ("correction-with-ik", "run", RUN + ["--controller", "ik", "--correction", "0.5"], "--correction: applies to the closed-loop controllers (itg, jacobian); ik is open loop"),
    ("max-step-400", "run", RUN + ["--max-step", "400"], "--max-step: must be in (0, 360] deg per iteration (as an arm file's benchmark.max_step_deg), got 400.0\n"),
    ("preview-no-servo-limit", "run", RUN + ["--controller", "jacobian", "--preview"], "--preview: plans under the servo limit: set max_step_deg (--max-step)"),
    ("preview-three-link", "run", RUN + ["--arm", "three-link", "--preview"], "--preview: plans for a planar two-link arm (its gripper slides along a line through the base); arm three-link is not"),
    ("gain-with-ik", "run", RUN + ["--controller", "ik", "--gain", "0.3"], "--gain: the ik controller takes no f"),
    ("step-unused", "run", RUN + ["--step", "3"], "table2.rules never uses S"),
    ("step-is-the-servo-limit", "run", RUN + ["--rules", "itg-plus-two-link", "--max-step", "10", "--step", "3"], "itg-plus-two-link.rules: S is the servo limit (10 deg per iteration): set the servo limit instead (max_step_deg; run's --max-step)"),
    ("rig-true-rig-missing", "run", ["--quiet", "--rig", "{lost-true-rig.yaml}"], "lost-true-rig.yaml: true_rig: nosuch.yaml: no such file, read from this file's folder ("),
    # a rule base naming a link, a joint or the elbow the arm lacks: one for another arm, as
    # one that leaves a joint unmoved (the next case) is said to be
    ("rules-elbow-one-link", "run", RUN + ["--arm", "one-link", "--rules", "{elbow.rules}"], "elbow.rules:2:12: 're2' reads the elbow LED, but a one-link arm has no elbow: a rule base for another arm? (its rules are for an arm of 2 joints or more, this one has 1; shipped: table1 (one-link), "),
    ("rules-table2-one-link", "run", RUN + ["--arm", "one-link", "--rules", "table2"], "table2.rules:18:24: 'L2' is link 2's length, but only 1 link length(s) were given (links_mm): a rule base for another arm? (its rules are for an arm of 2 joints or more, this one has 1; shipped: "),
    ("rules-three-link-two-link", "run", RUN + ["--rules", "three-link"], "three-link.rules:22:38: 'L3' is link 3's length, but only 2 link length(s) were given (links_mm): a rule base for another arm? (its rules are for an arm of 3 joints or more, this one has 2; shipped: "),
    ("rules-q2-one-link", "run", RUN + ["--arm", "one-link", "--rules", "{q2.rules}"], "q2.rules:1:34: RULE 1 holds q2, but the arm has 1 joint(s): a rule base for another arm? (its rules are for an arm of 2 joints or more"),
    # every vision-only option is named as given: --strobe was 'strobe: applies to ...'
    ("strobe-model", "run", RUN + ["--strobe"], "error: --strobe: applies to vision feedback only\n"),
    ("full-frame-model", "run", RUN + ["--full-frame"], "error: --full-frame: applies to vision feedback only\n"),
    ("allow-unseen-model", "run", RUN + ["--allow-unseen"], "error: --allow-unseen: applies to vision feedback only\n"),
    ("rules-table1-two-link", "run", RUN + ["--rules", "table1"], "table1.rules: no rule moves or holds q2 of this 2-joint arm"),
    ("rules-dev-zero", "run", RUN + ["--rules", "/dev/zero"], "/dev/zero: rule file larger than 1024 KiB"),
    ("rules-folder", "run", RUN + ["--rules", "{folder}"], "a-folder: is a folder, not a rule file"),
    ("rules-empty", "run", RUN + ["--rules", ""], "--rules: is empty: name a rule base or give a file's path"),
    ("trajectory-empty", "run", RUN + ["--trajectory", ""], "--trajectory: is empty: name a trajectory or give a file's path"),
    ("rig-empty", "run", ["--quiet", "--rig", ""], "--rig: is empty: name a rig or give a file's path"),
    # rig files (vision feedback, the default)
    ("rig-binary", "run", ["--quiet", "--rig", "{binary.yaml}"], "binary.yaml:2:118: not UTF-8 text (byte 0x80)"),
    ("rig-yaml-syntax", "run", ["--quiet", "--rig", "{syntax.yaml}"], "syntax.yaml:4:1: not valid YAML (expected ',' or ']'"),
    ("rig-5000-digit-int", "run", ["--quiet", "--rig", "{digits.yaml}"], "digits.yaml:2:10: not valid YAML (a number of more than 4300 digits)"),
    ("rig-nested", "run", ["--quiet", "--rig", "{nested.yaml}"], "nested.yaml: nested too deeply"),
    ("arm-most-fields-missing", "run", ["--quiet", "--arm", "{arm-two-fields.yaml}"], "arm-two-fields.yaml: links_mm: missing (and led_standoff_mm, start_pose_deg, defaults, pose_ranges_deg, benchmark, calibration)\n"),
    ("arm-negative-standoff", "run", ["--quiet", "--arm", "{negative-standoff.yaml}"], "negative-standoff.yaml: led_standoff_mm: must be in [0, 5000] (mm), got -3"),
    ("rig-not-a-rig", "run", ["--quiet", "--rig", "{not-rig.yaml}"], "not-rig.yaml: name: missing"),
    # arm files: every field checked when the file is read
    ("arm-pose-ranges-5", "run", RUN + ["--arm", "{arm-ranges-5.yaml}"], "arm-ranges-5.yaml: pose_ranges_deg: must be a list of 2 [lo, hi] ranges in deg (one per joint), got 5"),
    ("arm-pose-ranges-empty", "run", RUN + ["--arm", "{arm-ranges-empty.yaml}"], "arm-ranges-empty.yaml: pose_ranges_deg: must be a list of 2 [lo, hi] ranges in deg (one per joint), got None"),
    ("arm-pose-ranges-5-accuracy", "bench", ["accuracy", "--arm", "{arm-ranges-5.yaml}", "--poses", "5"], "arm-ranges-5.yaml: pose_ranges_deg: must be a list of 2"),
    ("arm-pose-range-reversed", "run", RUN + ["--arm", "{arm-ranges-reversed.yaml}"], "arm-ranges-reversed.yaml: pose_ranges_deg[1]: lo must be <= hi, got [150, -150]"),
    ("arm-start-pose-1-angle", "run", RUN + ["--arm", "{arm-start-1-angle.yaml}"], "arm-start-1-angle.yaml: start_pose_deg: must be a list of 2 angles in deg (one per joint), got 1 value"),
    ("arm-default-rules-5", "run", RUN + ["--arm", "{arm-rules-5.yaml}"], "arm-rules-5.yaml: defaults.rules: must be a name or a path on one line, got 5"),
    ("arm-default-trajectory-7", "run", RUN + ["--arm", "{arm-trajectory-7.yaml}"], "arm-trajectory-7.yaml: defaults.trajectory: must be a name or a path on one line, got 7"),
    ("arm-default-rules-unknown", "run", RUN + ["--arm", "{arm-rules-unknown.yaml}"], "arm-rules-unknown.yaml: defaults.rules: no shipped one is called 'nosuch' (shipped: itg-plus-one-link,"),
    ("arm-default-rig-unknown", "run", ["--quiet", "--arm", "{arm-rig-unknown.yaml}"], "arm-rig-unknown.yaml: defaults.rig: no shipped one is called 'nosuch' (shipped: planar, planar.calib, three-link, three-link.calib; or give a file's path)"),
    # a trajectory the file chose is the file's field, not --trajectory (the user gave none)
    ("arm-default-trajectory-3d", "run", RUN + ["--arm", "{arm-trajectory-3d.yaml}"], "arm-trajectory-3d.yaml: defaults.trajectory: line-ab-reach has z values, but arm two-link is planar"),
    ("arm-default-trajectory-unknown", "run", RUN + ["--arm", "{arm-trajectory-unknown.yaml}"], "arm-trajectory-unknown.yaml: defaults.trajectory: no shipped one is called 'circle' (shipped: ellipse-t1,"),
    ("calibrate-arm-default-rules-unknown", "calibrate", ["--quiet", "--arm", "{arm-rules-unknown.yaml}", "--out", "{tmp}/c.yaml"], "arm-rules-unknown.yaml: defaults.rules: no shipped one is called 'nosuch'"),
    # a rule base the arm file chose for another arm: the file's field, not the rule file alone
    ("arm-default-rules-for-another-arm", "run", RUN + ["--arm", "{arm-rules-one-link.yaml}"], "arm-rules-one-link.yaml: defaults.rules: " + str(RULES_DIR / "table1.rules") + ": no rule moves or holds q2 of this 2-joint arm"),
    # ... but one the user gave with --rules is the rule file's error, not the arm file's field
    ("arm-given-rules-for-another-arm", "run", RUN + ["--arm", "{arm-rules-one-link.yaml}", "--rules", "table1"], "error: " + str(RULES_DIR / "table1.rules") + ": no rule moves or holds q2 of this 2-joint arm"),
    # ... and in a sweep, before any run (every itg-plus run failed, after the folder was made)
    ("noise-arm-default-rules-for-another-arm", "noise", ["--quick", "--quiet", "--controllers", "itg-plus-model", "--conditions", "clean", "--seeds", "1", "--arm", "{arm-rules-one-link.yaml}", "--trajectories", "{path-2d.csv}", "--out", "{tmp}/n"], "arm-rules-one-link.yaml: defaults.itg_plus_rules: " + str(RULES_DIR / "itg-plus-one-link.rules") + ": no rule moves or holds q2"),
    ("arm-default-rig-list", "run", ["--quiet", "--arm", "{arm-rig-list.yaml}"], "arm-rig-list.yaml: defaults.rig: must be a name or a path on one line, got ['a']"),
    ("arm-servo-quoted", "run", RUN + ["--arm", "{arm-servo-quoted.yaml}", "--rules", "itg-plus-two-link"], "arm-servo-quoted.yaml: benchmark.max_step_deg: must be a finite number (deg per iteration), got '1e1'"),
    ("arm-duplicate-key", "run", RUN + ["--arm", "{arm-duplicate-key.yaml}"], "arm-duplicate-key.yaml:4:1: not valid YAML (duplicate key 'name' (first at line 3))"),
    ("arm-duplicate-key-flow", "run", RUN + ["--arm", "{arm-duplicate-flow-key.yaml}"], "arm-duplicate-flow-key.yaml:13:31: not valid YAML (duplicate key 'max_step_deg' (first at line 13))"),
    ("rig-duplicate-key", "run", ["--quiet", "--rig", "{rig-duplicate-key.yaml}"], "rig-duplicate-key.yaml:3:1: not valid YAML (duplicate key 'cameras' (first at line 2))"),
    ("arm-servo-abc", "run", RUN + ["--arm", "{arm-servo-abc.yaml}", "--rules", "itg-plus-two-link"], "arm-servo-abc.yaml: benchmark.max_step_deg: must be a finite number (deg per iteration), got 'abc'"),
    ("arm-servo-negative", "run", RUN + ["--arm", "{arm-servo-negative.yaml}"], "arm-servo-negative.yaml: benchmark.max_step_deg: must be in (0, 360] (deg per iteration), got -5"),
    ("arm-servo-zero", "run", RUN + ["--arm", "{arm-servo-zero.yaml}"], "arm-servo-zero.yaml: benchmark.max_step_deg: must be in (0, 360] (deg per iteration), got 0"),
    ("arm-servo-nan", "run", RUN + ["--arm", "{arm-servo-nan.yaml}"], "arm-servo-nan.yaml: benchmark.max_step_deg: must be a finite number (deg per iteration), got nan"),
    ("arm-iterations-0", "run", RUN + ["--arm", "{arm-iterations-0.yaml}"], "arm-iterations-0.yaml: benchmark.iterations: must be a whole number in 1..10000, got 0"),
    ("arm-iterations-1.5", "run", RUN + ["--arm", "{arm-iterations-half.yaml}"], "arm-iterations-half.yaml: benchmark.iterations: must be a whole number in 1..10000, got 1.5"),
    ("arm-name-newline", "run", RUN + ["--arm", "{arm-name-newline.yaml}"], "arm-name-newline.yaml: name: must be a name on one line, got 'two\\nlines'"),
    ("arm-unknown-field", "run", RUN + ["--arm", "{arm-unknown-field.yaml}"], "arm-unknown-field.yaml: colour: unknown field"),
    ("arm-sweep-poses-0", "run", RUN + ["--arm", "{arm-sweep-poses-0.yaml}"], "arm-sweep-poses-0.yaml: calibration.axis_sweeps[1].poses: must be a whole number in 3..1000, got 0"),
    # a bool is no number; a stand-off beyond the links' 5000 mm bound makes no arm
    ("arm-standoff-true", "run", RUN + ["--arm", "{arm-standoff-true.yaml}"], "/arm-standoff-true.yaml: led_standoff_mm: must be a finite number (mm), got True\n"),
    ("arm-standoff-5001", "run", RUN + ["--arm", "{arm-standoff-5001.yaml}"], "/arm-standoff-5001.yaml: led_standoff_mm: must be in [0, 5000] (mm), got 5001\n"),
    ("arm-kind-typo", "run", RUN + ["--arm", "{arm-kind-typo.yaml}"], "/arm-kind-typo.yaml: kind: must be one of planar, yaw-pitch-pitch, got 'planer'\n"),
    ("arm-planar-3-links", "run", RUN + ["--arm", "{arm-planar-3-links.yaml}"], "/arm-planar-3-links.yaml: links_mm: a planar arm has 1 or 2 links, got 3\n"),
    ("arm-no-base-sweep", "run", RUN + ["--arm", "{arm-no-base-sweep.yaml}"], "/arm-no-base-sweep.yaml: calibration.axis_sweeps: must sweep joint 1 (the base: the world's z axis)\n"),
    ("arm-base-swept-twice", "run", RUN + ["--arm", "{arm-base-swept-twice.yaml}"], "/arm-base-swept-twice.yaml: calibration.axis_sweeps[1].joint: joint 1 is swept twice\n"),
    ("arm-elbow-on-the-last-joint", "run", RUN + ["--arm", "{arm-elbow-on-the-last-joint.yaml}"], "/arm-elbow-on-the-last-joint.yaml: calibration.axis_sweeps[1].markers: the elbow LED does not move when joint 2 turns\n"),
    ("arm-5000-digit-int", "run", RUN + ["--arm", "{arm-standoff-5000-digits.yaml}"], "arm-standoff-5000-digits.yaml:6:18: not valid YAML (a number of more than 4300 digits)"),
    ("arm-nested", "run", RUN + ["--arm", "{arm-standoff-nested.yaml}"], "arm-standoff-nested.yaml: nested too deeply to be an arm file"),
    ("rig-dev-zero", "run", ["--quiet", "--rig", "/dev/zero"], "/dev/zero: rig file larger than"),
    ("rig-folder", "run", ["--quiet", "--rig", "{folder}"], "a-folder: is a folder, not a rig file"),
    ("arm-folder", "run", ["--quiet", "--arm", "{folder}"], "a-folder: is a folder, not an arm file"),
    ("rig-fx-1e300", "run", ["--quiet", "--rig", "{rig-fx-huge}"], "cameras[1].camera_matrix: fx must be at most 1e+06 px"),
    ("rig-matrix-2x3", "run", ["--quiet", "--rig", "{rig-km-2x3}"], "rig-km-2x3.yaml: cameras[0].camera_matrix: rows x cols must be 3 x 3, got 2 x 3"),
    # the right count in the wrong shape, and a misspelt key beside the matrix (both ran)
    ("rig-matrix-9x1", "run", ["--quiet", "--rig", "{rig-km-9x1}"], "rig-km-9x1.yaml: cameras[0].camera_matrix: rows x cols must be 3 x 3, got 9 x 1"),
    ("rig-matrix-colls", "run", ["--quiet", "--rig", "{rig-km-colls}"], "rig-km-colls.yaml: cameras[0].camera_matrix.colls: unknown field (known: rows, cols, data)"),
    ("rig-distortion-1x4", "run", ["--quiet", "--rig", "{rig-dist-1x4}"], "rig-dist-1x4.yaml: cameras[0].distortion_coefficients: rows x cols is 1 x 4, but data holds 5 values"),
    ("rig-rows-text", "run", ["--quiet", "--rig", "{rig-rows-text}"], "rig-rows-text.yaml: cameras[0].camera_matrix.rows: must be a whole number in 1..1000, got 'three'"),
    ("rig-same-place", "run", ["--quiet", "--rig", "{rig-same-place}"], "cameras[1].pose: at the same place as cameras[0]"),
    ("rig-40000x30000", "run", ["--quiet", "--rig", "{rig-40000x30000}"], "cameras[0]: a 40000 x 30000 px image needs about 72 GB"),
    # a camera's name is quoted in messages: on two lines, so was the message
    ("rig-camera-name-newline", "run", ["--quiet", "--rig", "{rig-name-newline}"], "rig-name-newline.yaml: cameras[0].name: must be a name on one line, got 'left\\n'\n"),
    ("rig-name-newline", "run", ["--quiet", "--rig", "{rig-rig-name-newline}", "--points", "3"], "rig-rig-name-newline.yaml: name: must be a name on one line, got 'planar\\nrig'\n"),
    ("rig-looking-away", "run", ["--quiet", "--rig", "{rig-away}"], "cameras[0] (left): cannot see the gripper LED"),
    ("rig-below-floor", "run", ["--quiet", "--rig", "{rig-below}"], "cameras[0] (left): is below the floor"),
    ("rig-4x3-px", "run", ["--quiet", "--rig", "{rig-4x3}"], "cameras[0] (left): cannot see the gripper LED"),
    ("rig-fx-1e-12", "run", ["--quiet", "--rig", "{rig-fx-tiny}"], "cameras[1].camera_matrix: fx = 1e-12 px gives a field of view of 180 deg"),
    ("rig-exposure-1e-9", "run", ["--quiet", "--rig", "{rig-dark}"], "cameras[0] (left): exposure 1e-09"),
    ("rig-exposure-1e300", "run", ["--quiet", "--rig", "{rig-bright}"], "cameras[0].sensor.exposure: must be in (0, 1000], got 1e+300"),
    ("rig-noise-1e300", "run", ["--quiet", "--rig", "{rig-noisy}"], "cameras[0].sensor.noise_sigma_gray: must be in [0, 255]"),
    ("rig-lens-folds", "run", ["--quiet", "--rig", "{rig-fold}"], "cameras[0].distortion_coefficients: the lens model folds back inside the image"),
    ("rig-rotation-1e300", "run", ["--quiet", "--rig", "{rig-spin}"], "cameras[1].pose.rotation_deg: each must be within +-3600 deg"),
    # a start-up measurement that fails names its cause, and the option that set it
    ("start-up-dropout-1", "run", ["--quiet", "--dropout", "1"], "with the base at -150 deg (missed: dropped at random (--dropout 1): 50 looks); the base axis needs 3 of the sweep's 11 poses covering 120 deg of arc, and the LEDs were seen at 0; the arm's lengths cannot be measured"),
    ("start-up-noise-1e6-px", "run", ["--quiet", "--noise-px", "1e6"], "(missed: reprojection residual above 2 px (--noise-px 1e+06): 50 looks)"),
    ("start-up-rig-sees-another-arm", "run", ["--quiet", "--arm", "three-link", "--rig", "planar"], "cameras/planar.yaml (--rig), arm three-link: start-up measurement: the LEDs were measured in only 0 of 50 observations leaned"),
    ("start-up-names-allow-unseen", "run", ["--quiet", "--dropout", "1"], "the arm's lengths cannot be measured (--allow-unseen runs on the nominal model's lengths instead)"),
    ("arm-file-last-shorter-than-an-led", "run", ["--quiet", "--arm", "{arm-last-link-5.yaml}"], "arm-last-link-5.yaml): its last link, 5 mm (links_mm or --links), is shorter than an LED's diameter"),
    ("links-last-shorter-than-an-led", "run", ["--quiet", "--links", "100,10"], "arm two-link: its last link, 10 mm (links_mm or --links), is shorter than an LED's diameter (12 mm): the elbow and gripper LEDs overlap in every image"),
    # the simulated arm's lengths are named as given (it said '(links_mm or --links)')
    ("true-links-last-shorter-than-an-led", "run", ["--quiet", "--true-links", "100,5"],
     "arm two-link: its last link, 5 mm (true_links_mm or --true-links), is shorter than an "
     "LED's diameter (12 mm)"),
    # calibrate said "seen by both cameras in only 3 of 23 poses ... check the rig's camera poses"
    ("calibrate-true-links-last-shorter-than-an-led", "calibrate",
     ["--quiet", "--true-links", "100,5", "--out", "{tmp}/c.yaml"],
     "arm two-link: its last link, 5 mm (true_links_mm or --true-links), is shorter than an "
     "LED's diameter (12 mm): the elbow and gripper LEDs overlap in every image\n"),
    ("calibrate-arm-file-last-shorter-than-an-led", "calibrate",
     ["--quiet", "--arm", "{arm-last-link-5.yaml}", "--out", "{tmp}/c.yaml"],
     "arm-last-link-5.yaml): its last link, 5 mm (links_mm or --links), is shorter than an LED's "
     "diameter (12 mm): the elbow and gripper LEDs overlap in every image\n"),
    ("joint-offset-text", "run", ["--quiet", "--joint-offset", "1,x"], "--joint-offset: expected joint offsets in deg separated by commas, got '1,x'"),
    # a list whose first value is negative is the option's value, not an option: its own error
    ("links-first-negative", "run", ["--quiet", "--links", "-100,100"], "--links: link 1 must be a length in mm in (0, 5000], got -100.0"),
    ("links-without-value", "run", ["--quiet", "--links", "--quiet"], "argument --links: expected one argument"),
    ("links-text", "run", ["--quiet", "--links", "100,x"], "--links: expected link lengths in mm separated by commas, got '100,x'"),
    ("links-1000-planar-rig", "run", ["--quiet", "--links", "1000,1000"], "planar.yaml: cameras[0] (left): cannot see"),
    # trajectories
    ("csv-bom-bad-value", "run", RUN + ["--trajectory", "{bom-bad.csv}"], "bom-bad.csv:2: field y_mm: not a number: 'twenty'"),
    ("csv-all-out-of-reach", "run", RUN + ["--trajectory", "{unreachable.csv}"], "unreachable.csv is in reach of arm two-link (0 to 200 mm from its shoulder): nothing to track"),
    ("csv-3d-in-metres", "run", ["--quiet", "--arm", "three-link", "--trajectory", "{helix-in-m.csv}"], "helix-in-m.csv is in reach of arm three-link (0 to 200 mm from its shoulder, and at least 12 mm from the base axis, the LEDs' stand-off): nothing to track; every point lies within 1 % of the reach of the base: written in metres?\n"),
    ("csv-all-out-of-reach-true-links", "run", RUN + ["--trajectory", "ellipse-t1", "--true-links", "10,10"], "--true-links: none of the 180 set points of ellipse-t1 is in reach of arm two-link (0 to 20 mm"),
    ("csv-5000-digits", "run", RUN + ["--trajectory", "{digits.csv}"], "digits.csv:2: field x_mm: must be finite, got 1111"),
    ("csv-binary", "run", RUN + ["--trajectory", "{binary.csv}"], "binary.csv:3:1: not UTF-8"),
    ("csv-dev-zero", "run", RUN + ["--trajectory", "/dev/zero"], "/dev/zero: trajectory CSV larger than"),
    # options
    ("points-too-many", "run", RUN + ["--points", "1000000000"], "argument --points: must be in 2..100000"),
    ("points-not-a-number", "run", RUN + ["--points", "many"], "argument --points: expected a whole number"),
    ("decisions-too-many", "run", RUN + ["--points", "100000", "--iterations", "101"], "--iterations: 101 iterations at each of the 100000 set points make 10100000 decisions; a run makes at most 10000000: at most 100 iterations here"),
    ("unknown-option", "run", RUN + ["--colour", "red"], "unrecognized arguments: --colour red"),
    ("video-without-vision", "run", RUN + ["--video"], "--video needs --feedback vision"),
    # --out
    ("out-dot", "run", RUN + ["--out", "."], "--out .: name a folder"),
    ("out-dotdot", "run", RUN + ["--out", "{folder}/sub/.."], "sub/..: name a folder"),
    ("out-proc", "run", RUN + ["--out", "/proc/itg-vision-test"], "--out /proc/itg-vision-test: cannot create a folder there"),
    ("out-file", "run", RUN + ["--out", "{file}"], "notes.txt: exists and is not a folder"),
    ("out-user-folder", "run", RUN + ["--out", "{folder}"], "a-folder: is a folder that run did not make (1 entry: thesis.tex)"),
    ("out-other-command", "run", RUN + ["--out", "{paper-out}"], "paper-made: holds the output of `paper`"),
    ("paper-out-file", "paper", ["--quiet", "--out", "{file}"], "notes.txt: exists and is not a folder"),
    ("paper-out-user-folder", "paper", ["--quiet", "--out", "{folder}"], "a-folder: is a folder that paper did not make"),
    ("paper-seed", "paper", ["--quiet", "--seed", "-1"], "--seed: must be a whole number >= 0, got -1"),
    ("calibrate-out-other-rig", "calibrate", ["--quiet", "--out", str(CAMERAS_DIR / "three-link.yaml")], "three-link.yaml: is the rig file 'three-link', not a calibration of"),
    ("calibrate-out-other-calibration", "calibrate", ["--quiet", "--out", str(CAMERAS_DIR / "three-link.calib.yaml")], "is a calibration of three-link.yaml, not of"),
    ("calibrate-out-folder", "calibrate", ["--quiet", "--out", "{folder}"], "a-folder: is a folder; give the calibrated rig's file name"),
    ("calibrate-out-not-yaml", "calibrate", ["--quiet", "--out", "{file}"], "notes.txt: must name a .yaml file"),
    ("calibrate-out-not-a-rig", "calibrate", ["--quiet", "--out", "{not-rig.yaml}"], "not-rig.yaml: exists and is not a rig file"),
    ("calibrate-out-proc", "calibrate", ["--quiet", "--out", "/proc/itg-vision-test/p.yaml"], "--out: cannot write in /proc/itg-vision-test"),
    ("calibrate-out-dotdot", "calibrate", ["--quiet", "--out", "{folder}/x/.."], "x/..: name a file"),
    ("calibrate-rig-binary", "calibrate", ["--quiet", "--rig", "{binary.yaml}"], "binary.yaml:2:118: not UTF-8 text (byte 0x80)"),
    ("calibrate-views", "calibrate", ["--quiet", "--views", "0"], "--views: must be in 1..1000"),
    ("noise-out-file", "noise", ["--quick", "--quiet", "--out", "{file}"], "notes.txt: exists and is not a folder"),
    ("noise-out-user-folder", "noise", ["--quick", "--quiet", "--out", "{folder}"], "a-folder: is a folder this benchmark did not make"),
    ("noise-out-other-command", "noise", ["--quick", "--quiet", "--out", "{paper-out}"], "holds the output of `paper`"),
    ("noise-scheduler-garbage", "noise", ["--quick", "--quiet", "--scheduler", "garbage", "--out", "{tmp}/n"], "--scheduler garbage: expected tcp://HOST:PORT"),
    # a trajectory file of the wrong dimension for --arm: every run of the sweep failed, after
    # the sweep's folder was made
    ("noise-3d-file-on-two-link", "noise", ["--quick", "--quiet", "--controllers", "itg-model", "--conditions", "clean", "--seeds", "1", "--trajectories", "{path-3d.csv}", "--out", "{tmp}/n"], "path-3d.csv: has z values, but the two-link arm is planar (x_mm,y_mm); --arm names the arm of trajectory files\n"),
    ("noise-planar-file-on-three-link", "noise", ["--quick", "--quiet", "--controllers", "itg-model", "--conditions", "clean", "--seeds", "1", "--arm", "three-link", "--trajectories", "{path-2d.csv}", "--out", "{tmp}/n"], "path-2d.csv: is planar, but the three-link arm needs a 3-D trajectory (x_mm,y_mm,z_mm)"),
    ("noise-workers", "noise", ["--quick", "--quiet", "--workers", "0", "--out", "{tmp}/n"], "--workers: must be >= 1, got 0"),
    ("itg-plus-workers", "bench", ["itg-plus", "--quiet", "--workers", "-2", "--out", "{tmp}/n"], "--workers: must be >= 1, got -2"),
    ("noise-workers-type", "noise", ["--quick", "--workers", "two"], "--workers: expected a whole number, got 'two'"),
    ("noise-seeds-type", "noise", ["--quick", "--seeds", "two"], "argument --seeds: expected a whole number, got 'two'"),
    ("noise-out-empty", "bench", ["noise", "--quiet", "--out", ""], "--out: empty path"),
    ("noise-points-huge", "bench", ["noise", "--quiet", "--points", "1000000", "--out", "{tmp}/n"], "argument --points: must be in 2..100000, got 1000000"),
    # 100000 seeds spent minutes listing 43 million runs before anything was refused
    ("noise-seeds-huge", "bench", ["noise", "--quiet", "--seeds", "100000", "--out", "{tmp}/n"], "argument --seeds: must be in 1..1000, got 100000"),
    ("paper-out-empty", "paper", ["--quiet", "--out", ""], "--out: empty path"),
    ("speed-frames-no-vision", "bench", ["speed", "--no-vision", "--frames", "10"], "--frames: applies to the stereo loop's timings, which --no-vision skips\n"),
    ("speed-passes-no-vision", "bench", ["speed", "--passes", "2", "--no-vision"], "--passes: applies to the stereo loop's timings, which --no-vision skips\n"),
    ("speed-frames-0", "bench", ["speed", "--frames", "0"], "argument --frames: must be >= 1, got 0"),
    ("speed-frames-negative", "bench", ["speed", "--frames", "-3"], "argument --frames: must be >= 1, got -3"),
    ("speed-frames-161", "bench", ["speed", "--frames", "161"], "--frames: must be at most 160 (the set points of ellipse-t1 after the first 20), got 161"),
    ("speed-frames-type", "bench", ["speed", "--frames", "x"], "argument --frames: expected a whole number, got 'x'"),
    ("speed-passes-0", "bench", ["speed", "--passes", "0"], "argument --passes: must be >= 1, got 0"),
    ("accuracy-rig-inside-out", "bench", ["accuracy", "--rig", "{held/rig.yaml}", "--out", "{tmp}/held", "--force", "--poses", "5"], "/held/rig.yaml lies inside --out "),
    ("accuracy-seed-negative", "bench", ["accuracy", "--seed", "-1", "--poses", "5"], "--seed: must be >= 0, got -1"),
    # a rig that sees no LED: an IndexError traceback, exit 1, after rendering every pose
    ("accuracy-rig-looking-away", "bench", ["accuracy", "--rig", "{rig-away}", "--poses", "5"], "rig-away.yaml: no LED was seen by both cameras at any of the 5 random poses of arm two-link (10 looks missed): check the rig's camera poses"),
    ("accuracy-rig-dark", "bench", ["accuracy", "--rig", "{rig-dark}", "--poses", "5"], "rig-dark.yaml: cameras[0] (left): exposure 1e-09 makes an LED at most"),
    ("accuracy-poses-3", "bench", ["accuracy", "--poses", "3"], "--poses: must be in 5..100000, got 3"),
    ("accuracy-unknown-option", "bench", ["accuracy", "--bogus"], "unrecognized arguments: --bogus"),
    ("bench-unknown", "bench", ["sped"], "unknown benchmark 'sped'"),
    ("bench-nothing", "bench", [], "name a benchmark"),
]


def _fill(arg: str, names: dict) -> str:
    for k, v in names.items():
        arg = arg.replace("{" + k + "}", v)
    return arg


def _tree(root):
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = os.path.join(dirpath, name)
            out[os.path.relpath(p, root)] = None if os.path.isdir(p) else open(p, "rb").read()
    return out


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bad-inputs")
    return tmp, make_inputs(tmp)


def _cameras_tree():
    return {p.name: p.read_bytes() for p in CAMERAS_DIR.iterdir()}


@pytest.mark.parametrize("case, command, argv, expect", CASES, ids=[c[0] for c in CASES])
def test_bad_input_one_line_exit_2_nothing_touched(inputs, case, command, argv, expect,
                                                    capsys, monkeypatch):
    tmp, files = inputs
    work = tmp / "cwd"
    work.mkdir(exist_ok=True)
    monkeypatch.chdir(work)  # default outputs (runs/...) would land here
    argv = [_fill(a, {"tmp": str(tmp), **files}) for a in argv]
    if command == "run" and "--out" not in argv:
        argv += ["--out", str(tmp / "out")]
    before, cameras = _tree(tmp), _cameras_tree()
    rc = COMMANDS[command](argv)
    out, err = capsys.readouterr()
    assert rc == 2, err
    assert out == "", out
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert expect in lines[0] + "\n", lines[0]
    assert _tree(tmp) == before  # nothing written, nothing left behind (staging, parents)
    assert _cameras_tree() == cameras  # the shipped rigs and calibrations too


def test_every_run_config_field_is_named_by_an_option_of_run():
    """run names a RunConfig field's error by its option (OPTIONS): a field left out was named
    bare, 'strobe: applies to vision feedback only' where every other said '--dropout: ...'."""
    import dataclasses

    from itg_vision.options import OPTIONS
    from itg_vision.runner import RunConfig

    assert set(OPTIONS) == {f.name for f in dataclasses.fields(RunConfig)}
    assert set(OPTIONS.values()) <= set(run.build_parser()._option_string_actions)


@pytest.mark.parametrize("option, value, expect", [
    ("--seeds", "0", "argument --seeds: must be >= 1, got 0"),
    ("--seeds-three-link", "0", "argument --seeds-three-link: must be >= 1, got 0"),
    ("--seeds", "1001", "argument --seeds: must be in 1..1000, got 1001"),
    ("--seeds-three-link", "1001", "argument --seeds-three-link: must be in 1..1000, got 1001"),
    ("--points", "1", "argument --points: must be in 2..100000, got 1"),
])
def test_itg_plus_checks_every_option_before_making_or_running_anything(
        tmp_path, monkeypatch, capsys, option, value, expect):
    """No --out made (not even its manifest), no sweep started (the two-link sweep takes
    27 minutes: a sweep here fails the test at once instead)."""
    def no_sweep(*args, **kwargs):
        raise AssertionError("a sweep started before every option was checked")

    monkeypatch.setattr(noise, "run_sweep", no_sweep)
    rc = bench.main(["itg-plus", "--quiet", option, value, "--out", str(tmp_path / "n")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith(f"error: {expect} (see ") and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_an_arm_files_own_files_are_found_beside_it(tmp_path, monkeypatch):
    """defaults naming files: a relative one is read beside the arm file, whatever the current
    folder (as a rig's true_rig); a missing one is one line naming the field."""
    from itg_vision.rules import RULES_DIR

    mine = tmp_path / "my-arm"
    mine.mkdir()
    (mine / "mine.rules").write_text((RULES_DIR / "table2.rules").read_text())
    (mine / "path.csv").write_text("x_mm,y_mm\n120,40\n110,50\n100,60\n")
    arm = mine / "arm.yaml"
    arm.write_text(re.sub(r"(?m)^defaults:.*$",
                          "defaults: {rules: mine.rules, rig: planar, trajectory: path.csv}",
                          (ARMS_DIR / "two-link.yaml").read_text()))
    monkeypatch.chdir(tmp_path)
    assert run.main(["--quiet", "--arm", str(arm), "--feedback", "model", "--out", "o"]) == 0
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["rules"] == str(mine / "mine.rules") and summary["n_setpoints"] == 3
    (mine / "path.csv").unlink()
    with pytest.raises(UserError, match=rf"arm.yaml: defaults.trajectory: no such file: "
                                        rf"{re.escape(str(mine / 'path.csv'))}$"):
        ArmSpec.from_args(str(arm))
    # a file name that is a shipped one's, given as a file that is not there: the name to give
    for key, name, shipped in (("rig", "planar.yaml", "planar"), ("rules", "table2.rules", "table2"),
                               ("trajectory", "peanut.csv", "peanut")):
        arm.write_text(re.sub(rf"([{{ ]){key}: [^,}}]+", rf"\g<1>{key}: {name}",
                              (ARMS_DIR / "two-link.yaml").read_text(), count=1))
        with pytest.raises(UserError) as exc:
            ArmSpec.from_args(str(arm))
        assert str(exc.value).endswith(
            f"defaults.{key}: no such file: {mine / name} (the shipped one is named without its "
            f"folder and {Path(name).suffix}: {shipped})"), exc.value


def test_an_arm_may_have_any_one_line_name_markup_included(tmp_path):
    """The name goes into the URDF's robot name, escaped: spaces, quotes and brackets run."""
    arm = tmp_path / "arm.yaml"
    arm.write_text(re.sub(r"(?m)^name:.*$", "name: 'UR5 (\"modified\") <a/>'",
                          (ARMS_DIR / "two-link.yaml").read_text()))
    assert run.main(["--quiet", "--arm", str(arm), "--feedback", "vision", "--points", "4",
                     "--out", str(tmp_path / "o")]) == 0
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["arm"] == 'UR5 ("modified") <a/>'


def test_a_pose_range_of_one_angle_is_a_range(tmp_path):
    """An arm file's pose_ranges_deg[i]: lo must be <= hi (arm-pose-range-reversed above), so
    [30, 30] is a range: it holds the joint at 30 deg in every random pose."""
    arm = tmp_path / "fixed-q2.yaml"
    arm.write_text(re.sub(r"(?m)^pose_ranges_deg:.*$", "pose_ranges_deg: [[-180, 180], [30, 30]]",
                          (ARMS_DIR / "two-link.yaml").read_text()))
    spec = load_arm(str(arm))
    assert spec.pose_ranges_deg == ((-180.0, 180.0), (30.0, 30.0))
    assert np.all(spec.random_poses(5, np.random.default_rng(0))[:, 1] == 30.0)


def test_the_servo_limit_note_names_the_arm_file_in_use(tmp_path):
    arm = tmp_path / "my-arm.yaml"
    arm.write_text(re.sub(r"(?m)^benchmark:.*$", "benchmark: {max_step_deg: 7, iterations: 1}",
                          (ARMS_DIR / "two-link.yaml").read_text()))
    out = tmp_path / "o"
    assert run.main(["--quiet", "--arm", str(arm), "--feedback", "model", "--rules",
                     "itg-plus-two-link", "--points", "5", "--out", str(out)]) == 0
    note = json.loads((out / "summary.json").read_text())["servo_limit"]
    assert note == f"S = servo limit = 7 deg/iteration, from the arm file's benchmark limit ({arm})"
    # a shipped arm's file, relative to the project: the same on every machine
    assert run.main(["--quiet", "--feedback", "model", "--rules", "itg-plus-two-link",
                     "--points", "5", "--out", str(tmp_path / "p")]) == 0
    note = json.loads((tmp_path / "p" / "summary.json").read_text())["servo_limit"]
    assert note.endswith("benchmark limit (data/arms/two-link.yaml)")


def test_numbers_in_exponent_form_are_numbers_in_every_yaml_file(tmp_path):
    """As in YAML 1.2 and JSON: 1e1 and 1.5E-3 are numbers (PyYAML, after YAML 1.1, reads them
    as text unless written 1.0e+1); quoted, they stay text."""
    arm = tmp_path / "exp-arm.yaml"
    arm.write_text(re.sub(r"(?m)^benchmark:.*$", "benchmark: {max_step_deg: 1e1, iterations: 1}",
                          (ARMS_DIR / "two-link.yaml").read_text()))
    assert load_arm(str(arm)).benchmark["max_step_deg"] == 10.0
    doc = tmp_path / "n.yaml"
    doc.write_text("a: 1e1\nb: -1.5E-3\nc: .5e+2\nd: '1e1'\ne: 1_000\nf: 1e\n"
                   "g: &g {x: 1, y: 2}\nh:\n  <<: *g\n  x: 3\n")
    assert read_yaml(doc, "rig file") == {"a": 10.0, "b": -0.0015, "c": 50.0, "d": "1e1",
                                          "e": 1000, "f": "1e", "g": {"x": 1, "y": 2},
                                          "h": {"x": 3, "y": 2}}  # a merged key may be overridden


def test_a_utf8_bom_in_a_csv_header_is_accepted(tmp_path):
    from itg_vision.trajectory import read_csv

    f = tmp_path / "excel.csv"
    f.write_text("x_mm,y_mm\n10,20\n30,40\n", encoding="utf-8-sig")
    assert read_csv(f).points_mm.tolist() == [[10, 20, 0], [30, 40, 0]]


def test_allow_unseen_runs_a_rig_that_cannot_see(inputs, tmp_path, capsys):
    _, files = inputs
    argv = ["--quiet", "--rig", files["rig-away"], "--points", "3", "--out", str(tmp_path / "o")]
    assert run.main(argv) == 2
    assert run.main(argv + ["--allow-unseen"]) == 0
    import json
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["n_missed"] > 0  # the failure, measured


@pytest.mark.parametrize("argv, field, expect", [
    (["--joint-offset", "-1,2"], "joint_offset", (-1.0, 2.0)),
    (["--joint-offset", "-1.5,-.5"], "joint_offset", (-1.5, -0.5)),
    (["--joint-offset", "-1"], "joint_offset", (-1.0,)),
])
def test_a_list_that_starts_negative_is_an_options_value(argv, field, expect):
    """argparse reads ``-1,2`` as an unknown option ("expected one argument"); a joint offset
    of -1 deg is a value a user gives."""
    assert getattr(run.build_parser().parse_args(argv), field) == expect


@pytest.mark.parametrize("command", [["run"], ["paper"], ["calibrate"], ["bench"],
                                     ["bench", "speed"], ["bench", "accuracy"],
                                     ["bench", "noise"]])
def test_every_help_exits_0(command, capsys):
    main = {"run": run.main, "paper": paper.main, "calibrate": calibrate.main,
            "bench": bench.main}[command[0]]
    try:
        rc = main(command[1:] + ["--help"])
    except SystemExit as exc:
        rc = exc.code
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert "usage" in out.out and "Traceback" not in out.err


@pytest.mark.parametrize("module", ["itg_vision.run", "itg_vision.calibrate", "itg_vision.paper",
                                    "itg_vision.bench speed", "itg_vision.bench accuracy",
                                    "itg_vision.bench noise"])
def test_every_help_in_a_fresh_process_starts_with_its_usage(cli, module):
    """`bench speed --help` printed PyBullet's build-time banner above its usage (an import of
    pybullet in a fresh process); every command's help is its usage alone."""
    name, *sub = module.split()
    res = cli(name, *sub, "--help")
    assert res.returncode == 0 and res.stdout.startswith("usage: "), res.stdout[:200]
    assert res.stderr == ""


def test_cli_exit_status_and_one_line_in_a_real_process(cli, tmp_path):
    """The same contract through `python -m` (status, streams)."""
    bad = tmp_path / "bad.rules"
    bad.write_text("RULE 1: IF xd > xg THEN q1 += 1e999\n")
    res = cli("itg_vision.run", "--feedback", "model", "--rules", bad, "--out", tmp_path / "o")
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr == f"error: {bad}:1:31: number 1e999 is out of range (the largest is about 1.8e308)\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.rules"]


# ----------------------------------------------------------------------------- soak
def _mutations(rng: random.Random, text: bytes, n: int):
    """``n`` damaged copies of ``text``: cut, duplicated, spliced with random bytes or junk
    tokens, truncated; and a few files that are junk through and through."""
    junk = [b"(", b")", b"|", b"^", b"-", b"NOT ", b"1e999", b"9" * 400, b"\xff\xfe", b"\x00",
            b"[", b"{", b"&a ", b"*a", b"!!python/object:os.system ", b":", b",", b"\n", b"\r",
            b"\xef\xbb\xbf", b"RULE", b"nan", b"inf", b"-1e308"]
    for k in range(n):
        data = bytearray(text)
        for _ in range(rng.randint(1, 6)):
            i = rng.randrange(len(data) + 1)
            op = rng.randrange(5)
            if op == 0 and data:
                del data[i:i + rng.randint(1, 40)]
            elif op == 1:
                j = rng.randrange(len(data) + 1)
                data[i:i] = data[j:j + rng.randint(1, 200)] * rng.randint(1, 30)
            elif op == 2:
                data[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 20)))
            elif op == 3:
                data[i:i] = rng.choice(junk) * rng.randint(1, 300)
            else:
                del data[i:]
        yield bytes(data)
    yield b""
    yield bytes(rng.randrange(256) for _ in range(2000))
    yield b"(" * 5000


def _soak(tmp_path, monkeypatch, capsys, seed: int, per_kind: int):
    rng = random.Random(seed)
    canary = tmp_path / "canary"
    (canary / "sub").mkdir(parents=True)
    (canary / "thesis.tex").write_text("do not touch")
    (canary / "sub" / "data.csv").write_text("1,2,3\n")
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    canary_before = _tree(canary)
    sources = {
        "rules": (RULES_DIR / "table2.rules").read_bytes(),
        "rig": (CAMERAS_DIR / "planar.yaml").read_bytes(),
        "csv": b"x_mm,y_mm,t_s\n" + b"".join(b"%d,%d,%d\n" % (60 + i, 40 - 3 * i, i) for i in range(8)),
    }
    commands = {
        "rules": lambda p, o: run.main(["--quiet", "--feedback", "model", "--points", "4",
                                        "--rules", p, "--out", o]),
        "rig": lambda p, o: run.main(["--quiet", "--points", "2", "--rig", p, "--out", o]),
        "csv": lambda p, o: run.main(["--quiet", "--feedback", "model", "--trajectory", p,
                                      "--out", o]),
        "calibrate": lambda p, o: calibrate.main(["--quiet", "--views", "1",
                                                  "--check-poses", "1", "--rig", p,
                                                  "--out", f"{o}.yaml"]),
    }
    outcomes = {}
    for kind, command in commands.items():
        src = sources["rig" if kind == "calibrate" else kind]
        suffix = {"rules": ".rules", "rig": ".yaml", "csv": ".csv", "calibrate": ".yaml"}[kind]
        for k, data in enumerate(_mutations(rng, src, per_kind)):
            f = tmp_path / f"{kind}-{k}{suffix}"
            f.write_bytes(data)
            try:
                rc = command(str(f), str(tmp_path / "out" / f"{kind}-{k}"))
            except BaseException as exc:  # noqa: BLE001 - what we are looking for
                pytest.fail(f"{kind} file {f} (seed {seed}): {type(exc).__name__}: {exc}")
            err = capsys.readouterr().err
            assert "Traceback" not in err, (f, err)
            assert rc in (0, 2), (f, rc, err)
            if rc == 2:
                assert len(err.strip().splitlines()) == 1, (f, err)
            outcomes[rc] = outcomes.get(rc, 0) + 1
            assert _tree(canary) == canary_before, f
    assert list(work.iterdir()) == []  # nothing in the current folder
    assert not [p for p in (tmp_path / "out").glob(".*")] if (tmp_path / "out").exists() else True
    return outcomes


def test_soak_random_bad_files_never_crash_nor_touch_a_canary(tmp_path, monkeypatch, capsys):
    outcomes = _soak(tmp_path, monkeypatch, capsys, seed=10, per_kind=12)
    assert outcomes.get(2, 0) >= 20  # most damaged files are refused


@pytest.mark.slow
def test_soak_long(tmp_path, monkeypatch, capsys):
    outcomes = _soak(tmp_path, monkeypatch, capsys, seed=1010, per_kind=150)
    assert outcomes.get(2, 0) >= 300


def test_a_value_made_of_yaml_aliases_is_shown_short_without_being_written_out():
    """Ten levels of ten aliases are 1.7 KB of YAML and 1e10 items: a message that wrote the
    value out whole before shortening it ran out of memory (a traceback, exit 1); it writes a
    few items of a few levels."""
    import yaml

    from itg_vision.inputs import show

    text = "a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + "".join(
        f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]\n" for i in range(1, 10))
    bomb = yaml.safe_load(text)["a9"]
    shown = show(bomb)
    assert shown.startswith("[[[") and len(shown) < 200, shown
