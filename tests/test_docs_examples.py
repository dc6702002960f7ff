"""Every ```python block of the user guide runs, and the site builds with ``mkdocs --strict``.

The blocks of one page run in order in one namespace (a page reads as one script), in a
temporary folder; gear options a page registers are unregistered after it. ``--8<--
"path"`` lines (pymdownx.snippets) are replaced by the file.
"""

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide"
PAGES = sorted(GUIDE.glob("*.md"))
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)
_SNIPPET = re.compile(r'^--8<-- "([^":]+)(?::(\w+))?"$', re.M)


def snippet(match: re.Match[str]) -> str:
    """A snippet line's file, or its section ``# --8<-- [start:NAME]`` .. ``[end:NAME]``
    for ``"path:NAME"``, as pymdownx.snippets includes it."""
    text = (ROOT / match.group(1)).read_text(encoding="utf-8")
    name = match.group(2)
    if name is None:
        return text
    start, end = f"# --8<-- [start:{name}]\n", f"# --8<-- [end:{name}]"
    return text[text.index(start) + len(start):text.index(end)]


def python_blocks(page: Path) -> list[str]:
    """The page's python blocks, with snippet lines replaced by the files they name."""
    blocks = _BLOCK.findall(page.read_text(encoding="utf-8"))
    return [_SNIPPET.sub(snippet, b) for b in blocks]


def test_the_guide_has_pages_with_examples():
    names = {p.name for p in PAGES}
    assert {"index.md", "concepts.md", "tutorial.md", "adding-an-option.md",
            "adding-an-environment.md", "mountain-car.md", "file-formats.md",
            "cli.md"} <= names
    assert sum(len(python_blocks(p)) for p in PAGES) >= 20


@pytest.mark.parametrize("page", PAGES, ids=[p.stem for p in PAGES])
def test_every_python_example_runs(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))  # examples.* import as from the repository root
    from dynoplan.envs.gear.options import temporary_gear_options

    namespace: dict[str, object] = {"__name__": f"docs_{page.stem.replace('-', '_')}"}
    with temporary_gear_options():  # a gear option a page registers stays on that page
        for index, block in enumerate(python_blocks(page)):
            code = compile(block, f"{page.relative_to(ROOT)} (python block {index + 1})",
                           "exec")
            exec(code, namespace)


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason="mkdocs not installed")
def test_the_site_builds_strictly(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "guide" / "concepts" / "index.html").is_file()
