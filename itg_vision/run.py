"""python -m itg_vision.run: track a trajectory with the ITG and write runs/<name>/.

Output folder: ``--out DIR``, or by default ``runs/<arm>-<trajectory>-<controller>-<feedback>``
followed by every option that differs from its default (``-rules<name>``, ``-rig<name>``,
``-f0.3``, ``-noise0.5``, ``-seed3``, ...), so two different command lines never share a
folder. The folder is replaced only if this command made it and it holds nothing else (see
:mod:`itg_vision.outputs`); its manifest records the run's settings and a hash of its input
files, and a default folder holding a run with other settings (an edited rule file, a CSV of
the same name elsewhere) is refused too. ``--force`` writes there anyway, keeping a folder
that holds anything this command did not write beside it as ``OUT.replaced-N``.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import re
import sys
from contextlib import nullcontext
from pathlib import Path

from . import outputs, plot, trajectory as traj
from .arm import MAX_ITERATIONS
from .camera import MAX_SUPERSAMPLE
from .errors import (MAX_POINTS, ArgumentParser, ConfigError, UserError, exit_status, points_arg,
                     run_main)
from .feedback import DEFAULT_SUPERSAMPLE
from .controllers import DEFAULT_DAMPING_MM
from .inputs import FILE_TYPES, file_sha256
from .loop import DIVERGED_MM
from .progress import progress
from .options import OPTIONS, RULE_OPTIONS, add_rule_options
from .rules import PARAM_OF_FIELD, PARAM_UNITS
from .shipped import rule_names
from .identify import StartUpFailed
from .runner import (CONTROLLERS, FEEDBACKS, MAX_DECISIONS, RunConfig, config_dict, execute,
                     prepare, shown_path)

#: run notes looks that missed the gripper beyond this share over the --dropout asked for (and
#: three standard deviations of the misses that dropout draws).
MISSED_NOTE = 0.1
#: Options that name the default output folder when given with a value other than the parser's
#: default (the command line, not the run: `--rules table2` is named even where it is the default).
_NAMED = (("rules", "rules"), ("rig", "rig"), ("links", "links"), ("points", "n"),
          *RULE_OPTIONS.items(), ("damping", "damping"), ("iterations", "it"), ("max_step", "maxstep"),
          ("laps", "laps"), ("noise_px", "noise"), ("noise_mm", "noisemm"), ("dropout", "dropout"),
          ("strobe", "strobe"), ("supersample", "ss"), ("full_frame", "fullframe"),
          ("true_links", "truelinks"), ("joint_offset", "offset"),
          ("correction", "corr"), ("preview", "preview"), ("video", "video"),
          ("allow_unseen", "unseen"), ("seed", "seed"))


def _why_missed(summary: dict, marker: str) -> str:
    """The causes of a marker's missed looks, the most frequent first, as the run's note names
    them: ``reprojection residual above the gate 160, not round 2; summary.json's
    n_missed_why, trace.csv's flags say where``."""
    why = ", ".join(f"{cause} {n}" for cause, n in summary["n_missed_why"][marker].items())
    return f"{why}; summary.json's n_missed_why, trace.csv's flags say where"


def _numbers(what: str):
    """An option's parser of numbers separated by commas; its error names ``what`` they are."""
    def parse(text: str) -> tuple[float, ...]:
        try:
            return tuple(float(v) for v in text.replace(" ", "").split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what} separated by commas, got {text!r}")
    return parse


_links = _numbers("link lengths in mm")


