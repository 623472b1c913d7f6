"""The least-squares estimate: the optimiser, identifiability and standard errors.

:func:`fit_parameters` hands :func:`scipy.optimize.least_squares` the residual
and its forward-difference Jacobian together, refuses quantities the
measurements do not determine (:func:`check_identifiable`) and returns the
estimates with their standard errors and correlations (:class:`FitResult`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Protocol as TypingProtocol, Sequence

import numpy as np

from .parameters import FitError, FitParameter, NotIdentifiableError

#: Relative forward-difference step, as scipy's '2-point' scheme:
#: h = sqrt(eps) max(1, |x|) balances truncation and rounding error.
FD_RELATIVE_STEP = math.sqrt(np.finfo(float).eps)
#: A parameter whose relative sensitivity |dF/dx| |x| / |F| (norms over the
#: samples) is below this does not act on the force: the forward difference
#: itself carries a relative rounding error of about eps / FD_RELATIVE_STEP
#: = 1.5e-8, so anything within 100 times that is indistinguishable from zero.
MIN_RELATIVE_SENSITIVITY = 1e-6
#: Largest condition index s_max / s_k of the Jacobian with unit-length columns
#: accepted (Belsley, Kuh and Welsch 1980, Regression Diagnostics, ch. 3:
#: above 30 the columns are strongly, above 100 seriously, linearly
#: dependent). Above it J^T J is near-singular: the force determines a
#: combination of some parameters far better than each one, and their
#: standard errors are at least 100 times those of independent columns.
#: Protocol II gives 2.0 for f_iso_max_n, k_se_n_per_m and fv_a_n, and 139 for
#: the Riener fatigue constants tau_fatigue_s and fatigue_min of a 6 s run.
MAX_CONDITION_INDEX = 100.0
#: A parameter takes part in a near-singular direction when at least this
#: share of its estimate's variance comes from that direction (Belsley, Kuh
#: and Welsch's variance-decomposition proportion, their threshold).
VARIANCE_PROPORTION = 0.5
#: Tolerances of least_squares on the cost, the step and the gradient: far
#: below any force noise, yet above the simulation's rounding.
FIT_TOLERANCE = 1e-10
#: Most evaluations (each one K = n + 1 simulations).
MAX_EVALUATIONS = 100


class ForceModel(TypingProtocol):
    """What :func:`fit_parameters` needs of a model: predictions for parameter sets."""

    def predict(self, params: Sequence[Any]) -> np.ndarray:
        """The predicted measurements, one row per parameter set."""


@dataclass(frozen=True)
class FitResult:
    """The outcome of a fit.

    :param parameters: the fitted quantities
    :param start: the start parameters
    :param params: the fitted parameters (the rest unchanged)
    :param start_values: the fitted quantities' start values
    :param estimates: their estimates
    :param std_errors: their standard errors, sqrt(diag(sigma^2 (J^T J)^-1))
    :param correlation: the correlation matrix of the estimates
    :param rms_n: [N] residual RMS at the estimate (in the measured quantity's
        unit: [rad] for a joint angle)
    :param start_rms_n: [N] residual RMS at the start (as ``rms_n``)
    :param n_samples: number of samples fitted
    :param n_evaluations: evaluations of residual and Jacobian together
    :param message: the optimiser's reason to stop
    :param fitted: the prediction at the samples, at the estimate
    """

    parameters: tuple[FitParameter, ...]
    start: Any
    params: Any
    start_values: np.ndarray
    estimates: np.ndarray
    std_errors: np.ndarray
    correlation: np.ndarray
    rms_n: float
    start_rms_n: float
    n_samples: int
    n_evaluations: int
    message: str
    fitted: np.ndarray


def _perturbed(parameters: Sequence[FitParameter], start: Any,
               x: np.ndarray) -> tuple[list[Any], np.ndarray]:
    """The parameter sets of one evaluation: x itself, then x with each entry moved
    by its forward-difference step (backwards at an upper bound), and the steps."""
    base = start
    for p, v in zip(parameters, x):
        base = p.set(base, v)
    sets, steps = [base], np.empty(len(x))
    for j, p in enumerate(parameters):
        h = FD_RELATIVE_STEP * max(1.0, abs(x[j]))
        moved = x[j] + h if x[j] + h <= p.high else x[j] - h
        steps[j] = moved - x[j]   # the step actually taken, after rounding
        sets.append(p.set(base, moved))
    return sets, steps


def _and(names: Sequence[str]) -> str:
    quoted = [f'`{n}`' for n in names]
    return quoted[0] if len(quoted) == 1 else ', '.join(quoted[:-1]) + ' and ' + quoted[-1]


def check_identifiable(parameters: Sequence[Any], x: np.ndarray,
                       jac: np.ndarray, force: np.ndarray, quantity: str = 'force') -> None:
    """Raise if the Jacobian shows fitted quantities the force does not determine.

    :param parameters: the fitted quantities (:class:`FitParameter` or :class:`PlantParameter`)
    :param x: the values at which ``jac`` was taken
    :param jac: [N per unit] d force / d x, one column per quantity
    :param force: [N] the predicted force there (its norm sets the scale)
    :param quantity: what is measured, in the messages (``force``, ``joint angle``)
    :raises NotIdentifiableError: naming the quantities, with the reason
    """
    norms = np.linalg.norm(jac, axis=0)
    scale = max(float(np.linalg.norm(force)), np.finfo(float).tiny)
    sensitivity = norms * np.maximum(np.abs(x), np.finfo(float).tiny) / scale
    dead = [p.name for p, s in zip(parameters, sensitivity) if not s >= MIN_RELATIVE_SENSITIVITY]
    if dead:
        listed = _and(dead)
        raise NotIdentifiableError(dead, f'not identifiable from this recording: {listed} '
                                         f'(the {quantity} does not depend on '
                                         f'{"it" if len(dead) == 1 else "them"})')
    if len(parameters) < 2:
        return
    _, sv, vt = np.linalg.svd(jac / norms, full_matrices=False)
    weak = sv * MAX_CONDITION_INDEX < sv[0]
    if weak.any():
        # Variance-decomposition proportions: the share of each estimate's
        # variance sum_k v_jk^2 / s_k^2 that each singular direction k carries.
        phi = (vt.T / sv) ** 2
        share = phi[:, weak].max(axis=1) / phi.sum(axis=1)
        names = [p.name for p, w in zip(parameters, share) if w >= VARIANCE_PROPORTION]
        listed = _and(names)
        raise NotIdentifiableError(names, f'not identifiable from this recording: {listed} '
                                          f'(J^T J is near-singular: the {quantity} determines '
                                          'only a combination of them; fit fewer of them or use '
                                          'a recording that separates them)')


def fit_parameters(model: ForceModel, measured: np.ndarray, start: Any,
                   parameters: Sequence[Any],
                   progress: Callable[[str], None] | None = None, *,
                   quantity: str = 'force', unit: str = 'N') -> FitResult:
    """Least-squares estimate of ``parameters``, the rest of ``start`` held.

    Each evaluation predicts K = n + 1 parameter sets at once: the residual at
    x and the forward-difference Jacobian columns, handed to
    :func:`scipy.optimize.least_squares` (trust region reflective, within the
    fields' ranges) as ``fun`` and ``jac``.

    :param model: predicts the measurements for parameter sets (:class:`MuscleReplay`)
    :param measured: the measurements, in the order ``model.predict`` returns them
    :param start: the start parameters (their ``replace`` makes the others)
    :param parameters: the quantities to fit
    :param progress: called with one line per evaluation (cost, RMS)
    :param quantity: what ``measured`` is, in the messages (``force``, ``joint angle``)
    :param unit: its unit, in the progress lines
    :raises NotIdentifiableError: at the start or at the estimate
    :raises FitError: if a parameter set on the way is invalid
    """
    from scipy.optimize import least_squares
    parameters = tuple(parameters)
    n = len(parameters)
    m = len(measured)
    if m <= n:
        raise FitError(f'{m} {quantity} samples for {n} parameters: too few to fit')
    x0 = np.array([p.get(start) for p in parameters])
    cache: dict[str, Any] = {}

    def evaluate(x: np.ndarray) -> None:
        if cache.get('x') is not None and np.array_equal(cache['x'], x):
            return
        try:
            sets, steps = _perturbed(parameters, start, x)
        except ValueError as err:
            raise FitError(f'the fit reached invalid parameters: {err}') from None
        forces = model.predict(sets)
        residual = forces[0] - measured
        cache.update(x=x.copy(), residual=residual, force=forces[0],
                     jac=(forces[1:] - forces[0]).T / steps)
        cache['n'] = cache.get('n', 0) + 1
        if progress is not None:
            cost = 0.5 * float(residual @ residual)
            progress(f'evaluation {cache["n"]:3d}: cost {cost:.6g} {unit}^2, RMS '
                     f'{math.sqrt(2.0 * cost / m):.6g} {unit}  ' + ', '.join(
                         f'{p.name}={v:.8g}' for p, v in zip(parameters, x)))

    def fun(x: np.ndarray) -> np.ndarray:
        evaluate(x)
        return cache['residual']

    def jac(x: np.ndarray) -> np.ndarray:
        evaluate(x)
        return cache['jac']

    evaluate(x0)
    start_rms = float(np.sqrt(np.mean(cache['residual'] ** 2)))
    check_identifiable(parameters, x0, cache['jac'], cache['force'], quantity)
    lower = np.array([p.low for p in parameters])
    upper = np.array([p.high for p in parameters])
    result = least_squares(fun, x0, jac=jac, bounds=(lower, upper), method='trf',
                           x_scale='jac', ftol=FIT_TOLERANCE, xtol=FIT_TOLERANCE,
                           gtol=FIT_TOLERANCE, max_nfev=MAX_EVALUATIONS)
    x = result.x
    evaluate(x)
    J, residual = cache['jac'], cache['residual']
    check_identifiable(parameters, x, J, cache['force'], quantity)
    # sigma^2 (J^T J)^-1 through the column-normalised J: same result, better conditioned.
    norms = np.linalg.norm(J, axis=0)
    inv = np.linalg.inv((J / norms).T @ (J / norms)) / np.outer(norms, norms)
    sigma2 = float(residual @ residual) / (m - n)
    cov = sigma2 * inv
    d = np.sqrt(np.diag(inv))
    fitted = start
    for p, v in zip(parameters, x):
        fitted = p.set(fitted, v)
    return FitResult(parameters, start, fitted, x0, x.copy(), np.sqrt(np.diag(cov)),
                     inv / np.outer(d, d), float(np.sqrt(np.mean(residual ** 2))),
                     start_rms, m, cache['n'], str(result.message), cache['force'])
