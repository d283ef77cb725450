"""Search: what the effects found so far leave unexplained, regressed on a library of candidate
terms (sparse identification in the manner of SINDy); the survivors compete in the stepwise
search of :mod:`validation.diagnose.explain`, where output error refines them.

At each step of the stepwise search, a linear reference with the effects found so far is
replayed (``x_c``), and each library term ``theta_j(x, u)``, added to row ``i`` with a small
coefficient ``c_j``, would move the recorded outputs by ``c_j s_j(t)``, where ``s_j`` is the
response of the model's linear dynamics (``A_c``, the corrected state matrix) to the forcing
``e_i theta_j(x_c(t), u(t))``: exact to first order in ``c_j`` (the terms enter the dynamics the
way an input does, through the same zero-order-hold discretisation). So the noise-weighted
output residual is regressed on the weighted sensitivities, all terms at once::

    (y - x_c) / sigma  =  sum_j c_j s_j / sigma  +  noise

which is output error linearised at the current model (its first Gauss-Newton step) over the
whole library, rather than SINDy's regression of differentiated states (Brunton, Proctor &
Kutz, PNAS 113(15), 2016): sensor noise is not differentiated, and a term is judged by what it
does to the recorded outputs, as every named hypothesis is. The library, per derivative row:
the linear terms of every state and excited input (so that no nonlinear term stands in for a
linear error), and the signed squares, cubes and products of the row's *axis*
(:mod:`validation.vehicles.polynomial_terms`): its own state and the states and inputs whose
linear contribution to its rate is at least :data:`AXIS_FRACTION` of the largest. A term whose
sensitivity the linear terms reproduce to :data:`COLLINEAR` of its energy is left out (these data
cannot tell it from a derivative: an input's ``u|u|`` on steps of one amplitude). The sparse
regression keeps every linear term and selects nonlinear ones forward, the largest |t| beside
those already in first, while it passes a two-sided test at :data:`SCREEN_ALPHA` (orthogonal
forward regression, the term selection of NARMAX identification: Billings, Chen & Korenberg,
Int. J. Control 49(6), 1989). Forward rather than SINDy's backward thresholding, because the
library's siblings (``v|v|``, ``v^3``, ``v*p``) are so alike that thresholding them together
drops them together. That is a screen, not the decision (the residual is not white where
physics is missing, so its t statistics are optimistic); the decision below has the
multiplicity correction.

Surviving nonlinear terms (on the linear references linear survivors are derivative errors,
the named hypotheses' business, and are not offered, nor are terms a named hypothesis already
has, ``M_q|q|`` or ``N_v^3``; on the blimp, below, the linear terms it does not name are offered too)
become ``search_term`` hypotheses beside the named ones, the :data:`MAX_CANDIDATES` largest |t|
with their siblings: screened, fitted by output error and accepted by the same rule
(:func:`validation.diagnose.fitting.weigh_step`, Bonferroni over the named hypotheses and the
library together), so a nonlinear term competes with the linear derivative it would otherwise be
taken for. Accepted terms are reported as found by search, not as named effects.

The terms are evaluated on the model's replayed states, so outputs need not all be measured; the
search needs a reference that takes ``search_term`` and otherwise reports why it did not run.

**On a nonlinear reference** that takes them (the blimp: a term is a generalised force of its
row, :mod:`validation.vehicles.blimp_effects`; the RGBlimp: a body acceleration of its row,
:mod:`validation.vehicles.rgblimp_effects`; an FMU: an extra input of its row's input,
:mod:`validation.vehicles.fmu_reference`) there is no linear model to propagate the
forcing through, so each term's sensitivity is replayed: the model with the term added at a
small coefficient, one batch of replays for the whole library, exact to first order through the
reference's own equations (the "output sensitivities from replays" of a model without
linearisation; through an FMU, the FMU itself with the term fed into the input). The axes
come from the reference's Jacobian of its rows along the replay (``search_jacobian``; an FMU,
whose equations are closed, puts every signal on every input's axis), the sensitivities are
scaled to unit length before the regression (the terms' units span many decades), and, because
these named lists hold few derivatives, the linear terms that are not named compete in the
forward selection beside the nonlinear ones (``M_U``, a pitch moment linear in surge speed, is
then a finding of the search on the blimp).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from validation.diagnose.fitting import FitData, FittedModel
from validation.vehicles.effects import EffectModel, Hypothesis
from validation.vehicles.linear_discretisation import zero_order_hold
from validation.vehicles.polynomial_terms import factor_values, library, parse_term, term_name

#: A state or input belongs to a row's axis when its linear contribution to the row's rate (the
#: derivative times the signal's RMS) is at least this fraction of the row's largest.
AXIS_FRACTION = 0.1
#: Two-sided level of each term's t test in the regression (a screen: :func:`_sparse_regression`).
SCREEN_ALPHA = 0.01
#: A library term whose weighted sensitivity the linear terms reproduce to this fraction of its
#: energy is left out: these data cannot tell it from a linear derivative.
COLLINEAR = 1e-3
#: Screening step of a search term, a fraction of the regression's coefficient: 5 %, as a
#: derivative's (:meth:`validation.vehicles.linear_effects.LinearEffects.term_hypotheses`), where
#: one Gauss-Newton step stays near linear; the floor keeps a step where the coefficient is 0.
SEARCH_STEP = 0.05
SEARCH_STEP_FLOOR = 1e-12
#: Generalised force (N, or N m; on the RGBlimp an acceleration, m/s^2 or rad/s^2; through an FMU
#: an input, in its unit) a library term
#: is added with to find its sensitivity by replay on a nonlinear reference
#: (:func:`_replayed_normal_equations`), over the RMS of its factor: about 3e-6 of the blimp's
#: weight (3.4 N), 1e-6 of gravity, so its response is linear, yet far above rounding.
SENSITIVITY_FORCE = 1e-5
#: Survivors offered to each step of the stepwise search, the largest |t| first (each with its
#: sibling, :func:`_sibling`).
MAX_CANDIDATES = 4


@dataclass
class SearchCandidates:
    """Outcome of :func:`search_candidates`.

    Attributes
    ----------
    hypotheses : list of Hypothesis
        One ``search_term`` hypothesis per offered survivor (nonlinear; on the blimp also a
        linear term it does not name) and its sibling, null 0, unbounded.
    library_terms : int
        Terms regressed on, over every row (the size of the family the survivors come from).
    survivors : list of dict
        ``term``, ``coefficient`` (the regression's estimate, the term's unit), ``t``.
    reason : str or None
        Why the search did not run (None when it ran).
    """

    hypotheses: list = field(default_factory=list)
    library_terms: int = 0
    survivors: list = field(default_factory=list)
    reason: str | None = None


def search_candidates(data: FitData, reference: EffectModel, model: FittedModel, *, excited) -> SearchCandidates:
    """Regress the error of ``model`` on the term library (module docstring) and return its
    survivors as hypotheses.

    Parameters
    ----------
    data : FitData
        The recordings; the terms' inputs are the recorded ones (a screen: output error then
        replays each survivor with the model's own input effects).
    reference : EffectModel
        A reference that takes ``search_term``: a linear one, or one with ``search_jacobian``
        (the blimp, the RGBlimp, an FMU with input terms); any other gets a reason.
    model : FittedModel
        The effects found so far, jointly fitted.
    excited : sequence of str
        The inputs that move (the others get no linear or library terms).

    Returns
    -------
    SearchCandidates
    """
    linear = getattr(reference, "reference", None)
    if "search_term" in reference.kinds and hasattr(linear, "row_letters"):
        letters, signal_names = linear.row_letters, linear.state_names + linear.input_names
        equations, linear_offered = _normal_equations(data, reference, linear, model.effects(), excited), False
    elif "search_term" in reference.kinds and hasattr(reference, "search_jacobian"):
        letters, signal_names = reference.search_rows, reference.search_signals
        equations, linear_offered = _replayed_normal_equations(data, reference, model.effects(), excited), True
    else:
        return SearchCandidates(reason=f"the {reference.name} reference takes no searched terms (the linear "
                                       "references, the blimp, the RGBlimp and, with input terms, an FMU do)")
    if equations is None:
        return SearchCandidates(reason="no fitted samples, or no term of the library moves the outputs")
    gram, projection, energy, count, names, column_norms = equations
    # Coefficients per unit of a column scaled to unit length back to the term's unit.
    unit = dict(zip(names, column_norms))
    # Terms already hypotheses, or named effects screened as such, are not offered again.
    taken = {h.target for h in model.hypotheses if h.effect == "search_term"}
    taken |= {term for kind, terms in reference.terms.items() if kind != "search_term" for term in terms}
    # Library terms the reference does not offer (an FMU's input gain) are regressed on, not offered.
    taken |= set(getattr(reference, "search_library", ())) - set(reference.terms["search_term"])
    survivors = sorted(_sparse_regression(gram, projection, energy, count, names, offered_not=taken,
                                          linear_offered=linear_offered), key=lambda survivor: -abs(survivor[2]))
    offered = {}
    for term, coefficient, _ in survivors[:MAX_CANDIDATES]:
        offered.setdefault(term, coefficient / unit[term])
        sibling = _sibling(term, letters, signal_names, coefficient, gram=gram, names=names)
        if sibling is not None and sibling[0] not in taken:
            offered.setdefault(sibling[0], sibling[1] / unit[sibling[0]])
    survivors = [(term, coefficient / unit[term], t) for term, coefficient, t in survivors]
    return SearchCandidates([_hypothesis(term, coefficient) for term, coefficient in offered.items()], len(names),
                            [{"term": term, "coefficient": coefficient, "t": t} for term, coefficient, t in survivors])


def _sibling(term: str, letters, signal_names, coefficient: float, *, gram: np.ndarray, names: list):
    """The other odd power of the same signal in the same row (``M_w^3`` for ``M_w|w|`` and
    back), its coefficient matching the survivor's weighted sensitivity in least squares, or
    None for a product or a sibling not in the library: one amplitude barely tells a signed
    square from a cube, so output error chooses between them (and reports the other with its
    evidence ratio)."""
    parsed = parse_term(term, letters, signal_names)
    if parsed is None or parsed.kind == "product":
        return None
    other = term_name(parsed.letter, "cube" if parsed.kind == "signed_square" else "signed_square", parsed.signals[0])
    if other not in names:
        return None
    i, j = names.index(term), names.index(other)
    return other, coefficient * float(gram[i, j]) / float(gram[j, j]) if gram[j, j] > 0 else 0.0


def _hypothesis(term: str, coefficient: float) -> Hypothesis:
    """A search term free from 0 (no term), unbounded, screened at :data:`SEARCH_STEP` of the
    regression's value (at least :data:`SEARCH_STEP_FLOOR`)."""
    return Hypothesis("search_term", term, 0.0, -math.inf, math.inf,
                      max(SEARCH_STEP * abs(coefficient), SEARCH_STEP_FLOOR))


