"""What made an output: :func:`code_hash`, the version of the code and shipped data behind a
run's numbers (``summary.json``'s and each benchmark row's ``code``)."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

from .shipped import ARMS_DIR, CAMERAS_DIR, ROOT, RULES_DIR, TRAJECTORIES_DIR


@functools.cache
def code_hash() -> str:
    """A hash of what decides a run's numbers besides its parameters: the package's Python
    sources and the shipped arm, rig, rule and trajectory files beside it (those that exist).
    A run's ``summary.json`` and each row of a benchmark's ``results.csv`` record it
    (``code``)."""
    package = Path(__file__).resolve().parent
    # each file named as in the source tree (itg_vision/..., data/..., cameras/...), so that an
    # installed package and its clone give one hash
    files = [(f, f.relative_to(package.parent)) for f in sorted(package.rglob("*.py"))]
    files += [(f, f.relative_to(ROOT)) for f in sorted(ARMS_DIR.glob("*.yaml"))
              + sorted(CAMERAS_DIR.glob("*.yaml")) + sorted(RULES_DIR.glob("*.rules"))
              + sorted(TRAJECTORIES_DIR.glob("*.csv"))]
    h = hashlib.sha256()
    for f, name in files:
        h.update(name.as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:12]
