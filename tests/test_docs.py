"""The user docs stay short, free of history and in step with the code (docs/development.md, "Docs").

README.md ≤ 10 KB; README.md and the docs site's user pages (everything under docs/ except the development notes
and the changelog) hold no commit hash (a 7–40 character hex word with letters and digits) and no tracker
reference ("issue 12", "before issue"); the API reference pages list every public name; every page is in the nav.
"""
from __future__ import annotations

import importlib
import inspect
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
HISTORY_PAGES = {"development.md", "performance_history.md", "changelog.md"}
"""Pages that may hold history: the development notes, the performance history and the changelog (CHANGELOG.md)."""

HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
TRACKER = re.compile(r"\bissues?\s+#?\d+|\bbefore\s+issue|(?<![\w&])#\d+\b", re.IGNORECASE)


def user_docs() -> list[Path]:
    """README.md and every Markdown page of the docs site except the history pages."""
    pages = sorted(p for p in (ROOT / "docs").rglob("*.md") if p.name not in HISTORY_PAGES)
    return [ROOT / "README.md", *pages]


def history_in(text: str) -> list[str]:
    """Commit hashes and tracker references in ``text``, as 'line N: word'. Hex colours in code (#ff0000) and
    long numbers are not hashes (a hash needs a letter and a digit, and no '#')."""
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        for m in HASH.finditer(line):
            if m.start() == 0 or line[m.start() - 1] != "#":
                found.append(f"line {number}: {m.group(0)}")
        found += [f"line {number}: {m.group(0)}" for m in TRACKER.finditer(line)]
    return found


def test_history_finder_catches_hashes_and_tracker_references():
    text = "fast (c315800, before issue 12)\nsee issue 5 and #13\nfine: 1234567, deadbeef, abcdefg1x, #ff00aa"
    assert history_in(text) == ["line 1: c315800", "line 1: before issue", "line 2: issue 5", "line 2: #13"]


def test_readme_is_at_most_10_kb():
    size = (ROOT / "README.md").stat().st_size
    assert size <= 10 * 1024, f"README.md is {size} bytes"


def test_the_contributor_guide_is_at_most_12_kb():
    """docs/development.md is the contributor guide (checks, docs, layout); the performance history has its own
    page (docs/performance_history.md), so the guide stays readable in one sitting."""
    size = (ROOT / "docs" / "development.md").stat().st_size
    assert size <= 12 * 1024, f"docs/development.md is {size} bytes"


@pytest.mark.parametrize("page", user_docs(), ids=lambda p: str(p.relative_to(ROOT)))
def test_user_docs_hold_no_history(page):
    assert history_in(page.read_text()) == []


def test_every_docs_page_is_in_the_nav():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text().replace("!!python", "python"))

    def pages(node):
        if isinstance(node, str):
            yield node
        elif isinstance(node, list):
            for item in node:
                yield from pages(item)
        elif isinstance(node, dict):
            for value in node.values():
                yield from pages(value)

    listed = set(pages(config["nav"]))
    on_disk = {str(p.relative_to(ROOT / "docs")) for p in (ROOT / "docs").rglob("*.md")}
    assert on_disk - listed == set() and listed - on_disk == set()


def test_api_reference_lists_every_public_name_with_a_docstring():
    text = "\n".join(p.read_text() for p in (ROOT / "docs" / "reference").glob("*.md"))
    entries = set(re.findall(r"^::: (\S+)$", text, re.MULTILINE))
    headings = set(re.findall(r'^      heading: "(\w+)"$', text, re.MULTILINE))
    packages = ["datagen"] + [f"datagen.{p}" for p in ("scene", "sampling", "timing", "transport", "spad", "planner",
                                                       "simulation", "io", "dataset", "analysis", "plot", "cli")]
    missing, undocumented = [], []
    for package in packages:
        module = importlib.import_module(package)
        for name in module.__all__:
            if name not in headings or not any(e.endswith(f".{name}") for e in entries):
                missing.append(f"{package}.{name}")
            obj = getattr(module, name)
            doc = inspect.getdoc(obj) if callable(obj) or inspect.isclass(obj) else "attribute docstring"
            if not doc:
                undocumented.append(f"{package}.{name}")
    assert missing == [] and undocumented == []


def test_api_reference_pages_are_up_to_date():
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "api_reference.py"), "--check"], capture_output=True,
                       text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr


def test_the_code_holds_no_tracker_references():
    """Comments and docstrings say what the code does and cite the repo's docs; the history of a change ("issue 12",
    "before issue 24") belongs in git log and the changelog."""
    found = []
    for path in sorted((ROOT / "datagen").rglob("*.py")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            found += [f"{path.relative_to(ROOT)}:{number}: {m.group(0)}" for m in TRACKER.finditer(line)]
    assert found == []
