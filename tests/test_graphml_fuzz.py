"""Fuzzing the model reader with mutated valid files (hypothesis, derandomized, bounded).

Every outcome must be a model that saves and loads back equal, or a KgnavError whose message is
one line naming the file; the command line says the same in one line. Where the fast reader of
kgnav's own layout accepts a file, the XML reader must read the same model from it.
"""

from __future__ import annotations

import contextlib
import io
import pathlib
import re

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from kgnav import AbstractModel, KgnavError, ModelStore
from kgnav.memory.graphml import read as gr
from kgnav.memory.graphml import to_graphml
from kgnav.memory.synthetic import SyntheticWorld
from tests.strategies import models

DATA = pathlib.Path(__file__).parent / "data" / "graphml"

# what a value or an attribute gets replaced with: values that may well be right (first, as
# hypothesis draws early entries more often, so that mutants also load), numbers at and past
# every range, JSON of the wrong shape, ids the store refuses, XML that is not text, markup for
# rich, control characters
TOKENS = [
    "0.5", "1", "2", "12.25", "-3.0", "1e-3", "chair", "sofa", "tiny/s0", "[0]", "[0, 1]",
    "nan", "inf", "-inf", "1e308", "-1e308", "5e-324", "0", "-0.0", "-1", "-7", "3.5",
    "99999999999999999999", "1_0", "", " ", "\t1.5", "1.5 ", "\u0663", "0x10", "true", "[",
    "[]", "[1, 2]", '{"a": 1}', '["../.."]', "[/bold]", "[bold]x", "&amp;", "&lt;x&gt;", "&e;",
    "&#0;", "&#x1F;", "&#13;", "<!-- c -->", "<![CDATA[1.5]]>", "]]>", "<b/>", "\x01", "\r",
    "\r\n", "\u00e9", "\ufffe", "s0", "o0", "s99", "o-1", "sees", "move_forward", "jump",
    "../..", "a\nb", "AAAA", "AADAfw==", "x" * 300, "state", "object", "room", "long",
    "double", "string", "boolean", "graph", "node", "edge", "all", "undirected",
]
ATTRIBUTE = re.compile(rb'(?:id|source|target|key|for|attr\.name|attr\.type|edgedefault)="')
VALUE = re.compile(rb">([^<>]*)</data>")
NUMBER = re.compile(rb">(-?[0-9][0-9.e+-]*)</data>")


def _seeds() -> list[bytes]:
    """Valid files: kgnav's layout (a tiny model, one with a foreign attribute, a walk), and one
    networkx rewrote (which only the XML reader reads)."""
    walk = SyntheticWorld(seed=5, feature_dim=8, n_objects=6).explore(12, seed=1)
    names = ["valid", "unknown_attribute", "rewritten_by_networkx"]
    return [(DATA / f"{n}.graphml").read_bytes() for n in names] + [to_graphml(walk)]


SEEDS = _seeds()


