"""Silencing what C libraries write straight to the process's stdout / stderr (PyBullet's
'build time' banner, FFmpeg's messages about encoders it cannot open): Python's own
redirection does not reach them, so the file descriptors are pointed at /dev/null."""

from __future__ import annotations

import ctypes
import os
import sys
from contextlib import contextmanager

from .errors import signals_held


@contextmanager
def quiet_c_streams(*names: str):
    """Point the file descriptors of ``sys.<name>`` (``"stdout"``, ``"stderr"``) at /dev/null
    for the ``with`` block.

    Python's buffers of those streams are flushed first. C's stdout is buffered, so if it is
    silenced C's stdio is flushed (``fflush(NULL)``) before it is restored: what the library
    left in the buffer goes to /dev/null too (C's stderr is unbuffered). Nothing is silenced
    if a stream has no file descriptor (replaced: pytest capture, notebooks). A command's
    Ctrl-C or SIGTERM waits for the block's end (it is short): one raised between a redirect and
    its undoing left stderr at /dev/null, and the command's last word unsaid.
    """
    streams = [getattr(sys, name) for name in names]
    try:
        fds = [s.fileno() for s in streams]
    except (AttributeError, OSError, ValueError):
        yield
        return
    with signals_held():
        for s in streams:
            s.flush()
        saved = [os.dup(fd) for fd in fds]
        devnull = os.open(os.devnull, os.O_WRONLY)
        for fd in fds:
            os.dup2(devnull, fd)
        try:
            yield
        finally:
            if "stdout" in names:
                ctypes.CDLL(None).fflush(None)
            for fd, keep in zip(fds, saved):
                os.dup2(keep, fd)
                os.close(keep)
            os.close(devnull)