def build_parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(
        prog="python -m itg_vision.run",
        description="Track a trajectory with the Intelligent Trajectory Generator and write "
                    "summary.json, trace.csv, path.png and error.png to runs/<name>/.")
    ap.add_argument("--arm", default="two-link", help="an arm of data/arms (one-link, two-link, three-link) or an arm file "
                         "(default %(default)s)")
    ap.add_argument("--links", type=_links, metavar="L1,L2[,L3]",
                    help="link lengths in mm (default: the arm file's links_mm; the shipped "
                         "arms': the paper's 100 mm each)")
    ap.add_argument("--trajectory", metavar="NAME|PATH",
                    help="ellipse-t1, ellipse-t2, abcd, line-ab, line-ab-reach, arc, a file of "
                         "data/trajectories by name (peanut, helix, ...), or a CSV with "
                         "header x_mm,y_mm[,z_mm][,t_s] (default: the arm file's defaults.trajectory: "
                         "ellipse-t1 for two-link, line-ab-reach for three-link, arc for one-link)")
    ap.add_argument("--points", type=points_arg, metavar="N",
                    help=f"number of set points of a named trajectory (2..{MAX_POINTS})")
    ap.add_argument("--rules", metavar="NAME|PATH",
                    help="rule base: one shipped in data/rules (" + ", ".join(rule_names())
                         + ") or a .rules file (default: the arm's). The itg-plus rule bases "
                         "take S from the servo limit (--max-step, default the arm file's)")
    ap.add_argument("--controller", default="itg", choices=CONTROLLERS,
                    help="itg (the rules), or a baseline: ik (closed-form inverse kinematics, "
                         "open loop) or jacobian (vision-fed damped least squares)")
    add_rule_options(ap)
    ap.add_argument("--damping", type=float, metavar="MM",
                    help="the jacobian controller's damping lambda in mm, in (0, 1e4] (default "
                         f"{DEFAULT_DAMPING_MM:g})")
    ap.add_argument("--iterations", type=int, default=1,
                    help=f"rule iterations per set point, 1..{MAX_ITERATIONS}, at most {MAX_DECISIONS} "
                         "decisions (set points x iterations) in all (default 1: the paper's one "
                         "step ahead)")
    ap.add_argument("--max-step", type=float, metavar="DEG",
                    help="servo rate limit: no joint moves more than DEG per iteration, whatever "
                         "the controller, in (0, 360] (default: none, as in the paper; the "
                         "three-link composition needs one, see README)")
    ap.add_argument("--correction", type=float, default=1.0, metavar="K",
                    help="itg, jacobian: feed the set point's motion forward and correct only K "
                         "of the error measured against the previous decision's set point (0 < K "
                         "<= 1; default 1: aim at the set point). The eye's noise then reaches the "
                         "gripper scaled by K, and the controller's own step errors take 1/K "
                         "steps to correct (README, 'Noise and memory')")
    ap.add_argument("--preview", action="store_true",
                    help="two-link arm: near the base, aim where a plan of the whole path puts "
                         "the gripper, the line through the base turning at most the servo "
                         "limit per iteration (needs --max-step, or an ITG+ rule base, which "
                         "takes the arm file's limit). E_i is still measured from the set point "
                         "(README, 'Preview')")
    ap.add_argument("--laps", type=int, default=1,
                    help="run a closed trajectory this many times, 1..1000 and at most "
                         f"{MAX_POINTS} set points in all (default %(default)s); the "
                         "tracking-phase metrics then cover the laps after the first")
    ap.add_argument("--feedback", default="vision", choices=FEEDBACKS,
                    help="vision (two cameras, LEDs), model (encoders + nominal kinematic model) "
                         "or truth (the simulator's marker positions) (default %(default)s)")
    ap.add_argument("--rig", metavar="NAME|PATH",
                    help="camera rig the estimator believes: cameras/<NAME>.yaml or a path; a "
                         "calibrated rig renders with the true rig it names (default: the arm file's "
                         "defaults.rig: planar, or three-link for the three-link arm)")
    ap.add_argument("--noise-px", type=float, default=0.0, help="vision: extra Gaussian centroid noise, px std, in [0, 1e6] (default 0)")
    ap.add_argument("--noise-mm", type=float, default=0.0,
                    help="with --feedback truth: Gaussian noise added to each LED coordinate, mm "
                         "std, in [0, 1e6] (default 0)")
    ap.add_argument("--true-links", type=_links, metavar="L1,L2[,L3]",
                    help="model error: the simulated arm's link lengths in mm, each in (0, "
                         "5000] (default: the nominal --links). Only --feedback model and --controller ik know the "
                         "nominal model; vision and truth runs measure the lengths at start-up")
    ap.add_argument("--joint-offset", type=_numbers("joint offsets in deg"), metavar="D1,D2[,D3]",
                    help="model error: the simulated joints sit this many degrees off their "
                         "commanded angles, each within +-180 (default: none)")
    ap.add_argument("--dropout", type=float, default=0.0, help="vision: probability in [0, 1] that an LED detection is dropped (default 0)")
    ap.add_argument("--strobe", action="store_true",
                    help="light one LED per frame (as active-marker systems do) instead of telling "
                         "them apart by colour; doubles the rendering")
    ap.add_argument("--supersample", type=int, metavar="S",
                    help="vision: render at S times the resolution and area-average down "
                         f"(anti-aliased LEDs; 1..{MAX_SUPERSAMPLE}; default: the rig file's, "
                         f"else {DEFAULT_SUPERSAMPLE})")
    ap.add_argument("--full-frame", action="store_true",
                    help="vision: render whole frames instead of windows around the LEDs "
                         "(~50-70x slower: 195 ms a look against 2.8 on 640x480; --video "
                         "implies it)")
    ap.add_argument("--seed", type=int, default=0, help="seed of every random thing, a whole number >= 0 (default %(default)s)")
    ap.add_argument("--allow-unseen", action="store_true",
                    help="run even if the cameras cannot see the arm along the trajectory (refused "
                         "by default, at start-up): to measure that failure")
    ap.add_argument("--out", metavar="DIR",
                    help="output folder (default runs/<arm>-<trajectory>-<controller>-<feedback> "
                         "plus every option that differs from its default); replaced only if a "
                         "run made it and it holds nothing else")
    ap.add_argument("--force", action="store_true",
                    help="write --out even if it is a folder this command did not make (that folder "
                         "is kept beside it as OUT.replaced-N)")
    ap.add_argument("--video", action="store_true",
                    help="also write a video of both camera views (vision): H.264 video.mp4, "
                         "where OpenCV cannot encode H.264 VP9 video.webm, else MPEG-4 Part 2 "
                         "video.mp4")
    ap.add_argument("--quiet", action="store_true", help="no progress bar and no table")
    return ap


