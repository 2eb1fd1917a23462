"""Property tests: on garbage input the readers succeed or raise FormatError / MeasurementError, nothing else."""

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import brdffit.io as bio
from brdffit.io import FormatError
from brdffit.measurements import MeasurementError, Measurements

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
EXPECTED = (FormatError, MeasurementError)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def load_or_fail_cleanly(path, **options):
    try:
        m = bio.load(path, **options)
    except EXPECTED as err:
        assert str(path) in str(err)  # every error names the file
        return None
    assert isinstance(m, Measurements)
    return m


def saved_text(workdir, m: Measurements, name: str, **options) -> str:
    """The text of ``m`` saved as ``name`` (its extension choosing the format)."""
    path = workdir / name
    bio.save(m, path, **options)
    return path.read_text()


def damaged_and_truncated(path, text: str, cut: int, start: int, junk: str) -> None:
    """Write ``text`` with ``junk`` put in at ``start`` over up to 30 characters, then ``text`` cut anywhere, and read
    each: they load or fail cleanly."""
    start %= len(text) + 1
    path.write_text(text[:start] + junk + text[start + cut % 30:])
    load_or_fail_cleanly(path)
    path.write_text(text[: cut % (len(text) + 1)])  # truncated anywhere
    load_or_fail_cleanly(path)


@FUZZ
@given(data=st.binary(max_size=400),
       ext=st.sampled_from([".csv", ".tsv", ".txt", ".binary", ".h5", ".alta", ".astm", ".bsdf", ""]))
def test_random_bytes(workdir, data, ext):
    path = workdir / f"garbage{ext}"
    path.write_bytes(data)
    load_or_fail_cleanly(path)


TABLE_ALPHABET = "0123456789.,;-+eE \t\n#naif_xsgmthop\"'"


@FUZZ
@given(text=st.text(alphabet=TABLE_ALPHABET, max_size=300))
def test_random_table_text(workdir, text):
    path = workdir / "table.csv"
    path.write_text(text)
    load_or_fail_cleanly(path)


def _canonical_text(workdir) -> str:
    m = Measurements(np.radians([0, 30, 60]), 0.0, np.radians([10, 40, 70]), np.pi, [[0.1, 0.2], [0.3, np.nan],
                                                                                      [0.5, 0.6]],
                     sigma=0.01, weights=[1.0, 2.0, 3.0], channels=("a", "b"), meta={"k": [1, 2]})
    return saved_text(workdir, m, "canonical.csv")


@FUZZ
@given(cut=st.integers(0, 10_000), start=st.integers(0, 10_000), junk=st.text(alphabet=TABLE_ALPHABET, max_size=20))
def test_damaged_canonical_tables(workdir, cut, start, junk):
    damaged_and_truncated(workdir / "damaged.csv", _canonical_text(workdir), cut, start, junk)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 100_000), flip=st.integers(0, 100_000), byte=st.integers(0, 255))
def test_damaged_hdf5(workdir, cut, flip, byte):
    path = workdir / "m.h5"
    m = Measurements(np.radians([0, 30, 60]), 0.0, np.radians([10, 40, 70]), np.pi, [0.1, 0.2, 0.3])
    bio.save(m, path)
    data = bytearray(path.read_bytes())
    data[flip % len(data)] = byte
    path.write_bytes(bytes(data))
    load_or_fail_cleanly(path)
    path.write_bytes(bytes(data[: cut % len(data)]))
    load_or_fail_cleanly(path)


@FUZZ
@given(tail=st.binary(max_size=200))
def test_merl_header_with_garbage(workdir, tail):
    path = workdir / "m.binary"
    path.write_bytes(np.asarray([90, 90, 180], "<i4").tobytes() + tail)
    with pytest.raises(FormatError, match="truncated"):
        bio.load(path)


ALTA_ALPHABET = "0123456789.-+eE \t\n#nafDIMPARM_INOUTVSCSLRGB"
ALTA_HEADERS = ["#DIM 4 1\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n", "#DIM 3 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n",
                "#DIM 3 1\n#PARAM_IN RUSIN_TH_TD_PD\n#PARAM_OUT INV_STERADIAN_COSINE_FACTOR\n",
                "#DIM 6 3\n#PARAM_IN CARTESIAN\n#PARAM_OUT RGB_COLOR\n#VS 2\n", ""]


@FUZZ
@given(header=st.sampled_from(ALTA_HEADERS), text=st.text(alphabet=ALTA_ALPHABET, max_size=300))
def test_random_alta_text(workdir, header, text):
    path = workdir / "random.alta"
    path.write_text(header + text)
    load_or_fail_cleanly(path)


def _alta_text(workdir, param_in) -> str:
    m = Measurements(np.radians([0, 30, 60]), [0.0, 1.0, 2.0], np.radians([10, 40, 70]), np.pi,
                     [[0.1, 0.2, 0.3], [0.3, 0.4, 0.5], [0.5, 0.6, 0.7]], sigma=0.01, meta={"alta": {"header": {
                         "URL": "https://example.org"}}})
    return saved_text(workdir, m, "valid.alta", param_in=param_in)


@FUZZ
@given(param_in=st.sampled_from(["SPHERICAL_TL_PL_TV_PV", "CARTESIAN", "ISOTROPIC_TL_TV_PROJ_DPHI",
                                 "RUSIN_TH_TD_PD"]),
       cut=st.integers(0, 10_000), start=st.integers(0, 10_000), junk=st.text(alphabet=ALTA_ALPHABET, max_size=20))
def test_damaged_alta_files(workdir, param_in, cut, start, junk):
    # A .dat file: the content decides between ALTA and table.
    damaged_and_truncated(workdir / "damaged.dat", _alta_text(workdir, param_in), cut, start, junk)


