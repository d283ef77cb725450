"""Polynomial terms added to a linear reference's rows: the named nonlinear damping
(``M_q|q|``) and the terms the residual search of ``flightgp diagnose`` finds (``M_w^3``,
``M_q*w``, ``L_theta_1c|theta_1c|``).

A term is ``<row letter>_<factor>`` and adds ``value * factor`` to the derivative of the row's
state (:attr:`validation.vehicles.state_space.LinearReference.row_letters`). A factor is one of

- ``s|s|``: signed square of a state or input ``s`` (quadratic damping or stiffness, which keep
  the sign of the motion: Padfield, *Helicopter Flight Dynamics*, 2nd ed., 2007, ch. 4, on where
  the linear derivatives stop holding);
- ``s^3``: cube of ``s`` (a hardening or softening restoring term, the Duffing oscillator's;
  Nayfeh & Mook, *Nonlinear Oscillations*, 1979, ch. 4);
- ``a*b``: product of two different signals (an inertial or aerodynamic coupling).

Inputs in a factor are the held inputs after the dead bands, limits, rate limits and gains of
the input effects, before their delays and lags. The
replay (:func:`propagate_with_terms`) enters the terms through the reference's exact
zero-order-hold discretisation as extra inputs, each held over a sample interval at its mean of
the interval's two ends (Heun's predictor-corrector); its error is second order in the step.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from validation.core.errors import BadInputError
from validation.vehicles.linear_discretisation import zero_order_hold

#: Factor kinds, in the order the search's library lists them.
FACTOR_KINDS = ("signed_square", "cube", "product")


@dataclass(frozen=True)
class PolynomialTerm:
    """One parsed term.

    Attributes
    ----------
    name : str
        ``"M_q|q|"``.
    letter : str
        Derivative row letter.
    kind : str
        One of :data:`FACTOR_KINDS`.
    signals : tuple of str
        The state or input names in the factor (one, or two for a product).
    """

    name: str
    letter: str
    kind: str
    signals: tuple

    @property
    def factor(self) -> str:
        """The factor as written in the name (``"q|q|"``)."""
        return self.name.partition("_")[2]


def term_name(letter: str, kind: str, *signals: str) -> str:
    """The name of a term: ``term_name("M", "signed_square", "q") == "M_q|q|"``,
    ``"cube"`` -> ``"M_w^3"``, ``"product"`` -> ``"M_q*w"``."""
    if kind == "signed_square":
        return f"{letter}_{signals[0]}|{signals[0]}|"
    if kind == "cube":
        return f"{letter}_{signals[0]}^3"
    return f"{letter}_{signals[0]}*{signals[1]}"


def parse_term(name: str, letters, signal_names) -> PolynomialTerm | None:
    """The term called ``name`` with a row letter of ``letters`` and signals of
    ``signal_names``, or None when ``name`` is not such a term."""
    letter, _, factor = name.partition("_")
    if letter not in letters:
        return None
    if factor.endswith("|") and factor.count("|") == 2:
        signal = factor.split("|")[0]
        parsed = PolynomialTerm(name, letter, "signed_square", (signal,))
    elif factor.endswith("^3"):
        parsed = PolynomialTerm(name, letter, "cube", (factor[:-2],))
    elif factor.count("*") == 1:
        parsed = PolynomialTerm(name, letter, "product", tuple(factor.split("*")))
    else:
        return None
    if not all(signal in signal_names for signal in parsed.signals) or term_name(letter, parsed.kind,
                                                                                  *parsed.signals) != name:
        return None
    if parsed.kind == "product" and parsed.signals[0] == parsed.signals[1]:
        return None
    return parsed


def library(letters, signals) -> list[str]:
    """Every term of rows ``letters`` in ``signals``: each signal's signed square and cube,
    each pair's product."""
    names = []
    for letter in letters:
        names += [term_name(letter, kind, signal) for signal in signals for kind in ("signed_square", "cube")]
        names += [term_name(letter, "product", a, b) for a, b in combinations(signals, 2)]
    return names


#: Factor kinds of a search term held in a slot of a batched replay (the nonlinear references'
#: :func:`slot_values`), by index: the library's three and ``linear``, the signal itself (the
#: residual search's linear columns).
SLOT_FACTOR_KINDS = (*FACTOR_KINDS, "linear")
#: The arrays that hold a replay's search terms, one entry per slot (:func:`slot_values`).
SLOT_KEYS = ("search_kind", "search_first", "search_second", "search_row", "search_value")


def parse_search_term(term: str, letters, signal_names) -> tuple[str, str, tuple]:
    """``(row letter, factor kind, signals)`` of a search term of a nonlinear reference: a
    library term (:func:`parse_term`), or ``<letter>_<signal>``, a term linear in one signal
    (kind ``linear``, :data:`SLOT_FACTOR_KINDS`)."""
    letter, _, factor = term.partition("_")
    parsed = parse_term(term, letters, signal_names)
    return (letter, "linear", (factor,)) if parsed is None else (letter, parsed.kind, parsed.signals)


