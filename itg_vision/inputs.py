"""Reading the user's text files (rules, rigs, trajectories) without surprises.

:func:`read_text` reads at most :data:`MAX_FILE_BYTES` (a larger file, ``/dev/zero`` or a
device never ends in a MemoryError), decodes UTF-8 (a leading byte-order mark is dropped, as
spreadsheet programs write one), and turns every failure into one
:class:`~itg_vision.errors.UserError` line naming the file, and the line and column of a byte
that is not UTF-8 (a binary file). :func:`read_yaml` parses a YAML file (rigs, arms) the same
way; :class:`Fields` checks the fields of a parsed file, each failure one line naming the file
and the field. :func:`clip` shortens a user's text quoted in a message.
"""

from __future__ import annotations

import functools
import hashlib
import math
import numbers
import os
import re
import reprlib
import stat
from pathlib import Path

import numpy as np

from .errors import UserError

#: Largest input file read (bytes). The shipped files are a few kB.
MAX_FILE_BYTES = 1 << 20
#: The types of the user's input files (rule bases, rigs and arms, trajectories): a name
#: ending so is a file, any other a shipped name.
FILE_TYPES = (".rules", ".yaml", ".yml", ".csv")


def clip(text: str, n: int = 40) -> str:
    """``text`` shortened to about ``n`` characters for a one-line message."""
    return text if len(text) <= n else f"{text[: n - 12]}...({len(text)} chars)"


def resolve_relative(path: str, relative_to: Path) -> Path:
    """A path named inside a file: relative to that file's folder (as written), else as given."""
    p = Path(path)
    if p.is_absolute():
        return p
    beside = Path(relative_to).parent / p
    return beside if beside.exists() else p


#: Pipes read so far (``/dev/stdin``, bash's ``<(...)``), by path and inode: a command reads an
#: input more than once (an arm file for its defaults, the model, the true arm and the run's
#: input digest), and a pipe read again is empty, so a pipe is read once per process.
_PIPES: dict[tuple[str, int, int], bytes] = {}


