"""The names and bounds every part of the memory agrees on: the file schema's version, the
action set, the view edges' key, model ids and coordinates. They live here, not in
:mod:`kgnav.memory.model`, so that the model and its GraphML format both import them and
neither has to import the other."""

import re

#: Version of the GraphML schema (:mod:`kgnav.memory.graphml.schema`) this code writes.
SCHEMA_VERSION = 5

#: The paper's action set; transitions are keyed by these names.
ACTIONS: tuple[str, ...] = ("stop", "move_forward", "turn_left", "turn_right")

SEES = "sees"

#: Model ids name files in a store and appear in provenance: keep them plain. (``\Z``, not ``$``:
#: ``$`` also matches before a final newline.)
SAFE_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,127}\Z")

#: Largest coordinate (metres, absolute) a model holds: far beyond any building, small enough
#: that grid cells and distances stay finite.
MAX_COORD = 1e6

# the "episode" of a loop closure that a join of two stored models made (not an episode's)
JOIN_EPISODE = -1
