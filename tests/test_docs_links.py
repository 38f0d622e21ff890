"""Documents cited by the sources are files of this repository.

For every ``.py`` under ``tdfields/``, ``slam/``, ``benchmarks/`` and ``examples/``:

* each ``docs/<name>.md`` it mentions (``docs/slam.md``, ``docs/slam.md#anchor``, ``ROOT / "docs" / "x.md"``)
  exists, an ``#anchor`` names one of that file's headings, and a section quoted right after the path
  (``docs/slam.md, "The pipeline (as implemented)"`` or ``docs/data.md ("Recording ...")``) starts one;
* it cites no document that lives outside the repository: ``eslam-pipeline`` (with or without ``.md``),
  ``method.md``, or a document under ``../shared/`` (data folders there, e.g. ``../shared/data/...`` in a usage
  line, are not documents).

The files are read as text, nothing is imported.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("tdfields", "slam", "benchmarks", "examples")
FILES = sorted(p for folder in FOLDERS for p in (ROOT / folder).rglob("*.py"))

# docs/<name>.md, optionally #anchor, then optionally a quoted section: , "Title"  or  ("Title"
_DOC_PATH = re.compile(r"(?<![\w.-])docs/(?P<path>[\w./-]+?\.md)(?:#(?P<anchor>[\w-]+))?"
                       r"(?:,\s*\"(?P<section>[^\"]+)\"|\s+\(\"(?P<section2>[^\"]+)\")?")
# the same as path parts: "docs" / "name.md"
_DOC_JOIN = re.compile(r"[\"']docs[\"']\s*/\s*[\"'](?P<path>[\w.-]+\.md)[\"']")
_OUTSIDE = (
    (re.compile(r"(?<![\w-])eslam-pipeline\b"), "eslam-pipeline (a document outside the repository)"),
    (re.compile(r"(?<![\w-])method\.md\b"), "method.md (a document outside the repository)"),
    (re.compile(r"\.\./shared/(?:[^\s\"'`)]*\.(?:md|rst|txt|pdf|html?)\b|docs?\b)"),
     "a document under ../shared (outside the repository)"),
)


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _headings(doc: Path) -> list[str]:
    return [m.group(1).strip() for m in re.finditer(r"^#{1,6}\s+(.+?)\s*#*\s*$", doc.read_text(), re.M)]


def _violations(path: Path, root: Path = ROOT) -> list[str]:
    """One line per problem of ``path`` (``root``: the repository)."""
    text = path.read_text()
    out = []

    def where(pos: int) -> str:
        return f"{path.relative_to(root)}:{text.count(chr(10), 0, pos) + 1}"

    for m in list(_DOC_PATH.finditer(text)) + list(_DOC_JOIN.finditer(text)):
        doc = root / "docs" / m.group("path")
        if not doc.is_file():
            out.append(f"{where(m.start())}: docs/{m.group('path')} does not exist")
            continue
        groups = m.groupdict()
        heads = _headings(doc)
        if groups.get("anchor") and groups["anchor"] not in {_slug(h) for h in heads}:
            out.append(f"{where(m.start())}: docs/{m.group('path')} has no heading with anchor #{groups['anchor']}")
        section = groups.get("section") or groups.get("section2")
        if section and not any(h.startswith(section) for h in heads):
            out.append(f"{where(m.start())}: docs/{m.group('path')} has no section \"{section}\"")
    for pattern, what in _OUTSIDE:
        out += [f"{where(m.start())}: cites {what}" for m in pattern.finditer(text)]
    return out


def test_every_folder_is_read():
    for folder in FOLDERS:
        assert any(p.is_relative_to(ROOT / folder) for p in FILES), folder


@pytest.mark.parametrize("path", FILES, ids=[str(p.relative_to(ROOT)) for p in FILES])
def test_cited_documents_are_in_the_repository(path):
    assert not _violations(path), "\n".join(_violations(path))


def test_the_checks_catch_what_they_are_for(tmp_path):
    """Each kind of violation is caught, and the allowed forms pass (a guard against a pattern that matches
    nothing)."""
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# Title\n\n## The pipeline (as implemented)\n")
    src = tmp_path / "m.py"
    src.write_text('"""docs/a.md, "The pipeline (as implemented)"; docs/a.md#title; ROOT / "docs" / "a.md";\n'
                   'python x.py --data ../shared/data/tum_fr1_rpy"""\n')
    assert _violations(src, tmp_path) == []
    src.write_text('"""docs/b.md; docs/a.md#nope; docs/a.md, "Nope"; "docs" / "c.md"; eslam-pipeline section 10;\n'
                   '(method.md section 2); ../shared/notes.md"""\n')
    found = "\n".join(_violations(src, tmp_path))
    for needle in ("docs/b.md does not exist", "#nope", '"Nope"', "docs/c.md does not exist", "eslam-pipeline",
                   "method.md", "../shared"):
        assert needle in found, (needle, found)