def _library(linear, A: np.ndarray, signal_rms: np.ndarray, excited) -> tuple[list, list, list]:
    """The library (module docstring): names, and per term its row index (in the state vector)
    and its factor (a signal's index for a linear term, a PolynomialTerm otherwise)."""
    state_names, input_names = linear.state_names, linear.input_names
    signal_names = state_names + input_names
    moving = [name for name in input_names if name in excited]
    names, rows, factors = [], [], []
    B = linear.B
    for letter, row_state in linear.row_letters.items():
        row = state_names.index(row_state)
        contribution = np.abs(np.concatenate((A[row], B[row]))) * signal_rms
        axis = [name for name, size in zip(signal_names, contribution)
                if (name == row_state or size >= AXIS_FRACTION * contribution.max())
                and (name in state_names or name in moving)]
        for name in list(state_names) + moving:
            names.append(f"{letter}_{name}")
            rows.append(row)
            factors.append(signal_names.index(name))
        for name in library([letter], axis):
            names.append(name)
            rows.append(row)
            factors.append(parse_term(name, linear.row_letters, signal_names))
    return names, rows, factors


def _normal_equations(data: FitData, reference: EffectModel, linear, effects: list, excited):
    """``(gram, projection, energy, n, names, column_norms)`` of the regression of the weighted residual on the
    weighted sensitivities (module docstring): ``G^T G`` (L, L), ``G^T r`` (L,), ``r^T r``, the
    number of residuals and the library's names; None when nothing is fitted."""
    derivatives = {e["term"]: e["value"] for e in effects if e["effect"] in ("control_derivative",
                                                                              "stability_derivative")}
    A = (linear.with_derivatives(derivatives) if derivatives else linear).A
    state_names = linear.state_names
    signal_names = state_names + linear.input_names
    replays = data.simulate_states(reference, [effects], fitted_only=True)
    parts = [(replay[0], measured, u, time, mask, sd) for replay, measured, u, time, mask, sd
             in zip(replays, data.measured, data.inputs, data.time, data.fit_mask, data.noise_sd) if replay is not None]
    if not parts:
        return None
    signals = [np.concatenate((x_c, u), axis=1) for x_c, _, u, _, _, _ in parts]
    rms = np.sqrt(np.mean(np.concatenate([s[mask] for s, (*_, mask, _) in zip(signals, parts)]) ** 2, axis=0))
    names, rows, factors = _library(linear, A, rms, excited)
    outputs = [state_names.index(name) for name in data.output_names]
    polynomial = [i for i, factor in enumerate(factors) if not isinstance(factor, int)]
    linear_columns = [i for i, factor in enumerate(factors) if isinstance(factor, int)]
    gram, projection, energy, count = 0.0, 0.0, 0.0, 0
    for (x_c, measured, _, time, mask, sd), signal in zip(parts, signals):
        step = float(time[1] - time[0])
        unit = np.zeros((len(state_names), len(state_names)))
        unit[rows, rows] = 1.0
        Phi, Gamma = zero_order_hold(A, unit, step)
        Gamma = Gamma[:, rows]  # (n_states, L): each term's row forcing
        theta = np.empty((len(time), len(names)))
        theta[:, linear_columns] = signal[:, [factors[i] for i in linear_columns]]
        theta[:, polynomial] = factor_values([factors[i] for i in polynomial], signal_names, signal)
        forcing = theta[:-1, None, :] * Gamma[None]  # (n - 1, n_states, L), held over each interval
        response = np.zeros((len(time), len(state_names), len(names)))
        for k in range(len(time) - 1):
            response[k + 1] = Phi @ response[k] + forcing[k]
        weighted = (response[mask][:, outputs, :] / sd[None, :, None]).reshape(-1, len(names))
        residual = ((measured[mask] - x_c[mask][:, outputs]) / sd).ravel()
        gram = gram + weighted.T @ weighted
        projection = projection + weighted.T @ residual
        energy += float(residual @ residual)
        count += len(residual)
    return gram, projection, energy, count, names, np.ones(len(names))