def _less_type(name: str) -> str:
    """A file's name less its type (planar.calib.yaml -> planar.calib); a shipped name as it is."""
    return Path(name).stem if Path(name).suffix in FILE_TYPES else name


def default_out(args: argparse.Namespace, prep) -> Path:
    """``runs/<arm>-<trajectory>-<controller>-<feedback>[-<option><value>...]`` for the options
    given with a value other than the parser's default (file names less their type)."""
    cfg, defaults = prep.config, build_parser()
    parts = [_less_type(cfg.arm), Path(prep.trajectory.name).stem, cfg.controller, cfg.feedback]
    for dest, label in _NAMED:
        v = getattr(args, dest)
        if v == defaults.get_default(dest):
            continue
        if isinstance(v, bool):
            parts.append(label)
        elif isinstance(v, (tuple, list)):
            parts.append(label + "x".join(f"{x:g}" for x in v))
        elif isinstance(v, float):
            parts.append(f"{label}{v:g}")
        elif isinstance(v, str):
            parts.append(label + _less_type(Path(v).name))
        else:
            parts.append(f"{label}{v}")
    name = re.sub(r"[^A-Za-z0-9._+=-]", "_", "-".join(parts))
    if len(name) > 120:  # a name the file system takes, still telling runs apart
        name = f"{name[:100]}-{hashlib.sha1(name.encode()).hexdigest()[:8]}"
    return Path("runs") / name


