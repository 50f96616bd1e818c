"""The documents' links: every section a source file cites exists, and the method is in the repository."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CITATION = re.compile(r"docs/(method|results)\.md#([A-Za-z0-9_-]+)")


def github_anchors(markdown: str) -> set[str]:
    """Return the anchors GitHub gives a Markdown file's headings.

    GitHub lower-cases the heading's text, drops every character that is not a letter, a digit, a
    space, a hyphen or an underscore, turns spaces into hyphens and numbers repeats (-1, -2, ...).
    Headings inside fenced code blocks are not headings.
    """
    anchors: set[str] = set()
    seen: dict[str, int] = {}
    fenced = False
    for line in markdown.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if fenced or match is None:
            continue
        text = re.sub(r"`([^`]*)`", r"\1", match.group(1))
        text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
        slug = re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        anchors.add(slug if count == 0 else f"{slug}-{count}")
    return anchors


def test_github_anchors_follow_githubs_rules():
    text = "# The method\n## SH fit\n```\n# not a heading\n```\n## SH fit\n### Roughness std and flags\n## `code` (M1)"
    assert github_anchors(text) == {
        "the-method", "sh-fit", "sh-fit-1", "roughness-std-and-flags", "code-m1"}


def _citations(folders):
    for folder in folders:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if ".cache" in path.relative_to(ROOT).parts:  # renders and other refs' sources the benchmarks keep
                continue
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                for match in CITATION.finditer(line):
                    yield f"{path.relative_to(ROOT)}:{number}", match.group(1), match.group(2)


def test_every_cited_section_of_the_method_and_the_results_exists():
    anchors = {name: github_anchors((ROOT / "docs" / f"{name}.md").read_text(encoding="utf-8"))
               for name in ("method", "results")}
    citations = list(_citations(("src", "tests", "benchmarks", "scripts")))
    assert any(name == "method" for _, name, _ in citations)
    broken = [f"{where}: docs/{name}.md#{anchor}" for where, name, anchor in citations
              if anchor not in anchors[name]]
    assert broken == []


@pytest.mark.parametrize("document", ["README.md", "docs"])
def test_the_external_specification_is_not_cited(document):
    paths = [ROOT / document] if document.endswith(".md") else sorted((ROOT / document).rglob("*.md"))
    paths += sorted((ROOT / "src").rglob("*.py")) if document == "docs" else []
    cited = [str(p.relative_to(ROOT)) for p in paths if "METHOD.md" in p.read_text(encoding="utf-8")]
    assert cited == []