def slot_indices(term: str, letters, signal_names) -> tuple[int, int, int, int]:
    """Where a search term sits in a replay's slot: the indices of its factor kind in
    :data:`SLOT_FACTOR_KINDS`, of its first and (for a product, else again the first) second
    signal in ``signal_names`` and of its row in ``letters``."""
    letter, kind, signals = parse_search_term(term, letters, signal_names)
    return (SLOT_FACTOR_KINDS.index(kind), list(signal_names).index(signals[0]),
            list(signal_names).index(signals[-1]), list(letters).index(letter))


def search_slots(effect_lists, letters, signal_names, count: int) -> dict:
    """The search terms (``"effect": "search_term"``) of B effect lists in ``count`` slots each:
    :data:`SLOT_KEYS` -> arrays (B, count), integers but ``search_value`` (:func:`slot_indices`;
    an empty slot adds 0), for :func:`slot_values`.

    Raises
    ------
    BadInputError
        More than ``count`` search terms in one list (``check_effects`` refuses them first, by
        the reference's ``max_search_terms``).
    """
    slots = {key: np.zeros((len(effect_lists), count), dtype=float if key == "search_value" else np.int32)
             for key in SLOT_KEYS}
    for member, effects in enumerate(effect_lists):
        searched = [effect for effect in effects if effect.get("effect") == "search_term"]
        if len(searched) > count:
            raise BadInputError(f"at most {count} search terms per replay, got {len(searched)}")
        for slot, effect in enumerate(searched):
            for key, value in zip(SLOT_KEYS, (*slot_indices(effect["term"], letters, signal_names),
                                              float(effect["value"]))):
                slots[key][member, slot] = value
    return slots


def search_term_description(term: str, row_words: dict) -> str:
    """``"<row's words> proportional to <factor>"`` (``"yaw moment proportional to V|V|"``)."""
    letter, _, factor = term.partition("_")
    return f"{row_words[letter]} proportional to {factor}"


def search_term_unit(term: str, letters, signal_names, *, row_units: dict, signal_units: dict) -> str:
    """A search term's unit: its row's unit (``row_units[letter]``) per unit of its factor
    (``N m/(rad/s)^2`` for ``M_Q|Q|``, ``N/(m/s rad/s)`` for ``Y_U*R``, ``N m/rad`` for
    ``M_theta``; a signal of unit ``"1"`` adds none)."""
    letter, kind, signals = parse_search_term(term, letters, signal_names)
    row = row_units[letter]
    power = {"signed_square": 2, "cube": 3}.get(kind, 1)
    units = [signal_units[s] for s in (signals if kind == "product" else signals[:1])]
    units = [u for u in units if u != "1"]
    if not units:
        return row
    if len(units) == 2:
        return f"{row}/({units[0]} {units[1]})"
    unit = units[0]
    if power > 1:
        return f"{row}/({unit})^{power}"
    return f"{row}/({unit})" if "/" in unit else f"{row}/{unit}"


def slot_values(xp, signals, slots: dict, *, rows: int = 6):
    """What the search terms held in slots add to each row: ``sum_k value_k factor_k`` on row
    ``row_k``, for numpy or ``jax.numpy`` alike (``xp``).

    Parameters
    ----------
    xp : module
        ``numpy`` or ``jax.numpy``.
    signals : ndarray, shape (..., n_signals)
        The signals the factors use.
    slots : dict of str to ndarray
        ``search_kind`` (:data:`SLOT_FACTOR_KINDS` by index), ``search_first``,
        ``search_second`` (signal indices), ``search_row`` (row index; integers) and
        ``search_value``, each shape (..., K), broadcasting against ``signals``' leading axes.
    rows : int

    Returns
    -------
    ndarray, shape (broadcast leading axes, rows)
    """
    first = xp.take_along_axis(signals, slots["search_first"], axis=-1)
    second = xp.take_along_axis(signals, slots["search_second"], axis=-1)
    kind = slots["search_kind"]
    factor = xp.where(kind == 0, first * xp.abs(first),
                      xp.where(kind == 1, first**3, xp.where(kind == 2, first * second, first)))
    hits = slots["search_row"][..., None] == xp.arange(rows)
    return xp.sum(xp.where(hits, (slots["search_value"] * factor)[..., None], 0.0), axis=-2)