@st.composite
def mutated(draw) -> bytes:
    data = bytearray(SEEDS[draw(st.integers(0, len(SEEDS) - 1))])
    for _ in range(draw(st.sampled_from([1, 1, 1, 2, 3]))):
        op = draw(st.sampled_from(["number", "value", "attribute", "line", "bytes", "token"]))
        token = draw(st.sampled_from(TOKENS)).encode("utf-8")
        if op == "number":  # another number where there was one: often still a valid model
            spans = [m.span(1) for m in NUMBER.finditer(data)]
            if spans:
                a, b = spans[draw(st.integers(0, len(spans) - 1))]
                x = draw(st.one_of(st.integers(-3, 9), st.floats(-3, 3, allow_nan=False)))
                data[a:b] = repr(x).encode()
        elif op == "value":  # replace the text of one <data>
            spans = [m.span(1) for m in VALUE.finditer(data)]
            if spans:
                a, b = spans[draw(st.integers(0, len(spans) - 1))]
                data[a:b] = token
        elif op == "attribute":  # replace the value of one XML attribute
            starts = [m.end() for m in ATTRIBUTE.finditer(data)]
            if starts:
                a = starts[draw(st.integers(0, len(starts) - 1))]
                b = data.index(b'"', a)
                data[a:b] = token
        elif op == "line":  # drop, duplicate or swap lines
            lines = bytes(data).split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            j = draw(st.integers(0, len(lines) - 1))
            kind = draw(st.sampled_from(["drop", "duplicate", "swap"]))
            if kind == "drop":
                del lines[i]
            elif kind == "duplicate":
                lines.insert(j, lines[i])
            else:
                lines[i], lines[j] = lines[j], lines[i]
            data = bytearray(b"\n".join(lines))
        elif op == "bytes":  # flip, cut or truncate at random
            i = draw(st.integers(0, max(len(data) - 1, 0)))
            kind = draw(st.sampled_from(["flip", "cut", "truncate"]))
            if kind == "flip" and data:
                data[i] = draw(st.integers(0, 255))
            elif kind == "cut":
                del data[i : i + draw(st.integers(1, 64))]
            else:
                del data[i:]
        else:  # insert a token anywhere
            i = draw(st.integers(0, len(data)))
            data[i:i] = token
    return bytes(data)


def _cli(*args) -> tuple[int, str, str]:
    from kgnav.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in args])
    return exc.value.code, out.getvalue(), err.getvalue()


@settings(max_examples=400, derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=mutated())
def test_mutated_files_load_or_fail_cleanly(tmp_path, data):
    path = tmp_path / "m.graphml"
    path.write_bytes(data)
    try:
        model = AbstractModel.load(path)
    except KgnavError as exc:
        msg = str(exc)
        assert msg.startswith(f"{path}: ") and "\n" not in msg
        assert "internal error" not in msg, msg
        event("refused")
        model = None
    else:
        event("loads")
        again = tmp_path / "again.graphml"
        model.save(again)
        assert AbstractModel.load(again) == model

    # the fast reader of kgnav's layout never accepts what the XML reader reads otherwise
    try:
        canonical = AbstractModel.from_graph(gr._read_canonical(str(path), 1 << 24))
    except Exception:  # noqa: BLE001 - any failure sends read_graph to the XML reader
        canonical = None
    if canonical is not None:
        event("read by the fast reader")
        assert model is not None and canonical == model

    code, out, err = _cli("inspect", path)
    if model is None:
        assert code == 1 and err.count("\n") == 1 and err.startswith("kgnav: error: "), err
    else:
        assert code == 0, err
    assert "internal error" not in err


def test_store_with_mutated_files_lists_the_rest(tmp_path):
    store = ModelStore(tmp_path)
    good = AbstractModel.load(DATA / "valid.graphml")
    store.save(good)
    for i, tail in enumerate([b"", b"<", b"\x00", b"<graphml>"]):
        (tmp_path / f"bad{i}.graphml").write_bytes(SEEDS[0][: 500 + 300 * i] + tail)
    models, problems = store.load_all()
    assert list(models) == ["tiny"] and len(problems) == 4


@settings(max_examples=40, derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=models(), label=st.text(max_size=8), flag=st.booleans())
def test_both_readers_read_valid_files_the_same(tmp_path, m, label, flag):
    """Any model, with attributes outside the schema too, reads back the same through the fast
    reader and the XML reader (a file with an escaped character only takes the XML reader)."""
    sid = next(m.states())
    m.graph.nodes[sid]["note"] = "".join(c for c in label if c.isprintable())
    m.graph.graph["checked"] = flag
    path = tmp_path / "m.graphml"
    m.save(path)
    assert AbstractModel.from_graph(gr._XmlReader(str(path), 1 << 24).read()) == m
    if b"&" not in path.read_bytes():
        assert AbstractModel.from_graph(gr._read_canonical(str(path), 1 << 24)) == m