#: The option that names each input file of a run (run_key's names).
_INPUT_OPTIONS = {"rules": "--rules", "estimate_rig": "--rig", "render_rig": "--rig's true_rig",
                  "trajectory": "--trajectory", "arm": "--arm"}


def _input_paths(prep) -> dict[str, str]:
    """A run's input files by run_key's names: the rule base, the rigs, a trajectory file, the
    arm file (a shipped arm's too: it may be edited)."""
    files = {}
    for key in ("rules", "estimate_rig", "render_rig"):
        if key in prep.info:
            files[key] = prep.info[key]
    if prep.trajectory.file is not None:
        files["trajectory"] = str(prep.trajectory.file)
    files["arm"] = str(prep.model.source)
    return files


def input_files(prep) -> dict[str, str]:
    """A run's input files by the option that named them (:func:`outputs.check_out_dir`'s
    ``inputs``)."""
    return {_INPUT_OPTIONS[k]: p for k, p in _input_paths(prep).items() if Path(p).is_file()}


def run_key(prep) -> dict:
    """What identifies a run's result: its settings and the content of its input files."""
    files = _input_paths(prep)
    digests = {}
    for key, path in files.items():
        try:
            digests[key] = file_sha256(path)[:16]
        except OSError:
            digests[key] = None
    return {"config": outputs.json_safe(config_dict(prep.config)), "inputs_sha256": digests}


def _check_default_out(out: Path, key: dict, force: bool) -> None:
    """A default folder holding a run with other settings is not replaced silently."""
    made = outputs.read_manifest(out)
    if force or made is None or made.get("command") != "run":
        return
    old = made.get("key") or {}
    if old.get("config") is not None:  # a setting added since that run, at its default, is the same
        defaults = outputs.json_safe(config_dict(RunConfig()))
        old = {**old, "config": {**{k: defaults[k] for k in set(key["config"]) - set(old["config"])},
                                 **old["config"]}}
    made = old.get("inputs_sha256", {})
    if "arm" in key["inputs_sha256"] and "arm" not in made:  # made before arm files were hashed
        old = {**old, "inputs_sha256": {**made, "arm": key["inputs_sha256"]["arm"]}}
    if old == key:
        return
    diff = sorted(k for k in set(old.get("config", {})) | set(key["config"])
                  if old.get("config", {}).get(k) != key["config"].get(k))
    diff += [f"content of the {k} file" for k in sorted(key["inputs_sha256"])
             if old.get("inputs_sha256", {}).get(k) != key["inputs_sha256"][k]]
    raise UserError(f"{out} holds an earlier run with other settings ({', '.join(diff) or 'version'}"
                    "); give --out, or --force to replace it (a run made it: it is not kept)")


def _seconds(t: float) -> str:
    """A time for trace.csv: to the microsecond whatever its size (an epoch time keeps its
    milliseconds, where 6 significant digits dropped them), no trailing zeros, never "-0"."""
    return outputs.unsigned_zero(f"{t:.6f}".rstrip("0").rstrip("."))