def _replayed_normal_equations(data: FitData, reference: EffectModel, effects: list, excited):
    """:func:`_normal_equations` for a nonlinear reference that takes ``search_term`` and says how
    strongly each signal drives each row (``search_jacobian``: the blimp's, the RGBlimp's, an
    FMU's): each library term's weighted sensitivity is the change of the replayed outputs when the term is added with a
    small coefficient (:data:`SENSITIVITY_FORCE` over the factor's RMS), divided by it: one
    batch of replays, exact to first order as the linear references' responses are, through the
    reference's own nonlinear equations (module docstring)."""
    replays = data.simulate_states(reference, [effects], fitted_only=True)
    parts = [(replay[0], u, mask) for replay, u, mask in zip(replays, data.inputs, data.fit_mask)
             if replay is not None]
    if not parts:
        return None
    signal_names = list(reference.search_signals)
    states, inputs = list(reference.state_names), list(reference.input_names)
    columns = [(0, states.index(s)) if s in states else (1, inputs.index(s)) for s in signal_names]
    signals = [np.stack([(x, u)[where][:, column] for where, column in columns], axis=1) for x, u, _ in parts]
    fitted = np.concatenate([z[mask] for z, (*_, mask) in zip(signals, parts)])
    rms = np.sqrt(np.mean(fitted ** 2, axis=0))
    contribution = reference.search_jacobian([x for x, _, _ in parts], [u for _, u, _ in parts]) * rms
    allowed = set(getattr(reference, "search_library", reference.terms["search_term"]))
    usable = [s for s in signal_names if s not in reference.input_names or s in excited]
    names = []
    for row, (letter, own) in enumerate(reference.search_rows.items()):
        axis = [s for s in usable if s == own or contribution[row, signal_names.index(s)]
                >= AXIS_FRACTION * contribution[row].max()]
        names += [name for name in [f"{letter}_{s}" for s in usable] + library([letter], axis) if name in allowed]
    factors = [parse_term(name, reference.search_rows, signal_names) or name.partition("_")[2] for name in names]
    size = np.array([rms[signal_names.index(f)] if isinstance(f, str) else
                     float(np.sqrt(np.mean(factor_values([f], signal_names, fitted) ** 2))) for f in factors])
    kept = size > 0
    names = [name for name, keep in zip(names, kept) if keep]
    if not names:
        return None
    steps = SENSITIVITY_FORCE / size[kept]
    base, *moved = data.weighted_residuals_many(  # the model itself, then with each term
        reference, [effects] + [effects + [{"effect": "search_term", "term": name, "value": step}]
                                for name, step in zip(names, steps)])
    sensitivity = (base[None, :] - np.array(moved)) / steps[:, None]  # (L, N): d(replay)/d(coefficient), weighted
    # Each column to unit length (the coefficients' units span many decades, a cube of a rate
    # beside a command): the regression is unchanged, its pseudo-inverses well conditioned.
    norms = np.linalg.norm(sensitivity, axis=1)
    moves = norms > 1e-9 * norms.max(initial=0.0)  # not a column of rounding noise made unit length
    if not moves.any():
        return None
    unit = sensitivity[moves] / norms[moves, None]
    return (unit @ unit.T, unit @ base, float(base @ base), len(base), [n for n, m in zip(names, moves) if m],
            norms[moves])


