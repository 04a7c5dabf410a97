"""`calib.npz_stream.map_arrays`: the arrays of an uncompressed .npz mapped, equal to what np.load reads."""

import numpy as np

from calib.npz_stream import map_arrays
from calib.npzfile import read_npz


def test_mapped_arrays_equal_what_np_load_reads(tmp_path):
    rng = np.random.default_rng(3)
    arrays = {"a": rng.normal(size=(37, 29)).astype(np.float32), "f": np.asfortranarray(rng.normal(size=(5, 7))),
              "b": rng.random((11, 13, 3)) > 0.5, "i": np.arange(1000, dtype=np.int64).reshape(10, 100),
              "empty": np.zeros((0, 3)), "meta": np.array('{"format": "test/1"}')}
    np.savez(tmp_path / "plain.npz", **arrays)
    np.savez_compressed(tmp_path / "packed.npz", **arrays)
    mapped = map_arrays(tmp_path / "plain.npz")
    assert sorted(mapped) == ["a", "b", "f", "i"]            # the empty and the 0-d arrays are left to np.load
    with np.load(tmp_path / "plain.npz") as z:
        for name, value in mapped.items():
            assert isinstance(value, np.memmap) and not value.flags.writeable
            assert value.dtype == z[name].dtype and value.shape == z[name].shape
            np.testing.assert_array_equal(value, z[name])
    assert map_arrays(tmp_path / "packed.npz") == {}          # compressed members cannot be mapped
    meta, read = read_npz(tmp_path / "plain.npz", "test/1", "test", mapped=True)
    assert meta == {"format": "test/1"} and isinstance(read["a"], np.memmap)
    np.testing.assert_array_equal(read["empty"], arrays["empty"])
    meta, read = read_npz(tmp_path / "packed.npz", "test/1", "test", mapped=True)
    assert not isinstance(read["a"], np.memmap)
    np.testing.assert_array_equal(read["f"], arrays["f"])
