"""The relocator's index file and its feature table: streamed writes, mapped reads, rows on disk."""

import io
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from kgnav import KgnavError, Relocator
from kgnav.memory.index_file import Blob, IndexReader, write_index
from kgnav.memory.vector_table import VectorTable, unit_rows
from tests.strategies import walk_model

_walk = walk_model


@settings(max_examples=25, deadline=None)
@given(a=hnp.arrays(st.sampled_from([np.float32, np.int64, np.uint8, ">f4"]),
                    hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5)),
       fortran=st.booleans(), payload=st.binary(max_size=300))
def test_arrays_and_blobs_come_back_as_written(tmp_path_factory, a, fortran, payload):
    a = np.asfortranarray(a) if fortran else a
    path = tmp_path_factory.mktemp("i") / "i.npz"
    write_index(path, {"a": a, "b": Blob(lambda fh: np.lib.format.write_array(fh, a))},
                {"raw": Blob(lambda fh: fh.write(payload))})
    with IndexReader(path) as z:
        assert sorted(z.arrays) == ["a", "b"] and z.blobs == ["raw"]
        for mapped in (False, True):
            back = z.array("a", mapped=mapped)
            assert back.dtype == a.dtype and back.shape == a.shape
            assert np.array_equal(back, a, equal_nan=a.dtype.kind == "f")
        assert np.array_equal(z.array("b"), a, equal_nan=a.dtype.kind == "f")
        assert z.blob("raw").read() == payload
    with np.load(path) as npz:  # still an .npz NumPy reads
        assert np.array_equal(npz["a"], a, equal_nan=a.dtype.kind == "f")


def test_a_mapped_array_is_a_view_of_the_file_at_the_place_locate_names(tmp_path):
    rows = np.arange(12, dtype=np.float32).reshape(4, 3)
    path = write_index(tmp_path / "i.npz", {"pad": np.zeros(7, np.uint8), "rows": rows})
    with IndexReader(path) as z:
        offset, shape, dtype, fortran = z.locate("rows")
        mapped = z.array("rows", mapped=True)
        assert not mapped.flags.owndata and not mapped.flags.writeable
    raw = path.read_bytes()[offset:offset + rows.nbytes]
    assert (shape, dtype, fortran) == ((4, 3), np.float32, False) and raw == rows.tobytes()
    assert np.array_equal(mapped, rows)


def _hostile(tmp_path, header_shape, data: bytes, descr="<f4"):
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False,
                                               "shape": header_shape})
    path = tmp_path / "h.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        zf.writestr("rows.npy", buf.getvalue() + data)
    return path


def test_a_member_shorter_than_its_header_says_is_refused_not_mapped(tmp_path):
    path = _hostile(tmp_path, (1000, 512), np.zeros(8, np.float32).tobytes())
    with IndexReader(path) as z, pytest.raises(ValueError, match="shorter than its header"):
        z.array("rows", mapped=True)


def test_an_object_array_is_refused_either_way(tmp_path):
    buf = io.BytesIO()
    np.save(buf, np.array([{"x": 1}], dtype=object), allow_pickle=True)
    path = tmp_path / "p.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("rows.npy", buf.getvalue())
    with IndexReader(path) as z:
        with pytest.raises(ValueError, match="pickle|object"):
            z.array("rows", mapped=True)
        with pytest.raises(ValueError):
            z.array("rows")


def test_a_compressed_member_is_read_not_located(tmp_path):
    rows = np.ones((3, 2), np.float32)
    path = tmp_path / "c.npz"
    np.savez_compressed(path, rows=rows)
    with IndexReader(path) as z:
        assert z.locate("rows") is None
        assert np.array_equal(z.array("rows", mapped=True), rows)


# ---------------------------------------------------------------- the feature table

@settings(max_examples=20, deadline=None)
@given(batches=st.lists(st.integers(1, 40), min_size=1, max_size=6), seed=st.integers(0, 99))
def test_a_table_on_disk_holds_what_one_in_memory_holds(tmp_path_factory, batches, seed):
    rng = np.random.default_rng(seed)
    ram, disk = VectorTable(6), VectorTable(6, spill=tmp_path_factory.mktemp("spill"))
    for n in batches:
        rows = unit_rows(rng.normal(size=(n, 6)))
        assert ram.append(rows) == disk.append(rows)
    n = ram.n
    assert disk.on_disk and not ram.on_disk and disk.n == n
    assert np.array_equal(disk.vectors, ram.vectors)
    assert np.array_equal(disk.rows(3, n + 5), ram.rows(3, n + 5))
    idx = rng.integers(0, n, size=17)
    assert np.array_equal(disk.take(idx), ram.take(idx))
    assert np.array_equal(np.concatenate([r for _, r in disk.chunks(7)]), ram.vectors)
    keep = np.flatnonzero(rng.random(n) < 0.5)
    small = disk.compacted(keep)
    assert small.on_disk and np.array_equal(small.vectors, ram.vectors[keep])
    a, b = io.BytesIO(), io.BytesIO()
    ram.write_npy(a)
    disk.write_npy(b)
    assert a.getvalue() == b.getvalue()


