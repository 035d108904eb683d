"""The docs stand alone (issue #19, 8): nothing the repository ships cites a file outside
it, every relative link and every ``docs/...`` name resolves inside it, and the README
lists every tool and every doc."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
HERE = Path(__file__).resolve()

# assembled so this file does not match itself
OUTSIDE = [re.compile(p) for p in (
    "/" + "work/",              # absolute paths of the development machine
    "shared" + r"/(reference|seed|DESIGN|tools|hooks)",
    r"\bDESIGN" + r"\.md",
    r"\.\./shared",
)]


def shipped_text_files() -> list[Path]:
    files = [ROOT / "README.md", ROOT / "pyproject.toml"]
    for pattern in ("docs/**/*.md", "clradcom/**/*.py", "tools/*.py", "kernels/*.cl",
                    "kernels/*.h", "scenes/**/*.toml", "scenes/**/*.md", "scenes/**/*.xml",
                    "tests/*.py", "tests/data/*.toml"):
        files += sorted(ROOT.glob(pattern))
    return [f for f in files if f.resolve() != HERE]


def test_there_are_files_to_check():
    names = {f.relative_to(ROOT).as_posix() for f in shipped_text_files()}
    assert {"README.md", "docs/scene-format.md", "clradcom/trace.py",
            "docs/reference/propagation-physics.md"} <= names


@pytest.mark.parametrize("pattern", OUTSIDE, ids=lambda p: p.pattern)
def test_no_file_cites_a_path_outside_the_repository(pattern):
    hits = []
    for f in shipped_text_files():
        for n, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1):
            if pattern.search(line):
                hits.append(f"{f.relative_to(ROOT)}:{n}: {line.strip()[:100]}")
    assert not hits, "\n".join(hits)


LINK = re.compile(r"\]\(([^)\s]+)\)")


def test_relative_markdown_links_resolve_inside_the_repository():
    bad = []
    for f in [ROOT / "README.md", *sorted(ROOT.glob("docs/**/*.md")),
              *sorted(ROOT.glob("scenes/**/*.md"))]:
        for target in LINK.findall(f.read_text(encoding="utf-8")):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue  # a URL or an anchor in the same file
            path = (f.parent / target.split("#")[0]).resolve()
            if not path.exists() or ROOT not in path.parents:
                bad.append(f"{f.relative_to(ROOT)}: {target}")
    assert not bad, "\n".join(bad)


DOC_NAME = re.compile(r"\bdocs/([A-Za-z0-9_./-]+\.md)")


def test_every_docs_name_mentioned_exists():
    bad = []
    for f in shipped_text_files():
        for name in DOC_NAME.findall(f.read_text(encoding="utf-8")):
            if not (ROOT / "docs" / name).is_file():
                bad.append(f"{f.relative_to(ROOT)}: docs/{name}")
    assert not bad, "\n".join(bad)


def readme_section(title: str) -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index(f"\n## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end >= 0 else len(text)]


def test_readme_tool_table_lists_every_tool():
    rows = set(re.findall(r"^\| `(tools/[^`]+\.py)` \|", readme_section("Tools"), re.M))
    tools = {f.relative_to(ROOT).as_posix() for f in ROOT.glob("tools/*.py")}
    assert rows == tools


def test_readme_names_every_doc():
    row = next(line for line in readme_section("What is where").splitlines()
               if line.startswith("| `docs/`"))
    docs = {f.name for f in ROOT.glob("docs/*.md")}
    assert docs <= set(re.findall(r"`([a-z0-9_-]+\.md)`", row))
    assert "`reference/`" in row


def test_quickstart_states_the_street_time_that_was_measured():
    """The quickstart said the street "takes a few minutes"; it takes seconds. Its numbers
    are the ones docs/performance.md measured for the main job."""
    quick = (ROOT / "docs" / "quickstart.md").read_text()
    perf = (ROOT / "docs" / "performance.md").read_text()
    assert "minutes" not in quick
    stated = re.search(r"traces\s+in ([\d.]+ s) on PoCL and runs whole in about ([\d.]+ s)",
                       quick)
    assert stated, "the quickstart states the street's time"
    measured = re.search(r"now traces in ([\d.]+ s) \(kernel\s+builds included\) and runs "
                         r"whole in about ([\d.]+ s)", perf)
    assert measured and stated.groups() == measured.groups()
