"""docs/api.md's examples run as written: every ```python block, in order, in one
namespace, in a scratch folder (each block's asserts check what the text claims)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_the_doc_has_examples() -> None:
    blocks = python_blocks(DOC.read_text(encoding="utf-8"))
    assert len(blocks) >= 4
    assert all("sweepedit." in b or "abstraction" in b for b in blocks)


@pytest.mark.slow
def test_api_doc_examples_run(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "api_doc"}
    for i, block in enumerate(python_blocks(DOC.read_text(encoding="utf-8"))):
        try:
            exec(compile(block, f"{DOC.name} block {i + 1}", "exec"), namespace)
        except Exception as exc:
            raise AssertionError(f"docs/api.md block {i + 1} failed: {exc!r}\n{block}") from exc
    out = capsys.readouterr().out
    # What the text says the prints show.
    assert re.search(r"<sweepedit.Abstraction: [1-4] primitives, fitted in [0-9.]+ s>", out)
    assert "mesh 1.5" in out
    assert "voxels" in out
    assert (tmp_path / "cactus.json").is_file()
    assert (tmp_path / "bar.glb").is_file() and (tmp_path / "bar.png").is_file()
