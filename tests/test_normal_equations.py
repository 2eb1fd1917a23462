"""The channel-compressed normal matrices (`brdffit.fitting.normal_equations`) against a dense ``jax.jacfwd``
Jacobian."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import models, programs, synth
from brdffit.fitting import api, normal_equations
from brdffit.fitting.normal_equations import accumulate, chunks
from brdffit.fitting.problem import flatten_free, make_fit_data, physical_params, residual_fn


def _setup(spec, loss="cosine", robust=None, n=700, seed=3):
    truth = models.get(spec, channels=3)
    data = synth.generate(truth, pattern="uniform", n=n, noise="relative:0.05", seed=seed)
    problem, model, fixed, _ = api._prepare(data, truth, loss=loss, solver="lm", fixed=None, free=None,
                                            robust=robust, max_steps=10, rtol=1e-8, atol=1e-12)
    # Move every parameter off its default (and channels off each other) so no derivative vanishes by symmetry.
    rng = np.random.default_rng(seed)
    specs = problem.specs
    y = {k: specs[k].to_unconstrained(model.params[k]) + 0.1 * rng.standard_normal(np.shape(model.params[k]))
         for k in problem.free}
    fit_data = make_fit_data(data, fixed, np.full(3, 1e-3), 0.5)
    params = physical_params(problem, y, fit_data.fixed)
    fit_data = fit_data._replace(fixed={k: v for k, v in params.items() if k not in problem.free})
    return problem, {k: params[k] for k in problem.free}, fit_data


def _dense(problem, tree, data):
    """JᵀJ, Jᵀr, rᵀr, Jᵀdiag(r²)J and the per-channel rᵀr from the full Jacobian in the physical parameters."""
    flat, unravel = flatten_free(problem, tree)

    def r(theta):
        params = physical_params(problem, {}, dict(data.fixed, **unravel(theta)))
        return residual_fn(problem, params, data).ravel()

    # Jitted: run eagerly, every primitive of a many-lobe model would compile on its own (minutes of CI time).
    jac, res = (np.asarray(a) for a in jax.jit(lambda theta: (jax.jacfwd(r)(theta), r(theta)))(flat))
    scaled = jac * res[:, None]
    per_channel = np.sum(res.reshape(-1, problem.channels) ** 2, axis=0)
    return jac.T @ jac, jac.T @ res, float(res @ res), scaled.T @ scaled, per_channel


def _check(problem, tree, data, chunk=None):
    pieces = chunks(data) if chunk is None else chunks(data, chunk)
    got = accumulate(problem, {k: np.asarray(v)[None, None] for k, v in tree.items()}, pieces).at_point(0, 0)
    want = _dense(problem, tree, data)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-12 * np.max(np.abs(w)))


def test_a_batch_of_points_gives_each_point_its_own_sums():
    # Three points of one material in one pass (the polish's batch of starts): each point's sums equal the dense
    # Jacobian's at that point, so no point's values leak into another's.
    problem, physical, data = _setup("lambert+cook-torrance")
    points = [physical, dict(physical, m=jnp.asarray(0.4)), dict(physical, rho_d=jnp.asarray([0.1, 0.2, 0.3]))]
    trees = {k: np.stack([np.asarray(p[k]) for p in points])[None] for k in problem.free}
    got = accumulate(problem, trees, chunks(data))
    for s, point in enumerate(points):
        for g, w in zip(got.at_point(0, s), _dense(problem, point, data)):
            np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-12 * np.max(np.abs(w)))


def test_first_forms_the_sums_of_the_first_points_alone():
    # A batch of four copies of one point (the pass at an answer, in the polish's compiled shape) reduced with
    # first=1: every field, the meat, metric sums and noise forms' Gram matrices included, is the full batch's first
    # point's, bit for bit, with one point left on the points axis.
    problem, physical, data = _setup("lambert+cook-torrance")
    trees = {k: np.broadcast_to(np.asarray(physical[k]), (1, 4) + np.shape(physical[k])).copy() for k in problem.free}
    full = accumulate(problem, trees, chunks(data), metrics=True)
    first = accumulate(problem, trees, chunks(data), metrics=True, first=1)
    assert first.cost.shape == (1, 1)
    for name, g, w in zip(full._fields, first.at_point(0, 0), full.at_point(0, 0)):
        assert g is not None, name
        np.testing.assert_array_equal(g, w, err_msg=name)


def test_matches_dense_jacobian_for_a_sum_of_lobes():
    # The assembly is lobe-agnostic (one tangent per parameter name), so one sum covers what differs between
    # lobes: per-channel colour and shared shape parameters, an anisotropic pair, numbered Lafortune sub-lobes
    # and a declared-fixed parameter (toon width). A sum of every registered lobe tested the same in 60 s of CI.
    problem, physical, data = _setup("oren-nayar+cook-torrance+ashikhmin-shirley-aniso+lafortune(lobes=2)"
                                     "+toon-specular")
    assert {"rho_d", "sigma", "m", "nu", "nv", "cxy_2", "n_2"}.issubset(problem.free)
    assert "width" not in problem.free
    _check(problem, physical, data)


@pytest.mark.parametrize("loss, robust", [("log", None), ("relative", None), ("sigma", "cauchy"),
                                          ("absolute", "huber")])
def test_matches_dense_jacobian_for_losses(loss, robust):
    problem, physical, data = _setup("oren-nayar+ggx", loss=loss, robust=robust)
    _check(problem, physical, data)


def test_chunking_gives_the_same_sums():
    # 2,500 samples in chunks of 1,100: the last chunk is padded with masked samples.
    problem, physical, data = _setup("lambert+ward-aniso", n=2500)
    _check(problem, physical, data, chunk=1100)


def test_misshaped_parameter_is_rejected():
    problem, _, data = _setup("lambert")
    bad = {"rho_d": jnp.ones((1, 1, 2))}
    with pytest.raises(ValueError, match="rho_d"):
        accumulate(problem, bad, chunks(data))


def test_padding_to_a_bucket_changes_no_sum():
    # make_fit_data(pad=True) appends masked samples up to bucket(n) (shared compiled programs across file sizes):
    # the sums are those of the unpadded data, and so are the metrics computed with the padded pair.
    from brdffit.fitting.problem import bucket
    from brdffit.fitting.uncertainty import normal_equations_at
    from brdffit.metrics import fit_metrics

    assert [bucket(n) for n in (1, 512, 513, 3072, 3073, 20_000, 65_536, 65_537)] == \
        [512, 512, 768, 3072, 4096, 24_576, 65_536, 131_072]
    truth = models.get("lambert+cook-torrance", channels=3)
    data = synth.generate(truth, pattern="uniform", n=700, noise="relative:0.05", seed=3)
    problem, model, fixed, _ = api._prepare(data, truth, loss="cosine", solver="lm", fixed=None, free=None,
                                            robust=None, max_steps=10, rtol=1e-8, atol=1e-12)
    plain = make_fit_data(data, fixed, np.full(3, 1e-3))
    padded = make_fit_data(data, fixed, np.full(3, 1e-3), pad=True)
    assert padded.values.shape[0] == 768 and not np.asarray(padded.mask)[700:].any()
    params = dict(model.params)
    for got, want in zip(normal_equations_at(problem, params, padded), normal_equations_at(problem, params, plain)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)
    with_pad, without = fit_metrics(model, data, pair=padded.pair), fit_metrics(model, data)
    for name in without:
        np.testing.assert_allclose(with_pad[name], without[name], rtol=1e-12)


def test_four_points_on_slots_give_each_point_its_own_sums():
    # Four points of one material on at most SLOT_ROWS samples (a polish's starts) run on the slotted pass, each
    # slot a point on all the rows: each point's sums equal the dense Jacobian's at that point.
    problem, physical, data = _setup("lambert+lafortune(lobes=2)")
    assert normal_equations._slots((1, normal_equations.SLOTS), chunks(data), None) == "points"
    points = [physical, dict(physical, n_1=jnp.asarray(3.0)), dict(physical, cxy_2=jnp.asarray(0.5)),
              dict(physical, rho_d=jnp.asarray([0.1, 0.2, 0.3]))]
    trees = {k: np.stack([np.asarray(p[k]) for p in points])[None] for k in problem.free}
    got = accumulate(problem, trees, chunks(data))
    for s, point in enumerate(points):
        for g, w in zip(got.at_point(0, s), _dense(problem, point, data)):
            np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-12 * np.max(np.abs(w)))


def test_one_point_on_four_slices_runs_the_program_of_four_points(monkeypatch):
    # One point on SLOTS × L samples runs on SLOTS slices of L (a selection's refit on four times its screen's
    # rows): the program that four points on L samples compiled, nothing more; its sums are the plain pass's on
    # the whole data, and the model values and tangents it keeps come back in the samples' order.
    problem, physical, data = _setup("lambert+cook-torrance", n=2048)
    quarter = jax.tree_util.tree_map(lambda a: a[:512] if np.ndim(a) and np.shape(a)[0] == 2048 else a, data)
    assert normal_equations._slots((1, 1), chunks(data), None) == "rows"
    compiled = []  # every signature a program compiles or loads (it is then kept in memory)
    original = programs.Program._path

    def counting(self, signature):
        compiled.append(self._name)
        return original(self, signature)

    monkeypatch.setattr(programs.Program, "_path", counting)
    four = {k: np.broadcast_to(np.asarray(v), (1, 4) + np.shape(v)) for k, v in physical.items()}
    accumulate(problem, four, chunks(quarter))
    before = list(compiled)
    one = {k: np.asarray(v)[None, None] for k, v in physical.items()}
    got, kept = accumulate(problem, one, chunks(data), values=True)
    assert compiled == before, compiled[len(before):]
    monkeypatch.setattr(normal_equations, "_slots", lambda *args: None)
    plain, plain_kept = accumulate(problem, one, chunks(data), values=True)
    for g, w in zip(got, plain):
        if w is not None:
            np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-15 * np.max(np.abs(w)))
    for (a, f), (a0, f0) in zip(kept, plain_kept):
        assert a.shape == a0.shape and f.shape == f0.shape
        np.testing.assert_allclose(a, a0, rtol=1e-12, atol=1e-15 * np.max(np.abs(a0)))
        np.testing.assert_allclose(np.asarray(f), np.asarray(f0), rtol=1e-12, atol=0)
