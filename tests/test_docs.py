"""The Markdown a user reads: every table row has its header's cells, every link lands.

Figures are pasted into the README's tables by hand and by scripts; a replacement that
matched a row of another table once left a 7-cell row in a 3-column table. A link moved
from the README into docs/ kept its README-relative path and led nowhere.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _cells(line: str) -> int:
    return len(re.split(r"(?<!\\)\|", line.strip())) - 2


def _tables(text: str):
    """(line number of the header, line number, cell count) for every table row."""
    header = None
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if stripped.startswith("|") and stripped.endswith("|"):
            if header is None:
                header = (number, _cells(line))
            yield header, number, _cells(line)
        else:
            header = None


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(text: str) -> set[str]:
    return {_slug(line.lstrip("#")) for line in text.splitlines() if re.match(r"#+ ", line)}


def test_the_checks_find_what_they_look_for():
    bad = "| a | b |\n|---|---|\n| 1 | 2 | 3 |\n\n| c |\n|---|\n| 4 |\n"
    assert [(n, c) for head, n, c in _tables(bad) if c != head[1]] == [(3, 3)]
    assert _slug("ITG+ against issue 13's targets") == "itg-against-issue-13s-targets"
    assert _slug("What `python -m itg_vision.run` does") == "what-python--m-itg_visionrun-does"


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_every_table_row_has_its_headers_cells(path):
    text = path.read_text(encoding="utf-8")
    wrong = [
        f"{path.name}:{number}: {cells} cells, its header (line {head[0]}) {head[1]}"
        for head, number, cells in _tables(text)
        if cells != head[1]
    ]
    assert wrong == []


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_every_relative_link_lands_on_a_file_and_heading(path):
    text = path.read_text(encoding="utf-8")
    broken = []
    for match in LINK.finditer(text):
        target = match.group(1)
        if target.startswith(("http://", "https://", "mailto:")):
            continue
        file, _, anchor = target.partition("#")
        landing = (path.parent / file) if file else path
        line = text.count("\n", 0, match.start()) + 1
        if not landing.exists():
            broken.append(f"{path.name}:{line}: {target} (no such file)")
        elif anchor and landing.suffix == ".md" and anchor not in _anchors(
            landing.read_text(encoding="utf-8")
        ):
            broken.append(f"{path.name}:{line}: {target} (no such heading)")
    assert broken == []


# Written only by some runs: a trajectory file with times, --video, a third joint.
_SOMETIMES = {"t_s", "video", "video_codec", "q3_deg"}


def _documented(section: str) -> set[str]:
    """The backquoted names in the first cells of the field and column tables (not the flags')
    under '## `section`' of outputs.md."""
    text = (ROOT / "docs" / "outputs.md").read_text(encoding="utf-8")
    body = text.split(f"## `{section}`\n", 1)[1].split("\n## ", 1)[0]
    names, kind = set(), None
    for line in body.splitlines():
        if not line.startswith("|"):
            kind = None
        elif kind is None:
            kind = line.split("|")[1].strip()  # the header's first cell
        elif kind in ("field", "column"):
            names |= set(re.findall(r"`([^`]+)`", line.split("|")[1]))
    return names


def test_outputs_md_lists_exactly_what_runs_write(tmp_path):
    """docs/outputs.md documents summary.json's fields and trace.csv's columns one by one. A rule
    base on the eye, ITG+ (its servo limit) and the Jacobian tracker on the model (no rules, no
    rig) write between them each one it lists (but those of a file with times, --video and a
    third joint) and nothing it does not list."""
    import csv
    import json

    from itg_vision.run import main

    summary, columns = set(), set()
    for k, extra in enumerate(([], ["--rules", "itg-plus-two-link"],
                               ["--controller", "jacobian", "--feedback", "model"])):
        out = tmp_path / f"run{k}"
        assert main(["--points", "12", "--out", str(out), "--quiet", *extra]) == 0
        summary |= set(json.loads((out / "summary.json").read_text()))
        with open(out / "trace.csv", newline="") as f:
            columns |= set(next(csv.reader(f)))
    assert _documented("summary.json") - _SOMETIMES == summary
    assert _documented("trace.csv") - _SOMETIMES == columns


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_every_python_block_compiles(path):
    """A script pasted into the docs is one a reader runs: a block moved with the prose around
    it was once reflowed into one line of invalid Python."""
    text = path.read_text(encoding="utf-8")
    for match in re.finditer(r"```python\n(.*?)```", text, re.S):
        line = text.count("\n", 0, match.start()) + 2
        compile(match.group(1), f"{path.name}:{line}", "exec")
