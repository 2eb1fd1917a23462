"""Parameter posteriors by MCMC with emcee (docs/posterior.md).

`posterior(fit_result, measurements)` samples the free parameters of a least-squares fit, and optionally one
noise scale per channel, with emcee's affine-invariant ensemble sampler (Goodman & Weare 2010; Foreman-Mackey
et al. 2013). The log-probability is one jitted JAX function, vmapped over walkers (emcee ``vectorize=True``).
The likelihood uses the same residuals as the fit's loss.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import logging
import math
import os
import signal
import threading
import time

import emcee
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln

from .blas_threads import one_blas_thread
from .defaults import POSTERIOR
from .fitting.result import FitResult
from .fitting.losses import loss_epsilon, residual_scale
from .io.hdf5 import is_lock_conflict, open_h5_waiting
from .io.locking import LockTimeout, locked
from .models.model import evaluate
from .params import ParamSpec
from .programs import compiler_options
from .fitting.problem import FitData, Problem, flatten_free, make_fit_data, physical_params, residual_fn
from .progress import Progress

__all__ = ["posterior", "load_posterior", "Posterior", "StepBackend", "Interrupted", "raise_interrupted", "LIKELIHOODS",
           "PRIOR_FAMILIES"]

LIKELIHOODS = ("gaussian", "student-t")
PRIOR_FAMILIES = ("uniform", "loguniform", "normal", "lognormal")
QUANTILES = (2.5, 16.0, 50.0, 84.0, 97.5)
_LOG_SIGMA_RANGE = (-30.0, 10.0)


class ChainMoved(RuntimeError):
    """Another process stored a step of the chain after this one read where the chain stood (`StepBackend`)."""


class StepBackend(emcee.backends.HDFBackend):
    """emcee's HDF5 backend, with every step committed by its last write, so that a killed run resumes exactly,
    and with the steps of concurrent runs of one chain never mixed.

    emcee's ``save_step`` adds the step's acceptances to ``accepted`` and writes the new random state before it
    counts the step in ``iteration``; a process killed (or interrupted) between those writes redoes the step when
    it resumes and counts its acceptances twice, so ``accepted`` ends too high. Here the
    acceptance counts and the random state after step ``k`` go into the group ``step_state_<k mod 2>``, and
    ``iteration``, written last, says which of the two is current: an unfinished step leaves the current one
    untouched and the redone step writes exactly what the first attempt would have. emcee's own ``accepted`` field
    is set (not added to) each step, for readers without this class.

    Concurrent processes (``brdffit posterior`` run twice on one result): every open of the file holds the lock of
    its folder (`brdffit.io.locking.locked`; shared to read, exclusive to write), so no one reads a step half
    written and `update_hdf5` (the posterior's summary) never copies the file in the middle of one. A step is
    stored only where the chain still stands where this process read it (`resume_point`); where another process
    stored a step meanwhile, `save_step` raises `ChainMoved` and stores nothing, and `posterior` goes on from the
    step stored last. The chain stays one Markov chain, each step drawn from the one stored before it.
    """

    expected: int | None = None  # the stored iteration this process's next step follows (None: not checked)

    @contextlib.contextmanager
    def _opened(self, mode: str):
        with locked(self.filename, shared=mode == "r"):
            f = open_h5_waiting(self.filename, mode)
            try:
                if not self.dtype_set and self.name in f and "chain" in f[self.name]:
                    self.dtype = f[self.name]["chain"].dtype
                    self.dtype_set = True
                yield f
            finally:
                f.close()

    @property
    def initialized(self):
        """Whether the file holds the chain's group (emcee's check, with a lock that could not be had an error, not
        an answer: emcee's sampler empties a chain it finds uninitialised)."""
        if not os.path.exists(self.filename):
            return False
        try:
            with self.open() as f:
                return self.name in f
        except OSError as err:
            if isinstance(err, LockTimeout) or is_lock_conflict(err):
                raise
            return False

    def open(self, mode="r"):
        """The file, open for a ``with`` block that holds its folder's lock (emcee's ``open`` opens it bare)."""
        if self.read_only and mode != "r":
            raise RuntimeError("The backend has been loaded in read-only mode. Set `read_only = False` to make "
                               "changes.")
        return self._opened(mode)

    def prepare(self, nwalkers: int, ndim: int, fresh: bool) -> None:
        """Create the chain's group where there is none, or empty it with ``fresh``, in one locked step (emcee's
        sampler would create it unlocked, after its own check: two processes could both create it)."""
        with locked(self.filename):
            if fresh or not self.initialized:
                self.reset(nwalkers, ndim)

    def resume_point(self):
        """Where the chain stands: the stored iteration and its last state (None before the first step), read
        together; the next step is stored only where the chain is still there (`save_step`)."""
        with locked(self.filename, shared=True):
            iteration = self.iteration
            state = self.get_last_sample() if iteration else None
        self.expected = iteration
        return iteration, state

    def grow(self, ngrow, blobs):
        """emcee's ``grow`` by ``ngrow`` rows after the step this process continues (`resume_point`), never
        shrinking the stored rows (another run of the chain may have grown it further)."""
        with locked(self.filename):
            with self.open() as f:
                g = f[self.name]
                rows, iteration = g["chain"].shape[0], int(g.attrs["iteration"])
            base = iteration if self.expected is None else self.expected
            super().grow(max(base + int(ngrow), rows) - iteration, blobs)

    @staticmethod
    def _slot(iteration: int) -> str:
        return f"step_state_{int(iteration) % 2}"

    def _current(self, g):
        """The slot of the stored iteration, or the group itself before the first step (emcee's layout)."""
        return g.get(self._slot(g.attrs["iteration"]), g)

    @property
    def accepted(self):
        with self.open() as f:
            return self._current(f[self.name])["accepted"][...]

    @property
    def random_state(self):
        with self.open() as f:
            attrs = self._current(f[self.name]).attrs
            elements = [v for k, v in sorted(attrs.items()) if k.startswith("random_state_")]
        return elements if len(elements) else None

    def save_step(self, state, accepted):
        """Store one step (emcee's ``Backend.save_step``); ``iteration`` is the last field written.

        Raises:
            ChainMoved: the stored chain is no longer where this process read it (`resume_point`); nothing is
                stored.
        """
        with locked(self.filename):
            self._save_step(state, accepted)

    def _save_step(self, state, accepted):
        self._check(state, accepted)
        with self.open("a") as f:
            g = f[self.name]
            iteration = int(g.attrs["iteration"])
            if self.expected is not None and iteration != self.expected:
                raise ChainMoved(f"{self.filename}: the chain {self.name} holds {iteration} steps, not the "
                                 f"{self.expected} this process continued")
            total = self._current(g)["accepted"][...] + accepted
            g["chain"][iteration, :, :] = state.coords
            g["log_prob"][iteration, :] = state.log_prob
            if state.blobs is not None:
                g["blobs"][iteration, :] = state.blobs
            after = g.require_group(self._slot(iteration + 1))
            if "accepted" not in after:
                after.create_dataset("accepted", data=total)
            after["accepted"][...] = total
            for i, v in enumerate(state.random_state):
                after.attrs[f"random_state_{i}"] = v
            g["accepted"][...] = total
            g.attrs["iteration"] = iteration + 1
        if self.expected is not None:
            self.expected = iteration + 1


class Interrupted(KeyboardInterrupt):
    """The sampling was stopped by a signal after the step in progress (the steps so far are stored whole where a
    store was given). A KeyboardInterrupt, so that code that catches Ctrl-C catches it; ``signum`` names the signal:
    SIGINT (Ctrl-C) or SIGTERM (what ``kill`` and batch systems send, where the handler is `raise_interrupted`). The
    CLI exits with ``128 + signum``, as a shell reports a command that the signal ended."""

    def __init__(self, message: str = "", signum: int = signal.SIGINT):
        super().__init__(message)
        self.signum = int(signum)


def raise_interrupted(signum, frame):
    """A signal handler that raises `Interrupted` naming the signal: Python's SIGINT handler (which raises
    KeyboardInterrupt) for another signal. ``brdffit posterior`` installs it for SIGTERM, so that SIGTERM stops it as
    Ctrl-C does."""
    raise Interrupted(signum=signum)


@contextlib.contextmanager
def _stop_between_steps():
    """Make SIGINT and SIGTERM stop the sampling after the step in progress, which is stored whole.

    A signal is taken over where its handler raises KeyboardInterrupt: Python's own for SIGINT
    (``signal.default_int_handler``), and `raise_interrupted`. Any other disposition is left as it is: an ignored
    SIGINT stays ignored (a shell without job control ignores SIGINT and SIGQUIT in the commands it starts in the
    background, ``cmd &``, and Python keeps them ignored), a program's own handler stays its own, and SIGTERM's
    default ends the process at once (the stored chain still resumes: `StepBackend`). Outside the main thread
    nothing changes.

    Yields a list that receives the number of the first signal; a second signal raises `Interrupted` at once.
    """
    asked: list[int] = []
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        previous = {s: h for s, h in previous.items() if h is signal.default_int_handler or h is raise_interrupted}

    def handler(signum, frame):
        if asked:
            raise Interrupted(signum=signum)
        asked.append(signum)

    try:
        for signum in previous:
            signal.signal(signum, handler)
        yield asked
    finally:
        for signum, before in previous.items():
            signal.signal(signum, before)


def _prior_term(spec: ParamSpec, user):
    """log prior density (up to a constant) of one parameter, as a function of its value array.

    Default ("bounds"): uniform inside the declared bounds; log-uniform (∝ 1/p) for scale parameters whose lower
    bound is positive (1/p is not integrable at 0, so scale parameters bounded by 0 stay uniform).
    """
    if user is None:
        if spec.scale and spec.lower > 0:
            return lambda v: -jnp.sum(jnp.log(v))
        return lambda v: jnp.zeros(())
    if callable(user):
        return lambda v: jnp.sum(user(v))
    family, a, b = user
    if family == "uniform":
        return lambda v: jnp.sum(jnp.where((v >= a) & (v <= b), 0.0, -jnp.inf))
    if family == "loguniform":
        return lambda v: jnp.sum(jnp.where((v >= a) & (v <= b), -jnp.log(v), -jnp.inf))
    if family == "normal":
        return lambda v: jnp.sum(-0.5 * ((v - a) / b) ** 2)
    if family == "lognormal":
        return lambda v: jnp.sum(jnp.where(v > 0, -0.5 * ((jnp.log(jnp.maximum(v, 1e-300)) - a) / b) ** 2
                                           - jnp.log(jnp.maximum(v, 1e-300)), -jnp.inf))
    raise ValueError(f"unknown prior family {family!r}; use one of {', '.join(PRIOR_FAMILIES)} or a callable")


def _check_priors(prior, free):
    if prior == "bounds" or prior is None:
        return {}
    if not isinstance(prior, dict):
        raise ValueError("prior must be 'bounds' or a dict name -> (family, a, b) or callable log density")
    for name, value in prior.items():
        if name not in free:
            raise ValueError(f"prior for {name!r}: not a free parameter of this fit ({', '.join(free)})")
        if not callable(value) and (not isinstance(value, tuple) or len(value) != 3
                                    or value[0] not in PRIOR_FAMILIES):
            raise ValueError(f"prior for {name!r} must be a callable or (family, a, b) with family in "
                             f"{', '.join(PRIOR_FAMILIES)}, got {value!r}")
    return prior


def _split_r_hat(chain: np.ndarray) -> np.ndarray:
    """Gelman-Rubin R-hat per parameter with the walkers split into two halves, each pooled as one chain.

    Arguments:
        chain: ``(steps, walkers, ndim)`` after burn-in.

    Returns:
        ``(ndim,)``; values near 1 mean both halves sample the same distribution.
    """
    steps, walkers, ndim = chain.shape
    half = walkers // 2
    groups = [chain[:, :half, :].reshape(-1, ndim), chain[:, half:2 * half, :].reshape(-1, ndim)]
    n = groups[0].shape[0]
    means = np.stack([g.mean(axis=0) for g in groups])
    within = np.mean([g.var(axis=0, ddof=1) for g in groups], axis=0)
    between = n * means.var(axis=0, ddof=1)
    pooled = (n - 1) / n * within + between / n
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(pooled / within)


@dataclasses.dataclass
class Posterior:
    """What `brdffit.posterior` returns.

    Attributes:
        names: labels of the sampled dimensions (``name`` or ``name[i]``; noise scales ``noise_sigma[i]``).
        samples: flat posterior samples after burn-in and thinning, ``(n, ndim)``, physical units (noise as σ).
        chain: the whole chain ``(steps, walkers, ndim)`` in the same units (for trace plots).
        log_prob: ``(steps, walkers)`` log posterior of the chain.
        burn, thin: what was discarded and kept.
        summary: name -> {"mean", "median", "std", "q2.5", "q16", "q84", "q97.5"}.
        correlation: posterior correlation matrix of the samples.
        laplace_stderr: name -> the least-squares fit's Laplace standard error (NaN for noise scales).
        fit_values: name -> the least-squares value.
        diagnostics: acceptance fraction, autocorrelation times, effective sample sizes, split R-hat, lengths.
        warnings: human-readable warnings (too short a chain, odd acceptance, subsampled data).
        model_spec: the fitted model's spec; ``fit`` the `FitResult` sampled around.
        likelihood, noise, subsample: how the posterior was defined (subsample: None or (n used, n total)).
        wall_time: seconds spent sampling.
    """

    names: list
    samples: np.ndarray
    chain: np.ndarray
    log_prob: np.ndarray
    burn: int
    thin: int
    summary: dict
    correlation: np.ndarray
    laplace_stderr: dict
    fit_values: dict
    diagnostics: dict
    warnings: list
    model_spec: str
    likelihood: str
    noise: str
    subsample: tuple | None
    wall_time: float
    fit: FitResult | None = None

    def table(self) -> str:
        """A readable table: least-squares value ± Laplace error next to posterior median and intervals."""
        lines = [f"posterior of {self.model_spec} ({self.likelihood} likelihood, noise {self.noise})",
                 f"{'parameter':<16}{'LS value':>12}{'± Laplace':>12}{'median':>12}{'68% interval':>26}"
                 f"{'95% interval':>26}"]
        for name in self.names:
            s = self.summary[name]
            ls = self.fit_values.get(name, float("nan"))
            err = self.laplace_stderr.get(name, float("nan"))
            lines.append(f"{name:<16}{ls:>12.5g}{err:>12.3g}{s['median']:>12.5g}"
                         f"{'[' + format(s['q16'], '.5g') + ', ' + format(s['q84'], '.5g') + ']':>26}"
                         f"{'[' + format(s['q2.5'], '.5g') + ', ' + format(s['q97.5'], '.5g') + ']':>26}")
        d = self.diagnostics
        lines.append(f"acceptance {d['acceptance_fraction']:.3f}  max autocorrelation time {d['tau_max']:.1f}  "
                     f"steps {d['steps']}  burn {self.burn}  thin {self.thin}  samples {len(self.samples)}  "
                     f"min ESS {d['ess_min']:.0f}  max split R-hat {d['r_hat_max']:.4f}")
        lines.extend(f"warning: {w}" for w in self.warnings)
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()

    def to_dict(self) -> dict:
        """``{"params": {name: {"mean", "median", "std", "q2.5", "q16", "q84", "q97.5"}}, "diagnostics": {...}}``
        plus the correlation matrix, names, warnings and settings; JSON-ready."""
        def clean(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {
            "params": {n: {k: clean(v) for k, v in s.items()} for n, s in self.summary.items()},
            "diagnostics": {k: ([clean(x) for x in v] if isinstance(v, list) else
                                (clean(v) if isinstance(v, float) else v)) for k, v in self.diagnostics.items()},
            "names": list(self.names),
            "correlation": [[clean(x) for x in row] for row in self.correlation],
            "laplace_stderr": {k: clean(v) for k, v in self.laplace_stderr.items()},
            "fit_values": {k: clean(v) for k, v in self.fit_values.items()},
            "warnings": list(self.warnings),
            "model": self.model_spec,
            "likelihood": self.likelihood,
            "noise": self.noise,
            "subsample": list(self.subsample) if self.subsample else None,
            "burn": self.burn,
            "thin": self.thin,
            "wall_time": self.wall_time,
        }

    def save(self, path, name: str | None = None) -> str:
        """Write the summary (JSON attribute ``summary``) and the flat samples under ``/posteriors/<name>/result``
        of an HDF5 file; other groups (measurements, fits, a stored chain) are kept, the file replaced atomically.

        Returns:
            The group path written.
        """
        from .io.hdf5 import update_hdf5

        group = f"posteriors/{(name or self.model_spec).replace('/', '_')}/result"

        def write(g):
            g.attrs["summary"] = json.dumps(self.to_dict())
            g.create_dataset("samples", data=self.samples)
            g.attrs["names"] = json.dumps(self.names)

        update_hdf5(path, group, write)
        return "/" + group

    def draws(self, n: int, seed: int = 0) -> np.ndarray:
        """``n`` rows of `samples` drawn with a seed (with replacement when n exceeds the sample count)."""
        rng = np.random.default_rng(seed)
        return self.samples[rng.choice(len(self.samples), n, replace=n > len(self.samples))]

    def predictive_band(self, theta_i, phi_i, theta_o, phi_o, *, quantiles=QUANTILES, n_draws: int = 200,
                        seed: int = 0) -> dict:
        """Credible bands of the BRDF along any set of directions (e.g. an in-plane slice).

        Arguments:
            theta_i, phi_i, theta_o, phi_o: angles (radians), broadcastable.
            quantiles: percentiles to return.
            n_draws: posterior draws evaluated.
            seed: seed of the draws.

        Returns:
            percentile -> array ``(..., channels)`` of f_r in 1/sr (noise scales are not added: this is the band
            of the model, not of new measurements).
        """
        model = self.fit.model
        free = [n for n in self.fit.params if n not in self.fit.fixed]
        draws = self.draws(n_draws, seed)
        values = []
        for row in draws:
            flat = dict(zip(self.names, row))
            params = {}
            for name in free:
                shape = np.shape(self.fit.params[name])
                if len(shape) == 0:
                    params[name] = flat[name]
                else:
                    params[name] = np.array([flat[f"{name}[{i}]"] for i in range(shape[0])])
            values.append(np.asarray(evaluate(model.replace(**params), theta_i, phi_i, theta_o, phi_o)))
        stack = np.stack(values)
        return {q: np.percentile(stack, q, axis=0) for q in quantiles}


@functools.lru_cache(maxsize=32)
def _log_prob_fn(problem: Problem, estimate: bool, likelihood: str, nu: float, priors: tuple):
    """The jitted log posterior, vmapped over walkers: ``f(thetas (W, ndim), context) -> (W,)``.

    Cached by its static definition, so repeated posteriors of data of the same shape compile once. ``context``
    holds the data (`FitData`), the residual scale for known noise, the bounds and the optimum.
    """
    specs = problem.specs
    template = {n: jnp.zeros((problem.channels,) if specs[n].colour else ()) for n in problem.free}
    _, unravel = flatten_free(problem, template)
    p = sum(int(np.size(v)) for v in template.values())
    user = dict(priors)
    prior_terms = {n: _prior_term(specs[n], user.get(n)) for n in problem.free}
    log_norm_t = gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * jnp.log(nu * jnp.pi)

    def one(theta, context):
        data = context["data"]
        mask = data.mask
        flat = theta[:p]
        inside = jnp.all((flat > context["lowers"]) & (flat < context["uppers"]))
        params = unravel(jnp.where(inside, flat, context["flat0"]))
        lp = sum(term(params[n]) for n, term in prior_terms.items())
        r = residual_fn(problem, physical_params(problem, {}, dict(data.fixed, **params)), data)
        if estimate:
            log_s = theta[p:]
            inside = inside & jnp.all((log_s > _LOG_SIGMA_RANGE[0]) & (log_s < _LOG_SIGMA_RANGE[1]))
            s = jnp.exp(log_s)[None, :]
            log_s_total = jnp.sum(jnp.sum(mask, axis=0) * log_s)
        else:
            s = context["scale"]
            log_s_total = jnp.sum(jnp.where(mask, jnp.log(s), 0.0))
        z = r / s
        if likelihood == "gaussian":
            ll = -0.5 * jnp.sum(jnp.where(mask, z * z, 0.0)) - log_s_total
        else:  # Student-t with nu degrees of freedom and scale s
            ll = jnp.sum(jnp.where(mask, log_norm_t - 0.5 * (nu + 1) * jnp.log1p(z * z / nu), 0.0)) - log_s_total
        total = lp + ll
        return jnp.where(inside & jnp.isfinite(total), total, -jnp.inf)

    return jax.jit(jax.vmap(one, in_axes=(0, None)), compiler_options=compiler_options())


def _noise_scale(noise, measurements, data: FitData, problem: Problem):
    """The likelihood's noise scale in the loss's residual units (None: estimated per channel as log σ) and its
    label in the summary (`posterior`'s ``noise``)."""
    if noise == "estimate":
        return None, "estimated per channel"
    if noise == "known":
        if measurements.sigma is None:
            raise ValueError("noise='known' needs measurements with sigma")
        sigma = np.where(np.isfinite(measurements.sigma), measurements.sigma, 1.0)
        scale = np.where(np.asarray(data.mask), sigma * residual_scale(problem.loss, data), 1.0)
        label = "known (measurement sigma)"
    elif isinstance(noise, (int, float)) and noise > 0:
        scale = np.where(np.asarray(data.mask), float(noise) * residual_scale(problem.loss, data), 1.0)
        label = f"fixed sigma {float(noise):g} 1/sr"
    else:
        raise ValueError(f"noise must be 'estimate', 'known' or a positive number, got {noise!r}")
    return jnp.asarray(np.where(scale > 0, scale, 1.0)), label


def _stored_chain(store, run_name: str, nwalkers: int, ndim: int, resume: bool):
    """The `StepBackend` of ``posteriors/<run_name>/chain`` in ``store``, prepared for this run (None without a
    store); a stored chain of another shape is refused when resuming."""
    if store is None:
        return None
    backend = StepBackend(str(store), name=f"posteriors/{run_name}/chain")
    with locked(store):
        if backend.initialized and backend.iteration > 0 and backend.shape != (nwalkers, ndim) and resume:
            raise ValueError(f"{store}: the stored chain has shape {backend.shape}, this run needs "
                             f"{(nwalkers, ndim)}; pass resume=False or another name")
        backend.prepare(nwalkers, ndim, fresh=not resume)
    return backend


def _sample(sampler, backend, fresh_start, log_prob_numpy, nsteps: int, store, progress: bool,
            nwalkers: int) -> float:
    """Run the chain up to ``nsteps`` steps a walker (from a stored chain's last step, else from ``fresh_start()``,
    whose log probability must be finite), stopping between steps on SIGINT/SIGTERM; the wall seconds.

    Raises:
        ValueError: a start where the posterior is NaN or zero. Interrupted: stopped by a signal (the message says
            what ``store`` holds).
    """
    already, start = backend.resume_point() if backend is not None else (0, None)
    if already == 0:
        start = fresh_start()
        initial = log_prob_numpy(start)
        if np.any(np.isnan(initial)):
            raise ValueError("the initial log probability is NaN for some walkers: check the data for NaN sigma "
                             "or the user priors")
        if not np.all(np.isfinite(initial)):
            bad = int(np.flatnonzero(~np.isfinite(initial))[0])
            raise ValueError(f"walker {bad} starts where the posterior is zero (outside a prior's support): "
                             "the least-squares optimum lies outside the priors given")
    remaining = max(nsteps - already, 0)
    bar = Progress("MCMC", remaining, enabled=progress and remaining > 0, unit="steps")
    t0 = time.perf_counter()
    if remaining:
        try:
            with _stop_between_steps() as asked:
                stored, left = already, remaining
                while left:
                    try:
                        for step, _ in enumerate(sampler.sample(start, iterations=left), start=1):
                            bar.update(min(max(stored + step - already, 0), remaining))
                            if asked:
                                break
                        break
                    except ChainMoved:  # another process stored steps meanwhile: go on from the last one stored
                        stored, start = backend.resume_point()
                        start = fresh_start() if stored == 0 else start
                        left = max(nsteps - stored, 0)
            if asked:
                raise Interrupted(signum=asked[0])
        except KeyboardInterrupt as stop:
            signum = getattr(stop, "signum", signal.SIGINT)
            if backend is None:
                raise Interrupted("the chain was not stored (pass store= to keep and resume one)", signum) from None
            raise Interrupted(f"{backend.iteration} of {nsteps} steps are stored in {store}; run the same command "
                              "again to continue the chain", signum) from None
    bar.close(f"({nwalkers} walkers)")
    return time.perf_counter() - t0


def _burn_and_thin(chain: np.ndarray, burn, thin) -> tuple:
    """The integrated autocorrelation time of each dimension (emcee's; the chain's length where it has none), and
    the burn-in and thinning: given, or ``"auto"``: twice the largest time (at most half the chain) and half the
    smallest."""
    steps = chain.shape[0]
    emcee_log = logging.getLogger("emcee.autocorr")
    level = emcee_log.level
    emcee_log.setLevel(logging.ERROR)  # its "chain too short" message is in our own warnings
    try:
        tau = emcee.autocorr.integrated_time(chain, quiet=True)
    finally:
        emcee_log.setLevel(level)
    tau = np.where(np.isfinite(tau) & (tau > 0), tau, float(steps))
    burn_n = int(min(math.ceil(2 * tau.max()), steps // 2)) if burn == "auto" else int(burn)
    thin_n = int(max(1, math.floor(0.5 * tau.min()))) if thin == "auto" else int(thin)
    return tau, burn_n, thin_n


def _diagnostics(chain: np.ndarray, tau: np.ndarray, burn: int, p: int, acceptance: float, samples: int):
    """The chain's diagnostics (acceptance, autocorrelation times, effective sample sizes, split R-hat after the
    burn-in) and the warnings they call for.

    Returns:
        ``(diagnostics, warnings)``: the `Posterior.diagnostics` dict and a list of sentences.
    """
    steps, nwalkers, ndim = chain.shape
    after = chain[burn:]
    ess = (after.shape[0] * nwalkers) / tau
    r_hat = _split_r_hat(_to_reported(after, p)) if after.shape[0] > 1 else np.full(ndim, np.nan)
    warnings = []
    if steps < 50 * tau.max():
        warnings.append(f"the chain ({steps} steps) is shorter than 50 autocorrelation times "
                        f"(tau max = {tau.max():.1f}): run at least {int(50 * tau.max())} steps for reliable "
                        "intervals")
    if not 0.15 <= acceptance <= 0.6:
        warnings.append(f"acceptance fraction {acceptance:.3f} is outside 0.15-0.6")
    diagnostics = {
        "acceptance_fraction": acceptance,
        "tau": [float(t) for t in tau],
        "tau_max": float(tau.max()),
        "ess": [float(e) for e in ess],
        "ess_min": float(ess.min()),
        "r_hat": [float(r) for r in r_hat],
        "r_hat_max": float(np.nanmax(r_hat)) if np.isfinite(r_hat).any() else float("nan"),
        "steps": int(steps),
        "walkers": int(nwalkers),
        "samples": int(samples),
    }
    return diagnostics, warnings


def _quantiles(x: np.ndarray) -> dict:
    """Mean, median, standard deviation and the 2.5/16/84/97.5 % quantiles of one dimension's samples."""
    q = np.percentile(x, QUANTILES)
    return {"mean": float(x.mean()), "median": float(q[2]), "std": float(x.std(ddof=1)),
            "q2.5": float(q[0]), "q16": float(q[1]), "q84": float(q[3]), "q97.5": float(q[4])}


@one_blas_thread()
def posterior(fit_result: FitResult, measurements, *, nwalkers: int = POSTERIOR.walkers, nsteps: int = POSTERIOR.steps, burn="auto",
              thin="auto", likelihood: str = "gaussian", noise="estimate", prior="bounds", nu: float = 4.0,
              max_samples: int | None = None, store=None, name: str | None = None, resume: bool = True,
              progress: bool = True, seed: int = POSTERIOR.seed) -> Posterior:
    """Sample the posterior of a fit's free parameters with emcee.

    Arguments:
        fit_result: a shared-shape `FitResult` (its model, fixed parameters, loss and Laplace errors are used).
        measurements: the data the fit used (or others with the same channels).
        nwalkers: emcee walkers (at least twice the dimension).
        nsteps: steps per walker (in total, counting those already stored when resuming).
        burn: steps discarded at the start; ``"auto"``: twice the largest integrated autocorrelation time.
        thin: keep every ``thin``-th step; ``"auto"``: half the smallest autocorrelation time.
        likelihood: ``"gaussian"`` or ``"student-t"`` (robust, ``nu`` degrees of freedom) on the fit's residuals.
        noise: ``"estimate"`` (one noise scale per channel sampled as log σ with a uniform prior in log σ),
            ``"known"`` (the measurements' σ), or a number (a fixed σ in 1/sr). σ is mapped into the loss's
            residual units by the loss's derivative at the data.
        prior: ``"bounds"`` (uniform within the declared bounds; log-uniform for scale parameters with a positive
            lower bound), or a dict name -> ``(family, a, b)`` (``uniform``/``loguniform`` with bounds a, b;
            ``normal``/``lognormal`` with mean a and sd b) or a callable log density; unnamed parameters keep
            the bounds prior.
        nu: degrees of freedom of the Student-t likelihood.
        max_samples: run on a seeded stratified subsample of at most this many samples (said in the summary).
        store: an HDF5 path: the chain is written as it runs through emcee's HDF backend, in group
            ``posteriors/<name>/chain``.
        name: the run's group name (default: the model spec).
        resume: with ``store``, continue a stored chain of the same run up to ``nsteps`` instead of restarting.
        progress: print a progress line on stderr.
        seed: seed of the walkers' start, the subsample and emcee's random state.

    Returns:
        A `Posterior`.

    Raises:
        ValueError: bad arguments, a fit in independent channel mode, or a non-finite log probability at the
            start (emcee's own checks, e.g. walkers not linearly independent, also raise ValueError).
        Interrupted: SIGINT (Ctrl-C), or SIGTERM where its handler is `raise_interrupted`, arrived while sampling
            (in the main thread); the sampling stopped after the step in progress, and the message says how many
            steps ``store`` holds.
    """
    if fit_result.model is None:
        raise ValueError("posterior needs a shared-shape fit; fit each channel separately for independent mode")
    if likelihood not in LIKELIHOODS:
        raise ValueError(f"likelihood must be one of {', '.join(LIKELIHOODS)}, got {likelihood!r}")
    model = fit_result.model
    specs = model.param_specs
    free = tuple(n for n in model.params if n not in fit_result.fixed)
    priors = _check_priors(prior, free)
    problem = Problem(lobes=model.lobes, channels=model.channels, free=free, loss=fit_result.loss, robust=None,
                      solver=None, max_steps=0)
    total = measurements.n
    subsample = None
    if max_samples is not None and measurements.n > max_samples:
        measurements = measurements.subsample(max_samples, seed=seed, stratified=True)
        subsample = (measurements.n, total)
    fixed = {k: jnp.asarray(v) for k, v in model.params.items() if k in fit_result.fixed}
    data = make_fit_data(measurements, fixed, loss_epsilon(fit_result.loss, measurements.values))
    channels = model.channels

    scale, noise_label = _noise_scale(noise, measurements, data, problem)

    fit_values = {k: jnp.asarray(model.params[k]) for k in free}
    flat0, _ = flatten_free(problem, fit_values)
    p = int(flat0.size)
    labels = model.layout.labels(free)
    estimate = noise == "estimate"
    ndim = p + (channels if estimate else 0)
    if nwalkers < 2 * ndim or nwalkers % 2:
        raise ValueError(f"nwalkers must be even and at least twice the number of sampled dimensions ({ndim}: "
                         f"{p} parameters{' + one noise scale per channel' if ndim > p else ''}); use "
                         f"nwalkers={2 * ndim + (2 * ndim) % 2} or more")
    context = {
        "data": data,
        "scale": jnp.ones_like(data.values) if scale is None else scale,
        "lowers": jnp.concatenate([jnp.full(np.size(model.params[n]), specs[n].lower) for n in free]),
        "uppers": jnp.concatenate([jnp.full(np.size(model.params[n]), specs[n].upper) for n in free]),
        "flat0": flat0,
    }
    log_prob = _log_prob_fn(problem, estimate, likelihood, float(nu), tuple(sorted(priors.items())))
    lowers, uppers = context["lowers"], context["uppers"]

    def log_prob_numpy(thetas):  # NumPy in, transferred by jit: an eager jnp.asarray adds a dispatch to every step
        return np.asarray(log_prob(np.asarray(thetas, dtype=float), context))

    backend = _stored_chain(store, (name or model.spec).replace("/", "_"), nwalkers, ndim, resume)
    sampler = emcee.EnsembleSampler(nwalkers, ndim, log_prob_numpy, vectorize=True, backend=backend)

    def fresh_start():
        sampler.random_state = np.random.RandomState(seed).get_state()
        return _initial_ball(fit_result, free, labels, flat0, lowers, uppers, nwalkers, ndim, p, data, problem,
                             seed)

    wall = _sample(sampler, backend, fresh_start, log_prob_numpy, nsteps, store, progress, nwalkers)

    with locked(store, shared=True) if backend is not None else contextlib.nullcontext():
        chain = sampler.get_chain()  # one chain: another process may store steps after it
        lp_chain = sampler.get_log_prob()
        accepted = sampler.acceptance_fraction
    tau, burn_n, thin_n = _burn_and_thin(chain, burn, thin)
    kept = chain[burn_n::thin_n]
    names = labels + ([f"noise_sigma[{c}]" for c in range(channels)] if noise == "estimate" else [])
    physical = _to_reported(chain, p)
    flat = _to_reported(kept, p).reshape(-1, ndim)
    diagnostics, warnings = _diagnostics(chain, tau, burn_n, p, float(np.mean(accepted)), flat.shape[0])
    if subsample:
        warnings.append(f"the chain ran on a stratified subsample of {subsample[0]} of {subsample[1]} samples")
    summary = {n: _quantiles(flat[:, k]) for k, n in enumerate(names)}
    # The posterior's likelihood weights the residuals as the loss does, so its widths compare with the Laplace
    # standard errors (which `FitResult.stderr` holds only when the noise model matches the loss).
    laplace = dict(zip(labels, np.concatenate([np.ravel(fit_result.stderr_laplace[n]) for n in free])))
    laplace.update({n: float("nan") for n in names[p:]})
    values = dict(zip(labels, np.asarray(flat0, dtype=float)))
    return Posterior(names=names, samples=flat, chain=physical, log_prob=lp_chain, burn=burn_n, thin=thin_n,
                     summary=summary, correlation=np.corrcoef(flat, rowvar=False) if flat.shape[0] > 1 else
                     np.eye(ndim), laplace_stderr={k: float(v) for k, v in laplace.items()},
                     fit_values={k: float(v) for k, v in values.items()}, diagnostics=diagnostics,
                     warnings=warnings, model_spec=model.spec, likelihood=likelihood, noise=noise_label,
                     subsample=subsample, wall_time=wall, fit=fit_result)


def _to_reported(chain: np.ndarray, p: int) -> np.ndarray:
    """Turn sampled log σ columns (after the first p) into σ."""
    out = np.array(chain, dtype=float, copy=True)
    out[..., p:] = np.exp(out[..., p:])
    return out


def _initial_ball(fit_result, free, labels, flat0, lowers, uppers, nwalkers, ndim, p, data, problem, seed):
    """Walkers in a ball around the optimum: 0.1 Laplace standard errors wide, kept inside the bounds."""
    rng = np.random.default_rng(seed)
    centre = np.asarray(flat0, dtype=float)
    width = np.concatenate([np.ravel(np.asarray(fit_result.stderr_laplace[n], dtype=float)) for n in free])
    fallback = 1e-3 * np.maximum(np.abs(centre), 1e-3)
    width = np.where(np.isfinite(width) & (width > 0), width, fallback)
    ball = centre + 0.1 * width * rng.standard_normal((nwalkers, p))
    lo, hi = np.asarray(lowers), np.asarray(uppers)
    margin = 1e-9 * np.maximum(np.abs(centre), 1.0)
    ball = np.clip(ball, lo + margin, hi - margin)
    if ndim == p:
        return ball
    r = np.asarray(residual_fn(problem, physical_params(problem, {}, dict(data.fixed,
                                                                          **{k: jnp.asarray(v) for k, v in
                                                                             fit_result.params.items()
                                                                             if k in free})), data))
    mask = np.asarray(data.mask)
    rms = np.sqrt(np.sum(np.where(mask, r * r, 0.0), axis=0) / np.maximum(mask.sum(axis=0), 1))
    log_sigma = np.log(np.maximum(rms, 1e-12))
    return np.concatenate([ball, log_sigma + 0.01 * rng.standard_normal((nwalkers, ndim - p))], axis=1)


def load_posterior(fit_result: FitResult, measurements, store, *, name: str | None = None, **options) -> Posterior:
    """Rebuild the `Posterior` of a chain stored by ``posterior(..., store=...)`` without sampling more.

    Arguments:
        fit_result: the fit the chain belongs to.
        measurements: the data it was sampled on.
        store: the HDF5 file.
        name: the run's group name (default: the model spec).
        **options: the ``likelihood``, ``noise``, ``prior`` and ``max_samples`` the chain was run with (defaults as
            in `posterior`; the CLI uses the defaults).

    Returns:
        The `Posterior` of the stored steps.

    Raises:
        ValueError: the file holds no chain for that fit.
    """
    run_name = (name or fit_result.spec).replace("/", "_")
    backend = StepBackend(str(store), name=f"posteriors/{run_name}/chain", read_only=True)
    try:
        steps = backend.iteration
        nwalkers = backend.shape[0]
    except (KeyError, OSError):
        raise ValueError(f"{store}: no stored chain for {run_name!r}; run `brdffit posterior` first") from None
    return posterior(fit_result, measurements, nwalkers=nwalkers, nsteps=steps, store=store, name=name,
                     resume=True, progress=False, **options)
