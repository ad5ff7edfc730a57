"""The relocator's feature rows: unit-norm float32 rows with an alive mask, in memory or on disk.

A relocator over a store of a million states holds 2 GB of 512-d features, and its HNSW graph
about half as much again. The graph must be in memory; the rows need not be: a graph search
re-ranks a few dozen of them. A table made with ``spill=DIR`` therefore keeps its rows in an
unnamed temporary file in ``DIR`` (gone when the table is), appends by writing, reads ranges and
samples with ``pread`` (page cache, which the kernel can drop, not process memory), and offers
:attr:`VectorTable.vectors` as a read-only mapping for the searches that want an array.

>>> t = VectorTable(2)
>>> t.append(unit_rows([[3.0, 4.0], [0.0, 2.0]]))
0
>>> t.vectors.tolist(), t.alive.tolist()
([[0.6000000238418579, 0.800000011920929], [0.0, 1.0]], [True, True])
>>> import tempfile
>>> d = VectorTable(2, spill=tempfile.gettempdir())
>>> d.append(t.vectors)
0
>>> d.rows(1, 2).tolist(), d.on_disk
([[0.0, 1.0]], True)
"""

from __future__ import annotations

import mmap
import os
import tempfile
import weakref
from typing import BinaryIO

import numpy as np

#: Rows per read or write when a table streams through its rows.
CHUNK_ROWS = 16384


def unit_rows(x: np.ndarray) -> np.ndarray:
    """Rows scaled to unit L2 norm (zero rows stay zero), as float32."""
    x = np.asarray(x, dtype=np.float32)
    norms = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / np.maximum(norms, 1e-12)


