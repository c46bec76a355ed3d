"""The JSON Schema (draft 2020-12) of sweepedit's parameter file, shipped with the package.

params.schema.json beside this module is the one copy; docs/parameter-format.md explains
it field by field. The schema describes what `sweepedit.io.params` reads, for tools that
check or produce parameter files without sweepedit. The reader checks a little more
than a schema can say (numbers finite, f(t) > 0 on [0, 1], an axis of non-zero length);
the schema's own description lists those checks.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["PARAMS_SCHEMA_PATH", "params_schema"]

PARAMS_SCHEMA_PATH = Path(__file__).resolve().with_name("params.schema.json")


def params_schema() -> dict[str, Any]:
    """The parameter-file schema as a dict (for example for `jsonschema.validate`)."""
    return json.loads(PARAMS_SCHEMA_PATH.read_text(encoding="utf-8"))