def test_a_table_in_an_index_file_copies_itself_into_memory_before_it_grows(tmp_path):
    rows = unit_rows(np.arange(12, dtype=np.float32).reshape(4, 3) + 1)
    path = write_index(tmp_path / "i.npz", {"rows": rows})
    with IndexReader(path) as z:
        offset, shape, _, _ = z.locate("rows")
    t = VectorTable.in_file(path, offset, *shape)
    assert t.on_disk and np.array_equal(t.take([3, 0]), rows[[3, 0]])
    t.append(unit_rows([[1.0, 0.0, 0.0]]))
    assert not t.on_disk and t.n == 5
    assert path.read_bytes().count(rows.tobytes()) == 1  # the file was never written


# ---------------------------------------------------------------- the relocator over them

@pytest.mark.parametrize("backend", ["exact", "hnsw"])
def test_a_fit_with_rows_on_disk_answers_as_one_in_memory(tmp_path, backend):
    if backend == "hnsw":
        pytest.importorskip("faiss")
    params = {"min_rows": 10, "pca_dim": 4} if backend == "hnsw" else None
    ms = [_walk(f"h{k}", 30, k) for k in range(4)]
    ram = Relocator(backend=backend, backend_params=params).fit(ms)
    disk = Relocator(backend=backend, backend_params=params).fit(ms, spill=tmp_path)
    assert disk._table.on_disk and not ram._table.on_disk
    assert list(tmp_path.iterdir()) == []  # an unnamed file: nothing left behind
    for r in (ram, disk):
        r.add(_walk("h1", 12, 7))  # replaced: dead rows, compacted on save
        r.add(_walk("h9", 25, 8))
    for q in np.random.default_rng(3).normal(size=(15, 8)):
        assert disk.nearest(q, 4) == ram.nearest(q, 4)
    a, b = ram.save(tmp_path / "a.npz"), disk.save(tmp_path / "b.npz")
    back = Relocator.load(b)
    assert back._table.on_disk == (backend == "hnsw")  # hnsw: the rows left in the file
    with np.load(a) as za, np.load(b) as zb:
        assert np.array_equal(za["vectors"], zb["vectors"])
        assert np.array_equal(za["state_ids"], zb["state_ids"])
    for q in np.random.default_rng(4).normal(size=(15, 8)):
        assert back.nearest(q, 4) == ram.nearest(q, 4)


def test_an_index_of_version_1_still_loads(tmp_path):
    faiss = pytest.importorskip("faiss")
    params = {"min_rows": 10, "pca_dim": 4}
    r = Relocator(backend="hnsw", backend_params=params).fit([_walk("a", 40, 0)])
    v2 = r.save(tmp_path / "v2.npz")
    with np.load(v2) as z:  # the arrays of version 2 in version 1's layout: np.savez, and
        parts = {k: z[k] for k in z.files if k != "meta"}  # the graph as a byte array
        meta = __import__("json").loads(bytes(z["meta"]))
    meta["version"] = 1
    parts["meta"] = np.frombuffer(__import__("json").dumps(meta).encode(), np.uint8)
    parts["backend.graph"] = faiss.serialize_index(r._backend._index)
    np.savez(tmp_path / "v1.npz", **parts)
    back = Relocator.load(tmp_path / "v1.npz")
    assert back._backend._index is not None and back._backend._index.ntotal == 40
    for q in np.random.default_rng(1).normal(size=(10, 8)):
        assert back.nearest(q, 3) == r.nearest(q, 3)


def test_an_index_of_a_later_version_is_one_line(tmp_path):
    import json
    path = Relocator().fit([_walk("a", 4, 0)]).save(tmp_path / "i.npz")
    with np.load(path) as z:
        parts = {k: z[k] for k in z.files}
    meta = json.loads(bytes(parts["meta"]))
    meta["version"] = 99
    parts["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(path, **parts)
    with pytest.raises(KgnavError, match="index version 99") as err:
        Relocator.load(path)
    assert "\n" not in str(err.value)


def test_an_index_whose_rows_are_cut_short_is_refused(tmp_path):
    path = Relocator().fit([_walk("a", 40, 0)]).save(tmp_path / "i.npz")
    with IndexReader(path) as z:
        offset, _, _, _ = z.locate("vectors")
    data = bytearray(path.read_bytes())
    # claim more rows than the member holds: the header's shape is the lie
    head = data[offset - 128:offset]
    data[offset - 128:offset] = head.replace(b"(40, 8)", b"(90, 8)")
    path.write_bytes(bytes(data))
    with pytest.raises(KgnavError, match="not a usable relocator index"):
        Relocator.load(path)
