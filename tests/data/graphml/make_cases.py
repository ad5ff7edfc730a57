"""Write the regression files of tests/test_graphml_files.py: one small broken or foreign model
file per problem the fuzz campaign of issue 16 found, each a few edits of one valid model.

    python tests/data/graphml/make_cases.py      # from the repository root; rewrites the files
"""

from __future__ import annotations

import gzip
import pathlib
import sys

HERE = pathlib.Path(__file__).parent
sys.path.insert(0, str(HERE.parents[2]))  # this checkout's kgnav, not an installed one

import networkx as nx  # noqa: E402
import numpy as np  # noqa: E402

from kgnav import AbstractModel, Detection  # noqa: E402


def base() -> str:
    m = AbstractModel(feature_dim=4, model_id="tiny", classes=("chair", "sofa"))
    feats = np.eye(4, dtype=np.float32)
    chair = Detection("chair", (2.0, 0.0, 0.5), (10, 20, 30, 40), 2.0, 400)
    s0 = m.add_state(feats[0], (0.0, 0.0, 0.0), [chair], episode=0, step=0)
    s1 = m.add_state(feats[1], (0.25, 0.0, 0.0), [chair], episode=0, step=1)
    sofa = Detection("sofa", (1.0, 2.0, 0.4))
    s2 = m.add_state(feats[2], (0.25, 0.0, np.pi / 6), [chair, sofa], step=2)
    m.add_transition(s0, "move_forward", s1)
    m.add_transition(s1, "turn_left", s2)
    path = HERE / "valid.graphml"
    m.save(path)
    return path.read_text()


def edit(text: str, old: str, new: str, count: int = 1) -> str:
    assert text.count(old) >= count, old
    return text.replace(old, new, count)


S1 = '<node id="s1"><data key="n0">state</data><data key="n1">0.25</data>'
NODE_KEYS = '<key id="n11" for="node" attr.name="n_views" attr.type="long" />\n'
GRAPH = '<graph edgedefault="directed">\n'
NAN_FEATURES = "AADAfwAAAAAAAAAAAAAAAA=="  # float32 NaN, 0, 0, 0