def _sparse_regression(gram: np.ndarray, projection: np.ndarray, energy: float, count: int,
                       names: list, *, offered_not=frozenset(), linear_offered: bool = False) -> list:
    """Forward selection of nonlinear terms on t statistics beside every linear term (module
    docstring), from the normal equations: the survivors as ``(term, coefficient, t)``, at most
    :data:`MAX_CANDIDATES`, in the order selected. Terms in ``offered_not`` are left out, so they
    take no candidate's place; not regressed either, as they are screened on their own, and a
    sibling the data barely tell from one of them (``N_v|v|`` for ``N_v^3``) may stand in for it.
    ``linear_offered``: the linear terms not in ``offered_not`` compete in the pool too (a reference
    whose named list lacks most derivatives, the blimp's); the named ones stay in the base."""
    nonlinear = np.array([_is_nonlinear(name) for name in names])
    usable = (np.diag(gram) > 0) & ~(nonlinear & _linear_in_these_data(gram, nonlinear))
    kept_out = np.array([name in offered_not for name in names])
    offered = nonlinear | linear_offered
    base = list(np.flatnonzero(usable & ~nonlinear & (kept_out | ~offered)))
    pool = list(np.flatnonzero(usable & offered & ~kept_out))
    critical = stats.norm.isf(SCREEN_ALPHA / 2)
    selected = []
    for _ in range(MAX_CANDIDATES):
        if not pool:
            break
        t = _t_if_added(gram, projection, energy, count, base + selected, pool)
        best = int(np.argmax(np.abs(t)))
        if abs(t[best]) < critical:
            break
        selected.append(pool.pop(best))
    if not selected:
        return []
    coefficients, t = _least_squares(gram, projection, energy, count, base + selected)
    offset = len(base)
    return [(names[column], float(coefficients[offset + i]), float(t[offset + i])) for i, column in enumerate(selected)]


