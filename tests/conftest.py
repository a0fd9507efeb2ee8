import importlib
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent

#: PyBullet returns link positions as float32 metres: each coordinate is the exact (float64)
#: position rounded to half a float32 ulp, |x| 2**-24 (measured: every one of 14 000 marker
#: coordinates over the three arms equals float32 of forward kinematics). One ulp, 2**-23
#: relative, is the tolerance against the kinematic model: 3.6e-5 mm at 300 mm.
PYBULLET_RTOL = 2.0**-23


def roundoff(scale, ulps=16):
    """Absolute tolerance for float64 results of a short chain of arithmetic on values of size
    ``scale``: ``ulps`` units in the last place of ``scale`` (each operation rounds by half an
    ulp, a few chained ones and a subtraction of near-equal values add up)."""
    return ulps * np.finfo(float).eps * scale


def flat_disc(centre, radius, size=(21, 21), s=16):
    """A white RGB image (``size`` rows, columns) with a flat red disc of ``radius`` px about
    ``centre`` (u, v; pixel centres at integers), anti-aliased: drawn at ``s`` x and area-
    averaged, so each pixel holds its coverage to 1 / s^2 and half a grey level."""
    h, w = size
    jj, ii = np.mgrid[0:h * s, 0:w * s]
    u, v = centre
    inside = (ii - ((u + 0.5) * s - 0.5)) ** 2 + (jj - ((v + 0.5) * s - 0.5)) ** 2 <= (radius * s) ** 2
    big = np.full((h * s, w * s, 3), 255.0)
    big[inside] = (255, 0, 0)
    return big.reshape(h, s, w, s, 3).mean(axis=(1, 3)).round().astype(np.uint8)


def affine_eye(scale=1.0, shift_mm=(0.0, 0.0, 0.0)):
    """A feedback that sees the simulator's LEDs through a wrong world frame, x -> scale x +
    shift: a stereo baseline calibrated too short or long scales the world it triangulates
    about the base; a rig moved as one body after calibration shifts it (its turn left out)."""
    from itg_vision.feedback import Markers, TruthFeedback

    shift = np.asarray(shift_mm, float)

    class AffineEye(TruthFeedback):
        def observe(self, world) -> Markers:
            m = super().observe(world)
            return Markers(m.gripper_mm * scale + shift, m.elbow_mm * scale + shift, m.missed)

    return AffineEye()


@pytest.fixture(autouse=True, scope="session")
def _native_cache(tmp_path_factory):
    """Rule bases compiled to C (itg_vision.native) go to a folder of this session, not the
    user's cache (commands run by the tests inherit it)."""
    os.environ["ITG_VISION_CACHE"] = str(tmp_path_factory.mktemp("native-cache"))


def run_cli(module: str, *args, cwd=None, timeout=600):
    """Run ``python -m <module> args`` and return the CompletedProcess (text)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=cwd or ROOT,
                          capture_output=True, text=True, timeout=timeout, env=env)


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture
def main_in_process(capsys):
    """Call a command's ``main([...])`` in this process, as ``python -m`` would: returns its
    exit status and what it printed (``returncode``, ``stdout``, ``stderr``), like ``cli``.
    Use ``cli`` only where a real process matters (exit status, signals, the output contract)."""

    def call(module: str, *args):
        mod = importlib.import_module(module)
        capsys.readouterr()
        try:
            code = mod.main([str(a) for a in args])
        except SystemExit as exc:  # argparse: --help, usage errors
            code = exc.code if isinstance(exc.code, int) else 2
        out, err = capsys.readouterr()
        return SimpleNamespace(returncode=code, stdout=out, stderr=err)

    return call


def front_rig(path, look_y_mm=60.0):
    """A rig that frames the planar workspace but not the whole base sweep: the shipped planar
    rig with both cameras ``look_y_mm`` farther along +y and 220 mm lower (400 mm above the
    plane), looking at (0, look_y_mm, 0). At 60 mm the two-link arm's LEDs are in view of both
    cameras with the base at 0..150 deg of the start-up's sweep (at -150..-30 deg the gripper
    LED projects below the bottom of one image or both), and both of the elbow's branches
    along ellipse-t1 and ellipse-t2; at 100 mm at 30..150 deg, and along ellipse-t2 one branch
    only at 78 of its 180 set points. Written to ``path`` (a YAML file, as a user writes one);
    returns ``path``."""
    text = (ROOT / "cameras" / "planar.yaml").read_text()
    for x in ("-180.0", "180.0"):
        text = text.replace(f"position_mm: [{x}, -60.0, 620.0]",
                            f"position_mm: [{x}, {look_y_mm - 60.0:.1f}, 400.0]")
    text = text.replace("look_at_mm: [0.0, 0.0, 0.0]", f"look_at_mm: [0.0, {look_y_mm:.1f}, 0.0]")
    path.write_text(text.replace("name: planar", "name: front"))
    return path


def random_rotation(rng):
    """A random rotation matrix and its unit quaternion (x, y, z, w), from ``rng``."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]), q
