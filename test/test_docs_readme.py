"""The README stays a front door, and the links into the documents land on a heading.

The README says what the package is, how to install it, how to start in the simulated scene
and where the rest lives; every results table lives in docs/results.md (issue #35). A link
``file.md#anchor`` (or ``#anchor`` within a page) must name a heading of that file, as
GitHub makes anchors from headings: a renamed or moved section otherwise leaves a link that
opens the top of the page.
"""

from __future__ import annotations

import re
from pathlib import Path

from conftest import ROOT

README = ROOT / "README.md"
#: The README's length limit [lines]: beyond it, move detail to a page under docs/.
MAX_README_LINES = 300
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]


def test_the_readme_stays_short():
    n = len(README.read_text().splitlines())
    assert n <= MAX_README_LINES, (
        f"README.md has {n} lines (at most {MAX_README_LINES}): move detail to docs/ "
        "(results to docs/results.md) and leave a link")


def test_the_readme_keeps_the_front_door():
    """What a lab needs first: the two install routes (the workspace block that CI runs as
    written), the scene quickstart, the hardware pointer and where the results are."""
    text = README.read_text()
    headings = re.findall(r"^#+ (.+)$", text, re.M)
    for wanted in ("Install", "Quickstart in the simulated scene", "Hardware it expects",
                   "Results"):
        assert wanted in headings, f"README.md lost its {wanted!r} section"
    assert "<!-- workspace -->\n```bash\n" in text       # scripts/ci_workspace.sh runs it
    assert "make demo" in text and "docs/hardware-quickstart.md" in text
    assert "](docs/results.md)" in text


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped but ``-`` and ``_``,
    spaces to hyphens."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set:
    seen, out = {}, set()
    in_code = False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            in_code = not in_code
        m = None if in_code else re.match(r"#+ (.+)$", line)
        if m:
            slug = _slug(m.group(1))
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_the_slug_is_githubs():
    assert _slug("Closed loop in the scene: the paper's Table III (`make demo`)") == \
        "closed-loop-in-the-scene-the-papers-table-iii-make-demo"
    assert _slug("Choosing the recipe: measured (`aslip train`, `--stage auto`)") == \
        "choosing-the-recipe-measured-aslip-train---stage-auto"


def test_every_link_to_a_section_lands_on_a_heading():
    broken = []
    for page in PAGES:
        for target, anchor in re.findall(r"\]\(([\w./-]*)#([^)\s]+)\)", page.read_text()):
            dest = (page.parent / target).resolve() if target else page
            if not dest.is_file():
                broken.append(f"{page.relative_to(ROOT)}: {target} does not exist")
            elif anchor not in _anchors(dest):
                broken.append(f"{page.relative_to(ROOT)}: {target or page.name}#{anchor} is "
                              f"no heading of {dest.relative_to(ROOT)}")
    assert not broken, "\n".join(broken)
