import os
import shutil
import subprocess
import sys
from pathlib import Path

import itg_vision

SHIPPED = ("itg_vision", "data", "cameras")
#: One file of each kind that decides a run's numbers.
DECIDING = ("itg_vision/loop.py", "data/rules/itg-plus-two-link.rules", "data/arms/two-link.yaml",
            "cameras/planar.yaml", "data/trajectories/peanut.csv")


def test_code_changes_with_every_kind_of_shipped_file_that_decides_numbers(tmp_path):
    """``code`` (summary.json, results.csv) changes when a source, a shipped rule base, arm file,
    rig or trajectory file changes, and not for a file beside them that no run reads; measured on
    a copy of the package, each file edited and put back in turn."""
    root = Path(itg_vision.__file__).resolve().parent.parent
    for d in SHIPPED:
        shutil.copytree(root / d, tmp_path / d, ignore=shutil.ignore_patterns("__pycache__"))
    script = ("import itg_vision, itg_vision.provenance as p; "
              "print(itg_vision.__file__); print(p.code_hash())")

    def code() -> str:
        out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, check=True,
                             env={**os.environ, "PYTHONPATH": str(tmp_path)},
                             capture_output=True, text=True).stdout.split()
        assert Path(out[0]).is_relative_to(tmp_path)  # the copy, not the installed package
        return out[1]

    base = code()
    (tmp_path / "data" / "notes.txt").write_text("read by nothing\n")
    assert code() == base
    codes = {}
    for name in DECIDING:
        f = tmp_path / name
        original = f.read_bytes()
        f.write_bytes(original + b"\n")
        codes[name] = code()
        f.write_bytes(original)
    assert base not in codes.values()
    assert len(set(codes.values())) == len(DECIDING)
