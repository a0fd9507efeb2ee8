"""Writing results safely: nothing the user owns is ever replaced, nothing is half-written.

Rules (what every command follows):

- **Files** are written to a temporary name in the same folder, then renamed
  (:func:`write_bytes`; several files that belong together, such as a calibrated rig and its
  picture, with :func:`write_files`: all written, then all renamed): a reader sees the old file
  or the new one, never a mix, and a failed or killed run leaves the old file.
- **Output folders** are built in a staging folder beside ``--out`` and swapped in whole when
  the command has finished (:func:`staged_dir`). A command replaces only what it made itself:
  every output folder carries a small manifest, :data:`MANIFEST`, naming the command that made
  it and listing the entries it wrote. An existing folder without it (or made by another
  command), one that holds anything else (a user's notes or analysis put in beside the
  results), or an existing file, is refused with one line
  (:class:`~itg_vision.errors.UserError`, exit 2) and left untouched; ``force=True``
  (``--force``) writes over a foreign *folder* (never a file), which is kept beside the new
  one as ``<name>.replaced-N`` (:func:`staged_dir`): nothing the user made is deleted. An empty
  folder holds nothing to lose and is replaced.
- ``--out .``, ``--out a/b/..``, the current folder or one of its ancestors, the root: refused
  (a folder cannot be swapped over itself or over where the user stands).
- ``--out`` names that the file system cannot take with our temporary suffixes are refused
  before any work (:func:`check_path`).
- A run killed with SIGKILL leaves a staging folder ``.<name>.staging-<pid>-<8 characters>``;
  the next run into the same place removes those whose process is gone. If it was killed
  between the two renames of the swap, the old folder (``.<name>.old-<pid>``) is put back first.
  Only folders named exactly so *and* carrying our manifest (or, for an old folder, beside its
  run's staging folder) are touched: a user's folder that happens to look alike is left alone.
- JSON is strict (:func:`write_json`): non-finite floats are written as ``null``, never as the
  bare ``NaN`` / ``Infinity`` that strict readers reject.
"""

from __future__ import annotations

import contextlib
import csv
import glob
import io
import json
import math
import os
import re
import shutil
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

from .errors import UserError, signals_held
from .inputs import count

#: The manifest file that marks a folder as made by an itg_vision command.
MANIFEST = ".itg_vision-output.json"


