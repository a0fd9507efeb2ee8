"""Progress on stderr: a tqdm bar on a terminal, a few plain lines in a log.

tqdm redraws its bar in place with carriage returns; written to a file or a pipe (a log, CI)
that becomes one ever-growing line. So when stderr is not a terminal, :func:`progress` prints a
line like ``run two-link-ellipse-t1: 90/180 pt (50%), 12 s, about 12 s left`` at every tenth of
the way (at most one a second, at least one a minute while something moves) and a last one when
done. The time left assumes the rest goes at the average pace so far.
"""

from __future__ import annotations

import sys
import time


class LineProgress:
    """The subset of tqdm's interface the commands use, as newline-terminated lines."""

    def __init__(self, total: int, desc: str = "", unit: str = "it", file=None,
                 steps: int = 10, min_interval_s: float = 1.0, max_interval_s: float = 60.0):
        self.total, self.desc, self.unit = int(total), desc, unit
        self.file = file or sys.stderr
        self.n, self.postfix = 0, ""
        self.steps, self.min_interval_s, self.max_interval_s = steps, min_interval_s, max_interval_s
        self.t0 = self._last_t = time.monotonic()
        self._last_step = self._last_n = 0
        self._last_postfix = ""
        self.closed = False

    def _line(self) -> str:
        pct = f"{100 * self.n / self.total:.0f}%" if self.total else ""
        done = f"{self.n}/{self.total} {self.unit} ({pct})" if self.unit else pct
        post = f", {self.postfix}" if self.postfix else ""
        elapsed = time.monotonic() - self.t0
        left = f", about {_duration(elapsed * (self.total - self.n) / self.n)} left" \
            if 0 < self.n < self.total else ""
        return f"{self.desc}: {done}{post}, {elapsed:.0f} s{left}"

    def _emit(self) -> None:
        print(self._line(), file=self.file, flush=True)
        self._last_t, self._last_n, self._last_postfix = time.monotonic(), self.n, self.postfix

    def update(self, n: int = 1) -> None:
        self.n += n
        step = self.steps * self.n // self.total if self.total else 0
        now = time.monotonic()
        due = step > self._last_step and now - self._last_t >= self.min_interval_s
        if due or now - self._last_t >= self.max_interval_s:
            self._last_step = step
            self._emit()

    def set_postfix_str(self, s: str) -> None:
        self.postfix = s

    def write(self, s: str, file=None) -> None:
        print(s, file=file or self.file, flush=True)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            if (self.n, self.postfix) != (self._last_n, self._last_postfix):  # the last word
                self._emit()


def _duration(s: float) -> str:
    """``45 s``, ``12 min``, ``3.5 h``: the estimate's own precision, no more."""
    if s < 120:
        return f"{s:.0f} s"
    return f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.1f} h"


class _Off:
    """No progress at all (``--quiet``)."""

    def update(self, n: int = 1) -> None:
        pass

    def set_postfix_str(self, s: str) -> None:
        pass

    def write(self, s: str, file=None) -> None:
        print(s, file=file or sys.stderr, flush=True)

    def close(self) -> None:
        pass


def progress(total: int, desc: str, *, quiet: bool = False, unit: str = "it", **tqdm_kw):
    """A progress meter on stderr: tqdm on a terminal, :class:`LineProgress` otherwise, nothing
    with ``quiet``. ``unit=""``: lines show the percentage only (``total`` counts something
    internal, e.g. estimated cost). ``tqdm_kw`` go to tqdm only (e.g. ``bar_format``)."""
    if quiet:
        return _Off()
    stream = sys.stderr
    if not (hasattr(stream, "isatty") and stream.isatty()):
        return LineProgress(total, desc, unit, stream)
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=stream, **tqdm_kw)
