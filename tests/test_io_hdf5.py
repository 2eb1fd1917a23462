"""brdffit's HDF5 schema: exact round trips, reproducible bytes, group updates that never damage a file."""

import faulthandler
import json
import os
import signal
import time

import h5py
import numpy as np
import pytest

import brdffit.io as bio
from brdffit.io import FormatError, read_hdf5, update_hdf5, write_hdf5
from brdffit.io import hdf5
from brdffit.io.hdf5 import read_hdf5_group
from brdffit.measurements import MeasurementError, Measurements


def sample(n=50, sigma=True, weights=True):
    rng = np.random.default_rng(11)
    values = rng.uniform(0.0, 2.0, (n, 2))
    values[3, 1] = np.nan
    sig = np.where(np.isnan(values), np.nan, 0.05) if sigma else None
    return Measurements(np.arccos(rng.random(n)), rng.random(n) * 7, np.arccos(rng.random(n)), rng.random(n) * 7,
                        values, sigma=sig, weights=rng.random(n) if weights else None, channels=("450 nm", "λ=550"),
                        meta={"source": "synthetic", "truth": {"spec": "lambert", "channels": 2,
                                                              "params": {"rho_d": [0.1, 0.2]}}, "nan": float("nan")})


def assert_same(a, b):
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "values", "sigma", "weights"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype == np.float64
            np.testing.assert_array_equal(x, y, err_msg=name)  # NaN == NaN here; exact otherwise
    assert a.channels == b.channels
    assert json.dumps(a.meta, sort_keys=True) == json.dumps(b.meta, sort_keys=True)


@pytest.mark.parametrize("sigma, weights", [(True, True), (False, False)])
def test_exact_round_trip(tmp_path, sigma, weights):
    m = sample(sigma=sigma, weights=weights)
    path = tmp_path / "m.h5"
    bio.save(m, path)
    back = bio.load(path)
    assert_same(m, back)
    with h5py.File(path, "r") as f:
        assert f.attrs["format_version"] == "1" and f.attrs["creator"].startswith("brdffit ")
        g = f["measurements"]
        expected = {"theta_i", "phi_i", "theta_o", "phi_o", "values"} | ({"sigma"} if sigma else set()) | (
            {"weights"} if weights else set())
        assert set(g) == expected
        assert g["values"].shape == (50, 2) and g["theta_i"].dtype == np.float64
        assert json.loads(g.attrs["channels"]) == ["450 nm", "λ=550"]


def test_bytes_are_reproducible(tmp_path):
    m = sample()
    write_hdf5(m, tmp_path / "a.h5")
    write_hdf5(m, tmp_path / "b.hdf5", compression="gzip")
    write_hdf5(m, tmp_path / "c.hdf5", compression="gzip")
    assert (tmp_path / "b.hdf5").read_bytes() == (tmp_path / "c.hdf5").read_bytes()
    assert_same(read_hdf5(tmp_path / "a.h5"), read_hdf5(tmp_path / "b.hdf5"))


def test_update_adds_and_replaces_groups(tmp_path):
    path = tmp_path / "m.h5"
    m = sample()
    write_hdf5(m, path)

    def fit_writer(value):
        def write(group):
            group.attrs["spec"] = "lambert"
            group.create_dataset("params", data=np.array([value]))
            return value
        return write

    assert update_hdf5(path, "fits/lambert", fit_writer(1.0)) == 1.0
    update_hdf5(path, "/fits/ggx", fit_writer(2.0))
    update_hdf5(path, "fits/lambert", fit_writer(3.0))  # replaced, not duplicated
    update_hdf5(path, "posteriors/run1", lambda g: g.create_dataset("chain", data=np.zeros((4, 3))))
    with h5py.File(path, "r") as f:
        assert sorted(f) == ["fits", "measurements", "posteriors"]
        assert sorted(f["fits"]) == ["ggx", "lambert"]
        assert f["fits/lambert/params"][()].tolist() == [3.0]
        assert f["fits/ggx/params"][()].tolist() == [2.0]
        assert f["fits/lambert"].attrs["spec"] == "lambert"
    assert_same(read_hdf5(path), m)
    assert read_hdf5_group(path, "fits/ggx", lambda g: g["params"][0]) == 2.0
    # replacing the measurements keeps the fits when asked to
    write_hdf5(m.select_channels([1]), path, keep_other_groups=True)
    with h5py.File(path, "r") as f:
        assert sorted(f) == ["fits", "measurements", "posteriors"]
    assert read_hdf5(path).channels == ("λ=550",)
    write_hdf5(m, path)  # by default a fresh file
    with h5py.File(path, "r") as f:
        assert list(f) == ["measurements"]


