"""Recovery of a synthetic material by a default fit, shared by the tests of the renderers' layered models."""

import numpy as np

import brdffit
from brdffit import models, synth


def assert_recovered(spec: str, truth_values: dict, noise: float, seed: int, rtol: float = 0.05,
                     atol: float = 0.02):
    """Fit ``spec`` by default to half-diff samples (3,000, relative noise ``noise``) of the truth: the fit must
    converge (on a bound or not), reach the optimum that a fit started at the truth reaches (1e-6 relative) and
    recover every parameter of ``truth_values`` within ``rtol``/``atol``.

    Arguments:
        spec: the model spec; truth_values: its true parameters (the others at their defaults).
        noise: relative noise of the samples; seed: their seed.
        rtol, atol: the tolerances of the parameters.

    Returns:
        ``(data, result)``: the samples and the default fit.
    """
    truth = models.get(spec, **truth_values)
    data = synth.generate(truth, pattern="half-diff", n=3000, noise=f"relative:{noise}", seed=seed)
    result = brdffit.fit(data, spec)
    assert result.status in ("converged", "converged-at-bound"), result.summary()
    from_truth = brdffit.fit(data, spec, init=truth)
    assert result.cost <= from_truth.cost * (1 + 1e-6), (result.summary(), from_truth.summary())
    for name, value in truth_values.items():
        np.testing.assert_allclose(np.asarray(result.params[name]), value, rtol=rtol, atol=atol, err_msg=name)
    return data, result
