import os
import re

import networkx as nx
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kgnav import AbstractModel, Detection, ModelFileError, SchemaVersionError
from kgnav.memory import graphml as gml
from kgnav.memory.constants import SCHEMA_VERSION
from kgnav.memory.graphml import write as gml_write
from tests.strategies import models


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(models())
def test_round_trip_is_exact(tmp_path, m):
    path = tmp_path / "m.graphml"
    m.save(path)
    back = AbstractModel.load(path)
    assert back == m
    for s in m.states():
        assert back.features(s).tobytes() == m.features(s).tobytes()
    # ids keep counting after load
    f = np.arange(m.feature_dim, dtype=np.float32) + 100
    assert back.add_state(f, (999.0, 0, 0)) == m.add_state(f, (999.0, 0, 0))


def test_round_trip_synthetic(tmp_path, episode_model):
    path = tmp_path / "e.graphml"
    episode_model.save(path)
    assert AbstractModel.load(path) == episode_model


def test_feature_codec_bit_exact():
    f = np.array([np.float32(0.1), -0.0, np.finfo(np.float32).tiny, 3.4e38], dtype=np.float32)
    back = gml.decode_features(gml.encode_features(f), 4)
    assert back.tobytes() == f.tobytes()
    with pytest.raises(ValueError, match="expected 5"):
        gml.decode_features(gml.encode_features(f), 5)


def test_networkx_reads_the_file(tmp_path, tiny):
    path = tmp_path / "t.graphml"
    tiny.save(path)
    g = nx.read_graphml(path, force_multigraph=True)
    assert set(g.nodes) == set(tiny.graph.nodes)
    assert set(g.edges(keys=True)) == set(tiny.graph.edges(keys=True))
    assert g.graph["kgnav_schema"] == SCHEMA_VERSION


def test_relocation_threshold_is_recorded_and_checked(tmp_path, tiny):
    """Schema 3 records the relocation threshold a model was built with; older files load
    without one (unknown, not guessed) and save as the current version; a value outside (0, 2] is
    refused by the API and in a file."""
    path = tmp_path / "t.graphml"
    assert tiny.relocation_threshold is None
    tiny.save(path)
    assert "relocation_threshold" not in path.read_text().split("<graph ")[1]  # only the key
    tiny.relocation_threshold = 0.0123
    tiny.save(path)
    back = AbstractModel.load(path)
    assert back.relocation_threshold == 0.0123 and back == tiny
    kid = re.search(r'<key id="(g[0-9]+)" for="graph" attr.name="relocation_threshold" '
                    r'attr.type="double" />', path.read_text()).group(1)
    text = path.read_text()
    path.write_text(text.replace(f'<data key="{kid}">0.0123</data>',
                                 f'<data key="{kid}">2.5</data>'))
    with pytest.raises(ModelFileError, match="attribute 'relocation_threshold': 2.5 is outside"):
        AbstractModel.load(path)
    # a version-2 file: the attribute did not exist then
    v2 = text.replace(f'<data key="g0">{SCHEMA_VERSION}</data>', '<data key="g0">2</data>')
    path.write_text(v2)
    with pytest.raises(ModelFileError, match="'relocation_threshold' is not a graph attribute"):
        AbstractModel.load(path)
    path.write_text(v2.replace(f'<data key="{kid}">0.0123</data>', ""))
    old = AbstractModel.load(path)
    assert old.relocation_threshold is None and old.graph.graph["kgnav_schema"] == SCHEMA_VERSION
    with pytest.raises(ValueError, match=r"relocation_threshold must be a cosine distance"):
        AbstractModel(feature_dim=2, relocation_threshold=0.0)
    with pytest.raises(ValueError, match=r"relocation_threshold must be a cosine distance"):
        tiny.relocation_threshold = float("nan")