def test_update_creates_a_file_and_a_failure_leaves_it_untouched(tmp_path):
    path = tmp_path / "new.h5"
    update_hdf5(path, "fits/a", lambda g: g.create_dataset("x", data=[1.0]))
    with h5py.File(path, "r") as f:
        assert f.attrs["format_version"] == "1" and f["fits/a/x"][0] == 1.0
    before = path.read_bytes()

    def broken(group):
        group.create_dataset("y", data=[2.0])
        raise RuntimeError("solver exploded")

    with pytest.raises(RuntimeError, match="solver exploded"):
        update_hdf5(path, "fits/a", broken)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["new.h5"]
    with pytest.raises(ValueError):
        update_hdf5(path, "/", broken)


def test_a_failed_save_keeps_the_old_file(tmp_path):
    path = tmp_path / "m.h5"
    write_hdf5(sample(), path)
    before = path.read_bytes()
    with pytest.raises(TypeError):
        write_hdf5("not measurements", path)
    with pytest.raises(TypeError):
        update_hdf5(path, "measurements", lambda g: g.create_dataset("x", data=object()))
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["m.h5"]


def foreign(path, version=None, drop=None, values=None):
    with h5py.File(path, "w") as f:
        if version is not None:
            f.attrs["format_version"] = version
        g = f.create_group("measurements")
        for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
            if name != drop:
                g.create_dataset(name, data=np.zeros(3))
        if drop != "values":
            g.create_dataset("values", data=np.array([[0.1], [0.2], [0.3]]) if values is None else values)
    return path


def test_bad_files(tmp_path):
    cases = [
        (tmp_path / "empty.h5", b"", "empty"),
        (tmp_path / "text.h5", b"theta_i,phi_i\n", "not an HDF5 file"),
        (tmp_path / "lfs.h5", b"version https://git-lfs.github.com/spec/v1\noid sha256:1\n", "Git LFS pointer"),
    ]
    for path, content, pattern in cases:
        path.write_bytes(content)
        with pytest.raises(FormatError, match=pattern) as info:
            read_hdf5(path)
        assert str(info.value).startswith(str(path))
    with pytest.raises(FormatError, match="no 'format_version' attribute"):
        read_hdf5(foreign(tmp_path / "plain.h5"))
    with pytest.raises(FormatError, match="format_version '2' is not one this brdffit reads"):
        read_hdf5(foreign(tmp_path / "v2.h5", version="2"))
    with pytest.raises(FormatError, match="dataset /measurements/phi_o is missing"):
        read_hdf5(foreign(tmp_path / "nophi.h5", version="1", drop="phi_o"))
    with pytest.raises(FormatError, match=r"no group /fits \(groups: /measurements\)"):
        read_hdf5(foreign(tmp_path / "g.h5", version="1"), group="fits")
    with pytest.raises(MeasurementError, match=r"neg.h5 \(/measurements\): row 1: values"):
        read_hdf5(foreign(tmp_path / "neg.h5", version="1", values=np.array([[0.1], [-0.2], [0.3]])))
    with pytest.raises(FormatError, match="not one brdffit wrote"):
        update_hdf5(tmp_path / "plain.h5", "fits/x", lambda g: None)