def cases(v: str) -> dict[str, str | bytes]:
    c: dict[str, str | bytes] = {
        # tracebacks before: non-finite or huge numbers, JSON that is not, edges without id...
        "nan_coordinate": edit(v, S1, S1.replace("0.25", "nan")),
        "inf_tolerance": edit(v, '<data key="g8">0.05</data>', '<data key="g8">inf</data>'),
        "huge_coordinate": edit(v, '<data key="n1">2.0</data>', '<data key="n1">1e308</data>'),
        "subnormal_tolerance": edit(v, '<data key="g8">0.05</data>',
                                    '<data key="g8">5e-324</data>'),
        "episodes_not_json": edit(v, '<data key="g6">[0]</data>', '<data key="g6">[0,</data>'),
        "episodes_not_list": edit(v, '<data key="g6">[0]</data>',
                                  '<data key="g6">{"0": 1}</data>'),
        "merged_from_not_ids": edit(v, '<data key="g7">[]</data>', '<data key="g7">[1]</data>'),
        "edge_without_id": edit(v, '<edge id="move_forward" ', "<edge "),
        "unknown_attribute": edit(
            edit(v, NODE_KEYS, NODE_KEYS
                 + '<key id="d0" for="node" attr.name="label" attr.type="string" />\n'),
            '<data key="n7">tiny/s0</data>', '<data key="n7">tiny/s0</data>'
            '<data key="d0">kitchen [/bold]</data>'),
        "markup_class": edit(edit(v, "chair,sofa", "[/bold],sofa"), ">chair<", ">[/bold]<"),
        # broken data accepted silently before
        "nan_features": edit(v, "AAAAAAAAgD8AAAAAAAAAAA==", NAN_FEATURES),
        "short_features": edit(v, "AAAAAAAAgD8AAAAAAAAAAA==", "AAAAAAAAgD8AAAAA"),
        "count_zero": edit(v, '<data key="e0">1</data>', '<data key="e0">0</data>'),
        "count_negative": edit(v, '<data key="e0">1</data>', '<data key="e0">-7</data>'),
        "n_views_wrong": edit(v, '<data key="n11">3</data>', '<data key="n11">5</data>'),
        "n_obs_negative": edit(v, '<data key="n10">3</data>', '<data key="n10">-1</data>'),
        "distance_negative": edit(v, '<data key="e2">2.0</data>', '<data key="e2">-2.0</data>'),
        "theta_out_of_range": edit(v, "0.5235987755982987", "7.0"),
        "bbox_three_numbers": edit(v, "10.0 20.0 30.0 40.0", "10.0 20.0 30.0"),
        "action_unknown": edit(v, 'id="turn_left"', 'id="jump"'),
        "model_id_traversal": edit(v, '<data key="g1">tiny</data>', '<data key="g1">../..</data>'),
        "model_id_empty": edit(v, '<data key="g1">tiny</data>', '<data key="g1"></data>'),
        "model_id_newline": edit(v, '<data key="g1">tiny</data>', '<data key="g1">tiny\n</data>'),
        "duplicate_node": edit(v, '<node id="s2">', '<node id="s1">'),
        "comment_in_value": edit(v, S1, S1.replace(">0.25<", "><!-- was 0.5 -->0.25<")),
        "entity": edit(v, "<graphml ", '<!DOCTYPE graphml [<!ENTITY e "tiny">]>\n<graphml ')
        .replace('<data key="g1">tiny</data>', '<data key="g1">&e;</data>'),
        "external_entity": edit(
            v, "<graphml ", '<!DOCTYPE graphml [<!ENTITY e SYSTEM "file:///etc/hostname">]>\n'
            "<graphml ").replace('<data key="g4">unspecified</data>', '<data key="g4">&e;</data>'),
        "xinclude": edit(v, GRAPH, GRAPH.rstrip("\n") + '<xi:include '
                         'xmlns:xi="http://www.w3.org/2001/XInclude" href="valid.graphml"/>\n'),
        "class_unknown": edit(v, ">sofa<", ">piano<"),
        "episode_unknown": edit(v, '<data key="n4">0</data><data key="n5">1</data>',
                                '<data key="n4">5</data><data key="n5">1</data>'),
        "declared_wrong_type": edit(v, 'attr.name="x" attr.type="double"',
                                    'attr.name="x" attr.type="boolean"'),
        "sees_between_states": edit(v, 'id="move_forward" source="s0" target="s1"',
                                    'id="sees" source="s0" target="s1"'),
        "edge_to_missing_node": edit(v, 'target="o1"', 'target="o9"'),
        "undirected": edit(v, 'edgedefault="directed"', 'edgedefault="undirected"'),
        "markup_in_value": edit(v, '<data key="n1">0.25</data>', '<data key="n1">0.<b/>25</data>'),
        "nested_graph": edit(v, '<data key="n7">tiny/s0</data></node>',
                             '<data key="n7">tiny/s0</data><graph edgedefault="directed">'
                             "</graph></node>"),
        "default_value": edit(v, 'attr.name="pixels" attr.type="long" />',
                              'attr.name="pixels" attr.type="long"><default>0</default></key>'),
        "underscore_int": edit(v, '<data key="e3">400</data>', '<data key="e3">4_00</data>'),
        "schema_version_99": edit(v, '<data key="g0">1</data>', '<data key="g0">99</data>'),
        "yed_graphics": edit(
            edit(v, NODE_KEYS,
                 NODE_KEYS + '<key id="d6" for="node" yfiles.type="nodegraphics"/>\n'),
            '<data key="n7">tiny/s0</data>', '<data key="n7">tiny/s0</data><data key="d6">'
            '<y:ShapeNode xmlns:y="http://www.yworks.com/xml/graphml"/></data>'),
        "no_namespace": v.replace(' xmlns="http://graphml.graphdrawing.org/xmlns"', ""),
        "truncated": v[: len(v) // 2],
        # foreign files: valid GraphML, not a kgnav model
        "foreign_networkx": "\n".join(nx.generate_graphml(nx.path_graph(3))),
        # resources
        "gzip": gzip.compress(v.encode(), mtime=0),
        "empty": "",
    }
    # a file kgnav wrote, reformatted by another tool (networkx): not the canonical layout, so
    # it takes the XML reader, and still loads
    g = nx.read_graphml(HERE / "valid.graphml", force_multigraph=True)
    c["rewritten_by_networkx"] = "\n".join(nx.generate_graphml(g, named_key_ids=True))
    return c


def main() -> None:
    for name, text in cases(base()).items():
        data = text if isinstance(text, bytes) else text.encode()
        (HERE / f"{name}.graphml").write_bytes(data)


if __name__ == "__main__":
    main()
