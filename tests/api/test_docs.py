"""Every ```python block of README.md and docs/*.md runs as written.

Each file reads as one script: its blocks run in order, each in a fresh namespace that starts from
the names the previous blocks of the same file defined, and none uses a deprecated sabre name.
Illustrative snippets use ```text or ```sh.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

# A fence opens with ``` plus an info string and closes with a bare ``` at the same indent.
FENCE = re.compile(r"^```(?P<info>[^\n`]*)\n(?P<body>.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def python_blocks(text: str) -> list[tuple[int, str]]:
    """(first line number, source) of each ```python block of a markdown text."""
    blocks = []
    for match in FENCE.finditer(text):
        if match.group("info").strip() == "python":
            line = text.count("\n", 0, match.start("body")) + 1
            blocks.append((line, match.group("body")))
    return blocks


def test_block_extraction_finds_python_fences_only():
    text = "intro\n```python\na = 1\n```\n```sh\nmake\n```\n```text\nx\n```\n```python\nb = a\n```\n"
    assert python_blocks(text) == [(3, "a = 1\n"), (12, "b = a\n")]


def test_the_readme_has_runnable_examples():
    assert len(python_blocks((ROOT / "README.md").read_text())) >= 3


@pytest.mark.parametrize("document", DOCUMENTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_python_block_runs(document: Path):
    names: dict[str, object] = {}
    for line, source in python_blocks(document.read_text()):
        namespace = {"__name__": f"docs:{document.name}", **names}
        code = compile(source, f"{document.relative_to(ROOT)}:{line}", "exec")
        with warnings.catch_warnings():  # the docs teach the current names, never a deprecated one
            warnings.filterwarnings("error", message=r"sabre\.\S+ is deprecated", category=DeprecationWarning)
            exec(code, namespace)
        names = {k: v for k, v in namespace.items() if k != "__builtins__"}