def _t_if_added(gram, projection, energy, count, active: list, pool: list) -> np.ndarray:
    """The t statistic each column of ``pool`` would have, added alone to the regression on
    ``active`` (from the normal equations by the Schur complement, one factorisation for the
    whole pool): with ``W = G_AA^-1 G_Ap``, the column's energy beyond the active ones is
    ``d = G_pp - G_pA W``, its coefficient ``c = (r_p - W^T r_A) / d``, the residual sum of squares
    falls by ``c^2 d``, and ``t = c sqrt(d / s^2)``. Zero where ``d`` vanishes (a column the active
    ones reproduce)."""
    inverse = np.linalg.pinv(gram[np.ix_(active, active)])
    cross = gram[np.ix_(active, pool)]
    weights = inverse @ cross
    beyond = np.diag(gram)[pool] - np.einsum("ap,ap->p", cross, weights)
    along = projection[pool] - weights.T @ projection[active]
    rss_active = energy - float(projection[active] @ inverse @ projection[active])
    safe = np.where(beyond > 1e-12 * np.diag(gram)[pool], beyond, np.inf)
    coefficient = along / safe
    variance = np.maximum(rss_active - coefficient * along, 1e-300) / max(count - len(active) - 1, 1)
    return coefficient * np.sqrt(np.where(np.isfinite(safe), safe, 0.0) / variance)


