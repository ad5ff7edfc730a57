"""The knowledge-graph memory, usable on its own: Abstract Models and what works on them.

* :mod:`~kgnav.memory.model` — :class:`AbstractModel`, the finite state machine as a networkx
  multi-digraph (states, objects, transitions, views);
* :mod:`~kgnav.memory.graphml` — its file format (read, write, schema);
* :mod:`~kgnav.memory.store` — :class:`ModelStore`, a directory of models;
* :mod:`~kgnav.memory.relocator` — :class:`Relocator`, nearest-neighbour state matching;
* :mod:`~kgnav.memory.merge` — merging two models through an anchor pair;
* :mod:`~kgnav.memory.query` — goal lookup, visibility ranking, summaries;
* :mod:`~kgnav.memory.evidence` — belief in stored objects; :mod:`~kgnav.memory.geometry` —
  scan geometry and occupancy from range profiles;
* :mod:`~kgnav.memory.html` — the interactive HTML view;
* :mod:`~kgnav.memory.synthetic`, :mod:`~kgnav.memory.demo` — synthetic worlds and the
  memory-only demo.

>>> from kgnav.memory import AbstractModel, ModelStore, Relocator, merge, query
"""

from kgnav.memory import query
from kgnav.memory.merge import best_anchor, merge
from kgnav.memory.model import ACTIONS, AbstractModel, Detection, ObjectInfo
from kgnav.memory.relocator import Match, Relocator
from kgnav.memory.store import ModelStore

__all__ = ["ACTIONS", "AbstractModel", "Detection", "Match", "ModelStore", "ObjectInfo",
           "Relocator", "best_anchor", "merge", "query"]
