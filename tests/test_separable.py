"""The separable core (`brdffit.fitting.separable`) and the parts of the engine declared once: amplitude
declarations, the bounded amplitude solve, the loss registry and the status ranking."""

import math

import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from scipy.optimize import lsq_linear

from brdffit import fit, models, synth
from brdffit.fitting.losses import LOSSES, loss_table
from brdffit.fitting.separable import _enumerate_box_qp, box_patterns, solve_box
from brdffit.fitting.status import STATUSES, Status
from brdffit.geometry import LocalPair, spherical_to_vector


def _pair(n=200, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((4, n))
    wi = spherical_to_vector(np.arccos(u[0]) * 0.98, 2 * np.pi * u[1])
    wo = spherical_to_vector(np.arccos(u[2]) * 0.98, 2 * np.pi * u[3])
    return LocalPair.from_dirs(jnp.asarray(wi), jnp.asarray(wo))


@pytest.mark.parametrize("name", models.names())
def test_declared_linear_amplitudes_are_affine_and_the_others_are_not_claimed(name):
    # A parameter declared linear must enter every lobe affinely, channel by channel: f(a) = f(0) + a (f(1) −
    # f(0)) for a = 0.37 and 2.5, each channel on its own (the separable solve relies on it).
    lobe = models.lobe_class(name)()
    pair = _pair()
    base = {spec.name: spec.initial(3) for spec in lobe.param_specs()}
    for spec in lobe.param_specs():
        if not spec.linear:
            continue
        assert spec.colour, spec.name

        def value(a, spec=spec):
            return np.asarray(jnp.broadcast_to(lobe(dict(base, **{spec.name: jnp.asarray(a)}), pair), (200, 3)))

        f0, f1 = value(np.zeros(3)), value(np.ones(3))
        for a in (0.37, 2.5):
            np.testing.assert_allclose(value(np.array([a, 0.0, 1.0])), f0 + np.array([a, 0.0, 1.0]) * (f1 - f0),
                                       rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("name", models.names())
def test_a_lobe_without_a_declared_offset_is_zero_with_its_amplitudes_at_zero(name):
    # amplitude_basis does not evaluate a lobe at zero amplitudes unless it declares an offset (Lobe.offset):
    # the declaration must hold exactly, at the defaults and at random values of the other parameters, and a
    # declared offset must be real (not a stale declaration that only costs time).
    lobe = models.lobe_class(name)()
    pair = _pair()
    rng = np.random.default_rng(1)
    amplitudes = [spec.name for spec in lobe.param_specs() if spec.linear]
    largest = 0.0
    for trial in range(3):
        params = {}
        for spec in lobe.param_specs():
            value = np.asarray(spec.initial(3))
            if trial and not spec.linear:  # within the bounds, around the default
                value = np.clip(value * rng.uniform(0.5, 1.5), spec.lower, spec.upper)
            params[spec.name] = jnp.asarray(0.0 * value if spec.linear else value)
        largest = max(largest, float(np.max(np.abs(np.asarray(lobe(params, pair))))))
    if not amplitudes:
        return
    if lobe.offset:
        assert largest > 0.0
    else:
        assert largest == 0.0


def test_the_amplitude_declarations_are_the_ones_the_engine_projects():
    declared = {s.name for lobe in models.names() for s in models.lobe_class(lobe)().param_specs() if s.linear}
    assert declared == ({"rho_d", "ks", "rs", "rho_shade", "A", "base_color", "reflectance", "diffuse_reflectance",
                         "specular_reflectance"} | {f"ks_{j}" for j in (1,)})
    conductor = models.get("cook-torrance(fresnel=conductor)").param_specs
    assert not conductor["eta"].linear and not conductor["k"].linear  # colour, but not affine


@pytest.mark.parametrize("seed", range(12))
def test_bounded_amplitude_solve_matches_scipy_bvls(seed):
    # The exact active-set enumeration against scipy's bounded-variable least squares (Stark & Parker 1995) on
    # the same problem written as ‖A a − y‖²: random sizes, bounds finite, one-sided or absent.
    rng = np.random.default_rng(seed)
    k = int(rng.integers(1, 5))
    a = rng.standard_normal((30, k)) * rng.uniform(0.01, 10.0, k)
    if k > 1 and seed % 3 == 0:
        a[:, -1] = a[:, 0] * 2.0 + 1e-3 * rng.standard_normal(30)  # nearly collinear columns
    y = rng.standard_normal(30) * 3.0
    lower = rng.choice([0.0, -1.0, -np.inf], k)
    upper = np.where(rng.random(k) < 0.5, np.inf, np.where(np.isfinite(lower), lower, 0.0) + 1.0)
    got = solve_box(a.T @ a, a.T @ y, lower, upper)
    want = lsq_linear(a, y, bounds=(lower, upper), method="bvls", tol=1e-14).x
    cost = lambda x: float(np.sum((a @ x - y) ** 2))  # noqa: E731
    assert np.all(got >= lower - 1e-12) and np.all(got <= upper + 1e-12)
    assert cost(got) <= cost(want) * (1 + 1e-9) + 1e-12


def test_batched_bounded_solve_equals_the_enumeration_inside_near_and_beyond_the_bounds():
    # solve_box solves the unconstrained system first and enumerates only where its optimum is not clearly inside
    # the box; on a batch of systems with optima inside, on (within 1e-12) and beyond their bounds it must give
    # the enumeration's answers bit for bit (the enumeration itself against BVLS: the test above).
    rng = np.random.default_rng(7)
    basis = rng.standard_normal((400, 40, 2)) * np.array([1.0, 0.05])
    target = rng.uniform(-0.5, 1.5, (400, 2))
    target[:50, 1] = rng.uniform(0.0, 1e-13, 50)  # optima just inside the lower bound 0 of the second amplitude
    y = np.einsum("bnk,bk->bn", basis, target) + 1e-3 * rng.standard_normal((400, 40))
    y[:50] = np.einsum("bnk,bk->bn", basis[:50], target[:50])
    gram, rhs = np.einsum("bnk,bnl->bkl", basis, basis), np.einsum("bnk,bn->bk", basis, y)
    lower, upper = np.array([0.0, 0.0]), np.array([1.0, np.inf])
    got = solve_box(gram, rhs, lower, upper)
    want = _enumerate_box_qp(gram, rhs, lower, upper, box_patterns((0.0, 0.0), (1.0, np.inf)), xp=np)[0]
    np.testing.assert_array_equal(got, want)
    inside = np.all((target > 0.01) & (target < [0.99, np.inf]), axis=-1)
    assert 100 < inside.sum() < 350  # the batch holds both kinds
    assert np.any(got[:50, 1] == 0.0)  # the near-bound optima went to the enumeration, which held some at 0


def test_box_patterns_enumerate_every_active_set():
    patterns = box_patterns((0.0, -math.inf, 0.0), (1.0, math.inf, math.inf))
    assert patterns.shape == (3 * 1 * 2, 3)
    assert {tuple(p) for p in patterns} == {(f, 0, g) for f in (0, 1, 2) for g in (0, 1)}


def test_lambert_is_one_linear_solve_with_the_closed_form_answer():
    # Cosine loss, ρ/π against f with weights c² w: ρ = π Σ c² w f / Σ c² w per channel (normal equations of one
    # unknown), inside the bounds here.
    truth = models.get("lambert", rho_d=[0.2, 0.5, 0.8])
    data = synth.generate(truth, pattern="uniform", n=800, noise="relative:0.05", seed=1)
    result = fit(data, "lambert")
    c2w = np.cos(data.theta_i)[:, None] ** 2 * (1.0 if data.weights is None else data.weights[:, None])
    closed = np.pi * np.sum(c2w * data.values, axis=0) / np.sum(c2w * np.ones_like(data.values), axis=0)
    assert result.steps == 0 and result.status == "converged"
    np.testing.assert_allclose(result.params["rho_d"], closed, rtol=1e-10)


def test_an_amplitude_the_data_push_below_zero_ends_exactly_on_its_bound():
    # A diffuse-free glossy material fitted with lambert + ward: the best ρd is negative, so its bound is active
    # and the projection puts it exactly at 0 (no transform approaching it without end).
    truth = models.get("ward", ks=[0.5, 0.4, 0.3], alpha=0.2)
    data = synth.generate(truth, pattern="half-diff", n=1500, noise="relative:0.01", seed=2)
    result = fit(data, "lambert+ward")
    assert result.status == "converged-at-bound"
    assert np.any(np.asarray(result.params["rho_d"]) == 0.0)
    assert all(label.startswith("rho_d") for label in result.bounds_hit)


def test_independent_channels_rank_every_status():
    # Every status is ranked (independent-channel fits report the worst), and a careless solver's stall is
    # reported.
    assert [Status(name).severity for name in STATUSES] == list(range(len(STATUSES)))
    assert Status.worst(["converged", "stalled", "converged-at-bound"]) == "stalled"
    truth = models.get("lambert+cook-torrance", rho_d=[0.3, 0.2, 0.1], ks=[0.8, 0.7, 0.6], m=0.15, f0=0.04)
    data = synth.generate(truth, pattern="half-diff", n=1000, noise="relative:0.01", seed=0)
    careless = optx.BFGS(rtol=0.5, atol=0.5)
    result = fit(data, "lambert+cook-torrance", fixed={"f0": 0.04}, solver=careless, init="model",
                 channel_mode="independent")
    assert result.status == "stalled"


def test_the_loss_table_in_the_docs_is_generated_from_the_registry():
    import pathlib

    root = pathlib.Path(__file__).resolve().parent.parent
    assert loss_table() in (root / "docs" / "fitting.md").read_text(encoding="utf-8"), \
        "docs/fitting.md's loss table is stale: paste brdffit.fitting.losses.loss_table()"
    cli = (root / "docs" / "cli.md").read_text(encoding="utf-8")
    for name in LOSSES:
        assert f"`{name}`" in cli


def test_a_negligible_basis_column_keeps_its_amplitude_on_the_lower_bound():
    """A basis column of squared norm 1e-320 (a denormal: a lobe that no sample sees) gets amplitude 0, and the
    other amplitude is the one-column least-squares answer b₀/G₀₀; with the column at 1e-20 both are solved
    (`_NEGLIGIBLE_COLUMN` = 1e-200)."""
    rhs = np.array([2.0, 1e-160])
    tiny = solve_box(np.array([[4.0, 0.0], [0.0, 1e-320]]), rhs, [0.0, 0.0], [1.0, np.inf])
    assert tiny[1] == 0.0
    np.testing.assert_allclose(tiny[0], 0.5, rtol=1e-12)  # the ridge's 1e-13
    small = solve_box(np.array([[4.0, 0.0], [0.0, 1e-20]]), np.array([2.0, 1e-10]), [0.0, 0.0], [1.0, np.inf])
    np.testing.assert_allclose(small, [0.5, 1e10], rtol=1e-9)


def test_a_spike_between_the_samples_does_not_win_the_search():
    """Lambert + Ward data on 300 uniform samples: the search's candidate at α = 0.002 (a spike no sample sees)
    was solved to ks = 4e158 at a cost that rounding made 0; it won, and the fit ended 'converged' at a cost of
    10 against 0.00645 for the truth's basin. The fit now reaches the basin of a start at the truth."""
    truth = models.get("lambert+ward", rho_d=0.3, ks=0.4, alpha=0.15, channels=1)
    data = synth.generate(truth, pattern="uniform", n=300, noise="gaussian:0.01", seed=1013)
    result = fit(data, "lambert+ward")
    reference = fit(data, "lambert+ward", init="model")
    assert result.status == "converged", result.summary()
    np.testing.assert_allclose(result.cost, reference.cost, rtol=1e-6)
    np.testing.assert_allclose(result.params["alpha"], 0.15, rtol=0.05)


@pytest.mark.parametrize("loss", ["cosine", "relative"])
@pytest.mark.parametrize("name", models.names() + ["cook-torrance(fresnel=conductor)"])
def test_the_shared_basis_sums_equal_the_per_channel_ones(name, loss):
    # The search's amplitude sums with the basis evaluated for one channel (every other colour parameter has one
    # value in all channels) equal the sums of the per-channel weighted basis: with a channel's samples partly
    # missing (a mask that differs between channels) and a loss whose weights differ between channels.
    from brdffit.fitting.api import _prepare
    from brdffit.fitting.losses import loss_epsilon
    from brdffit.fitting.problem import make_fit_data
    from brdffit.fitting.separable import amplitude_sums

    spec = name if name == "lambert" else f"lambert+{name}"
    model = models.get(spec)
    data = synth.generate(model, n=300, noise="relative:0.05", seed=3)
    values = np.array(data.values)
    values[::7, 1] = np.nan
    data = data.replace(values=values)
    problem, base, fixed, _ = _prepare(data, spec, loss=loss, solver="lm", fixed=None, free=None, robust=None,
                                       max_steps=10, rtol=1e-8, atol=1e-12)
    fit_data = make_fit_data(data, fixed, loss_epsilon(loss, data.values))
    params = {k: jnp.asarray(v, dtype=float) for k, v in base.params.items()}
    sums = [amplitude_sums(problem, params, problem.linear, fit_data, shared=shared) for shared in (False, True)]
    for per_channel, shared in zip(*sums):
        np.testing.assert_allclose(shared, per_channel, rtol=1e-10, atol=1e-12 * float(jnp.max(jnp.abs(per_channel))))


def test_a_search_with_colour_values_that_differ_between_channels_scores_each_channel_with_its_own():
    # A fixed diffuse colour is part of f₀ and differs between channels: the search must not evaluate one
    # channel's basis for all (`brdffit.fitting.search._channel_shared`). Its best start lies within a grid cell
    # (a factor 1.54 of α) of the truth; scored with channel 0's f₀ in every channel it started at α = 0.9.
    truth = models.get("lambert+ggx", rho_d=[0.1, 0.4, 0.8], ks=[0.3, 0.2, 0.1], alpha=0.3, f0=0.04)
    data = synth.generate(truth, n=2000, noise="relative:0.001", seed=5)
    result = fit(data, "lambert+ggx", fixed={"rho_d": [0.1, 0.4, 0.8], "f0": 0.04})
    assert result.status == "converged", result.summary()
    assert 0.3 / 1.6 < result.starts[0]["init"]["alpha"] < 0.3 * 1.6, result.starts
    np.testing.assert_allclose(result.params["alpha"], 0.3, rtol=2e-3)
    np.testing.assert_allclose(result.params["ks"], [0.3, 0.2, 0.1], rtol=5e-3)


@pytest.mark.parametrize("spec, fixed", [("lambert+toon-diffuse", {"rho_shade": 0.2}),
                                         ("lambert+lafortune(lobes=2)", {"ks_2": 0.3}),
                                         ("lambert+ashikhmin-shirley", {"rs": 0.1})])
def test_the_affine_decomposition_reproduces_the_model_with_a_fixed_amplitude_beside_a_free_one(spec, fixed):
    # f₀ + B a equals the model: a lobe's fixed amplitude adds its part to f₀ (`adds_to_offset`); the free one's
    # column held it before (2026-12-04), which misled the search and a fit_many's moment passes.
    from brdffit.fitting.api import _prepare
    from brdffit.fitting.losses import loss_epsilon
    from brdffit.fitting.problem import make_fit_data
    from brdffit.fitting.separable import amplitude_basis
    from brdffit.models.model import evaluate_pair

    model = models.get(spec, **fixed)
    data = synth.generate(model, n=200, seed=2)
    problem, base, fixed_values, _ = _prepare(data, spec, loss="cosine", solver="lm", fixed=fixed, free=None,
                                              robust=None, max_steps=10, rtol=1e-8, atol=1e-12)
    fit_data = make_fit_data(data, fixed_values, loss_epsilon("cosine", data.values))
    params = {k: jnp.asarray(v, dtype=float) for k, v in dict(base.params, **fixed_values).items()}
    params.update({name: jnp.asarray([0.3, 0.5, 0.7]) for name in problem.linear})
    f0, basis = amplitude_basis(problem, params, problem.linear, fit_data)
    amplitudes = jnp.stack([params[name] for name in problem.linear], axis=-1)  # (C, K)
    np.testing.assert_allclose(f0 + jnp.einsum("nck,ck->nc", basis, amplitudes),
                               evaluate_pair(problem.model(params), fit_data.pair), rtol=1e-12, atol=1e-14)