ASTM_ALPHABET = "0123456789.,-+eE \t\nnaNUM_POINTSVARthe_isopRGBm\""


def _astm_text(workdir) -> str:
    m = Measurements(np.radians([0, 30, 60]), 0.0, np.radians([10, 40, 70]), np.pi,
                     [[0.1, np.nan, 0.3], [0.3, 0.4, 0.5], [0.5, 0.6, 0.7]], channels=["400nm", "500nm", "600nm"],
                     meta={"astm": {"header": {"SAMPLE_NAME": "fuzzed paint"}}})
    return saved_text(workdir, m, "valid.astm")


@FUZZ
@given(cut=st.integers(0, 10_000), start=st.integers(0, 10_000), junk=st.text(alphabet=ASTM_ALPHABET, max_size=20))
def test_damaged_astm_files(workdir, cut, start, junk):
    # A .txt file: the content decides between ASTM E1392 and a table.
    damaged_and_truncated(workdir / "damaged.txt", _astm_text(workdir), cut, start, junk)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 100_000), header_flip=st.integers(0, 100_000), flip=st.integers(0, 100_000),
       byte=st.integers(0, 255), other=st.integers(0, 255))
# A field's extent damaged to 1.1e19 beside a zero one: no data, so the size check passed, and NumPy refused the
# reshape with its own message ("Maximum allowed dimension exceeded") instead of a FormatError naming the file.
@example(cut=0, header_flip=13950, flip=111, byte=0, other=29)
def test_damaged_rgl_files(workdir, cut, header_flip, flip, byte, other):
    from test_io_rgl import small_rgl_bytes

    valid = small_rgl_bytes()
    data = bytearray(valid)
    data[header_flip % 400] = byte  # the header (names, ranks, types, offsets, extents) is the first ~390 bytes
    data[flip % len(data)] = other
    path = workdir / "damaged.bsdf"
    path.write_bytes(bytes(data))
    load_or_fail_cleanly(path)
    path.write_bytes(valid[: cut % len(valid)])  # truncated anywhere
    with pytest.raises(FormatError, match="truncated|outside the file") as err:
        bio.load(path)
    assert str(path) in str(err.value)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=st.integers(0, 10**12), written=st.integers(0, 64), chunk=st.integers(1, 4096),
       gzip=st.booleans())
def test_hdf5_declared_sizes(workdir, rows, written, chunk, gzip):
    """Datasets declaring any number of rows (fill values beyond the written ones): read or refused, in bounded
    time, never allocated beyond what the file stores (issue 20)."""
    import time

    import h5py

    from brdffit.io import hdf5

    path = workdir / "declared.h5"
    written = min(written, rows)
    with h5py.File(path, "w") as f:
        f.attrs["format_version"] = hdf5.FORMAT_VERSION
        g = f.create_group("measurements")
        for name, width in (("theta_i", None), ("phi_i", None), ("theta_o", None), ("phi_o", None), ("values", 1)):
            shape = (rows,) if width is None else (rows, width)
            d = g.create_dataset(name, shape=shape, dtype="f8", chunks=(chunk,) + shape[1:], maxshape=(None,) +
                                 shape[1:], fillvalue=0.1, compression="gzip" if gzip else None)
            if written:
                d[:written] = 0.2
    start = time.perf_counter()
    m = load_or_fail_cleanly(path)
    # A hang guard (a dataset's fill values read or allocated row by row would take hours at 10**12 rows), not a
    # speed target: a load takes 10-30 ms here, 0.7 s for all 25 examples; 15 s is hundreds of times that.
    assert time.perf_counter() - start < 15
    if m is not None:
        assert m.n == rows and rows * 8 <= hdf5.MAX_DATASET_BYTES


def test_cli_on_mutated_files_in_a_memory_limited_child(workdir):
    """`brdffit info` on 40 mutated files of every format, in one child process limited to 4 GiB of address space:
    each exits 0 or 2, with no traceback (issue 20)."""
    import resource
    import subprocess
    import sys

    rng = np.random.default_rng(20)
    m = Measurements(np.radians([0, 30, 60]), 0.0, np.radians([10, 40, 70]), np.pi, [[0.1, 0.2], [0.3, 0.4],
                                                                                      [0.5, 0.6]], sigma=0.01)
    sources = []
    for ext in (".csv", ".h5", ".alta"):
        bio.save(m, workdir / f"source{ext}")
        sources.append(workdir / f"source{ext}")
    sources.append(workdir / "source.binary")
    sources[-1].write_bytes(np.asarray([90, 90, 180], "<i4").tobytes() + rng.bytes(500))
    files = []
    for k in range(40):
        source = sources[k % len(sources)]
        data = bytearray(source.read_bytes())
        for _ in range(int(rng.integers(1, 6))):
            data[int(rng.integers(len(data)))] = int(rng.integers(256))
        if k % 3 == 0:
            data = data[: int(rng.integers(len(data) + 1))]
        path = workdir / f"mutated{k}{source.suffix}"
        path.write_bytes(bytes(data))
        files.append(str(path))
    script = ("import sys; from brdffit.cli import main; "
              "print(' '.join(str(main(['info', f])) for f in sys.argv[1:]))")

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))

    done = subprocess.run([sys.executable, "-c", script, *files], capture_output=True, text=True, timeout=300,
                          preexec_fn=limit)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    codes = done.stdout.split()[-len(files):]
    assert set(codes) <= {"0", "2"} and len(codes) == len(files) and "2" in codes
    assert done.stderr.count("brdffit info: error: ") == codes.count("2")
