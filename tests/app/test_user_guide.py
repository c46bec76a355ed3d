"""docs/user-guide.md lists every keyboard shortcut the window really has."""

from __future__ import annotations

import re
from pathlib import Path

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "user-guide.md"


def _documented_keys() -> set[str]:
    """The first column of the guide's "All keys" table, one entry per key."""
    table = GUIDE.read_text(encoding="utf-8").split("## All keys", 1)[1]
    keys: set[str] = set()
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 2 or cells[0] in ("key", "") or set(cells[0]) <= {"-"}:
            continue
        keys.update(k.strip() for k in re.sub(r"\(.*?\)", "", cells[0]).split(","))
    return keys


def test_the_guide_lists_every_shortcut(window) -> None:
    from PySide6.QtGui import QAction, QKeySequence

    documented = _documented_keys()
    assert {"Ctrl+Z", "F1", "Keypad 9"} <= documented  # the table was found and parsed
    missing = set()
    for action in window.findChildren(QAction):
        for sequence in action.shortcuts():
            text = sequence.toString(QKeySequence.SequenceFormat.PortableText)
            key = text.replace("Num+", "Keypad ")  # Qt's name for keypad keys
            if key and key not in documented:
                missing.add(f"{key} ({action.text().replace('&', '')})")
    assert not missing, f"docs/user-guide.md lacks: {sorted(missing)}"
