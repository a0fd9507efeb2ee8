"""The package as a wheel installs it: built from this tree, unpacked away from the project,
run from another folder (a user's `pip install .` or `pip install git+...`, not `-e`)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from itg_vision.provenance import code_hash
from itg_vision.shipped import ARMS_DIR, CAMERAS_DIR, RULES_DIR, TRAJECTORIES_DIR

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_a_wheel_holds_the_shipped_files_and_runs_away_from_the_project(tmp_path):
    """The wheel used to hold the Python files only: installed so, every command said
    "unknown arm 'two-link' (choose from , ...)" and a Dask worker installed from the package
    failed every run. Now every shipped arm, rule base, trajectory file and rig is in it, the
    default job runs from another folder on the installed files alone (the project's folders
    not on the path), its summary names the shipped rule base as in a clone, and the code hash
    that every result records is the clone's."""
    # built from a copy: a build writes build/ and *.egg-info/ beside its sources, and a
    # stale build/ would lend the wheel files its configuration no longer ships
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "itg_vision", "data", "cameras"):
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, src / name)
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
                    "--wheel-dir", str(wheels), str(src)],  # pip's build, as `pip install .`
                   check=True, capture_output=True, cwd=tmp_path)
    (wheel,) = wheels.glob("itg_vision-*.whl")
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        z.extractall(site)
    shipped = [(ARMS_DIR, "*.yaml"), (RULES_DIR, "*.rules"), (TRAJECTORIES_DIR, "*.csv"),
               (CAMERAS_DIR, "*.yaml")]
    for folder, pattern in shipped:
        files = sorted(folder.glob(pattern))
        assert files
        for f in files:
            assert f"itg_vision/{f.relative_to(ROOT).as_posix()}" in names, f
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site), "ITG_VISION_CACHE": str(tmp_path / "cache")}
    run = subprocess.run([sys.executable, "-m", "itg_vision.run", "--points", "10", "--quiet",
                          "--out", "out"], cwd=work, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    summary = json.loads((work / "out" / "summary.json").read_text())
    assert summary["rules"] == "data/rules/table2.rules"
    assert summary["arm_file"] == "data/arms/two-link.yaml"
    assert summary["code"] == code_hash()
    where = subprocess.run([sys.executable, "-c", "import itg_vision.shipped as s; print(s.ROOT)"],
                           cwd=work, env=env, capture_output=True, text=True, check=True)
    assert Path(where.stdout.strip()) == site / "itg_vision"  # not this project
