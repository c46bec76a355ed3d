"""Build the Blender extension: dist/sweepedit_blender-<version>.zip with
blender_manifest.toml at the zip's root, as Blender 4.2+ extensions require.

    python scripts/build_blender_addon.py [--out DIR]

Install it in Blender with Edit > Preferences > Get Extensions > Install from Disk (or
`blender --command extension install-file -r user_default FILE.zip`).
"""

from __future__ import annotations

import argparse
import re
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ADDON = ROOT / "sweepedit" / "resources" / "blender" / "sweepedit_blender"


def version() -> str:
    text = (ADDON / "blender_manifest.toml").read_text(encoding="utf-8")
    match = re.search(r'^version\s*=\s*"([^"]+)"', text, re.MULTILINE)
    if not match:
        raise SystemExit(f"{ADDON / 'blender_manifest.toml'}: no version")
    return match.group(1)


def build(out_dir: Path) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"sweepedit_blender-{version()}.zip"
    tmp = target.with_suffix(".zip.tmp")
    files = sorted(p for p in ADDON.rglob("*") if p.is_file() and "__pycache__" not in p.parts
                   and p.suffix != ".pyc")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        for p in files:
            zf.write(p, p.relative_to(ADDON).as_posix())
    tmp.replace(target)
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "dist")
    args = parser.parse_args(argv)
    print(build(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
