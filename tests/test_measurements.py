"""The measurement type: validation with precise errors, immutability, selection helpers."""

import math
import pickle

import numpy as np
import pytest

from brdffit.geometry import spherical_to_vector
from brdffit.measurements import MeasurementError, Measurements, concatenate


def make(n=6, c=3, **kw):
    rng = np.random.default_rng(0)
    args = dict(theta_i=np.linspace(0.0, 1.2, n), phi_i=np.zeros(n), theta_o=np.linspace(0.1, 1.5, n),
                phi_o=np.full(n, math.pi), values=rng.uniform(0.1, 1.0, (n, c)))
    args.update(kw)
    return Measurements(**args)


def test_shapes_defaults_and_wrapping():
    m = Measurements([0.1, 0.2], [-0.1, 7.0], [0.3, 0.4], [2 * math.pi, -1e-300], [0.5, 0.25])
    assert m.values.shape == (2, 1) and m.n == 2 and len(m) == 2 and m.n_channels == 1
    assert m.channels == ("c0",)
    assert m.phi_i[0] == pytest.approx(2 * math.pi - 0.1, abs=1e-15)
    assert m.phi_i[1] == pytest.approx(7.0 - 2 * math.pi, abs=1e-15)
    assert m.phi_o.tolist() == [0.0, 0.0]  # 2π wraps to 0, and so does -1e-300 (np.mod would give 2π)
    assert m.values.dtype == np.float64 and m.sigma is None and m.weights is None and m.meta == {}
    assert make().channels == ("R", "G", "B")
    assert make(c=2).channels == ("c0", "c1")


def test_scalar_angles_broadcast_and_theta_tolerance():
    m = Measurements(math.pi / 2 + 5e-10, 0.0, -5e-10, 1.0, [[1.0, 2.0], [3.0, 4.0]])
    assert m.theta_i.tolist() == [math.pi / 2, math.pi / 2]
    assert m.theta_o.tolist() == [0.0, 0.0]
    assert m.phi_o.tolist() == [1.0, 1.0]


def test_immutable_and_no_aliasing():
    values = np.ones((6, 3))
    m = make(values=values)
    values[0, 0] = 5.0
    assert m.values[0, 0] == 1.0
    with pytest.raises(ValueError):
        m.values[0, 0] = 2.0
    with pytest.raises(AttributeError, match="immutable"):
        m.values = values
    assert not m.theta_i.flags.writeable


@pytest.mark.parametrize("kw, field, row, text", [
    (dict(values=np.array([[0.1], [0.2], [0.3], [-0.5]])), "values", 3, ">= 0"),
    (dict(values=np.array([[0.1], [np.inf], [0.3], [0.5]])), "values", 1, "finite"),
    (dict(theta_i=np.array([0.0, 0.1, 2.0, 0.3])), "theta_i", 2, "pi/2"),
    (dict(theta_o=np.array([0.0, -0.2, 0.2, 0.3])), "theta_o", 1, "pi/2"),
    (dict(phi_o=np.array([0.0, 0.0, 0.0, np.nan])), "phi_o", 3, "finite angle"),
    (dict(sigma=np.array([0.1, 0.0, 0.1, 0.1])), "sigma", 1, "> 0"),
    (dict(weights=np.array([1.0, 1.0, -1.0, 1.0])), "weights", 2, ">= 0"),
])
def test_errors_name_field_row_and_expectation(kw, field, row, text):
    args = dict(theta_i=np.zeros(4), phi_i=np.zeros(4), theta_o=np.zeros(4), phi_o=np.zeros(4),
                values=np.full((4, 1), 0.3))
    args.update(kw)
    with pytest.raises(MeasurementError) as info:
        Measurements(**args)
    err = info.value
    assert (err.field, err.row) == (field, row)
    assert f"row {row}" in str(err) and field in str(err) and text in str(err) and "expected" in str(err)


def test_error_names_file_and_line():
    err = MeasurementError("values", 2, "f_r >= 0", "channel 0 is -1.0;", channel=0)
    moved = err.with_file("x.csv", row_to_line=[4, 5, 9], column="f_r11")
    assert str(moved) == "x.csv: line 9: values (column 'f_r11'): channel 0 is -1.0; expected f_r >= 0"
    assert pickle.loads(pickle.dumps(moved)).row == 9


def test_whole_field_errors():
    with pytest.raises(MeasurementError, match=r"theta_o: got shape \(5,\); expected shape \(6,\)"):
        make(theta_o=np.zeros(5))
    with pytest.raises(MeasurementError, match="sigma"):
        make(sigma=np.ones((6, 2)))
    with pytest.raises(MeasurementError, match="channel names"):
        make(channels=("R", "G"))
    with pytest.raises(MeasurementError, match="unique"):
        make(channels=("R", "R", "B"))
    with pytest.raises(MeasurementError, match="meta"):
        make(meta={"f": object()})
    with pytest.raises(MeasurementError, match="values"):
        make(values=np.ones((2, 2, 2)))


def test_sigma_rules_for_missing_values():
    values = np.array([[0.5, np.nan], [0.5, 0.4]])
    m = Measurements([0, 0], 0, [0, 0], 0, values, sigma=np.array([[0.1, np.nan], [0.1, 0.2]]))
    assert np.isnan(m.sigma[0, 1])
    assert m.valid.tolist() == [[True, False], [True, True]]
    with pytest.raises(MeasurementError, match="row 1") as info:
        Measurements([0, 0], 0, [0, 0], 0, values, sigma=np.array([[0.1, np.nan], [0.1, np.nan]]))
    assert info.value.channel == 1
    # a scalar or per-sample sigma is broadcast across channels
    assert Measurements([0, 0], 0, [0, 0], 0, values, sigma=0.05).sigma.tolist() == [[0.05, 0.05], [0.05, 0.05]]
    assert make(sigma=np.arange(1, 7.0)).sigma[:, 2].tolist() == [1, 2, 3, 4, 5, 6]


