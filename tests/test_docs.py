"""The project's own documentation: the parameter-file schema against sweepedit's real
reader and writer, and the README and docs/ standing on their own (no paths outside
the repository, no broken relative links)."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from jsonschema import Draft202012Validator

from sweepedit.errors import FileFormatError
from sweepedit.geometry.model import Abstraction, Normalization, SweepPrimitive
from sweepedit.io.params import (
    FORMAT_VERSION,
    abstraction_from_json,
    read_abstraction,
    write_abstraction,
)
from sweepedit.io.schema import PARAMS_SCHEMA_PATH, params_schema

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
DOC_PAGES = ("primitive.md", "parameter-format.md", "quality.md", "architecture.md",
             "user-guide.md", "fitting.md")
EXAMPLE_SHAPE = ROOT / "resources" / "examples" / "cactus.off"


@pytest.fixture(scope="module")
def validator() -> Draft202012Validator:
    schema = params_schema()
    Draft202012Validator.check_schema(schema)  # the schema itself is valid 2020-12
    return Draft202012Validator(schema)


def _strict_json(text: str) -> Any:
    """JSON as the standard has it: NaN and Infinity are not numbers there."""
    def reject(token: str) -> None:
        raise ValueError(f"{token} is not JSON")
    return json.loads(text, parse_constant=reject)


def _written(abstraction: Abstraction, path: Path) -> dict[str, Any]:
    """Write through sweepedit's writer; the document as any JSON reader sees it."""
    write_abstraction(abstraction, path)
    return _strict_json(path.read_text(encoding="utf-8"))


def _rich_abstraction() -> Abstraction:
    """Everything the format holds: 4 control points, a cubic scaling, a hidden and a locked
    primitive, a real normalisation, source, fit record and unknown keys at each level."""
    bent = SweepPrimitive(np.array([[-0.3, 0.0, 0.0], [0.0, 0.2, 0.1], [0.2, -0.1, 0.0],
                                    [0.35, 0.0, 0.2]]), a=0.08, b=0.03, degree=0.6,
                          scaling=(0.2, -0.3, 0.1), name="limb", color="#12ab9F",
                          visible=False, extras={"note": [1, 2], "profile": {"unit": "m"}})
    straight = SweepPrimitive(np.array([[0.0, 0.0, -0.4], [0.0, 0.0, 0.0], [0.0, 0.0, 0.4]]),
                              a=0.5, b=0.01, degree=5.0, scaling=(), locked=True)
    return Abstraction(
        [bent, straight], normalization=Normalization(center=[1.5, -2.0, 3.0], scale=42.0),
        source={"path": "shapes/x.obj", "sha256": "ab" * 32},
        fit={"seconds": np.float32(1.5), "metrics": {"iou": np.float64(0.8)},
             "steps": np.arange(3)},
        extras={"normalization": {"units": "mm"}, "project": {"owner": "me"}})


# --------------------------------------------------------------------------- accepts


def test_schema_accepts_what_the_writer_writes(tmp_path: Path,
                                               validator: Draft202012Validator) -> None:
    doc = _written(_rich_abstraction(), tmp_path / "rich.json")
    validator.validate(doc)
    assert doc["version"] == FORMAT_VERSION
    validator.validate(_written(Abstraction(), tmp_path / "empty.json"))


@pytest.mark.slow
def test_schema_accepts_a_real_fit(tmp_path: Path, validator: Draft202012Validator) -> None:
    """A parameter file from an actual (short) fit, with its fit record and source."""
    from sweepedit.fitting.fit import FitSettings, fit_abstraction
    from sweepedit.io.shapes import load_shape

    shape = load_shape(EXAMPLE_SHAPE, resolution=32, n_samples=4096)
    result = fit_abstraction(shape, FitSettings(primitives=2, refine_iterations=5,
                                                residual_rounds=0))
    doc = _written(result.abstraction, tmp_path / "fit.json")
    validator.validate(doc)
    assert doc["fit"] and doc["source"]["sha256"] == shape.sha256
    assert len(doc["primitives"]) >= 1