def main(argv: list[str] | None = None) -> int:
    def body() -> int:
        args = build_parser().parse_args(argv)
        cfg = RunConfig(arm=args.arm, links_mm=args.links, trajectory=args.trajectory,
                        points=args.points, controller=args.controller, rules=args.rules,
                        gain_deg_per_mm=args.gain, step_deg=args.step, tolerance_mm=args.tolerance,
                        damping_mm=args.damping,
                        iterations=args.iterations, max_step_deg=args.max_step, laps=args.laps,
                        feedback=args.feedback, rig=args.rig, noise_px=args.noise_px,
                        noise_mm=args.noise_mm, dropout=args.dropout, strobe=args.strobe,
                        supersample=args.supersample,
                        full_frame=args.full_frame or (args.video and args.feedback == "vision"),
                        seed=args.seed, true_links_mm=args.true_links,
                        joint_offset_deg=args.joint_offset, allow_unseen=args.allow_unseen,
                        correction=args.correction, preview=args.preview)
        try:
            prep = prepare(cfg)
        except ConfigError as exc:
            raise exc.as_option(OPTIONS) from None
        if args.video and cfg.feedback != "vision":
            raise UserError("--video needs --feedback vision")
        notes = [traj.span_note(prep.trajectory, prep.true_arm.reach_mm()[1])]
        if prep.rig_arm not in (None, prep.model.name) and len(prep.model.marker_names) > 1:
            notes.append(f"note: {shown_path(prep.info['estimate_rig'])} was tied to the base by "
                         f"the {prep.rig_arm} arm's LEDs; calibrating with --arm "
                         f"{prep.model.name} ties it by this arm's own joint axes")
        n, n_in = len(prep.trajectory), prep.n_in_reach
        if 2 * n_in < n:
            notes.append(f"note: {n - n_in} of the {n} set points are out of the arm's reach: "
                         f"every metric rests on the {n_in} in reach")
        notes.extend(prep.notes)
        key = run_key(prep)
        if args.out is not None:  # '' is check_path's empty-path error, not the default folder
            out = outputs.check_path(args.out)
        else:
            out = default_out(args, prep)
            _check_default_out(out, key, args.force)
        with outputs.staged_dir(out, "run", force=args.force, key=key,
                                inputs=input_files(prep)) as tmp:
            for note in filter(None, notes):  # after every refusal of --out: an error is one line
                print(note, file=sys.stderr)
            bar = progress(len(prep.trajectory), f"run {out.name}", quiet=args.quiet, unit="pt")
            recorder = nullcontext()
            if args.video:
                from .video import VideoRecorder

                recorder = VideoRecorder(tmp / "video")
            with recorder:
                try:
                    trace, summary = execute(prep, progress=bar.update,
                                             recorder=recorder if args.video else None)
                except StartUpFailed as exc:  # say which rig and arm, and the way on
                    raise StartUpFailed(f"{shown_path(prep.info['estimate_rig'])} (--rig), "
                                        f"{prep.model.label}: {exc} (--allow-unseen runs on the "
                                        "nominal model's lengths instead)") from None
                finally:
                    bar.close()
            big, joint, k = trace.largest_step
            if big >= 360:
                print(f"note: q{joint} turned {big:.6g} deg in one iteration (set point k = {k}, as trace.csv numbers them): a "
                      "full turn or more, which no servo does (--max-step bounds the steps)",
                      file=sys.stderr)
            unseen = summary["n_at_last_aim"] + summary["n_held"]
            looks = summary["n_setpoints"] * summary["iterations"]
            p = cfg.dropout  # beyond what the dropout asked for gives, and its 3 sigma
            beyond = (p + MISSED_NOTE) * looks + 3 * math.sqrt(looks * p * (1 - p))
            if unseen > beyond:
                print(f"note: the gripper LED went unseen in {unseen} of the {looks} looks "
                      f"({_why_missed(summary, 'gripper')}): those decisions were made on the "
                      "last aim, not on a measurement", file=sys.stderr)
            if trace.missed_by.get("elbow", 0) > beyond:
                held = ("however old" if not trace.n_elbow_turned
                        else "turned with the base's commanded turn since" if prep.model.planar
                        else "turned with the base's and the shoulder's commanded turns since")
                print(f"note: the elbow LED went unseen in {trace.missed_by['elbow']} of the "
                      f"{looks} looks ({_why_missed(summary, 'elbow')}): those decisions were "
                      f"made on its last measured position, {held}", file=sys.stderr)
            if args.video:
                summary["video"] = recorder.path.name
                summary["video_codec"] = recorder.codec_note
            cols, rows = trace.rows()
            if prep.trajectory.t_s is not None:  # the file's times (laps go on by a period)
                cols.insert(1, "t_s")
                for row, t in zip(rows, prep.trajectory.t_s, strict=True):
                    row.insert(1, _seconds(t))
            outputs.write_text(tmp / "trace.csv", outputs.csv_text(cols, rows))
            outputs.write_json(tmp / "summary.json", summary)
            title = plot_title(summary)
            plot.path_figure(trace, title, tmp / "path.png", laps=summary["laps"])
            plot.error_figure(trace, title, tmp / "error.png", laps=summary["laps"])
        if not args.quiet:
            print(summary_table(summary, out))
        return 0

    return run_main(body)