def test_truncated_file(tmp_path):
    path = tmp_path / "m.h5"
    write_hdf5(sample(n=2000), path)
    data = path.read_bytes()
    for cut in (len(data) // 2, 1024, 9):
        path.write_bytes(data[:cut])
        with pytest.raises(FormatError):
            read_hdf5(path)


# ------------------------------------------------------------------------------- a batch inspected in one child
def zeroed_heap(path):
    """A brdffit file whose global heap objects are zeroed: libhdf5's H5Aread then loops forever (issue 20)."""
    write_hdf5(sample(), path)
    data = bytearray(path.read_bytes())
    heap = data.find(b"GCOL")
    assert heap > 0
    data[heap + 32:heap + 32 + 512] = bytes(512)
    path.write_bytes(bytes(data))
    return path


def test_a_batch_is_inspected_in_one_child_and_a_bad_file_spares_the_others(tmp_path, monkeypatch):
    m = sample()
    good = []
    for i in range(4):
        good.append(tmp_path / f"good{i}.h5")
        write_hdf5(m, good[-1])
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(good[0].read_bytes()[:1024])
    text = tmp_path / "text.h5"
    text.write_bytes(b"theta_i,phi_i\n")
    paths = [good[0], good[1], zeroed_heap(tmp_path / "zeroed.h5"), good[2], truncated, text, good[3],
             tmp_path / "missing.h5"]
    forks = []
    real_fork = os.fork

    def counting_fork():
        forks.append(1)
        return real_fork()

    monkeypatch.setattr(os, "fork", counting_fork)
    monkeypatch.setattr(hdf5, "INSPECT_TIMEOUT_S", 2.0)
    start = time.perf_counter()
    # Each file read by the child that inspects it (this process never opens one), from what the inspection kept.
    opened = list(hdf5.read_hdf5_many(paths, lambda path: {"/measurements"},
                                      lambda f, path, kept: hdf5.read_measurements_group(kept["/measurements"], path)))
    # A hang guard: the looping file must be killed at its timeout (without one, libhdf5 loops forever). Typical:
    # 2.1 s (the one 2 s timeout, milliseconds for the others); the bound is 10 times that and more, for a busy
    # host. That only the looping file waits for the timeout is checked by the forks and outcomes below.
    assert time.perf_counter() - start < 30.0
    # good0, good1 and the looping file in one child (killed at the timeout), good2 and the truncated file in a
    # second one, good3 in a third; the text file and the missing one never reach a child.
    assert len(forks) == 3
    assert [path for path, _ in opened] == paths
    results = dict(opened)
    for path in good:
        assert_same(results[path], m)
    problems = {path.name: str(results[path]) for path in paths if path not in good}
    assert problems["zeroed.h5"].endswith("zeroed.h5: reading its HDF5 metadata did not finish within 2 s (damaged "
                                          "metadata makes libhdf5 loop); the file is refused")
    assert "truncated.h5: cannot be opened as HDF5 (truncated or damaged?)" in problems["truncated.h5"]
    assert "text.h5: not an HDF5 file" in problems["text.h5"]
    assert isinstance(results[tmp_path / "missing.h5"], FileNotFoundError)
    assert all(isinstance(results[path], FormatError) for path in (paths[2], truncated, text))


def test_a_child_that_crashes_refuses_only_the_file_it_crashed_on(tmp_path, monkeypatch):
    paths = []
    for i in range(3):
        paths.append(tmp_path / f"m{i}.h5")
        write_hdf5(sample(), paths[-1])
    inspect = hdf5._inspect

    def crashing(path):  # runs in the child: libhdf5 dying of a signal on the second file
        if str(path).endswith("m1.h5"):
            faulthandler.disable()  # pytest's traceback dump on SIGSEGV would only be noise here
            os.kill(os.getpid(), signal.SIGSEGV)
        inspect(path)

    monkeypatch.setattr(hdf5, "_inspect", crashing)
    problems = hdf5.inspect_hdf5_many(paths)
    assert problems[0] is None and problems[2] is None
    assert str(problems[1]) == (f"{paths[1]}: libhdf5 crashed (signal {int(signal.SIGSEGV)}) reading it: a damaged "
                                "HDF5 file")
    with pytest.raises(FormatError, match="libhdf5 crashed"):
        hdf5.inspect_hdf5(paths[1])


def test_the_inspection_reads_every_kind_of_dataset_as_h5py_does(tmp_path, monkeypatch):
    # The inspection opens datasets with h5py's low-level calls and reads plain numeric ones itself (issue 19):
    # what it keeps of a group must be what h5py's high-level reading gives, for every kind of dataset, and a
    # dataset's attributes are still checked.
    import h5py

    path = tmp_path / "kinds.h5"
    with h5py.File(path, "w") as f:
        g = f.create_group("g")
        g["scalar"], g["text"], g["ints"] = 3.5, "hello", np.arange(6, dtype="i2").reshape(2, 3)
        g.create_dataset("empty", shape=(0, 3), dtype="f8")
        g["compound"] = np.zeros(3, dtype=[("a", "f8"), ("b", "i4")])
        g.create_dataset("null", data=h5py.Empty("f8"))
        g["big_endian"] = np.arange(4, dtype=">f8")
        g["ints"].attrs["note"] = "x" * 10
    with hdf5._opened_for_inspection(path) as f:
        kept = hdf5._visit(f, path, {"/g"})["/g"]
        for name, dataset in kept.members.items():
            expected = f["g"][name][()]
            if dataset.read is None:  # a dataset whose declared bytes the file does not store is not read
                assert name == "null"
                continue
            got = dataset.read()
            assert type(got) is type(expected) and np.array_equal(got, expected), name
            if isinstance(got, np.ndarray):
                assert got.dtype == expected.dtype and got.shape == expected.shape, name
    with h5py.File(path, "a") as f:
        f["g"]["ints"].attrs.create("huge", np.zeros(1, dtype="u1"), shape=(1,))
    monkeypatch.setattr(hdf5, "MAX_ATTRIBUTE_BYTES", 0)  # every attribute too large: the first one checked refused
    with hdf5._opened_for_inspection(path) as f, pytest.raises(FormatError, match="attribute 'huge' of /g/ints"):
        hdf5._visit(f, path)
