"""The shared-moment pass (`brdffit.fitting.moments`): its normal equations equal those of the tangents' pass
(`brdffit.fitting.normal_equations.accumulate`) for every lobe, and it applies only where its assumptions hold."""

import numpy as np
import pytest

from brdffit import models, synth
from brdffit.fitting import moments
from brdffit.fitting.api import _prepare
from brdffit.fitting.losses import loss_epsilon
from brdffit.fitting.normal_equations import accumulate
from brdffit.fitting.problem import make_fit_data, stack_data


def _setup(spec, loss, n=300, fixed=None, pad=False):
    model = models.get(spec)
    data = synth.generate(model, n=n, noise="relative:0.05", seed=4)
    values = np.array(data.values)
    values[::5, 2] = np.nan  # a mask that differs between channels
    data = data.replace(values=values)
    problem, base, fixed_values, _ = _prepare(data, spec, loss=loss, solver="lm", fixed=fixed, free=None,
                                              robust=None, max_steps=10, rtol=1e-8, atol=1e-12)
    fit_data = make_fit_data(data, fixed_values, loss_epsilon(loss, data.values), pad=pad, device=False)
    return problem, base, stack_data([fit_data, fit_data])


def _points(problem, base, count, seed):
    """``count`` points per material around the model's values (amplitudes differ between channels)."""
    rng = np.random.default_rng(seed)
    trees = {}
    for name in problem.free:
        spec = problem.specs[name]
        value = np.broadcast_to(np.asarray(base.params[name], dtype=float), (2, count) + problem.layout[name].shape)
        scale = rng.uniform(0.7, 1.3, value.shape)
        trees[name] = np.clip(value * scale, spec.lower, spec.upper) if spec.linear or spec.scale else value
    return trees


# Beside every lobe: a shared parameter, two amplitudes in one lobe, a fixed amplitude beside a free one in the same
# lobe (its part is f₀'s, not the free one's column: `brdffit.fitting.separable.adds_to_offset`), padded samples.
def _moments_apply(name: str) -> bool:
    """Whether the moments serve a lobe beside Lambert: it needs an outer (shape) parameter (Lambert + sheen has
    none: no passes), and colour parameters that are amplitudes (principled's base colour also enters its Fresnel
    term, a per-channel value, like a conductor's η: `test_the_moments_do_not_apply_where_a_channel_has_its_own_values`)."""
    specs = models.lobe_class(name)().param_specs()
    return any(not s.colour and not s.fixed for s in specs) and all(s.linear or not s.colour for s in specs)


CASES = ([(f"lambert+{n}", None, False) for n in models.names() if n != "lambert" and _moments_apply(n)]
         + [("lambert+ggx+ggx(share=f0)", None, False), ("lambert+lafortune(lobes=2)", None, False),
            ("lambert+toon-diffuse", {"rho_shade": 0.2}, False), ("lambert+lafortune(lobes=2)", {"ks_2": 0.3}, False),
            ("lambert+ggx", None, True)])


@pytest.mark.parametrize("loss", ["cosine", "relative"])
@pytest.mark.parametrize("spec, fixed, pad", CASES)
def test_the_moments_give_the_normal_equations_of_the_tangents(spec, fixed, pad, loss):
    problem, base, data = _setup(spec, loss, fixed=fixed, pad=pad)
    assert moments.applies(problem, {k: np.asarray(v) for k, v in data.fixed.items()})
    trees = _points(problem, base, 3, seed=len(spec))
    materials = np.array([0, 1])
    ours = moments.moment_sums(problem, trees, [data], materials)
    theirs = accumulate(problem, trees, [data], meat=False, materials=materials)
    scale = np.sqrt(np.abs(np.einsum("...ii->...i", theirs.jtj)))
    for field in ("jtj", "jtr", "cost", "channel_cost"):
        mine, reference = getattr(ours, field), getattr(theirs, field)
        if field == "jtj":  # relative to the columns' norms: entries of near-orthogonal columns cancel
            mine, reference = mine / (scale[..., :, None] * scale[..., None, :]), \
                reference / (scale[..., :, None] * scale[..., None, :])
        np.testing.assert_allclose(mine, reference, rtol=1e-9, atol=1e-12 * float(np.max(np.abs(reference))),
                                   err_msg=field)


def test_the_moments_do_not_apply_where_a_channel_has_its_own_values():
    # A free conductor's η and k differ between channels in the polish; a fixed diffuse colour does as a value;
    # the log loss's residual is not linear in the model.
    problem, _, data = _setup("lambert+cook-torrance(fresnel=conductor)", "cosine")
    assert not moments.applies(problem, {})
    problem, _, data = _setup("lambert+ggx", "cosine", fixed={"rho_d": [0.1, 0.2, 0.3]})
    assert not moments.applies(problem, {k: np.asarray(v) for k, v in data.fixed.items()})
    problem, _, data = _setup("lambert+ggx", "cosine", fixed={"rho_d": 0.2})
    assert moments.applies(problem, {k: np.asarray(v) for k, v in data.fixed.items()})
    problem, _, data = _setup("lambert+principled", "cosine")
    assert not moments.applies(problem, {k: np.asarray(v) for k, v in data.fixed.items()})
    problem, _, _ = _setup("lambert+ggx", "log")
    assert not moments.applies(problem, {})


def test_a_fit_many_batch_steps_with_the_moments_and_answers_as_fits_one_by_one(monkeypatch):
    from brdffit import fit, fit_many
    from brdffit.fitting import marquardt

    calls = []
    counted = marquardt.moment_sums
    monkeypatch.setattr(marquardt, "moment_sums", lambda *a, **k: calls.append(1) or counted(*a, **k))
    sets = [synth.generate(models.get("lambert+ggx", alpha=0.1 + 0.1 * k, f0=0.04 + 0.1 * k), n=400,
                           noise="relative:0.01", seed=k) for k in range(3)]
    together = fit_many(sets, "lambert+ggx")
    assert calls  # three materials of four starts: a compact batch
    monkeypatch.setattr(marquardt, "moment_sums", counted)
    for data, batched in zip(sets, together):
        alone = fit(data, "lambert+ggx")
        assert batched.status == alone.status and batched.cost == pytest.approx(alone.cost, rel=1e-10)
        for name in alone.params:
            np.testing.assert_allclose(batched.params[name], alone.params[name], rtol=1e-6, atol=1e-10)
        for name in alone.stderr:
            np.testing.assert_allclose(batched.stderr[name], alone.stderr[name], rtol=1e-4)


def test_a_fit_many_with_a_fixed_amplitude_beside_a_free_one_answers_as_fits_one_by_one():
    # A toon lobe's rho_shade fixed at 0.2 beside its free rho_d_2: the moment passes see the fixed part in f₀.
    from brdffit import fit, fit_many

    truth = models.get("lambert+toon-diffuse", rho_shade=0.2)
    sets = [synth.generate(truth.replace(threshold=0.3 + 0.1 * k), n=400, noise="relative:0.01", seed=k)
            for k in range(3)]
    together = fit_many(sets, "lambert+toon-diffuse", fixed={"rho_shade": 0.2})
    for data, batched in zip(sets, together):
        alone = fit(data, "lambert+toon-diffuse", fixed={"rho_shade": 0.2})
        assert batched.status == alone.status
        assert batched.cost == pytest.approx(alone.cost, rel=1e-8)
