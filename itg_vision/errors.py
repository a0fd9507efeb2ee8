"""User errors: one line, exit status 2, no traceback."""

from __future__ import annotations

import argparse
import errno
import os
import re
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Callable


class UserError(Exception):
    """A problem with the user's input, reported as one line (exit status 2)."""


class ConfigError(UserError):
    """A bad configuration field, named as the library knows it (``gain_deg_per_mm``); a
    command line turns the field into its option (``--gain``) with :meth:`as_option`."""

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}")
        self.field, self.message = field, message

    def as_option(self, options: dict[str, str]) -> UserError:
        return UserError(f"{options.get(self.field, self.field)}: {self.message}")


class NothingInReach(ConfigError):
    """No set point of the trajectory is in reach of the simulated arm. A user error for
    ``run``; for a benchmark sweep an outcome of its condition (links made longer or shorter
    can leave a path out of reach: the one-link arm reaches only its circle), recorded as a run
    that did not start."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors are one line: a bad option raises `UserError` (naming the option),
    which :func:`run_main` prints as ``error: ...`` with status 2, instead of printing the usage
    and exiting. Parse inside the ``body`` given to :func:`run_main`.

    A value that starts with a minus and a digit is a value, not an option, lists included:
    argparse takes only a lone number (``-1``, ``-1.5``) for one, so ``--joint-offset -1,2``
    was "expected one argument". No option of ours is spelled like a negative number, which is
    argparse's own condition for reading such tokens as values."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\.?\d")

    def error(self, message: str):
        raise UserError(f"{message} (see {self.prog} --help)")


def at_least_one(text: str) -> int:
    """An argparse ``type``: a whole number >= 1 (``--workers``); otherwise the option's one-line
    error, ``argument --workers: must be >= 1, got 0``."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {n}")
    return n


#: Most set points a named trajectory may be given (``--points``; a vision run costs ~30 ms
#: per point).
MAX_POINTS = 100_000


def points_arg(text: str) -> int:
    """An argparse ``type``: ``--points``, a whole number of set points in 2..MAX_POINTS."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of set points, got {text!r}") \
            from None
    if not 2 <= n <= MAX_POINTS:
        raise argparse.ArgumentTypeError(f"must be in 2..{MAX_POINTS}, got {n}")
    return n


#: What the system says of a path the user chose (too long, on a full or read-only disk, over
#: the file size limit, not a folder, ...): one line naming the file, status 2, as for any
#: other bad input.
_REFUSED_PATH = {errno.ENAMETOOLONG, errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS,
                 errno.EACCES, errno.EPERM, errno.ENOTDIR, errno.EISDIR, errno.ELOOP}


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (``timeout``, a batch scheduler, ``docker stop``, a closed terminal),
    raised where the command is, as Ctrl-C is: what it was writing is cleaned up the same way."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


#: The signals a command turns into :class:`Terminated` (where the platform has them).
TERMINATING = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))

#: What carries a signal that landed inside an import to the import's end (see `_on_signal`).
_CARRIER = getattr(signal, "SIGALRM", None)
_DEFER_S = 0.01
_deferred: list[int] = []  # the signal being carried, if any
_held = [0]  # how many sections that no signal may cut are under way (`signals_held`)


@contextmanager
def signals_held():
    """A section that a command's signal must not cut in two (a file descriptor pointed
    elsewhere and put back, see `stdio.quiet_c_streams`): one that lands there is raised where
    the section ends. For short sections only: a held Ctrl-C waits for the end."""
    _held[0] += 1
    try:
        yield
    finally:
        _held[0] -= 1
        # raised here, not at the carrier's next tick (a body that ended within it returned 0,
        # the signal lost), in place of an error in flight; still carried inside an import
        if not _held[0] and _deferred and threading.current_thread() is threading.main_thread():
            signal.setitimer(signal.ITIMER_REAL, 0)
            _on_signal(_deferred[0], sys._getframe())


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside an import (importlib's frames are below it)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib._bootstrap"):
            return True
        frame = frame.f_back
    return False


def _on_signal(signum, frame):
    """Ctrl-C, SIGTERM and SIGHUP in a command's body: raise `KeyboardInterrupt` or
    `Terminated` where the command is, to be cleaned up and said by `run_main`.

    Not inside an import: a C extension's module code can swallow the exception (numpy.random's
    did: the run went on to its end, status 0, its results written as if no signal had come).
    Nor inside `signals_held` (stderr pointed at /dev/null for PyBullet's banner and never put
    back: the run ended, status 143, without a word). There the signal is taken up again every
    10 ms (on SIGALRM) until the import is done, and raised where the section ends."""
    if signum == _CARRIER:
        signum = _deferred[0] if _deferred else signum  # SIGALRM from outside: its default
    if _CARRIER and (_held[0] or _importing(frame)) and signal.getsignal(_CARRIER) is _on_signal:
        _deferred[:] = [signum]
        signal.setitimer(signal.ITIMER_REAL, _DEFER_S)
        return
    _deferred.clear()
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


def run_main(body: Callable[[], int]) -> int:
    """Run a command body; turn a `UserError` into one line on stderr and status 2.

    Ctrl-C prints ``interrupted`` on a line of its own (a progress bar may be half drawn on
    the current one) and returns 130. A path the system refuses (a name too long, a full or
    read-only disk) is one line too, status 2; a closed standard output (``| head``) ends the
    command quietly, status 1; a current folder deleted before the start is said, status 2.
    """
    try:
        os.getcwd()
    except FileNotFoundError:
        print("error: the current folder no longer exists (cd to another folder)",
              file=sys.stderr)
        return 2
    # SIGTERM / SIGHUP end the body as Ctrl-C does (their default kills the process on the
    # spot, leaving a staging folder behind); only where nobody else handles them. Ctrl-C is
    # taken over from the start-up's handler (under python -m), and afterwards left to Python.
    previous = {}
    package = sys.modules.get(__package__)
    start_handler = getattr(package, "_interrupted_at_start", None)  # only under python -m
    if start_handler is not None and signal.getsignal(signal.SIGINT) is start_handler:
        signal.signal(signal.SIGINT, _on_signal)
        previous[signal.SIGINT] = signal.default_int_handler
    if threading.current_thread() is threading.main_thread():
        for sig in (*TERMINATING, *([_CARRIER] if _CARRIER else [])):
            if signal.getsignal(sig) is signal.SIG_DFL:
                previous[sig] = signal.signal(sig, _on_signal)
    try:
        return body()
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Terminated as exc:
        print(f"\nterminated ({signal.Signals(exc.signum).name})", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away: stop, and say nothing more there
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as exc:
        if exc.errno not in _REFUSED_PATH:
            raise
        where = f"{os.fsdecode(exc.filename)}: " if exc.filename is not None else ""
        print(f"error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    finally:
        if _CARRIER in previous:
            signal.setitimer(signal.ITIMER_REAL, 0)
        _deferred.clear()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def exit_status(status: int) -> int:
    """A command's ``__main__``: ``sys.exit(exit_status(main()))``. After an interruption (130)
    a further Ctrl-C is ignored while the interpreter exits: it would land in the exit hooks
    that join a process pool's threads and print their traceback."""
    if status == 130:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    return status
