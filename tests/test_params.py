"""Parameter files: JSON and official SweepNet text, round trips, errors, atomic writes.

The truths checked here come from outside the code under test: raw text read back with
numpy and json, the official files of ../shared/sweepnet_params, and hand-built documents.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from sweepedit.errors import FileFormatError, InvalidPrimitiveError
from sweepedit.geometry.model import (
    MIN_SCALE,
    Abstraction,
    Normalization,
    SweepPrimitive,
    palette_color,
    scaling_polynomial_min,
)
from sweepedit.io import params
from sweepedit.io.params import (
    abstraction_from_json,
    abstraction_to_json,
    atomic_open,
    atomic_write_bytes,
    atomic_write_text,
    default_name,
    read_abstraction,
    read_official_txt,
    write_abstraction,
    write_official_txt,
)

SHARED = Path(__file__).resolve().parents[2] / "shared"
OFFICIAL = sorted((SHARED / "sweepnet_params").glob("*.txt"))


# --------------------------------------------------------------------------- helpers


def assert_same(a: Abstraction, b: Abstraction) -> None:
    """Exact equality, field by field (no tolerance: the formats must be lossless)."""
    assert len(a.primitives) == len(b.primitives)
    assert np.array_equal(a.normalization.center, b.normalization.center)
    assert a.normalization.scale == b.normalization.scale
    assert (a.source, a.fit, a.extras) == (b.source, b.fit, b.extras)
    for p, q in zip(a.primitives, b.primitives, strict=True):
        assert p.control_points.shape == q.control_points.shape
        assert np.array_equal(p.control_points, q.control_points)
        assert (p.a, p.b, p.degree, p.scaling) == (q.a, q.b, q.degree, q.scaling)
        assert (p.name, p.color, p.visible, p.locked) == (q.name, q.color, q.visible, q.locked)
        assert p.extras == q.extras


def primitive(index: int = 0, n: int = 3, scaling: tuple[float, ...] = (0.1, -0.2),
              **kw: Any) -> SweepPrimitive:
    t = np.linspace(-0.3, 0.3, n)
    cp = np.stack([t, 0.1 * t**2 + 0.01 * index, 0.05 * index + 0.0 * t], axis=1)
    kw.setdefault("name", f"primitive {index + 1}")  # the default name of the index-th
    kw.setdefault("color", palette_color(index))
    return SweepPrimitive(control_points=cp, a=0.05 + 0.01 * index, b=0.04, degree=2.5,
                          scaling=scaling, **kw)


def valid_doc() -> dict[str, Any]:
    """A hand-written, valid JSON document with two primitives (index 1 gets broken)."""
    prim = {"control_points": [[0.0, 0.0, 0.0], [0.1, 0.2, 0.0], [0.3, 0.1, 0.05]],
            "profile": {"a": 0.05, "b": 0.04, "degree": 2.0}, "scaling": [0.1, -0.2],
            "name": "leg", "color": "#e4572e", "visible": True, "locked": False}
    return {"format": "sweepedit.abstraction", "version": 1,
            "normalization": {"center": [1.0, 2.0, 3.0], "scale": 2.5},
            "source": {"path": "shapes/ant.ply", "sha256": "ab"},
            "primitives": [json.loads(json.dumps(prim)), json.loads(json.dumps(prim))],
            "fit": {"iterations": 10}}


# --------------------------------------------------------------------------- hypothesis

coord = st.floats(-0.5, 0.5, allow_nan=False, allow_infinity=False)
point = st.lists(coord, min_size=3, max_size=3)
json_scalar = (st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.text(max_size=8)
               | st.floats(allow_nan=False, allow_infinity=False))
json_value = st.recursive(json_scalar, lambda c: st.lists(c, max_size=3)
                          | st.dictionaries(st.text(max_size=5), c, max_size=3), max_leaves=6)


def extras_for(known: tuple[str, ...]) -> st.SearchStrategy[dict[str, Any]]:
    return st.dictionaries(st.text(min_size=1, max_size=8).filter(lambda k: k not in known),
                           json_value, max_size=3)


@st.composite
def sweep_primitives(draw: st.DrawFn, n: tuple[int, int] = (3, 6), k: tuple[int, int] = (0, 4),
                     plain: bool = False, index: int = 0) -> SweepPrimitive:
    """A valid primitive with n[0]..n[1] control points and k[0]..k[1] scaling coefficients."""
    n_cp = draw(st.integers(*n))
    cp = np.array(draw(st.lists(point, min_size=n_cp, max_size=n_cp)))
    assume(np.sum(np.linalg.norm(np.diff(cp, axis=0), axis=1)) > 1e-3)
    scaling = tuple(draw(st.lists(st.floats(-0.5, 0.5), min_size=(kk := draw(st.integers(*k))),
                                  max_size=kk)))
    assume(scaling_polynomial_min(scaling) > MIN_SCALE)
    p = SweepPrimitive(control_points=cp, a=draw(st.floats(0.01, 0.5)),
                       b=draw(st.floats(0.01, 0.5)), degree=draw(st.floats(0.3, 5.0)),
                       scaling=scaling, name=default_name(index), color=palette_color(index))
    if not plain:
        p.name = draw(st.text(max_size=12))
        p.color = draw(st.integers(0, 0xFFFFFF).map(lambda v: f"#{v:06x}")
                       | st.integers(0, 0xFFFFFF).map(lambda v: f"#{v:06X}"))
        p.visible, p.locked = draw(st.booleans()), draw(st.booleans())
        p.extras = draw(extras_for(params.PRIMITIVE_KEYS))
        profile_extras = draw(extras_for(params.PROFILE_KEYS))
        if profile_extras:
            p.extras["profile"] = profile_extras
    return p


@st.composite
def abstractions(draw: st.DrawFn) -> Abstraction:
    prims = draw(st.lists(sweep_primitives(), max_size=4))
    extras = draw(extras_for(params.TOP_KEYS))
    norm = Normalization(center=draw(st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3)),
                         scale=draw(st.floats(1e-3, 1e3)))
    return Abstraction(primitives=prims, normalization=norm,
                       source=draw(st.none() | st.dictionaries(st.text(max_size=5), json_value,
                                                               max_size=2)),
                       fit=draw(st.none() | st.dictionaries(st.text(max_size=5), json_value,
                                                            max_size=3)),
                       extras=extras)


@st.composite
def plain_abstractions(draw: st.DrawFn) -> Abstraction:
    """What the official format can hold: n = 3, two scaling coefficients, default names."""
    count = draw(st.integers(1, 5))
    return Abstraction(primitives=[
        draw(sweep_primitives(n=(3, 3), k=(2, 2), plain=True, index=i))
        for i in range(count)])


FAST = settings(max_examples=40, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


@FAST
@given(abstraction=abstractions())
def test_json_round_trip_is_exact(abstraction: Abstraction, tmp_path: Path) -> None:
    path = tmp_path / "a.json"
    write_abstraction(abstraction, path)
    back = read_abstraction(path)
    assert_same(abstraction, back)
    # Written again, the file is the same byte for byte.
    write_abstraction(back, tmp_path / "b.json")
    assert (tmp_path / "b.json").read_bytes() == path.read_bytes()


@FAST
@given(abstraction=plain_abstractions())
def test_json_txt_json_round_trip_is_exact(abstraction: Abstraction, tmp_path: Path) -> None:
    write_abstraction(abstraction, tmp_path / "a.json")
    write_abstraction(read_abstraction(tmp_path / "a.json"), tmp_path / "a.txt")
    via_txt = read_abstraction(tmp_path / "a.txt")
    write_abstraction(via_txt, tmp_path / "b.json")
    assert_same(abstraction, read_abstraction(tmp_path / "b.json"))
    assert (tmp_path / "b.json").read_bytes() == (tmp_path / "a.json").read_bytes()


# --------------------------------------------------------------------------- JSON by hand


@pytest.mark.parametrize("n", [3, 4, 5])
@pytest.mark.parametrize("k", [0, 1, 2, 3, 4])
def test_json_round_trip_control_points_and_scaling_degrees(tmp_path: Path, n: int,
                                                            k: int) -> None:
    scaling = (0.1, -0.05, 0.02, -0.01)[:k]
    a = Abstraction(primitives=[primitive(0, n=n, scaling=scaling, name="arm", visible=False),
                                primitive(1, n=n, scaling=scaling, locked=True,
                                          extras={"note": {"x": [1, 2]}, "profile": {"u": 1}})],
                    normalization=Normalization(center=[0.1, 1 / 3, -2.0], scale=0.7),
                    source={"path": "s.ply"}, fit={"seconds": 1.5}, extras={"zz": [1.5, None]})
    write_abstraction(a, tmp_path / "a.json")
    back = read_abstraction(tmp_path / "a.json")
    assert_same(a, back)
    assert back.primitives[0].n_control_points == n
    assert back.primitives[0].scaling == scaling


def test_json_layout_key_order_and_exact_numbers(tmp_path: Path) -> None:
    doc = valid_doc()
    doc["zz_unknown"] = {"keep": True}
    doc["aa_unknown"] = 1
    doc["primitives"][0]["profile"]["roundness"] = 0.25
    doc["primitives"][0]["tag"] = "wing"
    doc["normalization"]["unit"] = "mm"
    doc["primitives"][1]["control_points"][1] = [0.1, 1 / 3, 2 / 7]
    (tmp_path / "in.json").write_text(json.dumps(doc))
    write_abstraction(read_abstraction(tmp_path / "in.json"), tmp_path / "out.json")
    out = json.loads((tmp_path / "out.json").read_text(encoding="utf-8"))
    assert list(out) == ["format", "version", "normalization", "source", "primitives", "fit",
                         "zz_unknown", "aa_unknown"]
    assert out == doc  # unknown keys at every level survive, numbers are identical
    assert list(out["primitives"][0]) == [*params.PRIMITIVE_KEYS, "tag"]
    assert list(out["primitives"][0]["profile"]) == ["a", "b", "degree", "roundness"]
    # Readable layout: a point or a coefficient list per line, numbers in full.
    text = (tmp_path / "out.json").read_text(encoding="utf-8")
    assert '"scaling": [0.1, -0.2],' in text
    assert f"[0.1, {1 / 3!r}, {2 / 7!r}]" in text


def test_json_defaults_for_optional_keys(tmp_path: Path) -> None:
    doc = valid_doc()
    for prim in doc["primitives"]:
        for key in ("scaling", "name", "color", "visible", "locked"):
            del prim[key]
    del doc["normalization"], doc["source"], doc["fit"]
    (tmp_path / "min.json").write_text(json.dumps(doc))
    a = read_abstraction(tmp_path / "min.json")
    p = a.primitives[1]
    assert (p.name, p.color, p.visible, p.locked, p.scaling) == (
        "primitive 2", palette_color(1), True, False, ())
    assert np.array_equal(a.normalization.center, np.zeros(3)) and a.normalization.scale == 1
    assert a.source is None and a.fit is None and a.extras == {} and p.extras == {}


def test_abstraction_to_json_is_a_copy() -> None:
    a = Abstraction(primitives=[primitive(0, extras={"l": [1]})], fit={"m": [1]})
    doc = abstraction_to_json(a)
    doc["primitives"][0]["l"].append(2)
    doc["fit"]["m"].append(2)
    assert a.primitives[0].extras == {"l": [1]} and a.fit == {"m": [1]}


def test_numpy_values_in_fit_record_are_stored(tmp_path: Path) -> None:
    a = Abstraction(primitives=[primitive(0)],
                    fit={"iou": np.float32(0.5), "n": np.int64(3), "loss": np.arange(3.0)})
    write_abstraction(a, tmp_path / "f.json")
    assert read_abstraction(tmp_path / "f.json").fit == {"iou": 0.5, "n": 3,
                                                         "loss": [0.0, 1.0, 2.0]}


# --------------------------------------------------------------------------- official text


def test_scaling_column_order_in_official_txt(tmp_path: Path) -> None:
    a = Abstraction(primitives=[primitive(0, scaling=(0.1, -0.2))])
    write_abstraction(a, tmp_path / "one.txt")
    raw = np.loadtxt(tmp_path / "one.txt", ndmin=2)
    assert raw.shape == (1, 14)
    assert raw[0, 12] == -0.2 and raw[0, 13] == 0.1  # s_quad, then s_lin
    assert raw[0, 9:12].tolist() == [a.primitives[0].a, 0.04, 2.5]
    assert read_abstraction(tmp_path / "one.txt").primitives[0].scaling == (0.1, -0.2)


def test_official_txt_pads_low_degree_and_refuses_what_it_cannot_hold(tmp_path: Path) -> None:
    path = tmp_path / "w.txt"
    write_official_txt(Abstraction(primitives=[primitive(0, scaling=(0.3,)),
                                               primitive(1, scaling=()),
                                               primitive(2, scaling=(0.1, 0.1, 0.0))]), path)
    raw = np.loadtxt(path, ndmin=2)
    assert raw[:, 12:].tolist() == [[0.0, 0.3], [0.0, 0.0], [0.1, 0.1]]

    path.write_text("old")
    cases = [([primitive(0), primitive(1, scaling=(0.1, 0.1, 0.1))], ["primitive 2", "scaling",
                                                                      "degree"]),
             ([primitive(0), primitive(1, n=4)], ["primitive 2", "control points"]),
             ([], ["without primitives"])]
    for prims, words in cases:
        with pytest.raises(FileFormatError) as err:
            write_official_txt(Abstraction(primitives=prims), path)
        assert all(w in str(err.value) for w in [path.name, *words]), str(err.value)
        assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["w.txt"]


def test_official_txt_with_more_control_points(tmp_path: Path) -> None:
    a = Abstraction(primitives=[primitive(i, n=5) for i in range(3)])
    write_abstraction(a, tmp_path / "five.txt")
    assert np.loadtxt(tmp_path / "five.txt", ndmin=2).shape == (3, 20)
    assert_same(a, read_abstraction(tmp_path / "five.txt"))
    assert_same(a, read_official_txt(tmp_path / "five.txt", n_control_points=5))
    with pytest.raises(FileFormatError, match=r"five\.txt: line 1: 20 numbers, expected 14"):
        read_official_txt(tmp_path / "five.txt", n_control_points=3)


def test_official_txt_skips_blank_lines_and_comments(tmp_path: Path) -> None:
    row = " ".join(["0", "0", "0", "0.1", "0.1", "0", "0.2", "0", "0", "0.05", "0.05", "2",
                    "0", "0"])
    (tmp_path / "c.txt").write_text(f"# made by hand\n\n{row}\r\n{row}  # second\n")
    a = read_abstraction(tmp_path / "c.txt")
    assert len(a) == 2 and a.primitives[1].name == "primitive 2"


@pytest.mark.skipif(not OFFICIAL, reason="../shared/sweepnet_params is absent")
@pytest.mark.parametrize("path", OFFICIAL, ids=[p.stem for p in OFFICIAL])
def test_every_official_file_loads(path: Path, tmp_path: Path) -> None:
    a = read_abstraction(path)
    raw = np.loadtxt(path, ndmin=2)
    assert len(a) == raw.shape[0] >= 1
    for p, row in zip(a.primitives, raw, strict=True):
        p.validate()
        assert np.array_equal(p.control_points, row[:9].reshape(3, 3))
        assert (p.a, p.b, p.degree, p.scaling) == (row[9], row[10], row[11], (row[13], row[12]))
    assert np.array_equal(a.normalization.center, np.zeros(3)) and a.normalization.scale == 1
    # txt -> json -> read gives the same abstraction; json -> txt gives the original bytes.
    write_abstraction(a, tmp_path / "a.json")
    assert_same(a, read_abstraction(tmp_path / "a.json"))
    write_abstraction(read_abstraction(tmp_path / "a.json"), tmp_path / "a.txt")
    assert (tmp_path / "a.txt").read_bytes() == path.read_bytes()


# --------------------------------------------------------------------------- bad input


def _prim1(doc: dict[str, Any]) -> dict[str, Any]:
    return doc["primitives"][1]


def _set(fn: Any) -> Any:
    def make() -> str:
        doc = valid_doc()
        fn(doc)
        return json.dumps(doc)  # NaN is written as the bare token NaN, as a buggy tool would
    return make


OFFICIAL_ROW = " ".join(["0.0", "0.0", "0.0", "0.1", "0.1", "0.0", "0.2", "0.0", "0.0",
                         "0.05", "0.05", "2.0", "0.0", "0.0"])

BAD_CASES: dict[str, tuple[str, Any, list[str]]] = {
    # name: (extension, text maker, words the message must contain besides the file name)
    "a_out_of_range": ("json", _set(lambda d: _prim1(d)["profile"].update(a=0.9)),
                       ["primitive 2", "profile.a", "outside"]),
    "degree_out_of_range": ("json", _set(lambda d: _prim1(d)["profile"].update(degree=7)),
                            ["primitive 2", "profile.degree"]),
    "nan_control_point": ("json", _set(lambda d: _prim1(d)["control_points"][1].__setitem__(
        0, float("nan"))), ["primitive 2", "control_points", "finite"]),
    "two_control_points": ("json", _set(lambda d: _prim1(d)["control_points"].pop()),
                           ["primitive 2", "control_points", "at least 3"]),
    "coincident_points": ("json", _set(lambda d: _prim1(d).update(
        control_points=[[0.1, 0.1, 0.1]] * 3)), ["primitive 2", "control_points", "zero length"]),
    "scaling_reaches_zero": ("json", _set(lambda d: _prim1(d).update(scaling=[-0.5, -0.5])),
                             ["primitive 2", "scaling"]),
    "scaling_out_of_range": ("json", _set(lambda d: _prim1(d).update(scaling=[0.1, 0.7])),
                             ["primitive 2", "scaling[1]"]),
    "truncated": ("json", lambda: json.dumps(valid_doc(), indent=2)[:300],
                  ["ends unexpectedly", "truncated file", "line"]),
    "malformed": ("json", lambda: '{"format": "sweepedit.abstraction",\n "version": 1,,}',
                  ["line 2, column"]),
    "empty_json": ("json", lambda: "", ["empty"]),
    "not_an_object": ("json", lambda: "[1, 2]", ["object"]),
    "missing_profile": ("json", _set(lambda d: _prim1(d).pop("profile")),
                        ["primitive 2", "profile", "missing"]),
    "missing_degree": ("json", _set(lambda d: _prim1(d)["profile"].pop("degree")),
                       ["primitive 2", "profile.degree", "missing"]),
    "missing_control_points": ("json", _set(lambda d: _prim1(d).pop("control_points")),
                               ["primitive 2", "control_points", "missing"]),
    "missing_primitives": ("json", _set(lambda d: d.pop("primitives")),
                           ["primitives", "missing"]),
    "string_for_number": ("json", _set(lambda d: _prim1(d)["profile"].update(b="0.04")),
                          ["primitive 2", "profile.b", "number", "string"]),
    "bool_for_number": ("json", _set(lambda d: _prim1(d).update(scaling=[True])),
                        ["primitive 2", "scaling[0]", "number"]),
    "point_of_two": ("json", _set(lambda d: _prim1(d)["control_points"].__setitem__(2, [0, 1])),
                     ["primitive 2", "control_points[2]", "3 numbers"]),
    "string_for_bool": ("json", _set(lambda d: _prim1(d).update(visible="yes")),
                        ["primitive 2", "visible"]),
    "bad_colour": ("json", _set(lambda d: _prim1(d).update(color="red")),
                   ["primitive 2", "color", "#rrggbb"]),
    "number_for_name": ("json", _set(lambda d: _prim1(d).update(name=3)),
                        ["primitive 2", "name", "string"]),
    "bad_normalization": ("json", _set(lambda d: d["normalization"].update(scale=0)),
                          ["normalization"]),
    "version_2": ("json", _set(lambda d: d.update(version=2)),
                  ["version 2", "reads version 1", "newer"]),
    "version_string": ("json", _set(lambda d: d.update(version="1")), ["version"]),
    "wrong_format": ("json", _set(lambda d: d.update(format="other.tool")),
                     ["format", "other.tool", "sweepedit.abstraction"]),
    "unknown_extension": ("yaml", lambda: json.dumps(valid_doc()), ["extension", ".yaml"]),
    "txt_13_columns": ("txt", lambda: OFFICIAL_ROW + "\n" + OFFICIAL_ROW.rsplit(" ", 1)[0],
                       ["line 2", "13 numbers"]),
    "txt_first_row_13": ("txt", lambda: OFFICIAL_ROW.rsplit(" ", 1)[0], ["line 1", "13"]),
    "txt_empty": ("txt", lambda: "", ["empty"]),
    "txt_blank_only": ("txt", lambda: "\n  \n# nothing\n", ["empty"]),
    "txt_not_a_number": ("txt", lambda: OFFICIAL_ROW + "\n" + OFFICIAL_ROW.replace("0.05", "x",
                                                                                   1),
                         ["line 2", "column 10", "primitive 2", "profile.a", "'x'",
                          "not a number"]),
    "txt_nan": ("txt", lambda: OFFICIAL_ROW.replace("2.0", "nan"), ["line 1", "column 12",
                                                                     "primitive 1",
                                                                     "profile.degree",
                                                                     "finite"]),
    "txt_inf_s_lin": ("txt", lambda: OFFICIAL_ROW + "\n" + OFFICIAL_ROW.rsplit(" ", 1)[0]
                      + " inf", ["line 2", "column 14", "primitive 2", "scaling[0]",
                                 "finite"]),
    "txt_nan_control_point": ("txt", lambda: OFFICIAL_ROW.replace("0.2", "nan", 1),
                              ["line 1", "column 7", "primitive 1", "control_points[2]"]),
    "txt_out_of_range": ("txt", lambda: OFFICIAL_ROW + "\n" + OFFICIAL_ROW.replace("2.0", "9.0"),
                         ["line 2", "primitive 2", "profile.degree"]),
    "txt_binary": ("txt", lambda: "\udcff", ["UTF-8"]),
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_input_raises_file_format_error(tmp_path: Path, case: str) -> None:
    ext, make, words = BAD_CASES[case]
    path = tmp_path / f"bad_{case}.{ext}"
    path.write_bytes(make().encode("utf-8", "surrogateescape"))
    with pytest.raises(FileFormatError) as err:
        read_abstraction(path)
    message = str(err.value)
    for word in [path.name, *words]:
        assert word in message, f"{word!r} not in {message!r}"
    if "primitive 2" in words:  # people count from 1; the attribute is the index
        assert err.value.primitive == 1


def test_valid_doc_itself_loads(tmp_path: Path) -> None:
    # The bad cases above differ from this one only in what they break.
    (tmp_path / "good.json").write_text(json.dumps(valid_doc()))
    a = read_abstraction(tmp_path / "good.json")
    assert len(a) == 2 and a.primitives[0].scaling == (0.1, -0.2)
    assert a.normalization.to_original(np.zeros(3)).tolist() == [1.0, 2.0, 3.0]


def test_abstraction_from_json_names_the_given_path() -> None:
    doc = valid_doc()
    doc["primitives"][0]["profile"]["a"] = -1.0
    with pytest.raises(FileFormatError, match=r"^memo\.json: primitive 1, field 'profile\.a'"):
        abstraction_from_json(doc, "memo.json")


def test_write_unknown_extension_refused(tmp_path: Path) -> None:
    with pytest.raises(FileFormatError, match="extension"):
        write_abstraction(Abstraction(primitives=[primitive()]), tmp_path / "a.yaml")
    assert os.listdir(tmp_path) == []


# --------------------------------------------------------------------------- atomic writes


@pytest.fixture
def saved(tmp_path: Path) -> Path:
    path = tmp_path / "doc.json"
    write_abstraction(Abstraction(primitives=[primitive(0)]), path)
    return path


def _boom(*_: Any, **__: Any) -> Any:
    raise OSError("disk full (simulated)")


@pytest.mark.parametrize("target", ["os.replace", "os.fsync", "json.dumps"])
def test_failed_write_keeps_old_file_and_leaves_no_temp(saved: Path, target: str,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    old = saved.read_bytes()
    module, name = target.split(".")
    monkeypatch.setattr({"os": os, "json": json}[module], name, _boom)
    with pytest.raises(OSError, match="simulated"):
        write_abstraction(Abstraction(primitives=[primitive(0), primitive(1)]), saved)
    monkeypatch.undo()
    assert saved.read_bytes() == old
    assert os.listdir(saved.parent) == [saved.name]


def test_failure_inside_atomic_open_keeps_old_file(tmp_path: Path) -> None:
    path = tmp_path / "mesh.ply"
    atomic_write_bytes(path, b"old mesh")
    with pytest.raises(RuntimeError), atomic_open(path) as handle:
        handle.write(b"half a mesh")
        raise RuntimeError("exporter crashed")
    assert path.read_bytes() == b"old mesh"
    assert os.listdir(tmp_path) == ["mesh.ply"]
    with atomic_open(path, "w") as text:
        text.write("line\n")
    assert path.read_bytes() == b"line\n"


def test_invalid_primitive_is_refused_before_writing(saved: Path) -> None:
    old = saved.read_bytes()
    bad = primitive(0)
    bad.a = 2.0
    for suffix in (".json", ".txt"):
        target = saved.with_suffix(suffix)
        with pytest.raises(InvalidPrimitiveError, match=r"profile\.a"):
            write_abstraction(Abstraction(primitives=[primitive(1), bad]), target)
    assert saved.read_bytes() == old
    assert os.listdir(saved.parent) == [saved.name]


def test_atomic_write_permissions(tmp_path: Path) -> None:
    path = tmp_path / "p.txt"
    atomic_write_text(path, "a")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask  # not mkstemp's 0600
    path.chmod(0o640)
    atomic_write_text(path, "é")
    assert stat.S_IMODE(path.stat().st_mode) == 0o640  # a replaced file keeps its mode
    assert path.read_bytes() == "é".encode()


def test_non_finite_record_values_are_written_as_null(tmp_path) -> None:
    """A fit record's NaN or infinite number becomes null: the file stays strict JSON (a
    bare NaN is not JSON), and it reads back."""
    from sweepedit.geometry.model import Abstraction
    from sweepedit.io.params import read_abstraction, write_abstraction

    record = {"score": float("nan"), "best": [1.0, np.inf, np.float64(-np.inf)],
              "ok": np.float32(0.5)}
    abstraction = Abstraction([primitive()], fit=record)
    path = tmp_path / "record.json"
    write_abstraction(abstraction, path)

    def refuse(constant: str) -> None:
        raise AssertionError(f"bare {constant} in the file")

    data = json.loads(path.read_text(), parse_constant=refuse)
    assert data["fit"]["score"] is None
    assert data["fit"]["best"] == [1.0, None, None]
    assert data["fit"]["ok"] == 0.5
    assert read_abstraction(path).fit["score"] is None


def test_a_file_may_not_ask_for_more_than_the_limits(tmp_path: Path, capsys) -> None:
    """Past params.MAX_PRIMITIVES primitives (JSON or official txt), MAX_CONTROL_POINTS
    control points or MAX_SCALING_TERMS scaling terms, a file is refused with one line
    naming it, before any work: `eval` of 100,000 primitives once asked for 13.7 GiB."""
    from sweepedit.cli import main

    one = {"control_points": [[0, 0, -0.3], [0, 0, 0], [0, 0, 0.3]],
           "profile": {"a": 0.1, "b": 0.1, "degree": 2.0}, "scaling": [0.0]}

    def document(primitives: list[dict[str, Any]]) -> str:
        return json.dumps({"format": "sweepedit.abstraction", "version": 1,
                           "primitives": primitives})

    at_limit = tmp_path / "at_limit.json"
    at_limit.write_text(document([one] * params.MAX_PRIMITIVES))
    assert len(read_abstraction(at_limit).primitives) == params.MAX_PRIMITIVES
    cases = {
        "many.json": document([one] * (params.MAX_PRIMITIVES + 1)),
        "long.json": document([{**one, "control_points": [[0, 0, i / 1000] for i in
                                                          range(params.MAX_CONTROL_POINTS + 1)]}]),
        "poly.json": document([{**one, "scaling": [0.0] * (params.MAX_SCALING_TERMS + 1)}]),
        "many.txt": "0 0 -0.3 0 0 0 0 0 0.3 0.1 0.1 2 0 0\n" * (params.MAX_PRIMITIVES + 1),
        "wide.txt": " ".join(["0"] * (3 * (params.MAX_CONTROL_POINTS + 1) + 5)) + "\n",
    }
    for name, text in cases.items():
        path = tmp_path / name
        path.write_text(text)
        with pytest.raises(FileFormatError, match=name.replace(".", r"\.")) as info:
            read_abstraction(path)
        assert "at most" in str(info.value) or "more than" in str(info.value)
    shape = tmp_path / "box.stl"
    import trimesh

    trimesh.creation.box(extents=(0.2, 0.2, 0.6)).export(shape)
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "many.json"), str(shape)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "many.json" in err[0] and "1,024" in err[0]
