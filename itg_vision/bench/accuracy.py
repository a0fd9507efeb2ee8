"""python -m itg_vision.bench accuracy: stereo estimation error against its first-order prediction.

On random reachable poses of the arm, in one run: the detected LED centroid against the true
projection (px), the triangulated marker against the simulator's truth at zero added noise
(mm), and, for added centroid noise sigma, the measured RMS error against the prediction
sigma_total^2 (J^T J)^-1 propagated through the rig geometry, where sigma_total^2 = sigma^2 +
sigma_render^2 and sigma_render is the rendering's own centroid error measured here.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ..arm import ArmSpec
from ..camera import Rig, default_rig_path
from ..errors import UserError, run_main
from ..feedback import VisionFeedback
from ..triangulate import predicted_rms_error_mm
from ..world import World


def random_poses(arm: ArmSpec, n: int, rng: np.random.Generator) -> np.ndarray:
    lo = [-180.0, -150.0, -150.0][: arm.n_joints]
    hi = [180.0, 150.0, 150.0][: arm.n_joints]
    if not arm.planar:
        lo[1], hi[1] = -20.0, 110.0
    return rng.uniform(lo, hi, (n, arm.n_joints))


def measure(arm: ArmSpec, rig: Rig, sigmas, n_poses: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    poses = random_poses(arm, n_poses, rng)
    centroid_err, pts, errs = [], [], {s: [] for s in sigmas}
    with World(arm) as world:
        for k, q in enumerate(poses):
            world.set_q(q)
            truth = world.true_markers()
            pts += [truth[n] for n in arm.marker_names]
            for s in sigmas:
                fb = VisionFeedback(rig, rig, arm, noise_px=s)
                fb.reset(seed * 100003 + k)
                m = fb.observe(world)
                for name in arm.marker_names:
                    if name in m.missed:
                        continue
                    errs[s].append(float(np.linalg.norm(m.get(name) - truth[name])))
                    if s == 0:
                        for cam, d in zip(rig.cameras, fb.last_observation.detections[name]):
                            centroid_err.append(d.uv_raw_px - cam.project(truth[name]))
    c = np.array(centroid_err)
    sigma_render = float(np.sqrt(np.mean(np.sum(c**2, axis=1)) / 2))  # per axis
    out = {"n_poses": n_poses, "centroid_mean_px": c.mean(axis=0).tolist(),
           "centroid_rms_px": float(np.sqrt(np.mean(np.sum(c**2, axis=1)))), "sigma_render_px": sigma_render,
           "rows": []}
    pts = np.array(pts)
    for s in sigmas:
        e = np.array(errs[s])
        pred = float(np.sqrt(np.mean(predicted_rms_error_mm(rig, pts, float(np.hypot(s, sigma_render))) ** 2)))
        meas = float(np.sqrt(np.mean(e**2)))
        out["rows"].append({"sigma_px": s, "measured_rms_mm": meas, "predicted_rms_mm": pred,
                            "ratio": meas / pred, "n": int(e.size)})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m itg_vision.bench accuracy", description=__doc__.split("\n\n")[0])
    ap.add_argument("--arm", default="two-link")
    ap.add_argument("--rig", help="rig file (default: the arm's)")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    def body() -> int:
        arm = ArmSpec.from_args(args.arm)
        if args.poses < 5:
            raise UserError("--poses: at least 5")
        rig = Rig.from_yaml(args.rig or default_rig_path(arm.name))
        r = measure(arm, rig, (0.0, 0.1, 0.3, 1.0), args.poses, args.seed)
        print(f"{arm.name} on {rig.name}: {r['n_poses']} random poses, seed {args.seed}")
        print(f"centroid vs true projection: mean ({r['centroid_mean_px'][0]:+.3f}, {r['centroid_mean_px'][1]:+.3f}) px, "
              f"RMS {r['centroid_rms_px']:.3f} px (sigma_render {r['sigma_render_px']:.3f} px per axis)")
        print(f"{'added sigma px':>15}{'measured mm':>13}{'predicted mm':>14}{'ratio':>8}{'n':>6}")
        for row in r["rows"]:
            print(f"{row['sigma_px']:>15.2f}{row['measured_rms_mm']:>13.3f}{row['predicted_rms_mm']:>14.3f}"
                  f"{row['ratio']:>8.2f}{row['n']:>6}")
        return 0

    return run_main(body)


if __name__ == "__main__":
    sys.exit(main())