def test_schema_accepts_official_files_converted(shared_dir: Path, tmp_path: Path,
                                                 validator: Draft202012Validator) -> None:
    """Every official SweepNet file, read by sweepedit and written as JSON."""
    files = sorted((shared_dir / "sweepnet_params").glob("*.txt"))
    if not files:
        pytest.skip("no official SweepNet parameter files")
    for txt in files:
        doc = _written(read_abstraction(txt), tmp_path / f"{txt.stem}.json")
        errors = [e.message for e in validator.iter_errors(doc)]
        assert not errors, f"{txt.name}: {errors}"


def test_range_tolerance_matches_the_reader(validator: Draft202012Validator) -> None:
    """A hair outside a range (text formats round) is fine for both; more is not."""
    base = _base_document()
    for value, ok in ((0.5 + 5e-7, True), (0.5 + 5e-6, False), (0.01 - 5e-7, True),
                      (0.01 - 5e-6, False)):
        doc = copy.deepcopy(base)
        doc["primitives"][0]["profile"]["b"] = value
        assert validator.is_valid(doc) is ok, value
        if ok:
            abstraction_from_json(doc)
        else:
            with pytest.raises(FileFormatError):
                abstraction_from_json(doc)


# --------------------------------------------------------------------------- rejects


def _base_document() -> dict[str, Any]:
    from sweepedit.io.params import abstraction_to_json

    return _strict_json(json.dumps(abstraction_to_json(_rich_abstraction()),
                                   default=lambda v: v.tolist()))