def _least_squares(gram, projection, energy, count, columns) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients and t statistics of the regression on ``columns`` from the normal equations."""
    inverse = np.linalg.pinv(gram[np.ix_(columns, columns)])
    coefficients = inverse @ projection[columns]
    variance = max(energy - float(coefficients @ projection[columns]), 1e-300) / max(count - len(columns), 1)
    return coefficients, coefficients / np.sqrt(np.maximum(np.diag(inverse) * variance, 1e-300))


def _is_nonlinear(name: str) -> bool:
    """Whether library term ``name`` is a polynomial term rather than a linear one."""
    return any(mark in name for mark in ("|", "^", "*"))


def _linear_in_these_data(gram: np.ndarray, nonlinear: np.ndarray) -> np.ndarray:
    """Per library column: whether the linear columns reproduce its sensitivity to
    :data:`COLLINEAR` of its energy (from the normal equations ``gram``), so that these data
    cannot tell the term from a linear derivative (an input's signed square or cube on a
    manoeuvre that moves it between trim and one amplitude is exactly a multiple of the input:
    ``u|u| = A u`` for ``u`` in ``{0, A, -A}``)."""
    linear = np.flatnonzero(~nonlinear)
    if not len(linear):
        return np.zeros(len(gram), dtype=bool)
    cross = gram[np.ix_(linear, np.arange(len(gram)))]
    explained = np.einsum("ij,ij->j", cross, np.linalg.pinv(gram[np.ix_(linear, linear)]) @ cross)
    return np.diag(gram) - explained <= COLLINEAR * np.maximum(np.diag(gram), 1e-300)