def factor_values(terms, signal_names, signals: np.ndarray) -> np.ndarray:
    """The factors of ``terms`` at the signal values ``signals``.

    Parameters
    ----------
    terms : sequence of PolynomialTerm
    signal_names : sequence of str
        Names of the last axis of ``signals``.
    signals : ndarray, shape (..., n_signals)

    Returns
    -------
    ndarray, shape (..., len(terms))
    """
    index = {name: i for i, name in enumerate(signal_names)}
    columns = []
    for term in terms:
        first = signals[..., index[term.signals[0]]]
        if term.kind == "signed_square":
            columns.append(first * np.abs(first))
        elif term.kind == "cube":
            columns.append(first ** 3)
        else:
            columns.append(first * signals[..., index[term.signals[1]]])
    return np.stack(columns, axis=-1)


def propagate_with_terms(terms, values, rows, *, F: np.ndarray, step: float, Phi: np.ndarray,
                         forcing: np.ndarray, held: np.ndarray, n_states: int, signal_names) -> np.ndarray:
    """``x[k+1] = Phi x[k] + forcing[k] + sum_i Gamma_i c_i m_i[k]`` from trim (0), ``m_i[k]``
    term i's factor at the interval's mean of its start and its predicted end (module docstring):
    ``Gamma_i`` the exact zero-order-hold response of the augmented system ``F`` to a unit rate on
    term i's row.

    Parameters
    ----------
    terms : sequence of PolynomialTerm
    values : sequence of float
        The terms' coefficients.
    rows : sequence of int
        Index of each term's row state.
    F : ndarray, shape (size, size)
        The augmented continuous system (rigid body first, then lag states).
    step : float
        s.
    Phi : ndarray, shape (size, size)
        ``exp(F step)``.
    forcing : ndarray, shape (n - 1, size)
        The inputs' contribution over each interval.
    held : ndarray, shape (n - 1, n_inputs)
        The held inputs after the dead bands, limits, rate limits and gains (before delays and
        lags).
    n_states : int
        Rigid-body states (the first ``n_states`` of the augmented state).
    signal_names : sequence of str
        The states', then the inputs' names.

    Returns
    -------
    ndarray, shape (n, size)
    """
    unit = np.zeros((len(F), len(terms)))
    for i, row in enumerate(rows):
        unit[row, i] = 1.0
    Gamma_c = zero_order_hold(F, unit, step)[1] * np.asarray(values, dtype=float)
    states = np.zeros((len(forcing) + 1, len(F)))
    index = {name: i for i, name in enumerate(signal_names)}
    specs = [(FACTOR_KINDS.index(term.kind), index[term.signals[0]], index[term.signals[-1]]) for term in terms]
    if len(specs) == 1 and specs[0][0] != FACTOR_KINDS.index("product") and specs[0][1] < n_states:
        return _propagate_one_state_term(specs[0][0], specs[0][1], Gamma_c[:, 0], Phi, forcing, states)
    # Per step in Python floats (numpy's per-call cost would dominate a handful of terms).
    held_rows = held.tolist()
    sources = sorted({i for _, a, b in specs for i in (a, b) if i < n_states})
    gamma_rows = {source: Gamma_c[source].tolist() for source in sources}
    x = states[0]
    for k in range(len(forcing)):
        linear = Phi @ x + forcing[k]
        start_values = x.tolist()[:n_states] + held_rows[k]
        start = [scalar_factor(kind, start_values[a], start_values[b]) for kind, a, b in specs]
        end_values = list(start_values)
        linear_values = linear.tolist()
        for source in sources:
            end_values[source] = linear_values[source] + sum(g * m for g, m in zip(gamma_rows[source], start))
        mean = [0.5 * (m + scalar_factor(kind, end_values[a], end_values[b])) for m, (kind, a, b) in zip(start, specs)]
        x = linear + Gamma_c @ mean  # Heun: the terms' mean over the interval
        states[k + 1] = x
    return states


def _propagate_one_state_term(kind: int, source: int, gamma: np.ndarray, Phi, forcing, states) -> np.ndarray:
    """:func:`propagate_with_terms` for one signed square or cube of one state: the same
    recursion with the factor inline, the usual case (a named damping; 7 ms against 11 ms per
    2000-step replay through the general loop)."""
    gamma_source = float(gamma[source])
    for k in range(len(forcing)):
        linear = Phi @ states[k] + forcing[k]
        s = float(states[k, source])
        start = s * abs(s) if kind == 0 else s * s * s
        predicted = float(linear[source]) + gamma_source * start
        end = predicted * abs(predicted) if kind == 0 else predicted * predicted * predicted
        states[k + 1] = linear + gamma * (0.5 * (start + end))
    return states


def scalar_factor(kind: int, a: float, b: float) -> float:
    """One factor of two numbers (:data:`SLOT_FACTOR_KINDS` by index, whose first three are
    :data:`FACTOR_KINDS`): ``a|a|``, ``a^3``, ``a b`` or ``a``."""
    if kind == 0:
        return a * abs(a)
    if kind == 1:
        return a * a * a
    return a * b if kind == 2 else a