def plot_title(s: dict) -> str:
    """The run's figures' title: what ran on which path, what it saw and under which limits
    (servo, iterations), then E_av (and 'DIVERGED'); on a second line what else set the
    result: the rule base's f, S and w (S unless it is the servo limit), the memory K, the
    preview, the rig, dropout, the simulated arm's differences from the model, the seed. Files
    are named by their name less folder and type; an ITG run names its rule base."""
    who = _less_type(Path(s["rules"]).name) if s["controller"] == "itg" else s["controller"]
    seen = s["feedback"]
    fp = s.get("feedback_params", {})
    noise = fp.get("noise_px") or 0.0
    if seen == "vision" and noise > 0:
        seen += f", {noise:g} px noise"
    if fp.get("noise_mm"):
        seen += f", {fp['noise_mm']:g} mm noise"
    laps = f", {s['laps']} laps" if s.get("laps", 1) > 1 else ""
    limits = ", ".join(
        ([f"servo {s['max_step_deg']:g} deg/iteration"] if s.get("max_step_deg") else [])
        + ([f"{s['iterations']} iterations"] if s.get("iterations", 1) > 1 else []))
    e_av = s["e_av_mm"] if s["e_av_mm"] is not None else float("nan")
    line = (f"{s['arm']} {_less_type(Path(s['trajectory']).name)}{laps} ({who}, {seen}"
            f"{'; ' + limits if limits else ''}): E_av {e_av:.2f} mm"
            + (", DIVERGED" if s.get("diverged") else ""))
    more = []
    from_ = s.get("controller_params_from", {})
    more += [f"{n} {v:g} {PARAM_UNITS[n]}" for k, v in s.get("controller_params", {}).items()
             if (n := PARAM_OF_FIELD.get(k)) and from_.get(k) != "the servo limit"]  # (S: line 1)
    if s.get("correction", 1) != 1:
        more.append(f"memory K {s['correction']:g}")
    if s.get("preview"):
        more.append("preview")
    if s.get("estimate_rig"):
        est, ren = (_less_type(Path(s[k]).name) for k in ("estimate_rig", "render_rig"))
        more.append(f"rig {est}" if est == ren else f"rig {est} (renders {ren})")
    if fp.get("dropout"):
        more.append(f"LED dropout {fp['dropout']:g}")
    if s.get("true_links_mm") and s["true_links_mm"] != s.get("links_mm"):
        more.append("true links " + "/".join(f"{v:g}" for v in s["true_links_mm"]) + " mm")
    if any(s.get("joint_offset_deg") or ()):
        more.append("joint offset " + "/".join(f"{v:g}" for v in s["joint_offset_deg"]) + " deg")
    if "seed" in s and (s["feedback"] == "vision" or fp.get("noise_mm")):  # something random
        more.append(f"seed {s['seed']}")
    return line + ("\n" + ", ".join(more) if more else "")


def _lengths(geometry: dict) -> str:
    """The lengths the controller was given, their standard error where they were measured with
    one (the rules' sL), and where they came from."""
    se = geometry.get("length_se_mm", 0.0)
    return (f"{geometry['links_mm']} mm" + (f", standard error up to {se:g} mm" if se else "")
            + f" ({geometry['source']})")