def _pipe_key(path: str | Path) -> tuple[str, int, int] | None:
    """``path``'s key in :data:`_PIPES` if it is a pipe, else None."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return (str(path), st.st_dev, st.st_ino) if stat.S_ISFIFO(st.st_mode) else None


def is_pipe(path: str | Path) -> bool:
    """Whether ``path`` is a pipe (``/dev/stdin``, bash's ``<(...)``, a named FIFO)."""
    return _pipe_key(path) is not None


def _pipe_bytes(path: str | Path, limit: int) -> bytes | None:
    """A pipe's bytes (at most ``limit + 1`` of them), read once per process; None if ``path``
    is not a pipe (a file, a folder, nothing: read it as such)."""
    key = _pipe_key(path)
    if key is None:
        return None
    if key not in _PIPES:
        with open(path, "rb") as f:
            _PIPES[key] = f.read(limit + 1)
    return _PIPES[key]


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes, as 64 hex digits: a calibrated rig's ``true_rig_sha256``,
    and, cut short, a run's input digests and a sweep's file hashes (a pipe's: what it gave)."""
    piped = _pipe_bytes(path, 1 << 30)
    if piped is not None:
        return hashlib.sha256(piped).hexdigest()
    h = hashlib.sha256()
    with open(path, "rb") as f:  # in blocks: a long video is not read into memory whole
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _a(what: str) -> str:
    """``what`` with its article ('an arm file', 'a rule file')."""
    return ("an " if what[:1] in "aeiou" else "a ") + what


def read_text(path: str | Path, what: str, limit: int = MAX_FILE_BYTES) -> str:
    """The text of ``path`` (a ``what``: 'rule file', 'rig file', ...); raises `UserError`.

    Refused: a missing or unreadable file, a folder, more than ``limit`` bytes, bytes that are
    not UTF-8 (reported at their line and column), NUL characters (a binary file). Line ends
    are returned as ``\n`` whatever the file used (``\r\n``, ``\r``). A pipe is read once
    per process, and read again gives the same text.
    """
    path = Path(path)
    try:
        data = _pipe_bytes(path, limit)
        if data is None:
            with open(path, "rb") as f:
                data = f.read(limit + 1)
    except IsADirectoryError:
        raise UserError(f"{path}: is a folder, not {_a(what)}") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise UserError(f"{path}: {what} larger than {limit // 1024} KiB: not {_a(what)}?")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, col = position(data, exc.start)
        raise UserError(f"{path}:{line}:{col}: not UTF-8 text (byte 0x{data[exc.start]:02x}): "
                        f"not {_a(what)}?") from None
    nul = text.find("\0")
    if nul >= 0:
        line, col = position(text, nul)
        raise UserError(f"{path}:{line}:{col}: NUL character: a binary file, not {_a(what)}?")
    # Windows' and old Macs' line ends read as lines too (a rule file saved with CRs alone
    # read as one comment line: "no rules found")
    return text.replace("\r\n", "\n").replace("\r", "\n")


def position(data: bytes | str, offset: int) -> tuple[int, int]:
    """1-based line and column of ``offset`` in ``data``."""
    nl = b"\n" if isinstance(data, bytes) else "\n"
    line = data.count(nl, 0, offset) + 1
    col = offset - (data.rfind(nl, 0, offset) + 1) + 1
    return line, col


def is_whole(v) -> bool:
    """An integer (numpy's too), not a bool nor a float that happens to be whole: what a count
    or a seed given from code must be."""
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def is_real(v) -> bool:
    """A finite real number (numpy's too), not a bool nor a string: what a physical quantity
    given from code must be."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


@functools.cache
def _loader():
    """PyYAML's safe loader, made strict where it is silently lax: a key given twice in one
    mapping is refused at its line (PyYAML keeps the last), and a number in exponent form is a
    number as in YAML 1.2 and JSON (PyYAML, after YAML 1.1, reads 1e5 and 1.0e5 as text and
    only 1.0e+5 as a number)."""
    import yaml

    class StrictLoader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":  # << merges may override
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    first = seen.get(key)
                except TypeError:  # an unhashable key: the safe loader names it
                    continue
                if first is not None:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {show(key)} (first at line {first.line + 1})",
                        key_node.start_mark)
                seen[key] = key_node.start_mark
            return super().construct_mapping(node, deep)

    StrictLoader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
        list("-+0123456789."))
    return StrictLoader


def read_yaml(path: str | Path, what: str):
    """The parsed YAML of ``path`` (a ``what``: 'rig file', 'arm file'), read by
    :func:`read_text`. Every failure is one `UserError` naming the file: a YAML error at its line
    and column, an integer of more than 4300 digits (int's limit) at its own, a document nested
    too deeply."""
    import yaml

    text = read_text(path, what)
    try:
        return yaml.load(text, Loader=_loader())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        context, cmark = getattr(exc, "context", None), getattr(exc, "context_mark", None)
        if context and cmark is not None and cmark is not mark:
            problem += f", {context} at {cmark.line + 1}:{cmark.column + 1}"
        raise UserError(f"{where}: not valid YAML ({problem})") from None
    except ValueError as exc:  # an integer of more than 4300 digits (int's str limit)
        m = re.search(r"\d{4300,}", text)
        if m is None:
            raise UserError(f"{path}: not valid YAML ({clip(str(exc), 80)})") from None
        line, col = position(text, m.start())
        raise UserError(f"{path}:{line}:{col}: not valid YAML (a number of more than 4300 "
                        "digits)") from None
    except RecursionError:
        article = "an" if what[:1] in "aeiou" else "a"
        raise UserError(f"{path}: nested too deeply to be {article} {what}") from None


#: How much of a value :func:`show` writes out: a few levels and items of each, so that a value
#: made of YAML aliases (a few bytes in the file, billions of items written out) stays short.
_SHOW = reprlib.Repr()  # (keyword arguments only from Python 3.12)
_SHOW.maxlevel, _SHOW.maxstring, _SHOW.maxlong, _SHOW.maxother = 3, 60, 60, 60
_SHOW.maxtuple = _SHOW.maxlist = _SHOW.maxdict = _SHOW.maxset = 4


def show(v) -> str:
    """A value read from the file, for a one-line message (shortened)."""
    try:
        return clip(_SHOW.repr(v))
    except (RecursionError, ValueError):  # nested deeply, an int beyond int's str limit
        return f"a {type(v).__name__}"


def count(n, noun: str) -> str:
    """``n`` (a number, or a collection: its length) with ``noun``: '1 seed', '3 seeds'."""
    k = n if isinstance(n, int) else len(n)
    return f"{k} {noun}{'' if k == 1 else 's'}"


class Fields:
    """Field readers that raise `UserError` with ``file: where: problem``."""

    def __init__(self, path: str):
        self.path = path

    def fail(self, where: str, msg: str):
        raise UserError(f"{self.path}: {where}: {msg}")

    def mapping(self, v, where: str, required, optional=()) -> dict:
        """``v`` as a mapping holding every key of ``required`` and no key outside ``optional``."""
        known = (*required, *optional)
        if not isinstance(v, dict):
            self.fail(where, f"must be a mapping of {', '.join(known)}, got {show(v)}")
        prefix = f"{where}." if where != "(top level)" else ""
        for k in v:
            if k not in known:
                self.fail(f"{prefix}{clip(str(k))}", f"unknown field (known: {', '.join(known)})")
        missing = [k for k in required if k not in v]
        if missing:  # all of them at once: a file written from scratch misses several
            also = f" (and {', '.join(prefix + k for k in missing[1:])})" if missing[1:] else ""
            self.fail(f"{prefix}{missing[0]}", f"missing{also}")
        return v

    def get(self, d, key: str, where: str):
        """``d[key]``, ``d`` a mapping (``where``: its place, "" at the top)."""
        if not isinstance(d, dict):
            self.fail(where, "must be a mapping")
        if key not in d:
            self.fail(f"{where}.{key}" if where else key, "missing")
        return d[key]

    def number(self, v, where: str, lo: float = -math.inf, hi: float = math.inf, *,
               lo_open: bool = False, unit: str = "") -> float:
        """A finite number in [lo, hi] (``lo_open``: (lo, hi])."""
        x = math.nan
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            try:
                x = float(v)
            except OverflowError:  # an integer beyond the doubles
                x = math.inf
        if not math.isfinite(x):
            self.fail(where, f"must be a finite number{unit}, got {show(v)}")
        if not ((lo < x) if lo_open else (lo <= x)) or x > hi:
            span = (f"{'>' if lo_open else '>='} {lo:g}" if hi == math.inf else
                    f"in {'(' if lo_open else '['}{lo:g}, {hi:g}]")
            self.fail(where, f"must be {span}{unit}, got {x:g}")
        return x

    def numbers(self, v, n: int | None, where: str, what: str = "numbers",
                shape: tuple[int, int] | None = None, **kw) -> tuple:
        """A list of ``n`` (any number of, when None) finite numbers, each as :meth:`number`;
        or ROS's matrix form ``{rows, cols, data}`` of them, ``rows x cols`` ``shape`` when
        given."""
        if isinstance(v, dict) and "data" in v:  # ROS's matrix form (rig files)
            self.mapping(v, where, ("rows", "cols", "data"))
            rows, cols = (self.integer(v[k], f"{where}.{k}", 1, 1000) for k in ("rows", "cols"))
            if shape is not None and (rows, cols) != tuple(shape):
                self.fail(where, f"rows x cols must be {shape[0]} x {shape[1]}, got {rows} x "
                                 f"{cols}")
            v = v["data"]
            if isinstance(v, (list, tuple)) and rows * cols != len(v):
                self.fail(where, f"rows x cols is {rows} x {cols}, but data holds "
                                 f"{count(v, 'value')}")
        if not isinstance(v, (list, tuple)) or (n is not None and len(v) != n) or not v:
            got = count(v, "value") if isinstance(v, (list, tuple)) else show(v)
            self.fail(where, f"must be a list of {'' if n is None else f'{n} '}{what}, got {got}")
        return tuple(self.number(x, f"{where}[{i}]", **kw) for i, x in enumerate(v))

    def array(self, v, n: int, where: str, shape: tuple[int, int] | None = None) -> np.ndarray:
        """:meth:`numbers` as an array."""
        return np.array(self.numbers(v, n, where, shape=shape))

    def integer(self, v, where: str, lo: int | None = None, hi: int | None = None) -> int:
        """An integer (in ``lo..hi`` when given)."""
        if lo is None or hi is None:
            if isinstance(v, bool) or not isinstance(v, int):
                self.fail(where, f"must be an integer, got {show(v)}")
            return int(v)
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(where, f"must be a whole number in {lo}..{hi}, got {show(v)}")
        if not lo <= v <= hi:
            self.fail(where, f"must be a whole number in {lo}..{hi}, got {clip(str(v))}")
        return int(v)

    def text(self, v, where: str, pattern: str | None = None, what: str = "") -> str:
        if not isinstance(v, str) or not v.strip() or any(c in v for c in "\0\n\r") or (
                pattern is not None and not re.fullmatch(pattern, v)):
            self.fail(where, f"must be {what or 'a name or a path on one line'}, got "
                             f"{show(v)}")
        return v
