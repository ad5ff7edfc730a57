"""The bulk reader of kgnav's own layout (``graphml_read._Canonical``): whatever it accepts, the
XML reader reads the same (in the same order), and it reads kgnav's files in bulk, not line by
line, at any block size."""

from __future__ import annotations

import binascii
import re
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kgnav import AbstractModel
from kgnav.memory.graphml import read as gr
from kgnav.memory.graphml import schema as gs
from kgnav.memory.graphml import to_graphml
from kgnav.memory.synthetic import SyntheticWorld
from tests.strategies import SCAN, models


def _walk(dim: int = 16, steps: int = 150) -> AbstractModel:
    return SyntheticWorld(seed=3, feature_dim=dim, n_objects=12).explore(steps, seed=2)


def _agree(path, block: int = gr.BLOCK) -> dict:
    """Read ``path`` with both readers: the same model, in the same order; the bulk stats."""
    xml = AbstractModel.from_graph(gr._XmlReader(str(path), 1 << 30).read())
    reader = gr._Canonical(str(path), 1 << 30, block)
    m = AbstractModel.from_graph(reader.read())
    assert m == xml
    assert to_graphml(m) == to_graphml(xml)
    return reader.stats


def _body_lines(data: bytes) -> int:
    return len(re.findall(rb"^<(?:node|edge) ", data, re.MULTILINE))


def test_a_saved_walk_is_read_in_bulk(tmp_path):
    m = _walk()
    path = tmp_path / "w.graphml"
    m.save(path)
    data = path.read_bytes()
    stats = _agree(path)
    assert to_graphml(AbstractModel.from_graph(gr._read_canonical(str(path), 1 << 30))) == data
    # everything but the header (declaration, root, keys, graph, its data)
    body = _body_lines(data)
    assert body == m.graph.number_of_nodes() + m.graph.number_of_edges()
    assert stats["bulk"] == body + 2  # and the closing lines
    assert stats["line"] == data.count(b"\n") - stats["bulk"]


@pytest.mark.parametrize("block", [1, 7, 100, 999, 4096, 1 << 16])
def test_any_block_size_reads_the_same(tmp_path, block):
    m = _walk(steps=60)
    path = tmp_path / "w.graphml"
    m.save(path)
    stats = _agree(path, block)
    assert stats["bulk"] + stats["line"] == path.read_bytes().count(b"\n")
    if block >= 999:
        assert stats["bulk"] > 0


def test_a_line_outside_the_layout_is_read_line_by_line(tmp_path):
    """An attribute outside the schema on one state: its block goes line by line, the others
    in bulk; the model is the same as the XML reader's."""
    m = _walk(steps=200)
    sid = sorted(m.states(), key=lambda s: int(s[1:]))[100]
    m.graph.nodes[sid]["note"] = "kitchen"
    path = tmp_path / "w.graphml"
    m.save(path)
    stats = _agree(path, 4096)
    assert stats["bulk"] > 0 and stats["line"] > 10
    assert AbstractModel.load(path).graph.nodes[sid]["note"] == "kitchen"


@settings(max_examples=60, derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=models(max_states=12, scan=False) | models(max_states=12, scan=True),
       block=st.sampled_from([1, 50, 300, 2000, gr.BLOCK]))
def test_models_read_the_same_in_bulk(tmp_path, m, block):
    path = tmp_path / "m.graphml"
    m.save(path)
    _agree(path, block)
    assert AbstractModel.from_graph(gr._read_canonical(str(path), 1 << 30, block)) == m


# values a hand or another tool may write, where kgnav writes a plain number or id
ODD = ["1_0", " 1.5", "1.5 ", "+1.5", "1E5", "1e999", "-1e999", "nan", "inf", "-0", "0x10",
       "1.5.5", "--1", "1e", ".5", "5.", "\u0663", "1\u00a0", "", "99999999999999999999",
       "1 2", "1  2 3 4", "s1", "o1", "s01", "sees"]


@pytest.mark.parametrize("where", ["state", "object", "sees", "transition"])
@pytest.mark.parametrize("odd", ODD)
def test_odd_values_read_as_xml_reads_them(tmp_path, where, odd):
    """Replace each value of one line of each kind: the bulk reader either refuses the file
    (the XML reader then decides) or reads what the XML reader reads."""
    m = _walk(steps=40)
    data = to_graphml(m)
    pick = {"state": rb'^<node id="s', "object": rb'^<node id="o',
            "sees": rb'^<edge id="sees"', "transition": rb'^<edge id="(?!sees)'}[where]
    line = re.search(pick + rb".*$", data, re.MULTILINE)
    values = list(re.finditer(rb">([^<]*)</data>", line[0]))
    ids = list(re.finditer(rb'(?:source|target)="([^"]*)"', line[0]))
    spans = [v.span(1) for v in values if v[1] not in (b"state", b"object")]
    spans += [i.span(1) for i in ids]
    for a, b in spans:
        new = line[0][:a] + odd.encode() + line[0][b:]
        path = tmp_path / "m.graphml"
        path.write_bytes(data[: line.start()] + new + data[line.end() :])
        try:
            xml = AbstractModel.from_graph(gr._XmlReader(str(path), 1 << 30).read())
        except Exception:  # noqa: BLE001 - any refusal
            xml = None
        try:
            bulk = AbstractModel.from_graph(gr._read_canonical(str(path), 1 << 30))
        except Exception:  # noqa: BLE001 - read_graph then asks the XML reader
            continue
        assert xml is not None and bulk == xml and to_graphml(bulk) == to_graphml(xml), new


