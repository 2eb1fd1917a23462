"""`brdffit.metrics.fit_metrics` against the formulas of docs/fitting.md written out in NumPy."""

import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import models, synth
from brdffit.metrics import fit_metrics


def _numpy_metrics(model, data):
    f_model = np.asarray(models.evaluate(model, data.theta_i, data.phi_i, data.theta_o, data.phi_o))
    values = data.values
    valid = np.isfinite(values)
    f_data = np.where(valid, values, 0.0)
    c = np.cos(data.theta_i)[:, None]
    w = np.where(valid, (np.ones(data.n) if data.weights is None else data.weights)[:, None], 0.0)
    diff = np.where(valid, f_model - f_data, 0.0)
    positive = valid & (f_data > 0)
    rel = np.where(positive, diff / np.where(positive, f_data, 1.0), 0.0)
    low = np.where(valid, np.log1p(f_model * c) - np.log1p(f_data * c), 0.0)
    return {
        "rmse_abs": np.sqrt(np.sum(diff ** 2, axis=0) / valid.sum(axis=0)),
        "rmse_rel": np.sqrt(np.sum(rel ** 2, axis=0) / positive.sum(axis=0)),
        "ngan": np.sqrt(np.sum(w * (diff * c) ** 2, axis=0) / w.sum(axis=0)),
        "low": np.sqrt(np.sum(w * low ** 2, axis=0) / w.sum(axis=0)),
    }


@pytest.mark.parametrize("n", [1000, 140_001])  # one chunk; three chunks of 65,536 with a padded last one
def test_metrics_match_numpy(n):
    truth = models.get("lambert+ggx", rho_d=[0.3, 0.2, 0.1], ks=[0.5, 0.6, 0.7], alpha=0.2)
    data = synth.generate(truth, pattern="uniform", n=n, noise="relative:0.05", seed=1)
    rng = np.random.default_rng(2)
    values = np.array(data.values)
    values[rng.random(values.shape) < 0.1] = np.nan
    data = data.replace(values=values, weights=rng.uniform(0.5, 2.0, data.n))
    other = truth.replace(alpha=0.25, rho_d=[0.32, 0.2, 0.09])
    got = fit_metrics(other, data)
    want = _numpy_metrics(other, data)
    for name in want:
        assert np.all(want[name] > 0)
        np.testing.assert_allclose(got[name], want[name], rtol=1e-10, err_msg=name)


def test_metric_sums_over_leading_axes_equal_the_sums_of_each_set():
    # The fits sum every point of a pass in one call with leading (material, point) axes; each set's sums must be
    # those of its own call (to rounding: the host sums are BLAS products, whose order of addition may differ
    # between shapes), and those of the compiled sums.
    from brdffit.metrics import metric_sums

    rng = np.random.default_rng(3)
    f = rng.random((3, 4, 700, 3))
    data, valid = rng.random((3, 4, 700, 3)), rng.random((3, 4, 700, 3)) > 0.1
    cos_i, weights = rng.random((3, 4, 700)), rng.random((3, 4, 700))
    together = metric_sums(f, data, valid, cos_i, weights, xp=np)
    assert together.shape == (3, 4, 15, 3)
    for m in range(3):
        for s in range(4):
            np.testing.assert_allclose(together[m, s], metric_sums(f[m, s], data[m, s], valid[m, s], cos_i[m, s],
                                                                   weights[m, s], xp=np), rtol=1e-13)
    np.testing.assert_allclose(together, metric_sums(f, data, valid, cos_i, weights, xp=jnp), rtol=1e-12)
