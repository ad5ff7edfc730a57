"""The relocator's index file: an uncompressed ``.npz`` whose large parts never pass through
memory whole.

A relocator over a large store is mostly two things: the unit feature rows (4 bytes × dim per
state) and, with the HNSW backend, its search graph. Writing them the way ``np.savez`` and
``faiss.serialize_index`` do holds a second copy of the graph (and a third, for a moment, as a
NumPy array) while the file is written; reading them back holds all the rows in RAM although a
search touches a few dozen. Here instead:

* arrays are ``.npy`` members written one after another into the zip (``ZIP_STORED``, so
  NumPy, ``unzip`` and :func:`numpy.load` still read the file);
* a **blob** (:class:`Blob`) is a member its owner streams itself, such as a faiss index
  written through ``faiss.PyCallbackIOWriter``, and is read back as a stream;
* a stored member's bytes lie contiguous in the file, so :meth:`IndexReader.locate` says where
  an array's data are, and :meth:`IndexReader.array` with ``mapped=True`` maps them: reopening
  an index costs page cache, not process memory, and a query reads only the rows it re-ranks.

The file is written atomically (:func:`kgnav.common.atomic.atomic_open`).

>>> import tempfile, numpy as np
>>> path = tempfile.mkdtemp() + "/i.npz"
>>> _ = write_index(path, {"rows": np.eye(3, dtype=np.float32)},
...                 {"note": Blob(lambda fh: fh.write(b"hello"))})
>>> with IndexReader(path) as z:
...     rows = z.array("rows", mapped=True)
...     print(rows.flags.owndata, rows[1].tolist(), z.blob("note").read())
False [0.0, 1.0, 0.0] b'hello'
"""

from __future__ import annotations

import mmap
import os
import struct
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import BinaryIO, NamedTuple

import numpy as np

from kgnav.common.atomic import atomic_open

_NPY = ".npy"
_LOCAL_HEADER = struct.Struct("<4s22xHH")  # signature, ..., name length, extra length
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0,
                   (2, 0): np.lib.format.read_array_header_2_0}


class Blob(NamedTuple):
    """A member written by its owner: ``write(fh)`` streams the bytes into the open member."""

    write: Callable[[BinaryIO], object]


def write_index(path: str | os.PathLike[str], arrays: Mapping[str, np.ndarray | Blob],
                blobs: Mapping[str, Blob] = {}) -> Path:  # noqa: B006 - read only
    """Write ``arrays`` (as ``NAME.npy`` members; a :class:`Blob` there writes the ``.npy``
    bytes itself) and ``blobs`` (as ``NAME``) to ``path``."""
    path = Path(path)
    with atomic_open(path, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED,
                                                        allowZip64=True) as zf:
        for name, a in arrays.items():
            # force_zip64: a member's size is unknown when its header is written, and the
            # feature rows of a large store pass 2 GiB
            with zf.open(name + _NPY, "w", force_zip64=True) as out:
                if isinstance(a, Blob):  # streams a whole .npy itself
                    a.write(out)
                else:
                    np.lib.format.write_array(out, np.asanyarray(a), allow_pickle=False)
        for name, blob in blobs.items():
            with zf.open(name, "w", force_zip64=True) as out:
                blob.write(out)
    return path


class IndexReader:
    """An index file open for reading (a context manager). Errors are those of a damaged
    file: ``OSError``, ``ValueError``, ``KeyError``, ``zipfile.BadZipFile``."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        self._fh = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        try:
            self._zip = zipfile.ZipFile(self._fh)
        except BaseException:
            self._fh.close()
            raise

    def __enter__(self) -> IndexReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._zip.close()
        self._fh.close()

    @property
    def arrays(self) -> list[str]:
        """Names of the array members."""
        return [n[: -len(_NPY)] for n in self._zip.namelist() if n.endswith(_NPY)]

    @property
    def blobs(self) -> list[str]:
        """Names of the blob members."""
        return [n for n in self._zip.namelist() if not n.endswith(_NPY)]

    def array(self, name: str, mapped: bool = False) -> np.ndarray:
        """The array ``name`` (never a pickle). ``mapped``: a read-only view of the file where
        the member is stored uncompressed, else read into memory."""
        where = self.locate(name) if mapped else None
        if where is not None:
            offset, shape, dtype, fortran = where
            count = int(np.prod(shape, dtype=np.int64))
            if count == 0:
                return np.zeros(shape, dtype)  # mmap cannot map nothing
            base = offset - offset % mmap.ALLOCATIONGRANULARITY
            view = mmap.mmap(self._fh.fileno(), offset - base + count * dtype.itemsize,
                             access=mmap.ACCESS_READ, offset=base)
            rows = np.frombuffer(view, dtype, count, offset - base)
            return rows.reshape(shape, order="F" if fortran else "C")
        with self._zip.open(name + _NPY) as member:
            return np.lib.format.read_array(member, allow_pickle=False)

    def blob(self, name: str) -> BinaryIO:
        """A stream of the blob ``name``'s bytes (valid until the reader is closed)."""
        return self._zip.open(name)

    def locate(self, name: str) -> tuple[int, tuple[int, ...], np.dtype, bool] | None:
        """Where the array ``name``'s data lie in the file: ``(offset, shape, dtype,
        fortran_order)``, or None when the member is compressed (not contiguous there)."""
        info = self._zip.getinfo(name + _NPY)
        if info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 0x1:
            return None
        fh = self._fh
        fh.seek(info.header_offset)
        sig, n_name, n_extra = _LOCAL_HEADER.unpack(fh.read(_LOCAL_HEADER.size))
        if sig != b"PK\x03\x04":
            raise zipfile.BadZipFile(f"{info.filename}: bad local header")
        start = info.header_offset + _LOCAL_HEADER.size + n_name + n_extra
        fh.seek(start)
        version = np.lib.format.read_magic(fh)
        if version not in _HEADER_READERS:
            return None  # a header layout the public readers do not parse: read it instead
        shape, fortran, dtype = _HEADER_READERS[version](fh)
        if dtype.hasobject:
            raise ValueError(f"{info.filename}: an object array (a pickle) is refused")
        offset = fh.tell()
        if offset - start + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize > info.file_size:
            raise ValueError(f"{info.filename}: shorter than its header says")
        return offset, shape, dtype, fortran