def test_features_must_be_plain_base64_to_be_read_in_bulk(tmp_path):
    """Whitespace, a stray character or misplaced padding in a feature vector: not in bulk; the
    line-by-line reader (lenient base64, as the XML reader) or the XML reader decides."""
    m = _walk(dim=8, steps=10)
    data = to_graphml(m)
    header = data[: data.index(b"<node ")].count(b"\n")
    feats = re.search(rb'<data key="n6">([^<]*)</data>', data)
    a, b = feats.span(1)
    text = data[a:b]
    for bad in (text[:4] + b" " + text[5:], text[:4] + b"!" + text[5:], text[:4] + b"\n" + text[5:],
                text[:-1] + b"==", b"=" + text[1:], text[:-1] + b"A"):
        path = tmp_path / "m.graphml"
        path.write_bytes(data[:a] + bad + data[b:])
        try:
            xml = AbstractModel.from_graph(gr._XmlReader(str(path), 1 << 30).read())
        except Exception:  # noqa: BLE001
            xml = None
        reader = gr._Canonical(str(path), 1 << 30)
        try:
            back = AbstractModel.from_graph(reader.read())
        except Exception:  # noqa: BLE001 - read_graph then asks the XML reader
            continue
        assert reader.stats["line"] > header and back == xml, bad


def test_range_profiles_are_read_in_bulk(tmp_path):
    m = AbstractModel(feature_dim=4, model_id="r", classes=("chair",), scan=SCAN)
    f = np.ones(4, np.float32)
    a = m.add_state(f, (0, 0, 0), ranges=np.linspace(0.5, 5, SCAN.bins))
    s = m.add_state(f, (1, 0, 0))  # no profile
    m.add_transition(a, "move_forward", s)
    path = tmp_path / "m.graphml"
    m.save(path)
    stats = _agree(path)
    assert stats["bulk"] == 3 + 2
    back = AbstractModel.from_graph(gr._read_canonical(str(path), 1 << 30))
    assert "ranges" not in back.graph.nodes[s] and back == m


@pytest.mark.parametrize("decoder", ["pybase64", "binascii"])
@settings(max_examples=300, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/= "
                              "\n-_!", max_size=24))
def test_strict_base64_agrees_with_binascii_where_it_accepts(monkeypatch, decoder, text):
    if decoder == "binascii":
        monkeypatch.setattr(gs, "_pyb64decode", None)
    elif gs._pyb64decode is None:
        pytest.skip("pybase64 is not installed")
    try:
        raw = gs.b64decode_strict(text.encode())
    except (ValueError, binascii.Error):
        return
    assert raw == binascii.a2b_base64(text)
    assert re.fullmatch(r"[A-Za-z0-9+/]*={0,2}", text) and len(text) % 4 == 0


def test_both_base64_encoders_write_the_same():
    import base64

    rng = np.random.default_rng(0)
    for n in (0, 1, 2, 3, 4, 8191, 8192):
        raw = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert gs.b64encode(raw) == base64.b64encode(raw).decode("ascii")
        assert binascii.b2a_base64(raw, newline=False).decode("ascii") == gs.b64encode(raw)


def test_repeated_numbers_are_held_once_and_signed_zeros_stay_apart(tmp_path):
    import math

    m = _walk()
    sees = [(u, v) for u, v, k in m.graph.edges(keys=True) if k == "sees"]
    for u, v in sees:  # every sighting scored 1
        m.graph.edges[u, v, "sees"]["score"] = 1.0
    path = tmp_path / "m.graphml"
    m.save(path)
    reader = gr._Canonical(str(path), 1 << 30)
    back = AbstractModel.from_graph(reader.read())
    assert reader.stats["bulk"] == _body_lines(path.read_bytes()) + 2 and back == m
    got = [back.graph.edges[u, v, "sees"]["score"] for u, v in sees]
    assert len({id(x) for x in got}) < len(got) / 10  # shared, not one object per sighting
    texts = [b"-0.0", b"0.0", b"-0.0", b"2.5"]
    assert [math.copysign(1, x) for x in gr._shared(float, texts)] == [-1, 1, -1, 1]


@pytest.mark.skipif(sys.implementation.name != "cpython", reason="CPython's dict layout")
@pytest.mark.parametrize("reader", ["bulk", "xml"])
def test_a_loaded_model_keeps_its_attribute_dicts_compact_and_ordinary(tmp_path, reader):
    m = _walk()
    path = tmp_path / "w.graphml"
    m.save(path)
    g = (gr._read_canonical(str(path), 1 << 30) if reader == "bulk"
         else gr._XmlReader(str(path), 1 << 30).read())
    sees = [(kd, d) for _, nbrs in g._succ.items() for kd in nbrs.values()
            for k, d in kd.items() if k == "sees"]
    states = [d for _, d in g.nodes(data=True) if d["kind"] == "state"]
    assert sees and states
    for kd, d in sees[:50] + [(None, s) for s in states[:50]]:
        assert type(d) is dict and sys.getsizeof(d) < sys.getsizeof(dict(d))  # keys shared
        if kd is not None:
            assert type(kd) is dict and sys.getsizeof(kd) < sys.getsizeof(dict(kd))
    # still a model like any other: it grows, merges and saves as the one it was loaded from
    back = AbstractModel.from_graph(g)
    assert back == m
    d = sees[0][1]
    d["extra"] = 1.0  # a key outside the shared table: the dict turns ordinary, nothing lost
    assert d["extra"] == 1.0 and d["kind"] == "sees"
    del d["extra"]
    back.add_state(np.ones(16), (1.0, 1.0, 0.0), step=999)
    back.save(tmp_path / "again.graphml")
    assert AbstractModel.load(tmp_path / "again.graphml") == back