def test_meta_is_normalised_json():
    m = make(meta={"truth": {"alpha": np.float64(0.25), "rho": np.array([0.1, 0.2])}, "tags": ("a", "b")})
    assert m.meta == {"truth": {"alpha": 0.25, "rho": [0.1, 0.2]}, "tags": ["a", "b"]}
    assert type(m.meta["truth"]["alpha"]) is float


def test_direction_vectors():
    m = Measurements([0.0, math.pi / 2], [0.0, math.pi / 2], [math.pi / 4, math.pi / 3], [math.pi, 0.0],
                     [1.0, 1.0])
    wi, wo = m.wi(), m.wo()
    np.testing.assert_allclose(wi, [[0, 0, 1], [0, 1, 0]], atol=1e-16)
    s = math.sqrt(0.5)
    np.testing.assert_allclose(wo, [[-s, 0, s], [math.sqrt(3) / 2, 0, 0.5]], atol=1e-16)
    np.testing.assert_allclose(wo, np.asarray(spherical_to_vector(m.theta_o, m.phi_o)), atol=1e-15)


def test_select_channels():
    m = make(sigma=0.1)
    g = m.select_channels("G")
    assert g.channels == ("G",) and np.array_equal(g.values[:, 0], m.values[:, 1]) and g.sigma.shape == (6, 1)
    mixed = m.select_channels(["B", 0])
    assert mixed.channels == ("B", "R") and np.array_equal(mixed.values, m.values[:, [2, 0]])
    assert m.select_channels(1).channels == ("G",)
    with pytest.raises(KeyError, match="channels are R, G, B"):
        m.select_channels("X")
    with pytest.raises(KeyError):
        m.select_channels(3)


def test_select_angles():
    m = make(n=7)  # theta_i = 0, 0.2, ..., 1.2 ; theta_o = 0.1 ... 1.5
    assert m.select_angles(max_theta_i=0.5).theta_i.tolist() == pytest.approx([0.0, 0.2, 0.4])
    assert m.select_angles(min_theta_o=1.0).n == 3
    near = m.select_angles(max_theta_o=40, degrees=True)
    assert np.all(near.theta_o <= math.radians(40)) and near.n == 3
    assert m.select_angles(min_theta_i=0.3, max_theta_i=0.9).n == 3


def test_subsample_random_is_reproducible_and_ordered():
    m = make(n=100)
    a, b = m.subsample(10, seed=3), m.subsample(10, seed=3)
    assert a.n == 10 and np.array_equal(a.theta_i, b.theta_i)
    assert np.all(np.diff(a.theta_i) > 0)  # original order kept
    assert not np.array_equal(a.theta_i, m.subsample(10, seed=4).theta_i)
    assert m.subsample(100) is m and m.subsample(500) is m
    with pytest.raises(ValueError):
        m.subsample(0)


def test_subsample_stratified_keeps_each_incidence_share():
    theta_i = np.repeat(np.radians([0, 15, 30, 45, 60, 75]), 50)
    n = theta_i.size
    m = Measurements(theta_i, 0.0, np.tile(np.linspace(0, 1.4, 50), 6), 0.0, np.ones(n))
    sub = m.subsample(60, seed=1, stratified=True)
    assert sub.n == 60
    _, counts = np.unique(sub.theta_i, return_counts=True)
    assert counts.tolist() == [10] * 6
    # and within each incidence angle each of the 4 equal-count θo bins gets its 2.5 share (2 or 3)
    edges = np.quantile(m.theta_o, [0.25, 0.5, 0.75])
    for t in np.unique(theta_i):
        bins = np.bincount(np.searchsorted(edges, sub.theta_o[sub.theta_i == t], side="right"), minlength=4)
        assert set(bins.tolist()) <= {2, 3}


def test_split():
    m = make(n=50)
    train, test = m.split(0.2, seed=5)
    assert (train.n, test.n) == (40, 10)
    both = np.sort(np.concatenate([train.theta_i, test.theta_i]))
    assert np.array_equal(both, m.theta_i)
    assert np.array_equal(m.split(0.2, seed=5)[1].theta_i, test.theta_i)
    assert make(n=3).split(0.01)[1].n == 1
    with pytest.raises(ValueError):
        m.split(1.0)


def test_replace_take_concatenate_pickle_repr():
    m = make(sigma=0.1, weights=np.ones(6), meta={"source": "x.csv"})
    r = m.replace(sigma=None)
    assert r.sigma is None and r.weights is not None and m.sigma is not None
    with pytest.raises(MeasurementError):
        m.replace(values=-m.values)
    with pytest.raises(TypeError, match="no field"):
        m.replace(colour=1)
    t = m.take([4, 1])
    assert np.array_equal(t.values, m.values[[4, 1]])
    assert m.take(m.theta_i > 0.5).n == 3
    joined = concatenate([t, m])
    assert joined.n == 8 and joined.sigma.shape == (8, 3)
    back = pickle.loads(pickle.dumps(m))
    assert np.array_equal(back.values, m.values) and back.meta == m.meta and not back.values.flags.writeable
    assert repr(m) == "Measurements(n=6, channels=('R', 'G', 'B'), with=sigma+weights, source='x.csv')"
