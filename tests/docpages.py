"""The README and the docs pages beside it, as the tests read them: a section or a command the
README moved to a page of docs/ is still found, and still held to what it says."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


# the pages that carry the README's depth: its sections on results, use, the data and run times
README_PAGES = ("guide.md", "real-flights.md", "reliability.md", "results.md", "run-times.md", "simulated-world.md")


def pages(readme_only: bool = False) -> list[Path]:
    """README.md, then every page of docs/ by name (only the README's own pages: ``readme_only``)."""
    docs = sorted((ROOT / "docs").glob("*.md"))
    return [ROOT / "README.md", *(p for p in docs if not readme_only or p.name in README_PAGES)]


def text(readme_only: bool = False) -> str:
    """The pages' text, one after another."""
    return "\n\n".join(p.read_text() for p in pages(readme_only))


def page_of(marker: str) -> Path:
    """The one page that holds ``marker`` (a generated section's first line)."""
    found = [p for p in pages() if marker in p.read_text()]
    assert len(found) == 1, (marker, found)
    return found[0]