class VectorTable:
    """Unit-norm feature rows in a growable buffer, with an alive mask for replaced models.

    Parameters
    ----------
    dim:
        Row length.
    capacity:
        Rows to allocate up front (in memory) when the caller knows the count: growing by
        doubling would hold the old and the new buffer at once (up to 3x the rows) in the copy.
    spill:
        A directory: keep the rows in a temporary file there instead of in memory.
    """

    def __init__(self, dim: int, capacity: int = 0, spill: str | os.PathLike[str] | None = None):
        self.dim = dim
        self.n = 0
        self._file: BinaryIO | None = None
        self._offset = 0  # byte offset of row 0 in the file
        self._readonly = False  # rows in another's file (an index): appending copies them
        self._view: np.ndarray | None = None
        self._spill = spill
        if spill is not None:
            self._own(tempfile.TemporaryFile(dir=spill, prefix=".kgnav-rows-"))
            capacity = 0
        self._buf = np.empty((capacity, dim), dtype=np.float32)
        self._alive = np.zeros(capacity, dtype=bool)

    @classmethod
    def wrap(cls, rows: np.ndarray) -> VectorTable:
        """A table over ``rows`` as they are, all alive."""
        t = cls(rows.shape[1])
        t._buf, t._alive, t.n = rows, np.ones(len(rows), bool), len(rows)
        return t

    @classmethod
    def in_file(cls, path: str | os.PathLike[str], offset: int, n: int, dim: int) -> VectorTable:
        """A table over ``n`` C-ordered float32 rows at byte ``offset`` of the file ``path``
        (an index file's), all alive; the file is only read."""
        t = cls(dim)
        t._own(open(path, "rb"))  # noqa: SIM115 - closed with the table
        t._offset, t._readonly = offset, True
        t.n, t._alive = n, np.ones(n, bool)
        return t

    def _own(self, fh: BinaryIO) -> None:
        self._file = fh
        weakref.finalize(self, fh.close)  # a temporary file goes with its table

    @property
    def on_disk(self) -> bool:
        return self._file is not None

    @property
    def vectors(self) -> np.ndarray:
        """The rows as one array (read-only and mapped from the file for a table on disk)."""
        if self._file is None:
            return self._buf[: self.n]
        if self.n == 0:
            return np.zeros((0, self.dim), np.float32)
        if self._view is None or len(self._view) != self.n:
            base = self._offset - self._offset % mmap.ALLOCATIONGRANULARITY
            m = mmap.mmap(self._file.fileno(), self._offset - base + self.n * self._row_bytes,
                          access=mmap.ACCESS_READ, offset=base)
            self._view = np.frombuffer(m, np.float32, self.n * self.dim,
                                       self._offset - base).reshape(self.n, self.dim)
        return self._view

    @property
    def alive(self) -> np.ndarray:
        return self._alive[: self.n]

    @property
    def _row_bytes(self) -> int:
        return 4 * self.dim

    def append(self, rows: np.ndarray) -> int:
        """Append ``rows`` (already unit-norm); returns the index of the first."""
        rows = np.ascontiguousarray(rows, dtype=np.float32).reshape(-1, self.dim)
        if self._readonly:  # another's file: the rows come into memory first
            self._buf, fh = self.vectors.copy(), self._file
            self._file, self._view, self._readonly = None, None, False
            fh.close()
        start, need = self.n, self.n + len(rows)
        if need > len(self._alive):
            cap = max(need, 2 * len(self._alive), 1024)
            alive = np.zeros(cap, dtype=bool)
            alive[:start] = self._alive[:start]
            self._alive = alive
            if self._file is None:
                buf = np.empty((cap, self.dim), dtype=np.float32)
                buf[:start] = self._buf[:start]
                self._buf = buf
        if self._file is None:
            self._buf[start:need] = rows
        else:
            os.pwrite(self._file.fileno(), rows.tobytes(), start * self._row_bytes)
        self._alive[start:need] = True
        self.n = need
        return start

    def rows(self, start: int, stop: int) -> np.ndarray:
        """A copy of rows ``start:stop`` (read from the file, not mapped, for a table on disk:
        the pages stay the kernel's cache, not the process's memory)."""
        stop = min(stop, self.n)
        if self._file is None:
            return self._buf[start:stop].copy()
        if stop <= start:
            return np.zeros((0, self.dim), np.float32)
        nbytes = (stop - start) * self._row_bytes
        data = os.pread(self._file.fileno(), nbytes, self._offset + start * self._row_bytes)
        if len(data) != nbytes:
            raise OSError(f"feature rows cut short on disk ({len(data)} of {nbytes} bytes)")
        return np.frombuffer(data, np.float32).reshape(-1, self.dim).copy()

    def take(self, index: np.ndarray) -> np.ndarray:
        """A copy of the rows at ``index`` (on disk: one read per run of consecutive rows)."""
        if self._file is None:
            return self._buf[: self.n][index]
        idx = np.asarray(index, np.int64).reshape(-1)
        out = np.empty((len(idx), self.dim), np.float32)
        if len(idx):
            order = np.argsort(idx, kind="stable")
            runs = np.split(idx[order], np.flatnonzero(np.diff(idx[order]) != 1) + 1)
            out[order] = np.concatenate([self.rows(int(r[0]), int(r[-1]) + 1) for r in runs])
        return out

    def chunks(self, size: int = CHUNK_ROWS):
        """``(start, rows)`` of consecutive copies of at most ``size`` rows."""
        for start in range(0, self.n, size):
            yield start, self.rows(start, start + size)

    def compacted(self, keep: np.ndarray) -> VectorTable:
        """A table of the rows at ``keep``: on disk if this one spills, else in memory."""
        out = VectorTable(self.dim, capacity=0 if self._spill else len(keep), spill=self._spill)
        for start in range(0, len(keep), CHUNK_ROWS):
            out.append(self.take(keep[start:start + CHUNK_ROWS]))
        return out

    def write_npy(self, fh: BinaryIO) -> None:
        """Write the rows to ``fh`` as one ``.npy`` array, streamed from the file if on disk."""
        if self._file is None:
            np.lib.format.write_array(fh, self.vectors, allow_pickle=False)
            return
        np.lib.format.write_array_header_1_0(
            fh, {"descr": np.lib.format.dtype_to_descr(np.dtype(np.float32)),
                 "fortran_order": False, "shape": (self.n, self.dim)})
        for _, rows in self.chunks():
            fh.write(rows.tobytes())
