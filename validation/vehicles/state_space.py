"""Linear references ``x_dot = A x + B u``: the one implementation behind the Bo105 references and
any user's state-space model read from a JSON file (docs/vehicles.md, "State-space models").

A :class:`LinearReference` has named states and inputs (perturbations from trim), matrices ``A``
and ``B``, and *derivative rows*: the states whose rows of ``A`` and ``B`` are a force or moment
equation named by a letter (``X, Z, M, Y, L, N`` for a flight vehicle's ``u, w, q, v, p, r``);
the other states are kinematic (``theta``, ``phi``: no derivative on their row). A derivative is
named ``<letter>_<column>`` (``M_q``, ``L_theta_1c``), the convention of Padfield, *Helicopter
Flight Dynamics*, 2nd ed., 2007, ch. 4, whatever the vehicle. It is discretised exactly with a
zero-order hold (:func:`~validation.vehicles.linear_discretisation.zero_order_hold`).

The JSON format (:func:`state_space_from_dict`, :meth:`LinearReference.as_dict`)::

    {"name": "my-heli-80kt", "states": ["u", "w", "q", "theta", ...], "inputs": ["theta_0", ...],
     "A": [[...], ...], "B": [[...], ...],
     "derivative_rows": {"u": "X", "w": "Z", "q": "M", "v": "Y", "p": "L", "r": "N"},
     "units": {"u": "m/s", "q": "rad/s", "theta": "rad", "theta_0": "rad", ...},
     "sample_time": 0.01}

``A`` is n x n and ``B`` n x m for n states and m inputs; ``units`` names every state and
input; ``sample_time`` (s, the default recording interval) is optional (0.01 s).
"""
from __future__ import annotations

import copy
import math
import re

import numpy as np

from validation.core.errors import BadInputError, unknown_name_message
from validation.core.files import read_document
from validation.core.recordings import Recording, column_unit
from validation.core.sampling import check_history
from validation.vehicles.linear_discretisation import zero_order_hold

#: The file format's name, as ``flightgp`` writes it into the files it exports.
FORMAT = "flightgp-state-space"
#: Default recording interval of a state-space model without ``sample_time``, s (100 Hz).
DEFAULT_SAMPLE_TIME = 0.01
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_LETTER = re.compile(r"[A-Z]")


