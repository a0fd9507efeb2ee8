"""Output ownership: a command replaces only what it made; nothing half-written; strict JSON."""

import io
import json
import math
import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT

from itg_vision import outputs
from itg_vision.errors import UserError, run_main
from itg_vision.progress import LineProgress, progress


def _tree(root):
    """Every path below ``root`` with its bytes (None for folders)."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for d in dirnames:
            out[os.path.relpath(os.path.join(dirpath, d), root)] = None
        for f in filenames:
            p = os.path.join(dirpath, f)
            out[os.path.relpath(p, root)] = open(p, "rb").read()
    return out


def _make(out, command="run", text="new"):
    with outputs.staged_dir(out, command) as tmp:
        (tmp / "result.txt").write_text(text)


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


# ----------------------------------------------------------------------------- staged_dir
def test_a_command_replaces_its_own_folder_and_marks_it(tmp_path):
    out = tmp_path / "r"
    _make(out, text="one")
    assert outputs.read_manifest(out)["command"] == "run"
    _make(out, text="two")
    assert (out / "result.txt").read_text() == "two"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]  # no staging or old folder left


@pytest.mark.parametrize("where", ["in mkdtemp, once the folder exists", "in chmod"])
def test_a_signal_while_the_staging_folder_is_made_leaves_none_behind(tmp_path, monkeypatch,
                                                                      where):
    """SIGTERM/SIGHUP/Ctrl-C raise in the main thread wherever it is; one that landed after
    mkdtemp had made the staging folder and before the cleanup knew of it left the folder behind
    (seen once in test_processes' SIGHUP case, which polls for that folder and signals at once).
    An interrupt raised at either point now leaves nothing beside ``out``."""
    out = tmp_path / "r"
    if where == "in chmod":
        def interrupted(*args):
            raise KeyboardInterrupt
        monkeypatch.setattr(outputs.os, "chmod", interrupted)
    else:
        made = outputs.tempfile.mkdtemp

        def interrupted(**kwargs):
            made(**kwargs)
            raise KeyboardInterrupt
        monkeypatch.setattr(outputs.tempfile, "mkdtemp", interrupted)
    with pytest.raises(KeyboardInterrupt):
        with outputs.staged_dir(out, "run"):
            pass
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("setup, expect", [
    ("foreign", "is a folder that run did not make (2 entries: sub, thesis.tex)"),
    ("other-command", "holds the output of `paper`"),
    ("file", "exists and is not a folder"),
])
def test_foreign_things_are_refused_and_untouched(tmp_path, setup, expect):
    out = tmp_path / "thesis"
    if setup == "foreign":
        (out / "sub").mkdir(parents=True)
        (out / "thesis.tex").write_text("my thesis")
        (out / "sub" / "fig.png").write_bytes(b"\x89PNG")
    elif setup == "other-command":
        _make(out, "paper")
    else:
        out.write_text("my notes")
    before = _tree(tmp_path)
    with pytest.raises(UserError) as exc:
        _make(out)
    assert expect in str(exc.value)
    assert _tree(tmp_path) == before


def test_a_rerun_keeps_what_the_user_put_into_its_folder(tmp_path):
    """The manifest lists what the command wrote; a folder that holds anything else (notes, an
    analysis folder, a file inside one of the command's own folders) is not replaced: the
    refusal names the first such entry and how many there are. --force replaces it anyway."""
    out = tmp_path / "res1"
    with outputs.staged_dir(out, "run") as tmp:
        (tmp / "result.txt").write_text("one")
        (tmp / "video").mkdir()
        (tmp / "video" / "v.mp4").write_bytes(b"mp4")
    assert outputs.read_manifest(out)["entries"] == ["result.txt", "video/", "video/v.mp4"]
    _make(out, text="two")  # only its own entries there: replaced
    assert (out / "result.txt").read_text() == "two" and not (out / "video").exists()
    (out / "notes.txt").write_text("my notes")
    (out / "analysis").mkdir()
    (out / "analysis" / "fit.py").write_text("x")
    before = _tree(tmp_path)
    with pytest.raises(UserError) as exc:
        _make(out, text="three")
    assert str(exc.value) == ("--out {}: holds 2 entries that run did not write (first: "
                              "analysis/); move them out or choose another --out, or add --force "
                              "to write there anyway (the folder is kept)").format(out)
    assert _tree(tmp_path) == before
    with outputs.staged_dir(out, "run", force=True) as tmp:  # --force: replaced, and kept
        (tmp / "result.txt").write_text("forced")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res1", "res1.replaced-1"]
    assert sorted(p.name for p in out.iterdir()) == [outputs.MANIFEST, "result.txt"]
    kept = tmp_path / "res1.replaced-1"
    assert (kept / "notes.txt").read_text() == "my notes" and (kept / "analysis" / "fit.py").exists()


def test_a_file_put_inside_a_folder_the_command_wrote_is_the_users(tmp_path):
    out = tmp_path / "r"
    with outputs.staged_dir(out, "run") as tmp:
        (tmp / "video").mkdir()
    (out / "video" / "cut.mp4").write_bytes(b"the user's edit")
    with pytest.raises(UserError, match=r"holds 1 entry that run did not write \(first: "
                                        r"video/cut.mp4\); move it out"):
        _make(out)
    assert (out / "video" / "cut.mp4").read_bytes() == b"the user's edit"


def test_a_file_the_user_edited_in_a_folder_the_command_wrote_is_the_users(tmp_path):
    """A note appended to a result's trace.csv was overwritten by the next run: the manifest
    named the file, not its bytes. It now keeps each file's SHA-256: a file changed since is
    the user's, refused like a file put in; --force keeps the folder aside."""
    out = tmp_path / "r"
    with outputs.staged_dir(out, "run") as tmp:
        (tmp / "trace.csv").write_text("x_mm\n1\n")
        (tmp / "summary.json").write_text("{}")
    _make(out)  # unedited: replaced
    with outputs.staged_dir(out, "run") as tmp:
        (tmp / "trace.csv").write_text("x_mm\n1\n")
    with open(out / "trace.csv", "a") as f:
        f.write("my annotation\n")
    before = _tree(tmp_path)
    with pytest.raises(UserError) as exc:
        _make(out)
    assert str(exc.value) == (f"--out {out}: holds 1 file changed since run wrote it (first: "
                              "trace.csv); move it out or choose another --out, or add --force to "
                              "write there anyway (the folder is kept)")
    assert _tree(tmp_path) == before
    with outputs.staged_dir(out, "run", force=True) as tmp:
        (tmp / "result.txt").write_text("forced")
    assert (tmp_path / "r.replaced-1" / "trace.csv").read_text().endswith("my annotation\n")


def test_a_mount_point_is_refused_before_any_work(tmp_path, monkeypatch):
    """A mount point (a container's volume) cannot be renamed, and results replace --out by
    renaming it: the whole run used to finish, then end in an EBUSY traceback with its results
    in a hidden staging folder. Refused first, even with --force, pointing inside it."""
    out = tmp_path / "volume"
    out.mkdir()
    real = os.path.ismount
    monkeypatch.setattr(os.path, "ismount", lambda p: Path(p) == out or real(p))
    for force in (False, True):
        with pytest.raises(UserError, match=rf"--out {out}: is a mount point, which cannot be "
                                            rf"renamed, .*\(e.g. --out {out}/results\)"):
            with outputs.staged_dir(out, "run", force=force):
                raise AssertionError("no work before the refusal")
    assert sorted(tmp_path.iterdir()) == [out]


def test_a_swap_the_system_refuses_keeps_both_results(tmp_path, monkeypatch):
    """If renaming --out fails at the swap (EBUSY: a mount point that got past the check, a
    file system that refuses), the old results stay in place and the new ones are kept beside
    them as <name>.new-1, said in one line."""
    out = tmp_path / "r"
    _make(out, text="old")
    real = os.replace

    def busy(src, dst):
        if Path(src) == out:
            raise OSError(16, "Device or resource busy", str(src))
        return real(src, dst)

    monkeypatch.setattr(os, "replace", busy)
    with pytest.raises(UserError) as exc:
        _make(out, text="new")
    assert str(exc.value) == (f"--out {out}: could not be replaced (Device or resource busy); it "
                              f"is as it was, and the new results are in {out}.new-1")
    assert (out / "result.txt").read_text() == "old"
    assert (tmp_path / "r.new-1" / "result.txt").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r", "r.new-1"]


def test_ctrl_c_between_the_two_renames_puts_the_old_folder_back(tmp_path, monkeypatch):
    """Ctrl-C after --out was renamed aside and before the new folder took its place: the old
    folder is put back at once (it stayed missing until the next run, and a plain folder of the
    user's, an empty --out, never came back), the interruption goes on, nothing is left."""
    out = tmp_path / "empty"
    out.mkdir()
    real = os.replace

    def interrupted(src, dst):
        if Path(dst) == out and Path(src).name.startswith(".empty.staging-"):
            raise KeyboardInterrupt  # as the new folder was to take the old one's place
        return real(src, dst)

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _make(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty"] and not any(out.iterdir())


def test_a_refused_swap_over_a_forced_folder_says_no_false_note(tmp_path, monkeypatch, capsys):
    """With --force over the user's folder, the folder is renamed aside before the swap: if the
    swap is then refused, the folder goes back, and no note says it was kept elsewhere."""
    out = tmp_path / "u"
    out.mkdir()
    (out / "mine.txt").write_text("mine")
    real = os.replace

    def busy(src, dst):
        if Path(dst) == out and Path(src).name.startswith(".u.staging-"):
            raise OSError(16, "Device or resource busy", str(src))
        return real(src, dst)

    monkeypatch.setattr(os, "replace", busy)
    with pytest.raises(UserError, match=r"could not be replaced \(Device or resource busy\)"):
        with outputs.staged_dir(out, "run", force=True) as tmp:
            (tmp / "result.txt").write_text("new")
    assert capsys.readouterr().err == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["u", "u.new-1"]
    assert (out / "mine.txt").read_text() == "mine"


def test_a_manifest_that_cannot_be_written_is_named_under_out(tmp_path, monkeypatch):
    """The manifest, written last (with every file's digest), is as likely as any file to meet
    a full disk: its failure named the staging folder, gone by then."""
    out = tmp_path / "o"
    real = outputs.write_json

    def full(path, obj):
        if isinstance(obj, dict) and "entries" in obj:
            raise OSError(28, "No space left on device", str(path))
        return real(path, obj)

    monkeypatch.setattr(outputs, "write_json", full)
    with pytest.raises(UserError) as exc:
        _make(out)
    assert str(exc.value) == (f"--out {out}: could not write {outputs.MANIFEST} there (No space "
                              f"left on device); {out} was left as it was")
    assert list(tmp_path.iterdir()) == []


def test_commands_swapping_into_one_out_take_turns(tmp_path):
    """While another command holds --out's parent (checking or swapping), a second one waits
    for it, so that neither sees the other half-done (6 processes at a barrier: a rename of a
    folder another had just moved, or a false refusal, 2 trials in 20). Here the test holds the
    lock: the command must not finish in 2 s; released, it does."""
    import threading

    out = tmp_path / "o"
    done = threading.Event()

    def run():
        _make(out)
        done.set()

    with outputs.flocked(tmp_path):
        worker = threading.Thread(target=run)
        worker.start()
        assert not done.wait(2.0) and not out.exists()
    worker.join(30)
    assert done.is_set() and (out / "result.txt").read_text() == "new"


def test_a_path_through_a_folder_not_yet_made_is_made(tmp_path, monkeypatch):
    """b/../c with b missing: mkdir -p makes it; the swap used to refuse it ("File exists")."""
    monkeypatch.chdir(tmp_path)
    _make(Path("b/../c"))
    assert (tmp_path / "c" / "result.txt").read_text() == "new" and (tmp_path / "b").is_dir()


def test_what_an_earlier_run_wrote_counts_as_the_commands_own(tmp_path):
    """An earlier run of the same command may have written entries this one does not (a video,
    another version's files): they are the command's own and replaced; the new manifest lists
    only what this run wrote."""
    out = tmp_path / "r"
    with outputs.staged_dir(out, "run") as tmp:
        (tmp / "result.txt").write_text("one")
        (tmp / "video").mkdir()
        (tmp / "video" / "v.mp4").write_bytes(b"mp4")
    outputs.check_out_dir(out, "run")  # before the work: nothing foreign
    _make(out, text="two")
    assert sorted(p.name for p in out.iterdir()) == [outputs.MANIFEST, "result.txt"]
    assert outputs.read_manifest(out)["entries"] == ["result.txt"]


def test_a_folder_from_before_manifests_listed_entries(tmp_path):
    """A manifest without ``entries`` (written by an earlier version) proves nothing about the
    rest of the folder: refused before any work (the command body never runs), one line,
    nothing touched; --force replaces it, and the new manifest lists what it wrote."""
    out = tmp_path / "r"
    out.mkdir()
    outputs.write_json(out / outputs.MANIFEST, outputs.manifest("run"))
    (out / "result.txt").write_text("old")
    (out / "notes.txt").write_text("my notes")
    before = _tree(tmp_path)
    worked = []
    with pytest.raises(UserError, match=r"--out .*r: was made by an earlier itg_vision, whose "
                                        r"manifest does not list what it wrote; .* --force"):
        with outputs.staged_dir(out, "run"):
            worked.append(True)
    assert not worked and _tree(tmp_path) == before
    with outputs.staged_dir(out, "run", force=True) as tmp:
        (tmp / "result.txt").write_text("new")
    assert outputs.read_manifest(out)["entries"] == ["result.txt"]
    assert not (out / "notes.txt").exists()
    assert (tmp_path / "r.replaced-1" / "notes.txt").read_text() == "my notes"  # kept


def test_a_file_managers_own_files_do_not_make_a_result_the_users(tmp_path):
    """Finder's .DS_Store (or Explorer's Thumbs.db) in a result folder, even in a subfolder, is
    not the user's work: the re-run replaces the folder; a real file beside it is refused."""
    out = tmp_path / "r"
    with outputs.staged_dir(out, "run") as tmp:
        (tmp / "plots").mkdir()
        (tmp / "plots" / "a.png").write_bytes(b"png")
    (out / ".DS_Store").write_bytes(b"finder")
    (out / "plots" / "Thumbs.db").write_bytes(b"explorer")
    with outputs.staged_dir(out, "run") as tmp:
        (tmp / "plots").mkdir()
        (tmp / "plots" / "a.png").write_bytes(b"png 2")
    assert (out / "plots" / "a.png").read_bytes() == b"png 2"
    (out / "plots" / "mine.png").write_bytes(b"mine")
    with pytest.raises(UserError, match=r"first: plots/mine.png"):
        _make(out)


def test_a_file_the_user_puts_in_while_the_command_works_is_kept(tmp_path):
    """The user's file stays in --out, with the old results; the new results are not thrown
    away but kept whole beside it as r.new-1 (they were deleted), and the line says where."""
    out = tmp_path / "r"
    _make(out, text="old")
    with pytest.raises(UserError, match=rf"first: notes.txt\).*; the new results are in "
                                        rf"{re.escape(str(tmp_path / 'r.new-1'))}$"):
        with outputs.staged_dir(out, "run") as tmp:
            (tmp / "result.txt").write_text("new")
            (out / "notes.txt").write_text("written meanwhile")
    assert (out / "notes.txt").read_text() == "written meanwhile"
    assert (out / "result.txt").read_text() == "old"
    assert (tmp_path / "r.new-1" / "result.txt").read_text() == "new"
    assert outputs.read_manifest(tmp_path / "r.new-1")["entries"]  # a whole result, listed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r", "r.new-1"]


@pytest.mark.parametrize("taken_by", ["a folder", "a dangling link"])
def test_force_replaces_a_foreign_folder_keeping_it_and_never_a_file(tmp_path, capsys, taken_by):
    """A successful run never deletes what the user made: --force puts the folder it replaces
    beside the new one, as <name>.replaced-N (the first free N), and says so. A name taken by
    a dangling link is not free (the link stays)."""
    folder, file = tmp_path / "f", tmp_path / "notes.txt"
    folder.mkdir()
    (folder / "x").write_text("x")
    taken = tmp_path / "f.replaced-1"  # taken: the next free name is used
    if taken_by == "a folder":
        taken.mkdir()
    else:
        taken.symlink_to(tmp_path / "gone")
    file.write_text("keep")
    with outputs.staged_dir(folder, "run", force=True) as tmp:
        (tmp / "result.txt").write_text("new")
    assert sorted(p.name for p in folder.iterdir()) == [outputs.MANIFEST, "result.txt"]
    assert (tmp_path / "f.replaced-2" / "x").read_text() == "x"
    assert capsys.readouterr().err == (f"note: --out {folder}: held what run did not write; "
                                       f"kept as {tmp_path / 'f.replaced-2'}\n")
    assert taken.is_dir() if taken_by == "a folder" else (
        taken.is_symlink() and os.readlink(taken) == str(tmp_path / "gone"))
    # a folder of its own results is replaced, with or without --force: nothing kept
    with outputs.staged_dir(folder, "run", force=True) as tmp:
        (tmp / "result.txt").write_text("newer")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f", "f.replaced-1", "f.replaced-2",
                                                          "notes.txt"]
    assert capsys.readouterr().err == ""
    with pytest.raises(UserError, match="not a folder"):
        with outputs.staged_dir(file, "run", force=True):
            pass
    assert file.read_text() == "keep"


def test_an_empty_folder_is_replaced(tmp_path):
    (tmp_path / "e").mkdir()
    _make(tmp_path / "e")
    assert (tmp_path / "e" / "result.txt").exists()


@pytest.mark.parametrize("out", [".", "..", "a/b/..", "a/.", "/", ""])
def test_paths_that_cannot_be_swapped_in_are_refused(tmp_path, monkeypatch, out):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a" / "b").mkdir(parents=True)
    before = _tree(tmp_path)
    with pytest.raises(UserError, match="--out"):
        _make(out)
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("what, n, limit", [("folder", 240, 229), ("file", 245, 241)])
def test_names_too_long_with_our_temporary_suffix_are_refused(tmp_path, what, n, limit):
    """A staging folder is ``.<name>.staging-<pid>-<8>``, a temporary file ``.<name>.<8>.tmp``:
    a name the file system takes alone can be too long with them (it failed with OSError after
    all the work). On a file system taking 255 bytes a name."""
    name = "c" * n
    with pytest.raises(UserError, match=f"the {what} name is too long \\({n} bytes; at most "
                                        f"{limit} here\\)"):
        outputs.check_path(tmp_path / name, what=what)
    outputs.check_path(tmp_path / name[:limit], what=what)
    with pytest.raises(UserError, match="a name in it is too long \\(300 bytes"):
        outputs.check_path(tmp_path / ("d" * 300) / "x")
    assert list(tmp_path.iterdir()) == []


def test_the_current_folder_and_its_parents_are_refused(tmp_path, monkeypatch):
    work = tmp_path / "w" / "here"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    for out in (str(work), str(tmp_path / "w"), "../../w"):
        with pytest.raises(UserError, match="current folder"):
            outputs.check_out_dir(out, "run", force=True)


def test_unwritable_places_fail_before_any_work_and_leave_nothing(tmp_path):
    ran = []
    for out in ("/proc/itg-vision-test/x", str(tmp_path / "file" / "x")):
        (tmp_path / "file").write_text("a file")
        with pytest.raises(UserError, match="--out"):
            with outputs.staged_dir(out, "run"):
                ran.append(out)
    assert ran == [] and sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_an_error_or_interrupt_keeps_the_old_output_and_leaves_no_staging(tmp_path):
    out = tmp_path / "r"
    _make(out, text="old")
    for exc in (UserError("bad input"), KeyboardInterrupt()):
        with pytest.raises(type(exc)):
            with outputs.staged_dir(out, "run") as tmp:
                (tmp / "result.txt").write_text("half")
                raise exc
        assert (out / "result.txt").read_text() == "old"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


def test_missing_parents_made_for_a_failed_run_are_removed(tmp_path):
    out = tmp_path / "new" / "deeper" / "r"
    with pytest.raises(UserError):
        with outputs.staged_dir(out, "run"):
            raise UserError("bad input found late")
    assert list(tmp_path.iterdir()) == []


def _ours(folder, command="run", **files):
    """A folder as staged_dir leaves it: our manifest and ``files`` (name=text)."""
    folder.mkdir()
    outputs.write_json(folder / outputs.MANIFEST, outputs.manifest(command))
    for name, text in files.items():
        (folder / name.replace("_", ".")).write_text(text)
    return folder


def test_staging_of_a_killed_run_is_cleaned_by_the_next_run(tmp_path):
    dead = _dead_pid()
    stale = _ours(tmp_path / f".r.staging-{dead}-abc12_yz", half_csv="1,2")
    begun = tmp_path / f".r.staging-{dead}-0123abcd"  # killed before its manifest: empty
    begun.mkdir()
    live = _ours(tmp_path / f".r.staging-{os.getpid()}-livelive")  # a run still going: left alone
    other = _ours(tmp_path / f".rr.staging-{dead}-xxxxxxxx")  # another output's staging: left alone
    _make(tmp_path / "r")
    assert not stale.exists() and not begun.exists() and live.exists() and other.exists()


def test_a_run_killed_between_the_two_renames_gets_its_old_folder_back(tmp_path):
    dead = _dead_pid()
    old = _ours(tmp_path / f".r.old-{dead}", result_txt="old")
    assert outputs.clean_stale(tmp_path / "r") == [old]
    assert (tmp_path / "r" / "result.txt").read_text() == "old"
    # killed after the swap, while removing the old folder: the rest of it goes
    old = _ours(tmp_path / f".r.old-{dead}", result_txt="older")
    assert outputs.clean_stale(tmp_path / "r") == [old] and not old.exists()
    assert (tmp_path / "r" / "result.txt").read_text() == "old"


def test_a_users_folder_replaced_with_force_comes_back_if_the_swap_was_cut_short(tmp_path):
    """--force over the user's folder, killed between the renames: the folder (no manifest) lies
    at .r.old-<pid>, the run's staging folder beside it; the next run puts the folder back and
    removes the staging folder."""
    dead = _dead_pid()
    old = tmp_path / f".r.old-{dead}"
    old.mkdir()
    (old / "thesis.tex").write_text("the user's")
    staging = _ours(tmp_path / f".r.staging-{dead}-abcdefgh", result_txt="new")
    assert outputs.clean_stale(tmp_path / "r") == [old, staging]
    assert (tmp_path / "r" / "thesis.tex").read_text() == "the user's" and not staging.exists()


def test_on_windows_no_process_counts_as_gone(monkeypatch):
    """There os.kill(pid, 0) sends CTRL_C_EVENT: never called, every staging folder kept."""
    called, dead = [], _dead_pid()
    monkeypatch.setattr(outputs.os, "name", "nt")
    monkeypatch.setattr(outputs.os, "kill", lambda *a: called.append(a))
    assert outputs._pid_alive(dead) and not called


def test_user_folders_that_look_like_staging_or_old_folders_are_left_alone(tmp_path):
    """Only a folder named exactly as staged_dir names it and carrying our manifest is a stale
    staging or old folder: a user's folder whose name matches the pattern is neither removed
    nor moved to ``--out`` (it was, and then the run refused the folder it had made)."""
    dead = _dead_pid()
    mine = tmp_path / f".r.staging-{dead}-mine"  # not mkdtemp's 8 characters
    exact = tmp_path / f".r.staging-{dead}-abcdefgh"  # the exact name, but no manifest
    old = tmp_path / f".r.old-{dead}"  # no manifest: not ours to put back
    older = tmp_path / f".r.old-{dead}-2"
    for folder in (mine, exact, old, older):
        folder.mkdir()
        (folder / "keep.txt").write_text("the user's")
    link = tmp_path / f".r.staging-{dead}-linklink"  # a link to the user's folder: not followed
    link.symlink_to(_ours(tmp_path / "elsewhere", result_txt="x"))
    before = _tree(tmp_path)
    assert outputs.clean_stale(tmp_path / "r") == []
    assert _tree(tmp_path) == before
    _make(tmp_path / "r")
    assert {k: v for k, v in _tree(tmp_path).items() if not k.startswith("r")} == before


def test_probe_folder_leaves_nothing(tmp_path):
    outputs.probe_folder(tmp_path / "a" / "b")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(UserError, match="cannot write"):
        outputs.probe_folder("/proc/itg-vision-test")


# ----------------------------------------------------------------------------- files, JSON
def test_write_json_is_strict_nan_and_infinity_become_null(tmp_path):
    p = tmp_path / "s.json"
    outputs.write_json(p, {"e": float("nan"), "l": [1.0, math.inf, np.float64(-np.inf)],
                           "a": np.array([1.5, np.nan]), "n": np.int64(3), "t": (np.nan,)})

    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    doc = json.loads(p.read_text(), parse_constant=refuse)
    assert doc == {"e": None, "l": [1.0, None, None], "a": [1.5, None], "n": 3, "t": [None]}


def test_write_bytes_keeps_the_old_file_when_writing_fails(tmp_path, monkeypatch):
    p = tmp_path / "f.txt"
    p.write_text("old")

    def full(*a):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputs.os, "replace", full)
    with pytest.raises(OSError):
        outputs.write_text(p, "new")
    assert p.read_text() == "old" and sorted(x.name for x in tmp_path.iterdir()) == ["f.txt"]


def test_a_failed_write_names_the_file_not_its_temporary_name(tmp_path):
    (tmp_path / "x.calib.png").mkdir()
    with pytest.raises(IsADirectoryError) as exc:
        outputs.write_files({tmp_path / "x.calib.png": b"png", tmp_path / "x.yaml": b"rig"})
    assert exc.value.filename == str(tmp_path / "x.calib.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.calib.png"]


def test_write_files_replaces_none_when_one_cannot_be_written(tmp_path):
    """A calibrated rig and its picture are one result: if the second file cannot be written,
    the first is not replaced either, and no temporary file is left."""
    a = tmp_path / "x.calib.png"
    a.write_text("old picture")
    (tmp_path / "a-file").write_text("in the way")
    with pytest.raises(OSError):
        outputs.write_files({a: b"new picture", tmp_path / "a-file" / "x.calib.yaml": b"rig"})
    assert a.read_text() == "old picture"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a-file", "x.calib.png"]
    outputs.write_files({a: b"new picture", tmp_path / "x.calib.yaml": b"rig"})
    assert a.read_bytes() == b"new picture" and (tmp_path / "x.calib.yaml").read_bytes() == b"rig"
    assert oct(a.stat().st_mode & 0o777) == "0o644"


# ----------------------------------------------------------------------------- errors, progress
def test_interrupted_gets_a_line_of_its_own(capsys):
    def body():
        sys.stderr.write("run: 10/180 pt")  # a progress bar mid-line
        raise KeyboardInterrupt

    assert run_main(body) == 130
    assert capsys.readouterr().err.splitlines()[-1] == "interrupted"


def test_progress_in_a_log_is_plain_lines(capsys):
    bar = progress(100, "run x", unit="pt")
    assert isinstance(bar, LineProgress)  # pytest's captured stderr is not a terminal
    bar.min_interval_s = 0.0
    for _ in range(100):
        bar.update(1)
    bar.close()
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert 2 <= len(lines) <= 12 and lines[-1].startswith("run x: 100/100 pt (100%)")
    assert len(set(lines)) == len(lines)  # the last line once
    progress(100, "quiet", quiet=True).update(5)
    assert capsys.readouterr().err == ""


def test_a_logs_last_line_has_the_last_word(capsys):
    """A count set after the update that printed the 100 % line still ends the log (the noise
    sweep's log ended '71/72 runs')."""
    bar = progress(10, "sweep", unit="")
    bar.min_interval_s = 0.0
    for n in range(1, 3):
        bar.update(5)
        bar.set_postfix_str(f"{n}/2 runs")
    bar.close()
    assert capsys.readouterr().err.splitlines()[-1].startswith("sweep: 100%, 2/2 runs")


# ----------------------------------------------------------------------------- run's folders
def test_default_run_folders_tell_rigs_and_files_apart_by_their_whole_names():
    """A calibrated rig is not its true rig: planar.calib.yaml names its folder rigplanar.calib,
    not rigplanar (which took the name up to its first dot); a file's type is left out."""
    from types import SimpleNamespace

    from itg_vision import run

    def folder(*argv):
        args = run.build_parser().parse_args(list(argv))
        prep = SimpleNamespace(config=SimpleNamespace(arm="two-link", controller="itg",
                                                      feedback="vision"),
                               trajectory=SimpleNamespace(name="ellipse-t1"))
        return run.default_out(args, prep).name

    assert folder("--rig", "planar") == "two-link-ellipse-t1-itg-vision-rigplanar"
    assert folder("--rig", "cameras/planar.calib.yaml") == "two-link-ellipse-t1-itg-vision-rigplanar.calib"
    assert folder("--rules", "my/v1.2.rules") == "two-link-ellipse-t1-itg-vision-rulesv1.2"
    # --video renders whole frames and --allow-unseen runs what is refused by default: each is
    # a run of its own, not the default run's folder (which it would be refused to replace)
    assert folder("--video") == "two-link-ellipse-t1-itg-vision-video"
    assert folder("--allow-unseen") == "two-link-ellipse-t1-itg-vision-unseen"
    # the rule parameters by the rules' own names, as bench noise labels its folders
    assert folder("--tolerance", "1", "--gain", "0.3") == "two-link-ellipse-t1-itg-vision-f0.3-w1"


@pytest.mark.slow
def test_default_run_folders_tell_runs_apart(tmp_path, monkeypatch, capsys):
    from itg_vision import run
    from itg_vision.arm import ARMS_DIR
    from itg_vision.rules import RULES_DIR

    monkeypatch.chdir(tmp_path)
    base = ["--quiet", "--feedback", "model", "--points", "6"]
    assert run.main(base) == 0
    assert run.main(base + ["--seed", "3", "--gain", "0.3"]) == 0
    assert run.main(base + ["--controller", "ik"]) == 0
    names = sorted(p.name for p in (tmp_path / "runs").iterdir())
    assert names == ["two-link-ellipse-t1-ik-model-n6", "two-link-ellipse-t1-itg-model-n6",
                     "two-link-ellipse-t1-itg-model-n6-f0.3-seed3"]
    # the same command again replaces its own result (same settings, same bytes)
    before = _tree(tmp_path / "runs" / names[1])
    assert run.main(base) == 0
    after = _tree(tmp_path / "runs" / names[1])
    assert {k for k in before} == {k for k in after}
    assert before["trace.csv"] == after["trace.csv"]
    # made before a setting existed (no "correction" in its key): at the setting's default it
    # is the same run, so the same command replaces it rather than refusing
    manifest = tmp_path / "runs" / names[1] / outputs.MANIFEST
    made = json.loads(manifest.read_text())
    assert made["key"]["config"].pop("correction") == 1.0
    manifest.write_text(json.dumps(made))
    assert run.main(base) == 0
    assert json.loads(manifest.read_text())["key"]["config"]["correction"] == 1.0
    # an edited rule file under the same name: its default folder is not replaced silently
    rules = tmp_path / "mine.rules"
    rules.write_text((RULES_DIR / "table2.rules").read_text())
    assert run.main(base + ["--rules", str(rules)]) == 0
    folder = tmp_path / "runs" / "two-link-ellipse-t1-itg-model-rulesmine-n6"
    kept = _tree(folder)
    rules.write_text(rules.read_text().replace("f * |xd - xg|", "0.5 * f * |xd - xg|"))
    capsys.readouterr()
    assert run.main(base + ["--rules", str(rules)]) == 2
    err = capsys.readouterr().err
    assert "holds an earlier run with other settings (content of the rules file)" in err
    # --force replaces it, as it says: a run's own folder is not kept aside (the line offered
    # --force with "the old one is kept beside it as .replaced-N", and then removed it)
    assert err.endswith("; give --out, or --force to replace it (a run made it: it is not "
                        "kept)\n"), err
    assert _tree(folder) == kept
    assert run.main(base + ["--rules", str(rules), "--force"]) == 0
    assert _tree(folder) != kept
    assert [p.name for p in folder.parent.iterdir() if p.name.startswith(folder.name)] == [
        folder.name]
    # so is an edited arm file of the user's; a folder made before arm files were hashed is not
    # refused for that alone
    arm = tmp_path / "my-arm.yaml"
    arm.write_text((ARMS_DIR / "two-link.yaml").read_text())
    assert run.main(base + ["--arm", str(arm)]) == 0
    folder = tmp_path / "runs" / "my-arm-ellipse-t1-itg-model-n6"
    made = json.loads((folder / outputs.MANIFEST).read_text())
    assert "arm" in made["key"]["inputs_sha256"]
    del made["key"]["inputs_sha256"]["arm"]
    (folder / outputs.MANIFEST).write_text(json.dumps(made))
    assert run.main(base + ["--arm", str(arm)]) == 0
    arm.write_text(arm.read_text().replace("led_standoff_mm: 12", "led_standoff_mm: 15"))
    capsys.readouterr()
    assert run.main(base + ["--arm", str(arm)]) == 2
    assert "other settings (content of the arm file)" in capsys.readouterr().err


def test_an_edited_shipped_arm_file_is_not_replaced_silently(tmp_path, monkeypatch, capsys):
    """A shipped arm is read from its file too (data/arms/two-link.yaml, which a user of a clone
    may edit): its content is hashed like an arm file of the user's."""
    import shutil

    from itg_vision import arm as arm_module
    from itg_vision import run

    arms = tmp_path / "arms"
    arms.mkdir()
    shutil.copy(arm_module.ARMS_DIR / "two-link.yaml", arms)
    monkeypatch.setattr(arm_module, "ARMS_DIR", arms)
    monkeypatch.chdir(tmp_path)
    base = ["--quiet", "--feedback", "model", "--points", "6"]
    assert run.main(base) == 0
    folder = tmp_path / "runs" / "two-link-ellipse-t1-itg-model-n6"
    made = json.loads((folder / outputs.MANIFEST).read_text())
    assert made["key"]["inputs_sha256"]["arm"] is not None
    kept = _tree(folder)
    arm = arms / "two-link.yaml"
    arm.write_text(arm.read_text().replace("led_standoff_mm: 12", "led_standoff_mm: 15"))
    capsys.readouterr()
    assert run.main(base) == 2
    assert "other settings (content of the arm file)" in capsys.readouterr().err
    assert _tree(folder) == kept
    assert run.main(base + ["--force"]) == 0


def test_run_out_empty_is_an_error_not_the_default_folder(tmp_path, monkeypatch, capsys):
    from itg_vision import run

    monkeypatch.chdir(tmp_path)
    assert run.main(["--quiet", "--feedback", "model", "--points", "3", "--out", ""]) == 2
    assert capsys.readouterr().err == "error: --out: empty path\n"
    assert list(tmp_path.iterdir()) == []  # no runs/ folder


def test_calibrate_output_checks(tmp_path):
    from itg_vision.calibrate import check_out, default_out
    from itg_vision.camera import CAMERAS_DIR

    planar = CAMERAS_DIR / "planar.yaml"
    assert default_out(planar) == Path("runs/calibrate/planar.calib.yaml")
    check_out(CAMERAS_DIR / "planar.calib.yaml", planar)  # this rig's calibration: may refresh
    check_out(tmp_path / "new" / "p.calib.yaml", planar)
    assert list(tmp_path.iterdir()) == []  # the check made nothing
    with pytest.raises(UserError, match="is a calibration of planar.yaml, not of"):
        check_out(CAMERAS_DIR / "planar.calib.yaml", CAMERAS_DIR / "three-link.yaml")
    check_out(CAMERAS_DIR / "planar.calib.yaml", CAMERAS_DIR / "three-link.yaml", force=True)
    (tmp_path / "p.calib.png").write_bytes(b"a user's picture")
    with pytest.raises(UserError, match="p.calib.png exists and would be replaced"):
        check_out(tmp_path / "p.calib.yaml", planar)


def test_a_path_the_system_refuses_is_one_line_status_2(tmp_path, capsys):
    """A name longer than the file system allows (255 bytes) used to end in an OSError
    traceback; so did an --out path longer than PATH_MAX. Both are bad input."""
    from itg_vision import run

    long_name = str(tmp_path / ("a" * 300 + ".rules"))
    assert run.main(["--rules", long_name, "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and err[0].endswith("File name too long")
    assert not (tmp_path / "o").exists()

    def refused():
        raise PermissionError(13, "Permission denied", "/x/y")

    assert run_main(refused) == 2
    assert capsys.readouterr().err == "error: /x/y: Permission denied\n"

    def a_bug():
        raise ConnectionResetError(104, "Connection reset by peer")  # not a path: a traceback

    with pytest.raises(ConnectionResetError):
        run_main(a_bug)


def test_a_file_size_limit_is_one_line_naming_out_not_the_staging_folder(tmp_path):
    """Under a file size limit (ulimit -f) a run's figure write fails with EFBIG: it was a
    traceback; on a full disk the line named the staging folder's file, gone by then. Now one
    line naming --out and the file, status 2, nothing left behind."""
    resource = pytest.importorskip("resource")

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (20 * 1024, 20 * 1024))

    out = tmp_path / "o"
    res = subprocess.run([sys.executable, "-m", "itg_vision.run", "--feedback", "model",
                          "--points", "5", "--quiet", "--out", str(out)], capture_output=True,
                         text=True, preexec_fn=limit, cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: --out {out}: could not write "), lines
    assert lines[0].endswith(f"there (File too large); {out} was left as it was")
    assert list(tmp_path.iterdir()) == []


def test_a_deleted_current_folder_is_said_before_anything_runs(monkeypatch, capsys):
    def gone():
        raise FileNotFoundError(2, "No such file or directory")

    ran = []
    monkeypatch.setattr(os, "getcwd", gone)
    assert run_main(lambda: ran.append(1) or 0) == 2 and not ran
    assert capsys.readouterr().err == ("error: the current folder no longer exists (cd to "
                                       "another folder)\n")


def test_a_closed_standard_output_ends_the_command_quietly():
    """`bench speed | head -1` used to print a BrokenPipeError traceback."""
    code = ("import sys\nfrom itg_vision.errors import run_main\n"
            "def body():\n    for i in range(10**6):\n        print('line', i)\n    return 0\n"
            "sys.exit(run_main(body))\n")
    res = subprocess.run(f"{sys.executable} -c \"{code}\" | head -1", shell=True,
                         capture_output=True, text=True, timeout=60)
    assert res.stdout == "line 0\n" and res.stderr == ""


def test_a_symbolic_link_given_as_out_is_the_users_and_never_deleted(tmp_path, capsys):
    """`--out latest` where latest -> res1 (a result of ours) used to replace the link by a
    folder without a word, --force or not. It is refused; --force writes there and keeps the
    link, renamed, beside it (its target untouched either way)."""
    _make(tmp_path / "res1", text="first")
    link = tmp_path / "latest"
    link.symlink_to("res1")
    with pytest.raises(UserError, match=r"--out .*latest: is a symbolic link \(to res1\); give "
                                        r"the folder itself"):
        _make(link)
    assert link.is_symlink() and (tmp_path / "res1" / "result.txt").read_text() == "first"
    with outputs.staged_dir(link, "run", force=True) as tmp:
        (tmp / "result.txt").write_text("new")
    kept = tmp_path / "latest.replaced-1"
    assert kept.is_symlink() and os.readlink(kept) == "res1"
    assert not link.is_symlink() and (link / "result.txt").read_text() == "new"
    assert (tmp_path / "res1" / "result.txt").read_text() == "first"
    assert "was a symbolic link; kept as" in capsys.readouterr().err


def test_an_old_result_that_cannot_be_removed_is_said_not_left_in_silence(tmp_path, capsys,
                                                                         monkeypatch):
    """A previous result the user made read-only was left as a hidden .NAME.old-PID folder
    without a word (rmtree ignored its errors). The new result is in place; the note says
    where the old one stays. (As root, chmod does not stop a removal: the refusal is
    simulated.)"""
    _make(tmp_path / "r", text="first")
    real = outputs.shutil.rmtree

    def refuse_old(path, *args, **kwargs):
        if ".r.old-" in str(path) and not kwargs.get("ignore_errors"):
            raise PermissionError(13, "Permission denied", str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(outputs.shutil, "rmtree", refuse_old)
    _make(tmp_path / "r", text="second")
    assert (tmp_path / "r" / "result.txt").read_text() == "second"
    left = [p.name for p in tmp_path.iterdir() if p.name.startswith(".r.old-")]
    err = capsys.readouterr().err
    assert len(left) == 1 and f"note: could not remove {tmp_path / left[0]}" in err
    assert "(Permission denied); remove it yourself" in err


def test_text_written_keeps_a_file_names_bytes(tmp_path):
    """A report naming a folder whose name holds a Latin-1 byte used to fail to encode (every
    rerun of the sweep then failed the same way, and report.md was never written)."""
    outputs.write_text(tmp_path / "r.md", "results in lat/b\udce9\n")
    assert (tmp_path / "r.md").read_bytes() == b"results in lat/b\xe9\n"


def _sigint_default():
    """In the child: Ctrl-C as a terminal gives it, even when the suite was started with it
    ignored (nohup, a background job), which a child would inherit."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("after_s", [0.15, 0.4])
def test_ctrl_c_while_a_command_starts_says_interrupted_without_a_traceback(tmp_path, after_s):
    """Ctrl-C early in `python -m itg_vision.run` (its modules load for ~0.5-1 s) used to
    print a KeyboardInterrupt traceback from inside matplotlib's import. Nothing is written
    either way. The delay counts from the end of the interpreter's own start-up (timed just
    before, as `python -c pass` takes it): on a loaded host 0.15 s once landed in the site
    module's start-up, the interpreter's ("Fatal Python error"), which no command can catch."""
    import signal
    import time

    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True, preexec_fn=_sigint_default)
    start_up = time.perf_counter() - t0
    proc = subprocess.Popen([sys.executable, "-m", "itg_vision.run", "--laps", "3", "--out",
                             str(tmp_path / "o")], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_sigint_default)
    time.sleep(start_up + after_s)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "interrupted"
    assert not (tmp_path / "o").exists()


def test_ctrl_c_while_a_command_starts_ends_it_whatever_code_it_interrupts():
    """Ctrl-C at 0.15 s landed at times inside numpy's C-extension import, which turned the
    handler's exception into an ImportError traceback and status 1. Code that catches every
    exception cannot keep the interrupt now (deterministic: the process signals itself inside
    such a block, as a command's start-up sees it)."""
    code = ("import sys; sys.argv[:1] = ['-m']\n"  # as under python -m, while modules load
            "import os, signal, itg_vision\n"
            "try:\n"
            "    os.kill(os.getpid(), signal.SIGINT); signal.pause()\n"
            "except BaseException as exc:\n"
            "    print('kept', type(exc).__name__)\n"
            "print('went on')\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, preexec_fn=_sigint_default)
    assert (res.returncode, res.stdout, res.stderr.strip()) == (130, "", "interrupted")


def test_a_library_import_leaves_ctrl_c_alone():
    res = subprocess.run([sys.executable, "-c", "import signal, itg_vision; "
                          "print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)"],
                         capture_output=True, text=True, timeout=60, preexec_fn=_sigint_default)
    assert res.stdout.strip() == "True", res.stderr


# ------------------------------------------- refusals, permissions, names, the log
@pytest.mark.parametrize("below", ["res", "a/b/res"])
def test_an_out_below_a_file_is_refused_before_any_work(tmp_path, below):
    """An --out below a file is refused by the check made before any work (bench speed and
    accuracy swap in only at the end: they ran a minute, then failed), and nothing is written."""
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes")
    out = notes / below
    before = _tree(tmp_path)
    with pytest.raises(UserError) as exc:
        outputs.check_out_dir(out, "bench-speed")
    assert str(exc.value) == f"--out {out}: {notes} is a file, not a folder"
    assert _tree(tmp_path) == before


def test_the_staging_folder_of_a_process_we_may_not_signal_is_left_alone(tmp_path, monkeypatch):
    """A staging folder whose process we may not signal (another user's, still working:
    os.kill says PermissionError) is not stale: the next run leaves it alone."""
    out = tmp_path / "r"
    staging = tmp_path / ".r.staging-4242-abcd1234"
    staging.mkdir()
    outputs.write_json(staging / outputs.MANIFEST, outputs.manifest("run"))
    (staging / "trace.csv").write_text("half written by another user's run\n")

    def kill(pid, sig):  # what os.kill says of another user's live process
        if pid == 4242:
            raise PermissionError(1, "Operation not permitted")
        raise ProcessLookupError(3, "No such process")

    monkeypatch.setattr(os, "kill", kill)
    _make(out)
    assert (staging / "trace.csv").read_text() == "half written by another user's run\n"
    assert (out / "result.txt").read_text() == "new"


def test_an_output_folder_is_readable_by_everyone_like_its_files(tmp_path):
    """The output folder is 0755 like its files' 0644, not mkdtemp's private 0700."""
    out = tmp_path / "r"
    _make(out)
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
    assert stat.S_IMODE((out / outputs.MANIFEST).stat().st_mode) == 0o644


def test_a_log_says_something_at_least_once_a_minute(monkeypatch):
    """A log line comes at each tenth of the way and, between them, at least once a minute."""
    from itg_vision import progress as progress_mod

    now = [1000.0]
    monkeypatch.setattr(progress_mod.time, "monotonic", lambda: now[0])
    log = io.StringIO()
    bar = progress_mod.LineProgress(1000, "run x", unit="pt", file=log)
    now[0] += 30.0
    bar.update(1)  # not a tenth of the way, half a minute: nothing yet
    assert log.getvalue() == ""
    now[0] += 31.0
    bar.update(1)  # still not a tenth, but over a minute since the start
    assert log.getvalue() == "run x: 2/1000 pt (0%), 61 s, about 8.5 h left\n"


def test_a_log_line_says_how_long_the_rest_takes_at_the_pace_so_far(monkeypatch):
    """The time left is the time so far scaled by the share still to do (30 s for a quarter:
    90 s more), in the unit a reader wants (seconds, minutes, hours); none once done."""
    from itg_vision import progress as progress_mod

    now = [0.0]
    monkeypatch.setattr(progress_mod.time, "monotonic", lambda: now[0])
    log = io.StringIO()
    bar = progress_mod.LineProgress(100, "sweep", unit="", file=log)
    for dt, n in ((30.0, 25), (270.0, 25), (3300.0, 40), (1.0, 10)):
        now[0] += dt
        bar.update(n)
    assert log.getvalue().splitlines() == [
        "sweep: 25%, 30 s, about 90 s left",         # 30 s * 75 / 25
        "sweep: 50%, 300 s, about 5 min left",       # 300 s * 50 / 50
        "sweep: 90%, 3600 s, about 7 min left",      # 3600 s * 10 / 90 = 400 s
        "sweep: 100%, 3601 s"]
    assert progress_mod._duration(7200 * 1.25) == "2.5 h"


def test_a_file_the_user_puts_in_while_the_command_works_is_kept_whatever_its_name(tmp_path):
    """A file put into --out while the command works is refused at the swap and kept, even
    named like one of the run's outputs (the check used to count those as the run's own, and
    the user's video.mp4 went with the old folder)."""
    out = tmp_path / "r"
    _make(out)
    with pytest.raises(UserError, match=r"holds 1 entry that run did not write \(first: video.mp4\)"):
        with outputs.staged_dir(out, "run") as tmp:
            (tmp / "video.mp4").write_bytes(b"the new video")
            (out / "video.mp4").write_bytes(b"the user's video")  # meanwhile
    assert (out / "video.mp4").read_bytes() == b"the user's video"


def test_the_home_python_the_package_and_top_level_folders_are_refused(tmp_path, monkeypatch):
    """--out $HOME --force once renamed the home folder (and the Python in it) aside: such a
    folder, one holding it, and a folder at the top of the file system are refused even with
    force; a new folder inside the home is not."""
    home = tmp_path / "users" / "ana"
    home.mkdir(parents=True)
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir("/")  # not a parent of /tmp or /usr (those are refused as such)
    refused = {str(home): "is the home folder", str(tmp_path / "users"): "holds the home folder",
               sys.prefix: "is Python's installation",
               str(Path(outputs.__file__).parent): "is the itg_vision package",
               str(Path(outputs.__file__).parent.parent): "holds the itg_vision package",
               "/tmp": "top of the file system", "/usr": "top of the file system"}
    for out, why in refused.items():
        with pytest.raises(UserError, match=f"--out {re.escape(out)}: .*{why}"):
            outputs.check_out_dir(out, "run", force=True)
    assert outputs.check_out_dir(home / "results", "run", force=True) == home / "results"
    assert sorted(p.name for p in home.iterdir()) == []