def test_failed_save_keeps_previous_file(tmp_path, tiny, monkeypatch):
    path = tmp_path / "t.graphml"
    tiny.save(path)
    before = path.read_bytes()
    bigger = tiny.copy()
    sid = bigger.add_state(np.ones(4), (5, 5, 0))
    bigger.graph.nodes[sid]["features"] = "not a vector"  # fails after earlier chunks are out
    monkeypatch.setattr(gml_write, "_CHUNK", 10)
    with pytest.raises(ValueError, match=f"state '{sid}': attribute 'features'"):
        bigger.save(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["t.graphml"]  # no temp file left behind


def test_crash_during_write_keeps_previous_file(tmp_path, tiny, monkeypatch):
    path = tmp_path / "t.graphml"
    tiny.save(path)
    before = path.read_bytes()

    real_fsync = os.fsync

    def crash(fd):
        real_fsync(fd)
        raise KeyboardInterrupt  # interrupted after the bytes hit the temp file

    monkeypatch.setattr(os, "fsync", crash)
    with pytest.raises(KeyboardInterrupt):
        tiny.save(path)
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert path.read_bytes() == before
    assert len(list(tmp_path.iterdir())) == 1


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_missing_file(tmp_path):
    with pytest.raises(ModelFileError, match="nope.graphml: no such file"):
        AbstractModel.load(tmp_path / "nope.graphml")


def test_truncated_file(tmp_path, tiny):
    path = tmp_path / "t.graphml"
    tiny.save(path)
    path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(ModelFileError, match="t.graphml: not valid XML"):
        AbstractModel.load(path)


def test_foreign_graphml(tmp_path):
    path = tmp_path / "foreign.graphml"
    nx.write_graphml(nx.path_graph(3), path)
    with pytest.raises(ModelFileError, match="foreign.graphml: not a kgnav Abstract Model"):
        AbstractModel.load(path)


def test_not_graphml_xml(tmp_path):
    p = _write(tmp_path, "x.graphml", "<?xml version='1.0'?><svg></svg>")
    with pytest.raises(ModelFileError, match="root element is 'svg'"):
        AbstractModel.load(p)


def test_wrong_schema_version(tmp_path, tiny):
    path = tmp_path / "t.graphml"
    tiny.graph.graph["kgnav_schema"] = 99
    tiny.save(path)
    with pytest.raises(SchemaVersionError, match="schema version 99"):
        AbstractModel.load(path)


def test_bad_feature_payload(tmp_path, tiny):
    path = tmp_path / "t.graphml"
    tiny.save(path)
    text = path.read_text()
    good = gml.encode_features(tiny.features("s1"))
    path.write_text(text.replace(good, gml.encode_features(np.ones(3, np.float32))))
    with pytest.raises(ModelFileError,
                       match="node 's1' .line [0-9]+.: attribute 'features': 3 values, expected 4"):
        AbstractModel.load(path)


def test_missing_attribute(tmp_path, tiny):
    del tiny.graph.nodes["s1"]["step"]
    path = tmp_path / "t.graphml"
    tiny.save(path)
    with pytest.raises(ModelFileError, match="node 's1' .line [0-9]+.: missing attribute 'step'"):
        AbstractModel.load(path)


def test_edge_between_wrong_kinds(tmp_path, tiny):
    tiny.graph.add_edge("s0", "o0", key="move_forward", kind="transition", count=1)
    path = tmp_path / "t.graphml"
    tiny.save(path)
    with pytest.raises(ModelFileError, match="edge 's0'->'o0' .'move_forward'. .line [0-9]+.: "
                       "a transition edge joins state -> state"):
        AbstractModel.load(path)


def test_the_api_refuses_what_a_file_may_not_hold():
    """So that every model the API builds saves and loads back."""
    m = AbstractModel(feature_dim=2, model_id="api")
    s = m.add_state(np.ones(2), (0, 0, 0))
    with pytest.raises(ValueError, match="action must be one of"):
        m.add_transition(s, "jump", s)
    with pytest.raises(ValueError, match="count must be >= 1"):
        m.add_transition(s, "stop", s, count=0)
    with pytest.raises(ValueError):
        m.add_state(np.ones(2), (float("nan"), 0, 0))
    with pytest.raises(ValueError, match="pose must be finite"):
        m.add_state(np.ones(2), np.array([[1, 0, np.inf], [0, 1, 0], [0, 0, 1]]))
    with pytest.raises(ValueError, match="detection needs finite position"):
        m.add_state(np.ones(2), (1, 0, 0), [Detection("chair", (np.inf, 0.0, 0.0))])
    with pytest.raises(ValueError, match=r"pose_tol must be a number in \[0, 1e\+06\]"):
        AbstractModel(feature_dim=2, pose_tol=-1)
    tiny_tol = AbstractModel(feature_dim=2, model_id="t", pose_tol=5e-324)  # grid: one cell
    a = tiny_tol.add_state(np.ones(2), (1e5, -1e5, 0))
    assert tiny_tol.add_state(np.ones(2), (1e5, -1e5, 0)) == a


def test_unwritable_value_names_itself_and_keeps_the_file(tmp_path, tiny):
    path = tmp_path / "t.graphml"
    tiny.save(path)
    before = path.read_bytes()
    tiny.graph.nodes["s0"]["note"] = [1, 2]
    with pytest.raises(ValueError, match="node 's0': attribute 'note' holds a list"):
        tiny.save(path)
    tiny.graph.nodes["s0"]["note"] = "bell\x07"
    with pytest.raises(ValueError, match="which XML cannot store"):
        tiny.save(path)
    assert path.read_bytes() == before and len(list(tmp_path.iterdir())) == 1


def test_other_attributes_round_trip_typed(tmp_path, tiny):
    tiny.graph.graph.update(site="lab 3 & <b>", trusted=True, floors=2, scale=0.5)
    tiny.graph.nodes["o0"]["label"] = "red chair\r\n"
    tiny.graph.edges["s0", "s1", "move_forward"]["ms"] = 12
    path = tmp_path / "t.graphml"
    tiny.save(path)
    back = AbstractModel.load(path)
    assert back == tiny
    g = nx.read_graphml(path, force_multigraph=True)
    assert g.graph["trusted"] is True and g.graph["site"] == "lab 3 & <b>"
    assert g.nodes["o0"]["label"] == "red chair\r\n"


def test_saved_files_are_read_by_the_fast_reader(tmp_path, episode_model):
    from kgnav.memory.graphml import read as gr

    path = tmp_path / "e.graphml"
    episode_model.save(path)
    assert AbstractModel.from_graph(gr._read_canonical(str(path), 1 << 30)) == episode_model


def _element_by_element(model) -> bytes:
    """The document as the writer wrote it before it formatted whole columns: each node's and
    edge's values one element at a time (``_Writer._data``)."""
    w = gml_write._Writer(model)
    g = model.graph
    head = list(w.lines())[:len(w.decl) + 3]  # declaration, keys, graph, its data
    out = head[:]
    kind_key = w.ids["node", "kind"]
    for n, d in g.nodes(data=True):
        out.append(f'<node id="{n}"><data key="{kind_key}">{d["kind"]}</data>'
                   f'{w._data(d["kind"], repr(n), d)}</node>\n')
    for u, v, k, d in g.edges(keys=True, data=True):
        where = "sees" if k == "sees" else "transition"
        out.append(f'<edge id="{k}" source="{u}" target="{v}">{w._data(where, "", d)}</edge>\n')
    out.append("</graph>\n</graphml>\n")
    return "".join(out).encode()


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(models(max_states=10) | models(max_states=10, scan=True), st.integers(0, 3))
def test_columns_format_as_elements_do(m, odd):
    """Formatting a column at a time writes what formatting each element did, with attributes
    outside the schema, numpy scalars and an optional attribute on some states only."""
    states = list(m.states())
    s = states[len(states) // 2]
    if odd == 1:
        m.graph.nodes[s]["note"] = "kitchen & hall"
    elif odd == 2:
        m.graph.nodes[s]["x"] = np.float64(m.graph.nodes[s]["x"])
        m.graph.nodes[s]["step"] = np.int64(7)
    elif odd == 3:
        for *_ends, k, d in m.graph.edges(keys=True, data=True):
            if k == "sees":
                d["bbox"] = np.array(d["bbox"])
                d["pixels"] = 3.0
                break
    assert gml.to_graphml(m) == _element_by_element(m)


def test_a_bad_value_among_many_is_named(tmp_path):
    from kgnav.memory.synthetic import SyntheticWorld

    m = SyntheticWorld(seed=1, feature_dim=4, n_objects=5).explore(60, seed=0)
    u, v, k = next((u, v, k) for u, v, k in m.graph.edges(keys=True) if k == "sees")
    m.graph.edges[u, v, k]["obs"] = (1.0, 2.0)
    with pytest.raises(ValueError, match=rf"sees '{u}'->'{v}': attribute 'obs': 2 numbers"):
        m.save(tmp_path / "m.graphml")
    assert not list(tmp_path.iterdir())
