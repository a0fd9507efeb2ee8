"""Reading the user's text files (rules, rigs, trajectories) without surprises.

:func:`read_text` reads at most :data:`MAX_FILE_BYTES` (a larger file, ``/dev/zero`` or a
device never ends in a MemoryError), decodes UTF-8 (a leading byte-order mark is dropped, as
spreadsheet programs write one), and turns every failure into one
:class:`~itg_vision.errors.UserError` line naming the file, and the line and column of a byte
that is not UTF-8 (a binary file). :func:`clip` shortens a user's text quoted in a message.
"""

from __future__ import annotations

from pathlib import Path

from .errors import UserError

#: Largest input file read (bytes). The shipped files are a few kB.
MAX_FILE_BYTES = 1 << 20


def clip(text: str, n: int = 40) -> str:
    """``text`` shortened to about ``n`` characters for a one-line message."""
    return text if len(text) <= n else f"{text[: n - 12]}...({len(text)} chars)"


def read_text(path: str | Path, what: str, limit: int = MAX_FILE_BYTES) -> str:
    """The text of ``path`` (a ``what``: 'rule file', 'rig file', ...); raises `UserError`.

    Refused: a missing or unreadable file, a folder, more than ``limit`` bytes, bytes that are
    not UTF-8 (reported at their line and column), NUL characters (a binary file).
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except IsADirectoryError:
        raise UserError(f"{path}: is a folder, not a {what}") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise UserError(f"{path}: {what} larger than {limit // 1024} KiB: not a {what}?")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, col = position(data, exc.start)
        raise UserError(f"{path}:{line}:{col}: not UTF-8 text (byte 0x{data[exc.start]:02x}): "
                        f"not a {what}?") from None
    nul = text.find("\0")
    if nul >= 0:
        line, col = position(text, nul)
        raise UserError(f"{path}:{line}:{col}: NUL character: a binary file, not a {what}?")
    return text


def position(data: bytes | str, offset: int) -> tuple[int, int]:
    """1-based line and column of ``offset`` in ``data``."""
    nl = b"\n" if isinstance(data, bytes) else "\n"
    line = data.count(nl, 0, offset) + 1
    col = offset - (data.rfind(nl, 0, offset) + 1) + 1
    return line, col