def cached_zero_order_hold(cache: dict, A: np.ndarray, B: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~validation.vehicles.linear_discretisation.zero_order_hold` at ``step`` rounded to
    1e-12 s, kept in ``cache`` (one dict per system, so a vehicle discretises once per sample
    interval)."""
    key = round(step, 12)
    if key not in cache:
        cache[key] = zero_order_hold(A, B, key)
    return cache[key]


#: Steps per block of :func:`propagate`: long enough that its Python loops are short (about
#: ``2 sqrt(n)`` iterations for ``n`` steps near the optimum), short enough that the powers of
#: the transition matrix it keeps stay few.
PROPAGATE_BLOCK = 32


def propagate(transition: np.ndarray, forcing: np.ndarray, state: np.ndarray, *,
              every: int = 1) -> np.ndarray:
    """``x[j+1] = transition @ x[j] + forcing[j]`` from ``x[0] = state``; every ``every``-th ``x``.

    Computed in blocks of :data:`PROPAGATE_BLOCK` steps rather than step by step, with the same
    result up to rounding (about 1e-15 relative; tested against the step-by-step recursion): the
    response to each block's forcing from rest, ``c[b, i] = sum_{j<i} T^(i-1-j) f[b, j]``, for all
    blocks at once; the block starts ``x0[b+1] = T^L x0[b] + c[b, L]`` one block at a time; then
    ``x[b, i] = T^i x0[b] + c[b, i]`` for all blocks at once. That is ``L + n/L`` short Python
    iterations instead of ``n``, which is what a step of a small system costs.

    Returns shape (len(forcing) // every + 1, len(state)): ``x[0], x[every], ..., x[len(forcing)]``.
    """
    forcing = np.asarray(forcing, dtype=float)
    state = np.asarray(state, dtype=float)
    n_steps, size, block = len(forcing), len(state), PROPAGATE_BLOCK
    n_blocks = -(-n_steps // block)
    padded = np.zeros((n_blocks * block, size))
    padded[:n_steps] = forcing
    padded = padded.reshape(n_blocks, block, size)
    powers = np.empty((block + 1, size, size))  # T^0 .. T^L
    powers[0] = np.eye(size)
    for i in range(1, block + 1):
        powers[i] = transition @ powers[i - 1]
    from_rest = np.zeros((n_blocks, block + 1, size))  # c[b, i], i = 0 .. L
    for i in range(1, block + 1):
        from_rest[:, i] = from_rest[:, i - 1] @ transition.T + padded[:, i - 1]
    starts = np.empty((n_blocks + 1, size))
    starts[0] = state
    for b in range(n_blocks):
        starts[b + 1] = powers[block] @ starts[b] + from_rest[b, block]
    states = np.einsum("inm,bm->bin", powers[:block], starts[:-1]) + from_rest[:, :block]
    states = np.concatenate([states.reshape(-1, size), starts[-1:]])[:n_steps + 1]
    return np.concatenate([states[0:n_steps:every][:n_steps // every], states[-1:]])


class LinearReference:
    """A linear reference ``x_dot = A x + B u`` with named derivatives (module docstring).

    Parameters
    ----------
    name : str
        The reference's name (messages, recordings' metadata).
    state_names, input_names : sequence of str
    A : array_like, shape (n, n)
        1/s.
    B : array_like, shape (n, m)
        State units per input unit per s.
    row_letters : dict of str to str
        Derivative row letter -> the state whose row it names (``{"M": "q", ...}``).
    units : dict of str to str, optional
        Unit of every state and input; default flightgp's column units
        (:func:`validation.core.recordings.column_unit`).
    sample_time : float
        Default recording interval, s.

    An instance never changes: :meth:`with_derivatives` returns a new one.
    """

    #: Its states and inputs are perturbations from trim, so its recordings start near zero
    #: (``flightgp inspect`` flags one that does not).
    perturbations_from_trim = True

    def __init__(self, *, name: str, state_names, input_names, A, B, row_letters: dict, units: dict | None = None,
                 sample_time: float = DEFAULT_SAMPLE_TIME):
        self.name = name
        self.state_names, self.input_names = tuple(state_names), tuple(input_names)
        self._A, self._B = np.array(A, dtype=float), np.array(B, dtype=float)
        self.row_letters = dict(row_letters)
        self.units = dict(units) if units else {n: column_unit(n) for n in self.state_names + self.input_names}
        self.sample_time = float(sample_time)
        self._state_index = {n: i for i, n in enumerate(self.state_names)}
        self._input_index = {n: i for i, n in enumerate(self.input_names)}
        self._changed: dict[str, float] = {}
        self._discretisations: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def A(self) -> np.ndarray:
        """State matrix, shape (n, n), 1/s (a copy)."""
        return self._A.copy()

    @property
    def B(self) -> np.ndarray:
        """Control matrix, shape (n, m) (a copy)."""
        return self._B.copy()

    @property
    def changed_derivatives(self) -> dict[str, float]:
        """Derivative name -> value of what :meth:`with_derivatives` changed (a copy)."""
        return dict(self._changed)

    def eigenvalues(self) -> np.ndarray:
        """Eigenvalues of ``A``, shape (n,), 1/s, sorted by real part then imaginary part."""
        return np.sort_complex(np.linalg.eigvals(self._A))

    def derivative_names(self) -> list[str]:
        """Every derivative name: each row letter with each state and input (``"X_u"``, ...)."""
        return [f"{letter}_{column}" for letter in self.row_letters for column in self.state_names + self.input_names]

    def locate(self, name: str) -> tuple[str, int, int]:
        """(``"A"`` or ``"B"``, row, column) of derivative ``name``; BadInputError naming the
        convention otherwise."""
        letter, _, column = name.partition("_")
        if letter in self.row_letters and (column in self._state_index or column in self._input_index):
            row = self._state_index[self.row_letters[letter]]
            return ("A", row, self._state_index[column]) if column in self._state_index \
                else ("B", row, self._input_index[column])
        raise BadInputError(
            f"unknown derivative {name!r} of {self.name}: a name is a row letter ({', '.join(self.row_letters)}) + "
            f"'_' + a state ({', '.join(self.state_names)}) or input ({', '.join(self.input_names)}), e.g. the "
            f"dampings {', '.join(f'{letter}_{state}' for letter, state in self.row_letters.items())}")

    def derivative(self, name: str) -> float:
        """The value of derivative ``name`` (e.g. ``"M_q"``, 1/s)."""
        matrix, row, column = self.locate(name)
        return float((self._A if matrix == "A" else self._B)[row, column])

    def with_derivatives(self, values: dict[str, float]) -> LinearReference:
        """A new reference with the derivatives in ``values`` (name -> value) replaced.

        Raises
        ------
        BadInputError
            For an unknown name (the message gives the convention) or a non-finite value.
        """
        A, B, changed = self._A.copy(), self._B.copy(), dict(self._changed)
        for name, value in values.items():
            matrix, row, column = self.locate(name)
            try:
                number = float(value)
            except (TypeError, ValueError):
                number = math.nan
            if not math.isfinite(number):
                raise BadInputError(f"derivative {name} must be a finite number, got {value!r}")
            (A if matrix == "A" else B)[row, column] = number
            changed[name] = number
        changed_reference = copy.copy(self)  # the same kind of reference (a Bo105 keeps its speed)
        vars(changed_reference).update(_A=A, _B=B, _changed=changed, _discretisations={})
        return changed_reference

    def discretisation(self, step: float) -> tuple[np.ndarray, np.ndarray]:
        """Exact ZOH ``(Phi, Gamma)`` at ``step`` s, shapes (n, n) and (n, m); cached."""
        return cached_zero_order_hold(self._discretisations, self._A, self._B, step)

    def simulate_states(self, time, inputs, *, initial_state=None) -> np.ndarray:
        """State history from ``initial_state`` (default trim, zeros) under ``inputs`` (n, m),
        each row held from ``time[k]`` to ``time[k+1]``; ``time`` evenly spaced (n >= 2).
        Returns shape (n, n_states)."""
        time, inputs, step = check_history(time, inputs, self.input_names)
        state = np.zeros(len(self.state_names))
        if initial_state is not None:
            state = np.asarray(initial_state, dtype=float)
            if state.shape != (len(self.state_names),) or not np.all(np.isfinite(state)):
                raise BadInputError(f"initial_state must be {len(self.state_names)} finite numbers "
                                    f"({', '.join(self.state_names)}), got shape {state.shape}")
        Ad, Bd = self.discretisation(step)
        return propagate(Ad, inputs[:-1] @ Bd.T, state)

    def recording_metadata(self, step: float) -> dict:
        """The metadata of :meth:`simulate`'s recordings."""
        metadata = {"vehicle": self.name, "sample_time": step}
        if self._changed:
            metadata["changed_derivatives"] = dict(self._changed)
        return metadata

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Fly ``inputs`` from trim and record every state (:meth:`simulate_states`); ``seed`` is
        accepted for the Vehicle interface (the reference is deterministic)."""
        time, inputs, step = check_history(time, inputs, self.input_names)
        return Recording(time, inputs, self.input_names, self.simulate_states(time, inputs), self.state_names,
                         self.recording_metadata(step))

    def as_dict(self) -> dict:
        """The reference in the JSON format of the module docstring (derivatives as changed)."""
        return {"format": FORMAT, "name": self.name, "states": list(self.state_names),
                "inputs": list(self.input_names), "A": self._A.tolist(), "B": self._B.tolist(),
                "derivative_rows": {state: letter for letter, state in self.row_letters.items()},
                "units": dict(self.units), "sample_time": self.sample_time}


def _names(content: dict, key: str, source: str) -> list[str]:
    names = content.get(key)
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and _NAME.fullmatch(n) for n in names):
        raise BadInputError(f"{source}: {key!r} must be a non-empty list of names (letters, digits, underscores), "
                            f"got {names!r}")
    if len(set(names)) != len(names):
        raise BadInputError(f"{source}: {key!r} names {sorted({n for n in names if names.count(n) > 1})} twice")
    return names


def _matrix(content: dict, key: str, shape: tuple[int, int], source: str, meaning: str) -> np.ndarray:
    try:
        matrix = np.array(content.get(key), dtype=float)
    except (TypeError, ValueError):
        raise BadInputError(f"{source}: {key!r} must be a list of rows of numbers") from None
    if matrix.shape != shape:
        raise BadInputError(f"{source}: {key!r} has shape {matrix.shape}; {meaning} make it {shape}")
    if not np.all(np.isfinite(matrix)):
        raise BadInputError(f"{source}: {key!r} holds a non-finite number")
    return matrix


#: The keys of a state-space file (module docstring); any other is refused.
FILE_KEYS = ("format", "name", "states", "inputs", "A", "B", "derivative_rows", "units", "sample_time")
#: Units that are not flightgp's (docs/conventions.md, "Units and axes"), with the SI unit a
#: model's matrices must be converted to.
_NOT_SI = {"deg": "rad", "deg/s": "rad/s", "deg/s^2": "rad/s^2", "ft": "m", "ft/s": "m/s", "kt": "m/s",
           "kts": "m/s", "knot": "m/s", "mph": "m/s", "km/h": "m/s", "lbf": "N", "ft lbf": "N m",
           "ms": "s", "min": "s", "%": "1"}


def _check_unit(column: str, unit: str, source: str) -> None:
    """A state or input's declared unit must be flightgp's for a column flightgp knows (``q`` in
    rad/s) and SI for any other: a matrix in degrees or feet would be read as radians or metres."""
    own = column_unit(column)
    if own != "?" and unit != own:
        raise BadInputError(f"{source}: {column!r} is declared in {unit!r}, but flightgp's {column} is in {own} "
                            f"(docs/conventions.md, \"Units and axes\"); convert its rows and columns of A and B")
    if unit.strip().lower() in _NOT_SI:
        raise BadInputError(f"{source}: {column!r} is declared in {unit!r}; flightgp reads SI units "
                            f"({_NOT_SI[unit.strip().lower()]}): convert its rows and columns of A and B")


def state_space_from_dict(content, *, source: str = "state-space model") -> LinearReference:
    """The :class:`LinearReference` a JSON dict describes (module docstring).

    Raises
    ------
    BadInputError
        Not a JSON object; a missing or bad name, state or input list; matrices of the wrong
        shape or with non-finite numbers; derivative rows naming unknown states, letters that
        are not one capital, or a letter twice; units missing for a state or input or naming
        unknown columns; a sample time that is not a positive number. The message starts with
        ``source``.
    """
    if not isinstance(content, dict):
        raise BadInputError(f"{source}: a state-space model is a JSON object, got {type(content).__name__}")
    unknown = [key for key in content if key not in FILE_KEYS]
    if unknown:
        raise BadInputError(f"{source}: {unknown_name_message(unknown[0], FILE_KEYS)}")
    if content.get("format", FORMAT) != FORMAT:
        raise BadInputError(f"{source}: format {content['format']!r} is not a state-space model ({FORMAT!r})")
    name = content.get("name")
    if not isinstance(name, str) or not name.strip():
        raise BadInputError(f"{source}: 'name' must be a non-empty string")
    states, inputs = _names(content, "states", source), _names(content, "inputs", source)
    if set(states) & set(inputs):
        raise BadInputError(f"{source}: {sorted(set(states) & set(inputs))} are both states and inputs")
    n, m = len(states), len(inputs)
    A = _matrix(content, "A", (n, n), source, f"its {n} states")
    B = _matrix(content, "B", (n, m), source, f"its {n} states and {m} inputs")
    rows = content.get("derivative_rows", {})
    if not isinstance(rows, dict):
        raise BadInputError(f"{source}: 'derivative_rows' must map states to row letters")
    letters = {}
    for state, letter in rows.items():
        if state not in states:
            raise BadInputError(f"{source}: derivative_rows names {state!r}, which is not a state "
                                f"({', '.join(states)})")
        if not isinstance(letter, str) or not _LETTER.fullmatch(letter):
            raise BadInputError(f"{source}: the row letter of {state!r} must be one capital letter, got {letter!r}")
        if letter in letters:
            raise BadInputError(f"{source}: row letter {letter!r} names both {letters[letter]!r} and {state!r}")
        letters[letter] = state
    units = content.get("units")
    if not isinstance(units, dict) or not all(isinstance(u, str) for u in units.values()):
        raise BadInputError(f"{source}: 'units' must map every state and input to its unit (a string)")
    missing = [c for c in states + inputs if c not in units]
    unknown = [c for c in units if c not in states + inputs]
    if missing or unknown:
        raise BadInputError(f"{source}: units missing for {missing} and given for unknown {unknown}" if unknown
                            else f"{source}: units missing for {', '.join(missing)}")
    for column in states + inputs:
        _check_unit(column, units[column], source)
    sample_time = content.get("sample_time", DEFAULT_SAMPLE_TIME)
    if isinstance(sample_time, bool) or not isinstance(sample_time, (int, float)) or not \
            (math.isfinite(sample_time) and sample_time > 0):
        raise BadInputError(f"{source}: 'sample_time' must be a positive number of seconds, got {sample_time!r}")
    return LinearReference(name=name, state_names=states, input_names=inputs, A=A, B=B, row_letters=letters,
                           units=units, sample_time=float(sample_time))


def read_state_space(path) -> LinearReference:
    """The state-space model in the JSON file ``path`` (:func:`state_space_from_dict`)."""
    return state_space_from_dict(read_document(path, what="state-space model file"), source=str(path))
