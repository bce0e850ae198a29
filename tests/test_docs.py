"""What the documentation names exists: the code's own cross-references, and the README's links."""

import importlib
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("groundstation", "drivers", "web", "sim_bridge")


def _resolves(name: str) -> bool:
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for a in parts[i:]:
            if not hasattr(obj, a):
                return False
            obj = getattr(obj, a)
        return True
    return False


def test_every_cross_reference_in_a_docstring_names_something_that_exists():
    pattern = re.compile(r"`~?((?:" + "|".join(PACKAGES) + r")\.[A-Za-z_][\w.]*)`")
    broken = []
    for pkg in PACKAGES:
        for path in (REPO / pkg).rglob("*.py"):
            for m in pattern.finditer(path.read_text()):
                if not _resolves(m.group(1)):
                    broken.append(f"{path.relative_to(REPO)}: {m.group(1)}")
    assert not broken, "\n".join(broken)


def test_the_readme_is_short_and_its_links_lead_somewhere():
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 250
    for link in re.findall(r"\]\(([^)#]+)\)", readme):
        if not link.startswith("http"):
            assert (REPO / link).exists(), link
    for doc in (REPO / "docs").glob("*.md"):
        for link in re.findall(r"\]\(([^)#]+)\)", doc.read_text()):
            if not link.startswith("http"):
                assert (doc.parent / link).exists(), f"{doc.name}: {link}"


def test_no_document_or_docstring_narrates_the_development():
    history = re.compile(r"\b[Ss]essions? \d+|\b[Ii]ssue #?\d+|HISTORY\.md")
    found = []
    for path in [
        *REPO.glob("*.md"),
        *(REPO / "docs").glob("*.md"),
        *(REPO / "groundstation" / "vehicles").glob("*.json"),
    ]:
        found += [f"{path.name}: {m.group(0)}" for m in history.finditer(path.read_text())]
    for d in (*PACKAGES, "tests", "bench", "examples"):
        for path in (REPO / d).rglob("*.py"):
            found += [f"{path.relative_to(REPO)}: {m.group(0)}" for m in history.finditer(path.read_text())]
    assert not found, "\n".join(found)
