"""python -m itg_vision.calibrate: calibrate the stereo rig from rendered views of a checkerboard.

The command line of :mod:`itg_vision.calibration` (the method is described there; the board in
:mod:`itg_vision.board`): shows the board to the true rig, calibrates the pair, ties it to the
arm's base by the joint axes the LEDs trace, checks it on the LEDs, and prints the errors
against the true rig.

Outputs: the calibrated rig (``runs/calibrate/<rig>.calib.yaml`` by default: the shipped
``cameras/<rig>.calib.yaml`` is rewritten only when named with ``--out``), in the rig schema with
a ``calibration`` section, ``true_rig`` (the rig that rendered, relative to the file's folder)
and ``true_rig_sha256`` (that file's content hash: a run refuses the calibration once the true
rig is edited, :func:`itg_vision.camera.load_true_rig`), and a picture of the detected corners
of one view, titled with the rig, the camera and the view (``<name>.calib.png`` beside it).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from .arm import ArmSpec, arm_names
from .calibration import (DEFAULT_VIEWS, MAX_STEREO_EXCESS_PX, MAX_VIEWS, MIN_VIEWS, Result,
                          arm_of_rig, calibrate, picture_path, progress_steps, write_result)
from .camera import Rig, resolve_rig
from .errors import ConfigError, UserError, exit_status, run_main
from .inputs import file_sha256
from .outputs import FORCE_REPLACES, check_path, keep_aside
from .progress import progress
from .visibility import check_leds_apart

# ---------------------------------------------------------------------------- command line
#: Where calibrations go by default (relative to the current folder, like ``runs/`` of run).
DEFAULT_OUT_DIR = Path("runs") / "calibrate"


def default_out(rig_path: Path) -> Path:
    """``cameras/planar.yaml`` -> ``runs/calibrate/planar.calib.yaml``.

    Not beside the rig: the shipped ``cameras/<rig>.calib.yaml`` is a tracked file (the
    reference calibration the README's figures and ``bench noise``'s ``rig-calibrated`` use);
    following the README must not rewrite it. ``--out cameras/planar.calib.yaml`` refreshes it
    on purpose (allowed: that file is this rig's calibration).
    """
    return DEFAULT_OUT_DIR / f"{Path(rig_path).stem}.calib.yaml"


def check_out(out: Path, rig_path: Path, force: bool = False) -> list[Path]:
    """Refuse, before any work, an ``--out`` the calibration must not write (`UserError`).

    ``out`` must name a ``.yaml``/``.yml`` file (not a folder) in a folder that can be written,
    with a name the file system takes (:func:`itg_vision.outputs.check_path`), and not the true
    rig. An existing file there is replaced only if it is a calibration of this rig (its
    ``true_rig`` names ``rig_path``), or with ``force``; the same holds for the corner picture
    beside it. A symbolic link there (dangling or not) is replaced only with ``force``, and
    kept aside, never its target. A folder where either file goes is refused, even with ``force`` (it is never
    replaced: the write would fail after all the work). Returns the files ``force`` lets it
    replace that are not this rig's calibration and its picture, for
    :func:`itg_vision.outputs.keep_aside`.
    """
    from .outputs import probe_folder
    from .inputs import resolve_relative

    check_path(out, what="file")
    if out.is_dir():
        raise UserError(f"--out {out}: is a folder; give the calibrated rig's file name, e.g. "
                        f"{out / default_out(rig_path).name}")
    if out.suffix not in (".yaml", ".yml"):
        raise UserError(f"--out {out}: must name a .yaml file (the calibrated rig)")
    pic = picture_path(out)
    if pic.is_dir():
        raise UserError(f"--out {out}: {pic} is a folder, where the corner picture goes; choose "
                        "another --out")
    if out.resolve() == Path(rig_path).resolve():
        raise UserError(f"--out: {out} would overwrite the true rig")
    links = [p for p in (out, pic) if p.is_symlink()]  # the user's: replacing one deletes it
    if links and not force:
        which = "" if links[0] == out else f"{links[0]} "
        raise UserError(f"--out {out}: {which}is a symbolic link (to {os.readlink(links[0])}); "
                        "give the file itself or another --out, or add --force to write there "
                        "anyway (the link is kept)")
    if links:  # with force: kept aside, as run keeps a link given as --out
        probe_folder(out.parent)
        return [p for p in (out, pic) if p.exists() or p.is_symlink()]
    ours = False
    if out.exists():
        try:
            old = Rig.from_yaml(out)
        except UserError as exc:
            if not force:
                raise UserError(f"--out {out}: exists and is not a rig file ({exc}); choose "
                                f"another --out, or add {FORCE_REPLACES}") from None
        else:
            truth = old.true_rig and resolve_relative(old.true_rig, out)
            ours = bool(truth) and Path(truth).resolve() == Path(rig_path).resolve()
            if not ours and not force:
                what = (f"a calibration of {old.true_rig}, not of {rig_path}" if old.true_rig
                        else f"the rig file {old.name!r}, not a calibration of {rig_path}")
                raise UserError(f"--out {out}: is {what}; choose another --out, or add "
                                f"{FORCE_REPLACES}")
    if pic.exists() and not ours and not force:
        raise UserError(f"--out {out}: {pic} exists and would be replaced by the corner "
                        "picture; choose another --out, or add --force")
    probe_folder(out.parent)
    return [] if ours else [p for p in (out, pic) if p.exists()]


def measured_links(base_frame: dict) -> str:
    """'measured L2 99.90, L3 99.97 mm': the link lengths the joint-axis fits measured, named
    (a calibration file written before the names were recorded: 'measured links ...')."""
    values = base_frame["measured_links_mm"]
    names = base_frame.get("measured_links")
    if names is None or len(names) != len(values):
        return "measured links " + ", ".join(f"{v:.2f}" for v in values) + " mm"
    return "measured " + ", ".join(f"{n} {v:.2f}" for n, v in zip(names, values)) + " mm"


def summary_table(r: dict, tail=()) -> str:
    """The calibration figures as a short text table; ``tail``: (label, value) rows after them
    (the files written, the wall time), in the same columns."""
    e = r["error_vs_true"]
    names = list(e["cameras"])
    rows = [("", *names)]
    rows.append(("reprojection RMS (px)", *(f"{r['reprojection_rms_px'][n]:.3f}" for n in names)))
    rows.append(("worst view's reprojection RMS (px)",
                 *(f"{max(r['per_view_rms_px'][n]):.3f}" for n in names)))
    # against the true rig (calibrated - true), as error_vs_true in the file
    rows.append(("focal length error fx, fy (%)", *(
        "{:+.3f}, {:+.3f}".format(*e["cameras"][n]["focal_length_pct"]) for n in names)))
    rows.append(("principal point error u, v (px)", *(
        "{:+.2f}, {:+.2f}".format(*e["cameras"][n]["principal_point_px"]) for n in names)))
    rows.append(("distortion error, max over image (px)", *(
        f"{e['cameras'][n]['distortion_max_px']:.3f}" for n in names)))
    rows.append(("rotation error (deg)", *(f"{e['cameras'][n]['rotation_deg']:.3f}"
                                           for n in names)))
    rows.append(("world position error (mm)", *(f"{e['cameras'][n]['position_mm']:.2f}"
                                                 for n in names)))
    led = r["led_triangulation"]
    u = r["views_used"]
    rows.insert(1, ("views used", *(str(u[n]) for n in names)))
    both = r["views_found"].get("both")  # (not in calibrations made before it was recorded)
    pair = [("stereo views used / shown", f"{u['stereo']} / {r['views_shown']}"
             + (f" (found by both cameras in {both})" if both is not None else "")
             + (f", outlier views dropped {r['views_dropped']}" if r["views_dropped"] else "")),
            ("board tilt span (deg)", "{:.0f} x {:.0f}".format(*r["tilt_span_deg"])),
            ("stereo RMS (px)", f"{r['stereo_rms_px']:.3f}"),
            *([] if "stereo_excess_px" not in r else [  # (since the check: older files)
                ("stereo excess over the cameras' RMS / bound (px)",
                 f"{r['stereo_excess_px']:.3f} / {MAX_STEREO_EXCESS_PX:.2f}")]),
            ("baseline error (mm)", f"{e['baseline_mm']:+.3f}"),
            ("relative rotation error (deg)", f"{e['relative_rotation_deg']:.4f}"),
            ("base frame error: origin (mm), rotation (deg)",
             f"{e['base_frame']['origin_mm']:.2f}, {e['base_frame']['rotation_deg']:.3f}"),
            ("base frame: joint-axis circle fits RMS (mm)",
             f"{r['base_frame']['fit_rms_mm']:.3f} ("
             + (f"the {r['base_frame']['arm']} arm's LEDs, --arm; " if "arm" in r["base_frame"]
                else "") + f"{measured_links(r['base_frame'])})"),
            *([] if "worst_fit" not in r["base_frame"] else [  # (since the check: older files)
                ("worst circle fit / its LED-noise bound (mm)",
                 "{rms_mm:.3f} / {bound_mm:.3f} ({fit})".format(**r["base_frame"]["worst_fit"]))]),
            ("LED triangulation RMS (mm)", f"true rig {led['true_rig_rms_mm']:.3f}, calibrated "
                                           f"{led['calibrated_rig_rms_mm']:.3f}, ratio "
                                           f"{led['ratio']:.2f} ({led['points']} points)"),
            ("LED triangulation p95 / max (mm)",
             f"true rig {led['true_rig_p95_mm']:.3f} / {led['true_rig_max_mm']:.3f}, calibrated "
             f"{led['calibrated_rig_p95_mm']:.3f} / {led['calibrated_rig_max_mm']:.3f}")]
    pair += list(tail)  # (label, value) rows after the figures, in the same columns
    w0 = max(len(x[0]) for x in rows + pair)
    w = [max(len(row[i]) for row in rows) for i in range(1, len(rows[0]))]
    lines = ["  ".join([f"{row[0]:<{w0}}"] + [f"{v:>{w[i]}}" for i, v in enumerate(row[1:])])
             for row in rows]
    lines += [f"{k:<{w0}}  {v}" for k, v in pair]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    from .errors import ArgumentParser  # one-line option errors

    ap = ArgumentParser(
        prog="python -m itg_vision.calibrate",
        description="Calibrate a stereo rig from rendered views of a checkerboard (intrinsics, "
                    "distortion, the pair), tie it to the robot's base frame with the LEDs at "
                    "known joint angles, and write the calibrated rig (default "
                    "runs/calibrate/<rig>.calib.yaml).")
    ap.add_argument("--rig", metavar="NAME|PATH",
                    help="the true rig that renders: cameras/<NAME>.yaml or a path "
                         "(default: planar)")
    ap.add_argument("--views", type=int, default=DEFAULT_VIEWS, metavar="N",
                    help=f"board poses shown, 1..{MAX_VIEWS} (default %(default)s; at least "
                         f"{MIN_VIEWS} must show the board to both cameras)")
    ap.add_argument("--seed", type=int, default=0,
                    help="seed of the board poses, sensor noise and arm poses (default 0)")
    ap.add_argument("--out", metavar="PATH",
                    help="calibrated rig file, .yaml (default: runs/calibrate/<rig>.calib.yaml; "
                         "the shipped cameras/<rig>.calib.yaml is only rewritten when named "
                         "here); the corner picture goes beside it as <name>.png. An existing "
                         "file is replaced only if it is a calibration of this rig")
    ap.add_argument("--force", action="store_true",
                    help="write --out even if it is not a calibration of this rig (the file there, and a "
                         "picture beside it, are kept as NAME.replaced-N.yaml/.png)")
    ap.add_argument("--arm", metavar="NAME|PATH",
                    help=f"arm whose LEDs tie the rig to the base frame: a shipped arm "
                         f"({', '.join(arm_names())}) or an arm file FILE.yaml (default: "
                         "three-link for the three-link rig, else two-link)")
    ap.add_argument("--tilt", type=float, default=45.0, metavar="DEG",
                    help="largest board tilt about each in-plane axis, 0..75 deg (default %(default)s; "
                         "0 shows the board fronto-parallel, which is degenerate)")
    ap.add_argument("--sensor-noise", type=float, metavar="SIGMA",
                    help="override the rig's sensor noise (grey levels std, 0..100) while rendering")
    ap.add_argument("--true-links", metavar="L1,L2[,L3]",
                    help="model error: the simulated arm's link lengths in mm (the base frame "
                         "comes from the joint axes, not from the lengths: try 105,105)")
    ap.add_argument("--check-poses", type=int, default=20, metavar="N",
                    help="arm poses for the LED triangulation check, 1..1000, two LEDs each (default %(default)s)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar and no table")
    return ap


@dataclass(frozen=True)
class Job:
    """What a command line asks for, checked: the arguments of
    :func:`itg_vision.calibration.calibrate` and where the result goes."""

    rig_path: Path
    true_rig: Rig
    rig_sha256: str  # of the true rig file as read: the calibration's true_rig_sha256
    arm: ArmSpec
    true_arm: ArmSpec
    out: Path
    views: int
    seed: int
    tilt_deg: float
    check_poses: int
    force: bool
    quiet: bool

    @property
    def rig_name(self) -> str:
        """The calibrated rig's name: its file's name without ``.yaml``."""
        return self.out.name.removesuffix(".yaml")

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> "Job":
        """Check the options and load the rig and the arms; `UserError` names the option."""
        checks = [(1 <= args.views <= MAX_VIEWS,
                   f"--views: must be in 1..{MAX_VIEWS}, got {args.views}"),
                  (args.seed >= 0, f"--seed: must be >= 0, got {args.seed}"),
                  (0 <= args.tilt <= 75, f"--tilt: must be in 0..75 deg, got {args.tilt}"),
                  (args.sensor_noise is None or 0 <= args.sensor_noise <= 100,
                   f"--sensor-noise: must be in 0..100, got {args.sensor_noise}"),
                  (1 <= args.check_poses <= 1000, f"--check-poses: must be in 1..1000, got "
                                                  f"{args.check_poses}")]
        for ok, msg in checks:
            if not ok:
                raise UserError(msg)
        rig_path = resolve_rig(args.rig or "planar")
        true_rig = Rig.from_yaml(rig_path)
        rig_sha256 = file_sha256(rig_path)  # as read, not as it may be after the work
        if true_rig.true_rig:
            raise UserError(f"{rig_path} is already a calibrated rig (of {true_rig.true_rig}); "
                            f"calibrate the true rig")
        if args.sensor_noise is not None:
            true_rig = dataclasses.replace(true_rig, cameras=tuple(
                dataclasses.replace(c, noise_sigma_gray=float(args.sensor_noise))
                for c in true_rig.cameras))
        arm_arg = args.arm or arm_of_rig(true_rig.name)  # a name or an arm file, as run's
        arm = ArmSpec.from_args(arm_arg)
        true_arm = arm
        if args.true_links is not None:
            try:
                links = tuple(float(v) for v in args.true_links.split(","))
            except ValueError:
                raise UserError(f"--true-links: expected lengths in mm separated by commas, "
                                f"got {args.true_links!r}") from None
            try:
                true_arm = ArmSpec.from_args(arm_arg, links)
            except ConfigError as exc:
                raise exc.as_option({"links_mm": "--true-links"}) from None
        check_leds_apart(true_arm, args.true_links is not None)
        # '' is the empty-path error (check_path), not the default
        out = check_path(args.out, what="file") if args.out is not None else default_out(rig_path)
        return cls(rig_path, true_rig, rig_sha256, arm, true_arm, out, args.views, args.seed,
                   args.tilt, args.check_poses, args.force, args.quiet)


def report(result: Result, out: Path, picture: Path | None) -> str:
    """What the command prints: the figures, the files written and the wall time."""
    tail = [("calibrated rig", str(out))]
    if picture is not None:
        tail.append((f"detected corners (view {result.record['picture_view']})", str(picture)))
    tail.append(("wall time", f"{result.timing_s['total_s']:.1f} s"))
    return summary_table(result.record, tail)


def main(argv: list[str] | None = None) -> int:
    def body() -> int:
        job = Job.from_args(build_parser().parse_args(argv))
        foreign = check_out(job.out, job.rig_path, job.force)  # before the work, not after it
        # one step per rendered pose: the board's, then the arm's (joint sweeps, check poses)
        steps = progress_steps(job.arm, job.views, job.check_poses)
        bar = progress(steps, f"calibrate ({job.views} board + {steps - job.views} arm poses)",
                       quiet=job.quiet, unit="pose")
        try:
            result = calibrate(job.true_rig, job.arm, views=job.views, seed=job.seed,
                               tilt_deg=job.tilt_deg, true_arm=job.true_arm,
                               check_poses=job.check_poses, name=job.rig_name,
                               progress=lambda stage: bar.update())
        finally:
            bar.close()
        try:
            for p in foreign:
                keep_aside(p, f"--out: {p} was " + ("a symbolic link" if p.is_symlink() else
                                                    "not this rig's calibration"))
            picture = write_result(result, job.out, job.rig_path, job.rig_sha256)
        except OSError as exc:  # changed since check_out, a full disk: one line, the old files kept
            raise UserError(f"--out {job.out}: cannot write {exc.filename or job.out} "
                            f"({exc.strerror or exc})") from None
        if not job.quiet:
            print(report(result, job.out, picture))
        return 0

    return run_main(body)


if __name__ == "__main__":
    sys.exit(exit_status(main()))
