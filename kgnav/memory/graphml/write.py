"""Writing Abstract Model files: the document streamed one element per line, in the layout the
canonical reader (:mod:`kgnav.memory.graphml.read`) reads fastest."""

from __future__ import annotations

import os
from collections.abc import Iterator
from operator import itemgetter
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

from kgnav.common.atomic import atomic_open
from kgnav.memory.constants import SCHEMA_VERSION, SEES
from kgnav.memory.graphml.read import (
    CHUNK,
    NS,
    paused_gc,
)
from kgnav.memory.graphml.schema import (
    DOMAIN,
    KNOWN,
    format_other,
    other_type,
    schema,
    xml_text,
)

if TYPE_CHECKING:
    from kgnav.memory.model import AbstractModel

_CHUNK = CHUNK  # bytes per write


class _Writer:
    """The chunks of one model's GraphML document, with every key declared up front."""

    def __init__(self, model: AbstractModel):
        self.g = model.graph
        rows = schema(SCHEMA_VERSION)
        ids: dict[tuple[str, str], str] = {}
        decl: list[tuple[str, str, str, str]] = []  # id, domain, name, type
        for domain in ("graph", "node", "edge"):
            names = [name for (dom, name) in KNOWN if dom == domain]
            for i, name in enumerate(names):
                ids[domain, name] = kid = f"{domain[0]}{i}"
                decl.append((kid, domain, name, KNOWN[domain, name]))
        self.others = self._other_keys(ids, decl)
        self.ids, self.decl = ids, decl
        self.formats = {  # per element kind: (name, codec.format) in schema order
            where: [(name, a.codec.format) for name, a in attrs.items()]
            for where, attrs in rows.items()
        }
        self.templates = {
            where: "".join(f'<data key="{ids[DOMAIN[where], name]}">%s</data>' for name in attrs)
            for where, attrs in rows.items()
        }
        self.allowed = {
            w: set(attrs) | ({"kind"} if w != "graph" else set()) for w, attrs in rows.items()
        }
        self.sizes = {w: len(names) for w, names in self.allowed.items()}
        self.optional = {w: [n for n, a in attrs.items() if not a.required]
                         for w, attrs in rows.items()}
        self.codecs = {w: {n: a.codec for n, a in attrs.items()} for w, attrs in rows.items()}
        self._column_cache: dict = {}

    def _other_keys(self, ids, decl) -> dict[tuple[str, str], str]:
        """Declare a key per attribute outside the schema, typed from its values."""
        types: dict[tuple[str, str], set[str]] = {}

        def scan(domain: str, what: str, d: dict) -> None:
            for name, v in d.items():
                if (domain, name) not in KNOWN and not (domain == "edge" and name == "kind"):
                    try:
                        t = other_type(v)
                    except ValueError as exc:
                        raise ValueError(f"{what}: attribute {name!r} {exc}") from None
                    types.setdefault((domain, name), set()).add(t)

        scan("graph", "graph", self.g.graph)
        known_node = {n for (d, n) in KNOWN if d == "node"}
        known_edge = {n for (d, n) in KNOWN if d == "edge"} | {"kind"}
        for n, d in self.g.nodes(data=True):
            if not d.keys() <= known_node:
                scan("node", f"node {n!r}", d)
        succ = self.g._succ
        if any(not d.keys() <= known_edge
               for nbrs in succ.values() for keydict in nbrs.values() for d in keydict.values()):
            for batch in _edge_batches(self.g, 4096):
                for u, v, k, d in batch:
                    if not d.keys() <= known_edge:
                        scan("edge", f"edge {u!r}->{v!r} ({k!r})", d)
        out = {}
        for (domain, name), found in types.items():
            if found <= {"long", "double"}:
                gtype = "double" if "double" in found else "long"
            elif len(found) == 1:
                gtype = found.pop()
            else:
                raise ValueError(f"{domain} attribute {name!r} mixes {' and '.join(sorted(found))}")
            kid = f"x{domain[0]}{len(out)}"
            ids[domain, name] = kid
            out[domain, name] = gtype
            decl.append((kid, domain, name, gtype))
        return out

    def _data(self, where: str, label, d: dict) -> str:
        """The <data> elements of one element of kind ``where`` (schema order, then others)."""
        try:
            values = tuple([fmt(d[name]) for name, fmt in self.formats[where]])
            text = self.templates[where] % values
        except (KeyError, ValueError, TypeError):  # a missing or bad value: the slow way
            text = self._data_slow(where, label, d)
        absent = sum(1 for n in self.optional[where] if n not in d)
        if len(d) + absent != self.sizes[where]:  # attributes outside the schema
            text += self._others(where, label, d)
        return text

    def _data_slow(self, where: str, label, d: dict) -> str:
        parts = []
        for name, fmt in self.formats[where]:
            if name in d:
                try:
                    text = fmt(d[name])
                except (ValueError, TypeError) as exc:
                    raise ValueError(f"{where} {label}: attribute {name!r}: {exc}") from None
                parts.append(f'<data key="{self.ids[DOMAIN[where], name]}">{text}</data>')
        return "".join(parts)

    def _others(self, where: str, label, d: dict) -> str:
        domain = DOMAIN[where]
        parts = []
        for name, v in d.items():
            if name in self.allowed[where]:
                continue
            if (domain, name) in KNOWN:
                raise ValueError(f"{where} {label}: {name!r} is not a {where} attribute")
            text = format_other(v, self.others[domain, name])
            parts.append(f'<data key="{self.ids[domain, name]}">{text}</data>')
        return "".join(parts)

    def _many(self, where: str, ds: list[dict], label) -> list[str]:
        """:meth:`_data` of each of ``ds`` (elements of kind ``where``), a column at a time:
        one call per attribute for all of them (a save formats ~1e6 values). Where some value
        is missing or bad, each element of its group goes through :meth:`_data`, which names
        the problem; ``label(i)`` names element ``i``."""
        optional, size = self.optional[where], self.sizes[where]
        out: list[str | None] = [None] * len(ds)
        groups: dict[tuple[bool, ...], list[int]] = {}
        if not optional and all(n == size for n in map(len, ds)):
            groups[()] = list(range(len(ds)))
        else:
            for i, d in enumerate(ds):
                present = tuple([name in d for name in optional])
                if len(d) + present.count(False) != size:  # attributes outside the schema
                    out[i] = self._data(where, label(i), d)
                else:
                    groups.setdefault(present, []).append(i)
        for present, idx in groups.items():
            names, codecs, template = self._columns(where, present)
            sub = [ds[i] for i in idx] if len(idx) != len(ds) else ds
            try:
                columns = [list(map(itemgetter(name), sub)) for name in names]
                texts = [codec.format_many(col) for codec, col in zip(codecs, columns,
                                                                        strict=True)]
                done = list(map(template.__mod__, zip(*texts, strict=True)))
            except (KeyError, ValueError, TypeError):  # the slow way, naming the problem
                done = [self._data(where, label(i), ds[i]) for i in idx]
            for i, text in zip(idx, done, strict=True):
                out[i] = text
        return out

    def _columns(self, where: str, present: tuple[bool, ...]):
        """The attribute names, codecs and ``%s`` template of kind ``where`` with the optional
        attributes ``present``."""
        key = (where, present)
        if key not in self._column_cache:
            has = dict(zip(self.optional[where], present, strict=True))
            names = [n for n, _ in self.formats[where] if has.get(n, True)]
            codecs = [self.codecs[where][n] for n in names]
            template = "".join(f'<data key="{self.ids[DOMAIN[where], n]}">%s</data>'
                               for n in names)
            self._column_cache[key] = (names, codecs, template)
        return self._column_cache[key]

    def _batches(self, kinds: list[str], ds: list[dict], label_of) -> list[str]:
        """The <data> texts of elements ``ds`` of kinds ``kinds`` (in order), each kind
        formatted in columns; ``label_of(i)`` names element ``i``."""
        out: list[str] = [""] * len(ds)
        for where in set(kinds):
            idx = [i for i, kind in enumerate(kinds) if kind == where]
            texts = self._many(where, [ds[i] for i in idx],
                               lambda j, idx=idx: label_of(idx[j]))
            for i, text in zip(idx, texts, strict=True):
                out[i] = text
        return out

    def lines(self) -> Iterator[str]:
        """The document in pieces of whole lines: the header, keys, graph, nodes, edges, the
        end."""
        yield (
            "<?xml version='1.0' encoding='utf-8'?>\n"
            f'<graphml xmlns="{NS}" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
            f'xsi:schemaLocation="{NS} {NS}/1.0/graphml.xsd">\n'
        )
        for kid, domain, name, gtype in self.decl:
            yield (
                f'<key id="{kid}" for="{domain}" attr.name={quoteattr(xml_text(name))} '
                f'attr.type="{gtype}" />\n'
            )
        yield '<graph edgedefault="directed">\n'
        yield self._data("graph", "", self.g.graph) + "\n"
        quoted = {}
        kind_key = self.ids["node", "kind"]
        nodes = list(self.g._node.items())
        for n, d in nodes:
            kind = d.get("kind")
            if kind != "state" and kind != "object":
                raise ValueError(f"node {n!r}: kind {kind!r} is neither state nor object")
            quoted[n] = quoteattr(n)
        # whole batches of elements, of a few MB each (a state's features are the most of it)
        dim = self.g.graph.get("feature_dim")
        per_node = 6 * dim + 400 if isinstance(dim, int) and dim > 0 else 400
        step = max(1, min(1024, (4 << 20) // per_node))
        node_line = f'<node id=%s><data key="{kind_key}">%s</data>%s</node>\n'.__mod__
        for start in range(0, len(nodes), step):
            ns, ds = zip(*nodes[start : start + step], strict=True)
            kinds = [d["kind"] for d in ds]
            texts = self._batches(kinds, ds, lambda i, ns=ns: repr(ns[i]))
            yield "".join(map(node_line, zip(map(quoted.__getitem__, ns), kinds, texts,
                                             strict=True)))
        quoted_keys = _Quoted()
        edge_line = "<edge id=%s source=%s target=%s>%s</edge>\n".__mod__
        for batch in _edge_batches(self.g, 4096):
            us, vs, ks, ds = zip(*batch, strict=True)
            kinds = ["sees" if k == SEES else "transition" for k in ks]
            texts = self._batches(kinds, ds, lambda i, us=us, vs=vs: f"{us[i]!r}->{vs[i]!r}")
            yield "".join(map(edge_line, zip(map(quoted_keys.__getitem__, ks),
                                             map(quoted.__getitem__, us),
                                             map(quoted.__getitem__, vs), texts, strict=True)))
        yield "</graph>\n</graphml>\n"

    def chunks(self) -> Iterator[str]:
        """:meth:`lines` joined into pieces of at least :data:`_CHUNK` characters (a piece
        that large already is passed on as it is)."""
        out, size = [], 0
        for piece in self.lines():
            if len(piece) > _CHUNK and not out:
                yield piece
                continue
            out.append(piece)
            size += len(piece)
            if size > _CHUNK:
                yield "".join(out)
                out, size = [], 0
        yield "".join(out)


class _Quoted(dict):
    """Edge keys as quoted XML attribute values, each quoted once."""

    def __missing__(self, key) -> str:
        q = self[key] = quoteattr(str(key))
        return q


def _edge_batches(g, size: int) -> Iterator[list[tuple]]:
    """The graph's edges as ``(u, v, key, data)``, in its order, ``size`` at a time (straight
    from its adjacency: networkx's edge view costs a fifth of a save)."""
    batch: list[tuple] = []
    for u, nbrs in g._succ.items():
        for v, keydict in nbrs.items():
            for k, d in keydict.items():
                batch.append((u, v, k, d))
            if len(batch) >= size:
                yield batch
                batch = []
    if batch:
        yield batch


def to_graphml(model: AbstractModel) -> bytes:
    """The model as a GraphML document."""
    with paused_gc():
        return "".join(_Writer(model).chunks()).encode("utf-8")


def write_model(model: AbstractModel, path: str | os.PathLike[str]) -> None:
    """Save ``model`` to ``path`` (GraphML), replacing any previous file atomically.

    A value GraphML cannot hold (an attribute of another type, a control character) raises
    ``ValueError`` naming it, and the previous file stays as it was.
    """
    with paused_gc():
        chunks = _Writer(model).chunks()
        with atomic_open(path, "wb") as fh:
            for chunk in chunks:
                fh.write(chunk.encode("utf-8"))
