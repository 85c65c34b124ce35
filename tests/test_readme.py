"""The README is a user's guide that stays true: its Python blocks marked runnable run, quietly,
as a user would paste them; every shipped scene is in its table; it stays short."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
MARK = "<!-- runnable -->"


def runnable_blocks():
    """(page, index, code) of every ```python block right after a `<!-- runnable -->` line."""
    found = []
    for page in PAGES:
        text = page.read_text()
        for k, match in enumerate(re.finditer(re.escape(MARK) + r"\s*\n```python\n(.*?)\n```", text, re.S)):
            found.append(pytest.param(match.group(1), id=f"{page.relative_to(ROOT)}#{k + 1}"))
    return found


def test_the_readme_has_runnable_blocks():
    assert len([b for b in runnable_blocks() if "README" in b.id]) >= 2


@pytest.mark.slow
@pytest.mark.parametrize("code", runnable_blocks())
def test_runnable_block_runs_without_a_warning(code, tmp_path):
    """Each block runs in a fresh process (Taichi initialises once per process) from its own
    file, with RuntimeWarning an error and no warning in its log."""
    script = tmp_path / "block.py"  # a file: Taichi reads kernels' source
    script.write_text(code + "\n")
    done = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", str(script)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "warning" not in done.stderr.lower(), done.stderr[-3000:]


def test_readme_is_a_short_guide_with_every_scene():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 300
    for scene in sorted((ROOT / "scenes").glob("*.py")):
        assert f"`scenes/{scene.name}`" in text, f"{scene.name} is missing from the README's scene table"


def test_readme_links_point_at_files_and_headings():
    """Relative links of the README and docs/ name files that exist (and headings that exist)."""
    for page in PAGES:
        for target in re.findall(r"\]\(([^)#:]+\.md)(#[^)]+)?\)", page.read_text()):
            path = (page.parent / target[0]).resolve()
            assert path.is_file(), f"{page.name} links to {target[0]}, which does not exist"
            if target[1]:
                anchors = {re.sub(r"[^a-z0-9 -]", "", h.lower()).replace(" ", "-")
                           for h in re.findall(r"^#+ (.+)$", path.read_text(), re.M)}
                assert target[1][1:] in anchors, f"{page.name} links to {target[0]}{target[1]}: no such heading"