# ---------------------------------------------------------------------------- files
def write_files(files: dict[str | Path, bytes]) -> None:
    """Write several files as one result: every file to a temporary name in its own folder
    first, then all renamed, in the order given (put the file that readers look for last).

    If anything fails before the renames (a full disk, Ctrl-C), every temporary file is removed
    and no file is replaced; a command's Ctrl-C, SIGTERM or SIGHUP that lands among the renames
    is raised after the last (:func:`itg_vision.errors.signals_held`; under ``python -m``, where
    the platform has SIGALRM), so that a calibrated rig is never left beside a new picture of
    another calibration. This is the one place outputs are written;
    :func:`write_bytes`, :func:`write_text` and :func:`write_json` are its one-file forms.

    An `OSError` names the file that could not be written (its ``filename``), not the
    temporary name, so that a command can report it in one line.
    """
    temps: list[tuple[str, Path]] = []
    path = None
    try:
        for path, data in files.items():
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
            temps.append((tmp, path))
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.chmod(tmp, 0o644)  # mkstemp makes 0600; results are for everyone to read
        with signals_held():  # every file renamed, or (failing) the rest not
            while temps:
                tmp, path = temps[0]
                os.replace(tmp, path)
                temps.pop(0)
    except BaseException as exc:
        for tmp, _ in temps:
            if os.path.exists(tmp):
                os.unlink(tmp)
        if isinstance(exc, OSError) and exc.errno is not None and path is not None:
            raise OSError(exc.errno, exc.strerror, str(path)) from exc  # same subclass by errno
        raise


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    write_files({path: data})


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` atomically (newlines as given), as UTF-8; a file name's bytes that are not
    UTF-8 (lone surrogates, as Python decodes them) are written back as those bytes."""
    write_bytes(path, text.encode("utf-8", "surrogateescape"))


def json_safe(obj):
    """``obj`` with every non-finite float replaced by ``None`` and numpy scalars and arrays made
    plain Python (dicts, lists and tuples are walked; other values are returned as they are)."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):  # numpy scalar or array
        return json_safe(obj.tolist())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(obj) -> str:
    """Strict JSON text of ``obj`` (non-finite floats as null, see :func:`json_safe`)."""
    return json.dumps(json_safe(obj), indent=2, sort_keys=False, allow_nan=False) + "\n"


def write_json(path: str | Path, obj) -> None:
    """Write strict JSON atomically: NaN and infinities become ``null``."""
    write_text(path, json_text(obj))


def unsigned_zero(text: str, sign: str = "") -> str:
    """A formatted number that reads as zero without its minus sign (``sign`` in its place):
    "-0.0000" -> "0.0000", "-0" -> "0", with ``sign="+"`` "-0.00" -> "+0.00". A -6e-15 (cos 90
    deg) has a sign another maths library may not share; the text must not depend on it."""
    if text.startswith("-") and not re.search(r"[1-9]", text):
        return sign + text[1:]
    return text


def csv_text(columns: list[str], rows: list[list]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    w.writerows(rows)
    return buf.getvalue()


# ---------------------------------------------------------------------------- ownership
def read_manifest(folder: str | Path) -> dict | None:
    """The manifest of an output folder, or None if it has none (or an unreadable one)."""
    try:
        doc = json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("made_by") == "itg_vision" else None


def manifest(command: str, key=None, entries: list[str] | None = None,
             digests: dict[str, str] | None = None) -> dict:
    """The manifest a command writes into its output folder (no time stamp: the same run gives
    the same bytes). ``key``: what identifies the result (e.g. a run's settings). ``entries``:
    what the command wrote there (:func:`listing`), the only things a later run of it may
    replace; ``digests``: each written file's SHA-256 (:func:`digests`), so that a file edited
    since counts as the user's; :func:`staged_dir` fills both in."""
    from . import __version__

    doc = {"made_by": "itg_vision", "command": command, "version": __version__}
    if key is not None:
        doc["key"] = key
    if entries is not None:
        doc["entries"] = list(entries)
    if digests is not None:
        doc["sha256"] = dict(digests)
    return doc


def digests(folder: Path, entries: list[str]) -> dict[str, str]:
    """The SHA-256 of each regular file among ``entries`` (:func:`listing` of ``folder``)."""
    from .inputs import file_sha256

    return {e: file_sha256(folder / e) for e in entries
            if not e.endswith("/") and (folder / e).is_file() and not (folder / e).is_symlink()}


def recorded_digests(made: dict | None) -> dict:
    """The SHA-256 of each file the manifest ``made`` recorded (:func:`manifest`'s
    ``digests``; empty for no manifest, or one without them)."""
    recorded = (made or {}).get("sha256")
    return recorded if isinstance(recorded, dict) else {}


def edited(folder: Path, made: dict) -> list[str]:
    """The files of ``folder`` whose bytes differ from what the manifest ``made`` recorded of
    them (none for a manifest without digests)."""
    recorded = recorded_digests(made)
    if not recorded:
        return []
    try:
        now = digests(folder, [e for e in recorded if isinstance(e, str)])
    except OSError:
        return []  # unreadable: the listing's own check says so
    return sorted(e for e, h in now.items() if h != recorded[e])


#: How a refusal offers --force where it would replace an output (what --force does to it).
FORCE_REPLACES = "--force to replace it (the old one is kept beside it as .replaced-N)"

#: Files that file managers put into any folder they show (macOS Finder, Windows Explorer):
#: never listed, so that looking at a result does not make it the user's.
OS_METADATA = frozenset({".DS_Store", "Thumbs.db", "desktop.ini"})


def listing(folder: str | Path) -> list[str]:
    """Every entry below ``folder`` but its manifest and :data:`OS_METADATA`, sorted: paths
    relative to ``folder`` with ``/`` between parts, a folder's ending in ``/`` (symbolic links
    are entries, not followed)."""
    out = []

    def walk(d: str, prefix: str) -> None:
        for e in sorted(os.scandir(d), key=lambda e: e.name):
            rel = prefix + e.name
            if rel == MANIFEST or e.name in OS_METADATA:
                continue
            if e.is_dir(follow_symlinks=False):
                out.append(rel + "/")
                walk(e.path, rel + "/")
            else:
                out.append(rel)

    walk(str(folder), "")
    return out


def _foreign(folder: Path, own: set[str]) -> list[str]:
    """The entries below ``folder`` that are not in ``own`` (see :func:`listing`), sorted; a
    foreign folder counts as one entry (its contents are not listed)."""
    found: list[str] = []
    folders: list[str] = []  # the foreign folders found so far
    for rel in listing(folder):  # a folder comes before what it holds
        if rel not in own and not any(rel.startswith(f) for f in folders):
            found.append(rel)
            if rel.endswith("/"):
                folders.append(rel)
    return found


def _last_component(text: str) -> str:
    return text.rstrip("/" + os.sep).rsplit("/", 1)[-1].rsplit(os.sep, 1)[-1]


#: Bytes our temporary names add to an output's name: a folder's staging name
#: ``.<name>.staging-<pid>-<8 characters>`` (a pid has at most 7 digits on Linux), a file's
#: temporary name ``.<name>.<8 characters>.tmp``.
_NAME_RESERVE = {"folder": len("..staging--") + 7 + 8, "file": len("...tmp") + 8}


def _name_max(path: Path) -> int:
    """The longest file name (bytes) the file system under ``path`` takes (255 if unknown)."""
    for p in (path, *path.parents):
        if os.path.isdir(p):  # False, not OSError, for a name too long
            try:
                return int(os.pathconf(p, "PC_NAME_MAX"))
            except (OSError, ValueError, AttributeError):  # AttributeError: no pathconf (Windows)
                break
    return 255


def check_path(out: str | Path, option: str = "--out", what: str = "folder") -> Path:
    """Refuse an output path (of a ``what``: folder or file) that can never be swapped in (no
    writes).

    Empty, ``.``, ``..`` or ending in ``/..`` or ``/.``, the root, the current folder or one
    of its ancestors, a folder :func:`_what_it_holds` names (a top-level folder, the home
    folder, Python's installation, this package, or one holding them), below an existing file,
    or a name too long for the file system once our temporary suffix (staging folder,
    temporary file) is added.
    """
    text = str(out)
    if not text.strip():
        raise UserError(f"{option}: empty path")
    if _last_component(text) in ("", ".", ".."):
        raise UserError(f"{option} {text}: name a {what} (not '.', '..' or the root)")
    path = Path(text)
    limit = _name_max(path)
    for part in path.parts:
        if len(os.fsencode(part)) > limit:
            raise UserError(f"{option} {text}: a name in it is too long ({len(os.fsencode(part))}"
                            f" bytes; the file system takes at most {limit})")
    room = limit - _NAME_RESERVE.get(what, _NAME_RESERVE["folder"])
    if len(os.fsencode(path.name)) > room:
        raise UserError(f"{option} {text}: the {what} name is too long "
                        f"({len(os.fsencode(path.name))} bytes; at most {room} here)")
    resolved = path.resolve()
    cwd = Path.cwd().resolve()
    if cwd.is_relative_to(resolved):
        raise UserError(f"{option} {text}: is the current folder or one of its parents; name a "
                        "new folder for the results")
    held = _what_it_holds(resolved) if what == "folder" else ""
    if held:
        raise UserError(f"{option} {text}: {held}, which results never replace (even with "
                        "--force); name a new folder for the results")
    for parent in path.parents:
        if parent.exists() or parent.is_symlink():
            if not parent.is_dir():
                raise UserError(f"{option} {text}: {parent} is a file, not a folder")
            break
    return path


def _what_it_holds(resolved: Path) -> str:
    """Why a folder may never be replaced by results ("" if it may): a folder at the top of the
    file system (``/usr``, ``/tmp``), or the home folder, Python's installation or this package,
    or a folder holding one of them. Results replace ``--out`` whole, and ``--force`` puts any
    folder aside: these it must not move even for a moment."""
    if len(resolved.parts) <= 2:  # the root, or a folder in it
        return "is a folder at the top of the file system"
    for label, place in (("the home folder", Path.home()), ("Python's installation", sys.prefix),
                         ("Python's installation", sys.base_prefix),
                         ("the itg_vision package", Path(__file__).parent)):
        place = Path(place).resolve()
        if place.is_relative_to(resolved):
            return f"{'is' if resolved == place else 'holds'} {label} ({place})"
    return ""


def check_out_dir(out: str | Path, command: str, *, force: bool = False,
                  option: str = "--out", inputs: dict | None = None) -> Path:
    """Check that ``command`` may replace ``out`` with a new output folder; raise `UserError`
    (one line naming ``option``) if not. Writes nothing.

    Allowed: a path that does not exist, an empty folder, a folder whose manifest names
    ``command`` and that holds nothing but the entries that manifest lists (what an earlier run
    of ``command`` wrote), or any folder, and a symbolic link, with ``force``. Never a file.
    An entry named like one this run writes is no exception: a file the user put there while
    the command worked is theirs, whatever its name.

    A manifest written before manifests listed their entries proves nothing about the rest of
    the folder: such a folder is refused (``force`` replaces it). The file managers' own
    files (:data:`OS_METADATA`) are nobody's results and never count.

    ``inputs`` maps the option that named each of the command's input files to its path (None
    or empty: none): one inside ``out`` is refused even with ``force``, which would move it
    aside with the folder, leaving the record naming a path that is gone.
    """
    path = check_path(out, option)
    where = path.resolve()
    for label, file in (inputs or {}).items():
        if file and where in Path(file).resolve().parents:
            raise UserError(f"{label} {file} lies inside {option} {out}, which this command "
                            f"replaces whole: move it out of {out}, or give another {option}")
    if not (path.exists() or path.is_symlink()):
        return path
    if path.is_symlink():  # the user's link: replacing it would delete it (never its target)
        if force:
            return path
        raise UserError(f"{option} {out}: is a symbolic link (to {os.readlink(path)}); give the "
                        f"folder itself or another {option}, or add --force to write there "
                        "anyway (the link is kept)")
    if not path.is_dir():
        raise UserError(f"{option} {out}: exists and is not a folder; choose another {option}")
    if os.path.ismount(path):  # a volume: results replace --out whole, by renaming it
        raise UserError(f"{option} {out}: is a mount point, which cannot be renamed, and results "
                        f"replace {option} whole by renaming; give a folder inside it (e.g. "
                        f"{option} {path / 'results'})")
    try:
        entries = sorted(e.name for e in os.scandir(path))
    except OSError as exc:
        raise UserError(f"{option} {out}: cannot read the folder ({exc.strerror})") from None
    if not entries or force:
        return path
    made = read_manifest(path)
    if made is not None and made.get("command") == command:
        recorded = made.get("entries")
        if not (isinstance(recorded, list) and all(isinstance(e, str) for e in recorded)):
            raise UserError(f"{option} {out}: was made by an earlier itg_vision, whose manifest "
                            f"does not list what it wrote; choose another {option}, or add "
                            f"{FORCE_REPLACES}")
        try:
            foreign = _foreign(path, set(recorded))
        except OSError as exc:
            raise UserError(f"{option} {out}: cannot read the folder ({exc.strerror})") from None
        changed = edited(path, made)
        if not foreign and not changed:
            return path
        if foreign:
            n = f"{len(foreign)} entr{'y' if len(foreign) == 1 else 'ies'}"
            what = f"holds {n} that {command} did not write (first: {foreign[0]})"
        else:
            n = count(changed, "file")
            what = f"holds {n} changed since {command} wrote {'it' if len(changed) == 1 else 'them'} (first: {changed[0]})"
        raise UserError(f"{option} {out}: {what}; move "
                        f"{'it' if len(foreign) + len(changed) == 1 else 'them'} out or "
                        f"choose another {option}, or add --force to write there anyway (the folder is kept)")
    if made is not None:
        raise UserError(f"{option} {out}: holds the output of `{made.get('command')}`, not of "
                        f"`{command}`; choose another {option}, or add {FORCE_REPLACES}")
    shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
    n = f"{len(entries)} entr{'y' if len(entries) == 1 else 'ies'}"
    raise UserError(f"{option} {out}: is a folder that {command} did not make ({n}: {shown}); "
                    f"choose another {option}, or add {FORCE_REPLACES}")


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` may still run (its staging folder is then not stale). On Windows
    ``os.kill(pid, 0)`` would send CTRL_C_EVENT, not probe: every process counts as alive there,
    so nothing is cleaned."""
    if pid == os.getpid() or os.name == "nt":
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):  # someone else's process; a pid beyond the range
        return True
    return True


def _remove_ours(folder: Path) -> None:
    """Remove a folder of ours (a staging folder, an old output folder), its manifest last: a
    removal cut short leaves the folder still marked as ours, so the next run finishes it."""
    with contextlib.suppress(OSError):  # unreadable: the rmtree below says so
        for e in os.scandir(folder):
            if e.name == MANIFEST:
                continue
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(e.path, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    os.unlink(e.path)
    try:
        shutil.rmtree(folder)  # the manifest, then the folder
    except OSError as exc:  # e.g. a result the user made read-only: say where it stays
        if folder.exists():
            print(f"note: could not remove {folder}, what this command replaced or left "
                  f"unfinished ({exc.strerror or exc}); remove it yourself", file=sys.stderr)


def _stale_pattern(name: str) -> re.Pattern:
    """The names :func:`staged_dir` gives its staging folder (``mkdtemp``'s 8 characters) and the
    old folder of a swap, beside an output called ``name``."""
    return re.compile(rf"^\.{re.escape(name)}\.(?:staging-(?P<spid>\d+)-[a-z0-9_]{{8}}"
                      rf"|old-(?P<opid>\d+))$")


def clean_stale(out: str | Path) -> list[Path]:
    """Remove staging folders left beside ``out`` by killed runs (their process is gone); put
    back an old folder left by a run killed between the two renames of the swap. Returns the
    paths removed or restored.

    Only folders named exactly as :func:`staged_dir` names them are touched: a staging folder
    carrying our manifest (or empty: a run killed as it began), and an old folder carrying our
    manifest, or any old folder whose swap was cut short (its run's staging folder lies beside
    it: a folder of the user's replaced with ``--force``), which is put back. Anything else,
    however alike its name, is the user's and left alone."""
    out = Path(out)
    parent = out.parent
    if not parent.is_dir():
        return []
    pat = _stale_pattern(out.name)
    stale = []  # (entry, pid, staging?, ours?) of the processes that are gone
    for entry in sorted(os.scandir(parent), key=lambda e: e.name):
        m = pat.match(entry.name)
        if not m or not entry.is_dir(follow_symlinks=False):
            continue
        pid = int(m.group("spid") or m.group("opid"))
        if not _pid_alive(pid):
            stale.append((Path(entry.path), pid, m.group("spid") is not None,
                          read_manifest(entry.path) is not None))
    swapping = {pid for _, pid, staging, ours in stale if staging and ours}
    done = []
    for p, pid, staging, ours in sorted(stale, key=lambda s: s[2]):  # old folders first
        if staging and not ours:  # nothing in it yet: nothing to lose
            try:
                os.rmdir(p)
            except OSError:
                continue
        elif not staging and (ours or pid in swapping) and not (out.exists() or out.is_symlink()):
            os.replace(p, out)  # killed mid-swap: the old folder comes back
        elif ours:
            _remove_ours(p)
        else:
            continue
        done.append(p)
    return done


def _make_parents(folder: Path) -> list[Path]:
    """mkdir -p ``folder``; return the folders created (deepest last)."""
    missing = []
    p = folder
    while not p.exists():
        missing.append(p)
        p = p.parent
    created = []
    try:
        for d in reversed(missing):
            try:
                d.mkdir()
            except FileExistsError:  # "b/.." once b is made: there already
                if not d.is_dir():
                    raise
                continue
            created.append(d)
    except BaseException:
        _remove_dirs(created)
        raise
    return created


def _remove_dirs(created: list[Path]) -> None:
    for d in reversed(created):
        try:
            d.rmdir()
        except OSError:
            pass


def probe_folder(folder: str | Path, option: str = "--out") -> None:
    """Check that files can be created in ``folder`` (made if missing) by creating and removing
    one; whatever this made is removed again. Raises `UserError` naming ``option``."""
    folder = Path(folder)
    created: list[Path] = []
    try:
        created = _make_parents(folder)
        fd, tmp = tempfile.mkstemp(prefix=".itg_vision-probe.", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise UserError(f"{option}: cannot write in {folder} ({exc.strerror or exc})") from None
    finally:
        _remove_dirs(created)


@contextmanager
def flocked(path: Path, *, wait: bool = True):
    """Hold an advisory lock (``fcntl.flock``) on the file or folder ``path`` (nothing is written
    into it); yields False only when ``wait`` is False and another holds it (else once held:
    ``wait``, until the other lets go). No lock where there is no ``fcntl`` (Windows) or
    ``path`` cannot be opened: True, as nobody can hold it either."""
    try:
        import fcntl

        fd = os.open(path, os.O_RDONLY)
    except (ImportError, OSError):
        yield True
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            yield False
            return
        yield True
    finally:
        os.close(fd)  # releases the lock


@contextmanager
def staged_dir(out: str | Path, command: str = "itg_vision", *, force: bool = False,
               key=None, option: str = "--out", inputs: dict | None = None):
    """Yield a fresh staging folder; on success it replaces ``out`` whole, on error it goes.

    ``out`` is checked first (:func:`check_out_dir`: only a folder ``command`` made that holds
    nothing else and no file changed since, an empty one, or any folder with ``force``; never a
    mount point); the staging folder is marked with the manifest of ``command`` (and ``key``),
    which lists, once the command has written its results, every entry it wrote and each file's
    SHA-256: a later run of the same command may replace those, and nothing else. Readers of
    ``out`` see either the old results or the new ones, never a mix; commands swapping into
    the same ``out`` at once take turns (:func:`flocked` on its parent folder). Whatever goes wrong before the
    swap (a bad input, an error, a full disk, Ctrl-C) leaves ``out`` as it was and no staging
    folder behind, and a file that could not be written is named under ``out``, not under the
    staging folder. A file the user put into ``out`` meanwhile, or a swap the system refuses,
    leaves ``out`` as it was and the new results beside it (``<name>.new-N``), said in one line.
    """
    path = check_path(out, option)
    with flocked(path.parent):  # (no parent yet: nothing to lock, nobody swapping there)
        clean_stale(path)  # first: a killed swap's old folder comes back
        out = check_out_dir(out, command, force=force, option=option, inputs=inputs)
    created: list[Path] = []
    prefix = f".{out.name}.staging-{os.getpid()}-"
    try:
        created = _make_parents(out.parent)
        tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=out.parent))
        os.chmod(tmp, 0o755)
    except BaseException as exc:  # a signal may land after mkdtemp, before tmp is known: by name
        for made in out.parent.glob(f"{glob.escape(prefix)}*"):
            shutil.rmtree(made, ignore_errors=True)
        _remove_dirs(created)
        if not isinstance(exc, OSError):
            raise
        raise UserError(f"{option} {out}: cannot create a folder there ({exc.strerror or exc})") \
            from None
    try:
        try:
            write_json(tmp / MANIFEST, manifest(command, key))  # marks the staging folder as ours
            yield tmp
            entries = listing(tmp)
            write_json(tmp / MANIFEST, manifest(command, key, entries, digests(tmp, entries)))
        except OSError as exc:
            raise _named_under(exc, tmp, out, option) from None
        with flocked(out.parent):
            try:
                check_out_dir(out, command, force=force, option=option)  # changed meanwhile?
            except UserError as exc:  # the user's files stay; so do the results: beside them
                raise UserError(f"{exc}; the new results are in {_set_beside(out, tmp)}") \
                    from None
            keep = force and (out.is_symlink() or out.is_dir() and not _replaceable(out, command))
            old = _swap(out, tmp, keep, command, option)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _remove_dirs(created)
        raise
    if old is not None and not keep:
        if old.is_symlink() or not old.is_dir():
            old.unlink()  # a link (never what it points to)
        else:  # ours: the manifest goes last
            _remove_ours(old)


def _named_under(exc: OSError, tmp: Path, out: Path, option: str) -> OSError | UserError:
    """A write that failed in the staging folder, said of ``out``: the staging folder is about
    to go, and ``out`` is what the user named (a path the system refuses: one line)."""
    from .errors import _REFUSED_PATH

    name = os.fsdecode(exc.filename) if exc.filename is not None else ""
    if exc.errno not in _REFUSED_PATH or not name.startswith(str(tmp)):
        return exc
    rel = Path(name).relative_to(tmp)
    return UserError(f"{option} {out}: could not write {rel} there ({exc.strerror or exc}); "
                     f"{out} was left as it was")


def _swap(out: Path, tmp: Path, keep: bool, command: str, option: str) -> Path | None:
    """Put the staging folder ``tmp`` in place of ``out``: the old ``out`` is renamed aside
    first (kept as ``<name>.replaced-N`` if ``keep``, said once the swap is done, else to a name
    of ours the caller removes), which it returns (None if there was none). Whatever stops it
    between the two renames (Ctrl-C, a rename the system refuses), the old ``out`` is put back
    first; a refused rename keeps the new results as ``<name>.new-N`` beside it and raises a
    `UserError` saying so."""
    old = None
    try:
        if out.exists() or out.is_symlink():
            old = (_free_name(out, "replaced") if keep
                   else out.parent / f".{out.name}.old-{os.getpid()}")
            os.replace(out, old)
        os.replace(tmp, out)
    except BaseException as exc:
        if old is not None and not (out.exists() or out.is_symlink()):
            os.replace(old, out)
        if not isinstance(exc, OSError):
            raise
        raise UserError(f"{option} {out}: could not be replaced ({exc.strerror or exc}); it is "
                        f"as it was, and the new results are in {_set_beside(out, tmp)}") from None
    if keep and old is not None:  # --force over what this command did not make (or a link)
        why = "was a symbolic link" if old.is_symlink() else f"held what {command} did not write"
        print(f"note: {option} {out}: {why}; kept as {old}", file=sys.stderr)
    return old


def _set_beside(out: Path, tmp: Path) -> Path:
    """Keep the staging folder ``tmp``, a whole result of ours with its manifest, beside ``out``
    as ``<name>.new-N`` (``out`` could not take it); returns that name."""
    new = _free_name(out, "new")
    os.replace(tmp, new)
    return new


def _replaceable(out: Path, command: str) -> bool:
    """Whether ``command`` may replace ``out`` without ``--force``: only its own results there."""
    try:
        check_out_dir(out, command)
    except UserError:
        return False
    return True


def _free_name(path: Path, tag: str) -> Path:
    """``<name>.<tag>-N`` beside ``path``, before a file's suffix, N the smallest free from 1."""
    suffix = path.suffix if path.is_file() else ""
    stem = path.name[:-len(suffix)] if suffix else path.name
    k = 1
    while (free := path.parent / f"{stem}.{tag}-{k}{suffix}").exists() or free.is_symlink():
        k += 1
    return free


def keep_aside(path: Path, why: str) -> Path:
    """Rename ``path`` (a file or a folder ``--force`` writes over) to ``<name>.replaced-N``
    beside it, before a file's suffix, N the smallest free from 1; say so on stderr as
    ``note: <why>; kept as <new name>``. Nothing the user made is deleted. Returns the new name."""
    kept = _free_name(path, "replaced")
    os.replace(path, kept)
    print(f"note: {why}; kept as {kept}", file=sys.stderr)
    return kept


# ---------------------------------------------------------------------------- printed reports
class Transcript:
    """Print a report's lines as they come and keep them, so that a command which prints its
    figures can also save exactly what it printed (:func:`save_report`)."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def __call__(self, text: str = "") -> None:
        print(text, flush=True)
        self.lines.append(text)

    @property
    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


def save_report(out: str | Path, command: str, text: str, results, *, force: bool = False) -> Path:
    """Write ``report.txt`` (what the command printed) and ``results.json`` (its figures) as
    the folder ``out``, replacing it only as :func:`staged_dir` allows; return the folder."""
    with staged_dir(out, command, force=force) as tmp:
        write_files({tmp / "results.json": json_text(results).encode(),
                     tmp / "report.txt": text.encode()})
    return Path(out)
