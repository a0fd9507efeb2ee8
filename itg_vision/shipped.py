"""What ships with the package: the folders of arm files, rigs, rule bases and trajectory
files (``data/`` and ``cameras/`` beside the package in a clone, inside it once installed from a
wheel: :data:`ROOT`), and the names a user may give for each (``--arm two-link``, ``--rules
table2``...).

The modules that read these files (arm, camera, rules, trajectory) take their folder from here,
so that an arm file's ``defaults`` can be checked against the shipped names without the arm
module reaching up into the modules that need arms.
"""

from __future__ import annotations

import os
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
#: Where ``data/`` and ``cameras/`` are: in an installed package, the package itself
#: (pyproject.toml maps them to ``itg_vision/data`` and ``itg_vision/cameras`` in a wheel), else
#: the project folder above it (a clone, an editable install).
ROOT = _PACKAGE if (_PACKAGE / "data").is_dir() else _PACKAGE.parent
#: The shipped data: arms, rules, trajectories.
DATA_DIR = ROOT / "data"
#: The shipped arm files (``<name>.yaml``).
ARMS_DIR = DATA_DIR / "arms"
#: The shipped rule bases (``<name>.rules``).
RULES_DIR = DATA_DIR / "rules"
#: The shipped user-style trajectories (CSV files).
TRAJECTORIES_DIR = DATA_DIR / "trajectories"
#: The shipped rigs and their calibrations (``<name>.yaml``, ``<name>.calib.yaml``).
CAMERAS_DIR = ROOT / "cameras"
#: The paper's trajectories, made by ``trajectory.named``.
TRAJECTORY_NAMES = ("ellipse-t1", "ellipse-t2", "abcd", "line-ab", "line-ab-reach", "arc")


def trajectory_file_names() -> list[str]:
    """The shipped trajectory files, by name (``peanut`` for data/trajectories/peanut.csv)."""
    return sorted(p.stem for p in TRAJECTORIES_DIR.glob("*.csv"))


def rule_names() -> list[str]:
    """The shipped rule bases (``table2``, ``itg-plus-two-link``, ...)."""
    return sorted(p.stem for p in RULES_DIR.glob("*.rules"))


def rig_names() -> list[str]:
    """The shipped rigs (``planar``, ``three-link``, ...; calibrations too)."""
    return sorted(p.name[:-len(".yaml")] for p in CAMERAS_DIR.glob("*.yaml"))


#: The suffixes of a YAML file (arm and rig files).
YAML_SUFFIXES = (".yaml", ".yml")


def holds_a_folder(name_or_path: str) -> bool:
    """Whether a name holds a folder separator, which makes it a path whatever its suffix (a
    shipped name never holds one)."""
    return "/" in name_or_path or os.sep in name_or_path


def names_a_path(name_or_path: str, suffixes: tuple[str, ...]) -> bool:
    """Whether an option's value (``--arm``, ``--rig``, ``--rules``, ``--trajectory``) is a path,
    not a shipped name: it ends in one of its file type's ``suffixes`` or holds a folder."""
    return Path(name_or_path).suffix in suffixes or holds_a_folder(name_or_path)


def or_a_path(name: str, kind: str, suffix: str) -> str:
    """The end of an 'unknown <kind>' message for a name that is not shipped: a file of that
    name in the current folder, which a name does not reach (a name is always a shipped one),
    given as the path that does; else how a path is told from a name."""
    for candidate in (f"{name}{suffix}", name):
        if Path(candidate).is_file():
            return f"./{candidate} is in this folder: give it as a path, ./{candidate}"
    return f"or give the path of {kind} (a name ending in {suffix} or holding a '/')"


def not_found(path: Path, what: str, names: list[str]) -> str:
    """'<path>: <what> file not found', and where the file's name is a shipped one's
    (``--trajectory rounded-square.csv`` from the project folder, as the README names it) how a
    shipped one is named: by its name alone (a path is never looked for among the shipped)."""
    return f"{path}: {what} file not found" + shipped_name_hint(
        path, names, "rule base" if what == "rule" else what)


def shipped_name_hint(path: Path, names: list[str], what: str = "one") -> str:
    """`` (the shipped <what> is named without its folder and .csv: <stem>)`` for a missing
    ``path`` whose stem is one of the shipped ``names``, else ``""``."""
    if path.stem not in names:
        return ""
    drop = f" and {path.suffix}" if path.suffix else ""
    return f" (the shipped {what} is named without its folder{drop}: {path.stem})"