def _set(path: str, value: Any):
    """A change to a document: set the value at a dotted path ('-' deletes the key)."""
    def change(doc: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        node: Any = doc
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node[key]
        if isinstance(node, list):
            node[int(last)] = value
        elif value == "-":
            del node[last]
        else:
            node[last] = value
    return change


BROKEN = {
    "no format": _set("format", "-"),
    "other format": _set("format", "something.else"),
    "no version": _set("version", "-"),
    "future version": _set("version", FORMAT_VERSION + 1),
    "version 0": _set("version", 0),
    "version as text": _set("version", "1"),
    "version as boolean": _set("version", True),
    "no primitives": _set("primitives", "-"),
    "primitives not a list": _set("primitives", {"0": {}}),
    "primitive not an object": _set("primitives.0", [1, 2, 3]),
    "no control points": _set("primitives.0.control_points", "-"),
    "two control points": _set("primitives.1.control_points", [[0, 0, 0], [0, 0, 1]]),
    "2D control point": _set("primitives.0.control_points.1", [0.0, 0.1]),
    "control point as text": _set("primitives.0.control_points.1", "0 0 0"),
    "no profile": _set("primitives.0.profile", "-"),
    "no profile.a": _set("primitives.0.profile.a", "-"),
    "profile.a as text": _set("primitives.0.profile.a", "0.1"),
    "NaN written as a string": _set("primitives.0.profile.b", "NaN"),
    "profile.a null": _set("primitives.0.profile.a", None),
    "profile.a too large": _set("primitives.0.profile.a", 0.6),
    "degree too small": _set("primitives.0.profile.degree", 0.1),
    "scaling out of range": _set("primitives.0.scaling", [0.7]),
    "scaling not a list": _set("primitives.0.scaling", 0.1),
    "scaling boolean": _set("primitives.0.scaling", [True]),
    "colour name": _set("primitives.0.color", "red"),
    "short colour": _set("primitives.0.color", "#abc"),
    "visible as text": _set("primitives.0.visible", "yes"),
    "locked as number": _set("primitives.1.locked", 1),
    "name not text": _set("primitives.0.name", 3),
    "scale zero": _set("normalization.scale", 0.0),
    "2D centre": _set("normalization.center", [0.0, 0.0]),
    "normalization not an object": _set("normalization", [1.0]),
    "source as text": _set("source", "shapes/x.obj"),
    "fit as a list": _set("fit", [1, 2]),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_schema_and_reader_both_reject(case: str, validator: Draft202012Validator) -> None:
    doc = _base_document()
    validator.validate(doc)
    abstraction_from_json(doc)  # the unbroken document is fine for both
    BROKEN[case](doc)
    assert not validator.is_valid(doc), f"the schema accepts: {case}"
    with pytest.raises(FileFormatError):
        abstraction_from_json(doc, "broken.json")


def test_nan_token_is_not_json_and_the_reader_refuses_it(tmp_path: Path) -> None:
    """Python's json writes a bare NaN when asked to; that is not JSON (a schema tool never
    sees a document), and sweepedit's reader refuses the value as not finite."""
    doc = _base_document()
    doc["primitives"][0]["control_points"][0][0] = float("nan")
    path = tmp_path / "nan.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(ValueError, match="NaN is not JSON"):
        _strict_json(path.read_text(encoding="utf-8"))
    with pytest.raises(FileFormatError, match="finite"):
        read_abstraction(path)


# What only the reader can check (listed in the schema's description and in
# docs/parameter-format.md): the schema passes these, the reader refuses them.
READER_ONLY = {
    "f(t) reaches 0": _set("primitives.0.scaling", [-0.5, -0.5]),
    "axis of zero length": _set("primitives.1.control_points", [[0.1, 0.1, 0.1]] * 3),
    "version written as 1.0": _set("version", 1.0),
}


@pytest.mark.parametrize("case", sorted(READER_ONLY))
def test_reader_only_checks(case: str, validator: Draft202012Validator) -> None:
    doc = _base_document()
    READER_ONLY[case](doc)
    assert validator.is_valid(doc)
    with pytest.raises(FileFormatError):
        abstraction_from_json(doc)


def test_unknown_keys_are_allowed_at_every_level(validator: Draft202012Validator) -> None:
    doc = _base_document()
    doc["future_key"] = {"x": 1}
    doc["primitives"][0]["twist"] = 0.5
    doc["primitives"][0]["profile"]["rounding"] = 0.1
    doc["normalization"]["rotation"] = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    validator.validate(doc)
    abstraction = abstraction_from_json(doc)
    assert abstraction.extras["future_key"] == {"x": 1}
    assert abstraction.primitives[0].extras["twist"] == 0.5


# --------------------------------------------------------------------------- documents


def _markdown_files() -> list[Path]:
    """The documents a user reads. Not the measurement records (BENCHMARKS.md and its log,
    docs/benchmark-log.md): they name the team's shape sets outside the repository that
    the figures were taken on."""
    return [ROOT / "README.md", *sorted(p for p in DOCS.glob("*.md")
                                        if p.name != "benchmark-log.md"),
            ROOT / "resources" / "README.md",
            ROOT / "sweepedit" / "resources" / "benchmark" / "README.md"]


def test_docs_pages_exist() -> None:
    for name in DOC_PAGES:
        assert (DOCS / name).is_file(), name
    assert PARAMS_SCHEMA_PATH.is_file()


OUTSIDE = re.compile(r"\.\./shared|/work/|\bshared/(?:shapes|sweepnet_params|DESIGN)")


def test_no_reference_outside_the_repository() -> None:
    for path in _markdown_files():
        for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            assert not OUTSIDE.search(line), f"{path.name}:{lineno}: {line.strip()}"


LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")


def _relative_links(path: Path) -> list[str]:
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # code blocks hold no links
    return [t for t in LINK.findall(text) if not re.match(r"[a-z][a-z0-9+.-]*:", t, flags=re.I)]


def test_link_pattern_finds_links() -> None:
    """The link test below would pass vacuously if the pattern found nothing."""
    links = _relative_links(ROOT / "README.md")
    assert "docs/screenshot.png" in links
    assert any(link.startswith("docs/") and link.endswith(".md") for link in links)


def _anchors(path: Path) -> set[str]:
    """GitHub's anchors of a Markdown file's headings: lower case, punctuation dropped,
    spaces to hyphens."""
    text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.S)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-")
            for h in re.findall(r"^#+ (.+)$", text, flags=re.M)}


def test_anchor_slugs() -> None:
    assert "units-and-the-normalised-frame" in _anchors(DOCS / "primitive.md")
    assert "the-official-sweepnet-text-format" in _anchors(DOCS / "parameter-format.md")


@pytest.mark.parametrize("path", _markdown_files(), ids=lambda p: p.name)
def test_relative_links_point_at_files(path: Path) -> None:
    for target in _relative_links(path):
        name, _, anchor = target.partition("#")
        file = (path.parent / name).resolve() if name else path
        assert file.exists(), f"{path.name}: link to {target} points at nothing"
        assert ROOT in file.parents, f"{path.name}: link to {target} leaves the repository"
        if anchor and file.suffix == ".md":
            assert anchor in _anchors(file), f"{path.name}: no heading for {target}"
