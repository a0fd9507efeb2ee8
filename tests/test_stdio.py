import os
import subprocess
import sys

from conftest import ROOT

# Writes at the C level, as PyBullet and FFmpeg do: straight to the file descriptors, and
# through C's stdio buffer (full buffering: stdout is a pipe here, and PYTHONUNBUFFERED, which
# makes Python unbuffer C's stdio too, is dropped).
SCRIPT = r"""
import ctypes, os, sys
from itg_vision.stdio import quiet_c_streams
libc = ctypes.CDLL(None)
with quiet_c_streams(*sys.argv[1:]):
    os.write(1, b"fd-out ")
    os.write(2, b"fd-err ")
    libc.printf(b"c-out ")
os.write(1, b"after-out ")
os.write(2, b"after-err ")
"""


def run(*streams):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    env["PYTHONPATH"] = str(ROOT)
    res = subprocess.run([sys.executable, "-c", SCRIPT, *streams], capture_output=True,
                         text=True, timeout=60, env=env)
    assert res.returncode == 0, res.stderr
    return res.stdout.split(), res.stderr.split()


def test_only_the_named_streams_are_silenced_and_restored_after():
    out, err = run("stdout", "stderr")
    assert out == ["after-out"] and err == ["after-err"]
    # stdout silenced: what C left in its buffer is flushed into /dev/null, not printed later
    assert "c-out" not in out
    out, err = run("stderr")
    assert err == ["after-err"]
    assert set(out) == {"fd-out", "after-out", "c-out"}  # stdout untouched


def test_nothing_is_silenced_without_the_names():
    out, err = run()
    assert err == ["fd-err", "after-err"] and set(out) == {"fd-out", "after-out", "c-out"}
