"""Read and write Abstract Models as GraphML: one self-describing file per model.

The file is plain GraphML: ``<key>`` declarations name and type every attribute, state and object
nodes carry their attributes as ``<data>``, transitions and views are edges whose ``id`` is the
edge key (the action name, or ``sees``), as networkx writes multigraphs. GraphML holds only
scalars, so

* a state's feature vector is the base64 of its little-endian float32 bytes (the graph records
  ``feature_dim`` and ``feature_dtype``): a saved model loads back equal, features bit for bit;
* a view's bounding box and observed position are space-separated numbers (``bbox``, ``obs``);
* an edge's kind follows from its key and is not written.

The schema — every attribute with its type, range and the version that introduced it — is the
table in :mod:`kgnav.memory.graphml.schema`; :func:`read_graph` (:mod:`kgnav.memory.graphml.read`)
checks every value of a file against it and refuses anything else with a one-line
:class:`~kgnav.errors.ModelFileError`. Attributes outside the schema (added by another tool) are
kept, typed as declared, and written back by :func:`write_model`.

Saving is atomic (:func:`kgnav.common.atomic.atomic_open`): the file is written beside the target
and renamed over it, keeping the target's permissions. Writing streams the document in chunks, one
element per line. ``networkx.read_graphml(path, force_multigraph=True)`` reads the files too;
kgnav writes and parses them itself, schema first, because networkx's generic reader and writer
take several seconds for a 1e4-state model (``bench/bench_graphml.py`` measures ours).

>>> import numpy as np, tempfile, os
>>> from kgnav import AbstractModel
>>> m = AbstractModel(feature_dim=3, model_id="doc")
>>> s = m.add_state(np.array([0.1, 0.2, 0.3]), pose=(1.0, 2.0, 0.5))
>>> path = os.path.join(tempfile.mkdtemp(), "m.graphml")
>>> write_model(m, path)
>>> AbstractModel.load(path) == m  # read_graph, wrapped
True
"""

from kgnav.memory.graphml.read import (
    MAX_BYTES,
    MAX_BYTES_ENV,
    describe_mode,
    max_bytes_default,
    read_graph,
)
from kgnav.memory.graphml.schema import ATTRIBUTES, decode_features, encode_features
from kgnav.memory.graphml.write import to_graphml, write_model

__all__ = [
    "ATTRIBUTES",
    "MAX_BYTES",
    "MAX_BYTES_ENV",
    "decode_features",
    "describe_mode",
    "encode_features",
    "max_bytes_default",
    "read_graph",
    "to_graphml",
    "write_model",
]