def summary_table(s: dict, out: Path) -> str:
    def f(v, unit=""):
        return "n/a" if v is None else (f"{v:.3f}{unit}" if isinstance(v, float) else f"{v}{unit}")

    rows = [("arm", f"{s['arm']} {s['links_mm']} mm"), ("trajectory", s["trajectory"]),
            ("controller / feedback", f"{s['controller']} / {s['feedback']}"),
            *([("rule base", s["rules"])] if s.get("rules") else []),
            *([("rig", s["estimate_rig"]) if s["estimate_rig"] == s["render_rig"] else
               ("rig (estimates / renders)", f"{s['estimate_rig']} / {s['render_rig']}")]
              if s.get("estimate_rig") else []),
            ("set points (out of reach / flagged)",
             f"{s['n_setpoints']} ({s['n_out_of_reach']} / {s['n_flagged']})"),
            ("E_av", f(s["e_av_mm"], " mm")), ("E_max", f(s["e_max_mm"], " mm")),
            ("E_rms", f(s["e_rms_mm"], " mm")),
            (f"tracking from set point {s['tracking_from']}: median / mean / p95 / max",
             " / ".join(f(s[k]) for k in ("track_median_mm", "track_mean_mm", "track_p95_mm",
                                          "track_max_mm")) + " mm"),
            *([(f"diverged (tracking median > {DIVERGED_MM:g} mm)",
                "yes (README, 'Diverged runs')")] if s.get("diverged") else []),
            ("servo limit", "none" if s["max_step_deg"] is None else f"{s['max_step_deg']:g} deg/iteration"),
            ("controller parameters", ", ".join(
                f"{k} {v}" + (f" ({s['controller_params_from'][k]})"
                              if k in s.get("controller_params_from", {}) else "")
                for k, v in s["controller_params"].items()) or "none"),
            *([("memory: correction K (1: none)", f"{s['correction']:g}")]
              if s.get("correction", 1) != 1 else []),
            *([("preview: aims moved / largest move", "{moved} / {largest_move_mm:.3f} mm".format(
                **s["preview"]))] if s.get("preview") else []),
            *([("aims flagged out of reach, asked again with the set point",
                f(s["n_aim_out_of_reach"]))] if s.get("n_aim_out_of_reach") else []),
            ("lengths given to the controller", _lengths(s["geometry"])),
            *([("base axis measured at (x, y)", "({:.3f}, {:.3f}) mm".format(
                *(round(v, 3) + 0.0 for v in s["geometry"]["base_axis_mm"])))]  # no -0.000
              if s["geometry"]["source"].startswith("measured") else [])]
    if s["feedback"] == "vision":
        rows += [("estimate RMS gripper / elbow",
                  f"{f(s['est_gripper_rms_mm'])} / {f(s['est_elbow_rms_mm'])} mm"),
                 ("LED detections missed", f(s["n_missed"]) + (" ({})".format(", ".join(
                     f"{m} {k}" for m, k in s["n_missed_by"].items())) if s["n_missed"] else "")),
                 ("iterations given the last aim (the gripper missed)", f(s["n_at_last_aim"])),
                 *([("looks whose lost elbow was turned with the joints", f(s["n_elbow_turned"]))]
                   if s.get("n_elbow_turned") else []),
                 ("iterations held (missed before any aim)", f(s["n_held"]))]
        t = s.get("timing_ms", {})
        rows.append(("median ms render/detect/triang./rules",
                     " / ".join(f"{t[k]:.2f}" if k in t else "-"  # a stage that never ran
                                for k in ("render", "detect", "triangulate", "rules"))))
    if s.get("video"):
        rows.append(("video", f"{s['video']} ({s.get('video_codec', '')})"))
    rows += [("wall time", f(s["wall_s"], " s")), ("written to", str(out))]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


if __name__ == "__main__":
    sys.exit(exit_status(main()))
