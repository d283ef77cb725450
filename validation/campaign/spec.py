"""Campaign specs: a JSON file of studies, each expanded into tasks (docs/campaigns.md, "The spec
file").

A study names a task kind (:data:`KINDS`) and its fields; any field may vary between the study's
tasks (docs/campaigns.md, "Values that vary"): drawn from a distribution once per Monte Carlo
sample, or swept over a grid (every combination of the grids, times ``samples``). Expansion is
deterministic: a task's values are drawn from ``default_rng([seed, crc32(study id), grid point,
sample])``, so they do not depend on the other studies or on how many samples there are (its
id and derived seed, ``<study>-<index>`` and ``seed + index``, do in a study with grids), and a
re-run of the same spec gives the same tasks (which is what resuming relies on).

Everything is checked here that can be checked without running anything; a problem raises
:class:`~validation.core.errors.BadInputError` naming the spec file and the field
(``bo105_montecarlo.json: studies[0] ("mc").inputs.theta_1s.amplitude: ...``). What needs the
FMU or the recordings (variable names, case names) is checked by
:func:`validation.campaign.tasks.check_tasks` before anything runs.
"""
from __future__ import annotations

import itertools
import json
import math
import re
import zlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError, unknown_name_message
from validation.core.manoeuvres import MANOEUVRES

#: The task kinds a study may name.
KINDS = ("cosim", "diagnose", "diagnose-bench", "reproduce", "qtg")
#: The papers a ``reproduce`` study runs (``flightgp reproduce``'s with one seed each).
PAPERS = ("bo105", "blimp")
#: Version of the spec format this flightgp reads.
VERSION = 1
#: Most tasks one spec may expand into (each is a row of results.csv and a folder).
MAX_TASKS = 100_000
#: Laws of a value that varies (docs/campaigns.md, "Values that vary"): name -> whether it draws
#: numbers only.
LAWS = {"uniform": True, "normal": True, "loguniform": True, "choice": False, "grid": False}
_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
#: File suffixes that make a ``reference``/``through`` a file rather than a registry name.
_FILE_SUFFIXES = (".fmu", ".json")


@dataclass(frozen=True)
class Varying:
    """A field whose value varies between a study's tasks.

    Attributes
    ----------
    law : str
        A key of :data:`LAWS`.
    args : tuple
        ``(low, high)`` of ``uniform`` and ``loguniform``, ``(mean, standard deviation)`` of
        ``normal``, the values of ``choice`` and ``grid``.
    where : str
        The field, for messages.
    check : callable or None
        ``check(value, where)`` raising BadInputError, applied to every drawn value.
    """

    law: str
    args: tuple
    where: str
    check: object = None

    def draw(self, rng: np.random.Generator):
        """One value (not for ``grid``)."""
        if self.law == "uniform":
            value = float(rng.uniform(*self.args))
        elif self.law == "normal":
            value = float(rng.normal(*self.args))
        elif self.law == "loguniform":
            value = float(math.exp(rng.uniform(math.log(self.args[0]), math.log(self.args[1]))))
        else:
            value = self.args[int(rng.integers(len(self.args)))]
        if self.check is not None:
            self.check(value, self.where)
        return value


@dataclass(frozen=True)
class FileRef:
    """A file a study needs on the workers.

    Attributes
    ----------
    label : str
        How tasks name it: the path as the spec writes it, or ``"reference:<name>"``.
    path : Path or None
        The file, resolved against the spec's folder.
    reference : str or None
        A reference FMU the campaign builds (``flightgp build-fmu --reference <name>``) instead.
    companions : tuple of str
        Files that travel with it, by the paths it names them by, relative to its folder (a QTG
        spec's recordings; :meth:`validation.campaign.tasks.FileBundle.read` keeps them there).
    """

    label: str
    path: Path | None = None
    reference: str | None = None
    companions: tuple = ()


@dataclass(frozen=True)
class Task:
    """One task of a campaign.

    Attributes
    ----------
    id : str
        ``<study>-<index>``, the name of its folder ``DIR/tasks/<id>/``.
    study, kind : str
    seed : int
        Its random seed (docs/campaigns.md, "Seeds").
    settings : dict
        The study's fields with every varying value replaced by this task's (JSON-ready).
    files : tuple of str
        Labels (:class:`FileRef`) of the files it needs.
    """

    id: str
    study: str
    kind: str
    seed: int
    settings: dict
    files: tuple = ()

    def as_dict(self) -> dict:
        """The task as ``result.json`` records it (what resuming compares)."""
        return {"id": self.id, "study": self.study, "kind": self.kind, "seed": self.seed,
                "settings": self.settings}


@dataclass(frozen=True)
class CampaignSpec:
    """A parsed campaign.

    Attributes
    ----------
    name : str
    source : str
        Where it came from (the spec file), for messages.
    seed : int
        The campaign's seed (docs/campaigns.md, "Seeds").
    retries : int
        Times a task that raises is run again before it is recorded as failed.
    tasks : tuple of Task
    files : dict of str to FileRef
        Every file the tasks name, by label.
    """

    name: str
    source: str
    seed: int
    retries: int
    tasks: tuple
    files: dict


def read_spec(path) -> CampaignSpec:
    """Read and check a campaign spec file (JSON; paths in it are relative to its folder).

    Raises
    ------
    BadInputError
        A missing file, text that is not JSON (with line and column), or anything
        :func:`parse_spec` refuses.
    """
    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"{path}: no such campaign spec")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise BadInputError(f"{path}: not a text file; a campaign spec is JSON") from None
    except json.JSONDecodeError as error:
        raise BadInputError(f"{path}, line {error.lineno}, column {error.colno}: not JSON: {error.msg}") from None
    return parse_spec(data, base_dir=path.parent, source=path.name, default_name=path.stem)


def parse_spec(data, *, base_dir, source: str = "campaign", default_name: str = "campaign") -> CampaignSpec:
    """Check a campaign spec (the JSON object) and expand its studies into tasks.

    Parameters
    ----------
    data : dict
        The spec (docs/campaigns.md, "The spec file").
    base_dir : path
        The folder relative paths in the spec start from.
    source : str
        Names the spec in messages.
    default_name : str
        The campaign's name when the spec gives none.

    Raises
    ------
    BadInputError
        One line naming ``source`` and the field: unknown or missing fields, wrong types,
        unknown kinds, bad distributions, missing files, more than :data:`MAX_TASKS` tasks.
    """
    parser = _Parser(source, Path(base_dir))
    top = parser.object(data, "the spec", required=("studies",),
                        optional=("version", "name", "seed", "retries"))
    if "version" in top and top["version"] != VERSION:
        parser.fail("version", f"this flightgp reads campaign specs of version {VERSION}, not {top['version']!r}")
    name = parser.string(top.get("name", default_name), "name")
    seed = parser.whole(top.get("seed", 0), "seed")
    retries = parser.whole(top.get("retries", 1), "retries")
    studies = top["studies"]
    if not isinstance(studies, list) or not studies:
        parser.fail("studies", "must be a non-empty list of studies")
    tasks, seen = [], set()
    for index, raw in enumerate(studies):
        study = parser.study(raw, f"studies[{index}]")
        if study.id in seen:
            parser.fail(f"studies[{index}].id", f"{study.id!r} is the id of an earlier study; ids must differ")
        seen.add(study.id)
        tasks += study.expand(seed, parser)
        if len(tasks) > MAX_TASKS:
            parser.fail("studies", f"more than {MAX_TASKS} tasks; split the campaign")
    return CampaignSpec(name, source, seed, retries, tuple(tasks), dict(parser.files))


def is_file_reference(name: str) -> bool:
    """Whether a ``reference``/``through`` value names a file (``.fmu`` or state-space ``.json``)."""
    return name.endswith(_FILE_SUFFIXES)


def file_label(value) -> str:
    """The label of an ``fmu`` value: the path as written, or ``"reference:<name>"``."""
    return f"reference:{value['reference']}" if isinstance(value, dict) else value


@dataclass
class _Study:
    id: str
    kind: str
    samples: int
    template: dict
    seed: object  # int, Varying (grid) or None: derived
    where: str

    def expand(self, campaign_seed: int, parser: _Parser) -> list[Task]:
        """The study's tasks (module docstring)."""
        varying = list(_varying_fields(self.template))
        if isinstance(self.seed, Varying):
            varying.append(((), self.seed))
        grids = [(path, field) for path, field in varying if field.law == "grid"]
        points = list(itertools.product(*(field.args for _, field in grids)))
        total = len(points) * self.samples
        if total > MAX_TASKS:
            parser.fail(self.where, f"expands into {total} tasks, more than {MAX_TASKS}; split the study")
        width = max(3, len(str(total - 1)))
        tasks = []
        for point_index, point in enumerate(points):
            for sample in range(self.samples):
                index = point_index * self.samples + sample
                rng = np.random.default_rng([campaign_seed, zlib.crc32(self.id.encode()), point_index, sample])
                chosen = {id(field): value for (_, field), value in zip(grids, point)}
                try:
                    settings = _fill(self.template, chosen, rng)
                except BadInputError as error:
                    raise BadInputError(f"{error} (drawn for task {self.id}-{index:0{width}d}; narrow the "
                                        "distribution)") from None
                if self.seed is None:
                    seed = campaign_seed + index
                else:
                    seed = chosen[id(self.seed)] if isinstance(self.seed, Varying) else self.seed
                tasks.append(Task(f"{self.id}-{index:0{width}d}", self.id, self.kind, int(seed), settings,
                                  tuple(_task_files(self.kind, settings))))
        return tasks


def _varying_fields(tree, path=()):
    if isinstance(tree, Varying):
        yield path, tree
    elif isinstance(tree, dict):
        for key, value in tree.items():
            yield from _varying_fields(value, (*path, key))
    elif isinstance(tree, list):
        for index, value in enumerate(tree):
            yield from _varying_fields(value, (*path, index))


def _fill(tree, chosen: dict, rng: np.random.Generator):
    """``tree`` with each :class:`Varying` replaced: by its grid value in ``chosen`` (by ``id``),
    else by a draw from ``rng`` (in the order of the tree)."""
    if isinstance(tree, Varying):
        return chosen[id(tree)] if id(tree) in chosen else tree.draw(rng)
    if isinstance(tree, dict):
        return {key: _fill(value, chosen, rng) for key, value in tree.items()}
    if isinstance(tree, list):
        return [_fill(value, chosen, rng) for value in tree]
    return tree


def _task_files(kind: str, settings: dict) -> list[str]:
    """The labels of the files a task with ``settings`` needs."""
    if kind == "cosim":
        return [file_label(settings["fmu"])]
    if kind == "diagnose":
        files = [*settings["recordings"], *(settings["holdout"] or [])]
        return files + ([settings["reference"]] if is_file_reference(settings["reference"]) else [])
    if kind == "diagnose-bench":
        return [settings[key] for key in ("reference", "through")
                if settings[key] is not None and is_file_reference(settings[key])]
    if kind == "qtg":
        if settings["fmu"] is not None:
            return [settings["spec"], file_label(settings["fmu"])]
        return [settings["spec"]] + ([settings["reference"]] if is_file_reference(settings["reference"]) else [])
    return []


class _Parser:
    """Checks of a spec's parts; collects the files it names."""

    def __init__(self, source: str, base_dir: Path):
        self.source, self.base_dir = source, base_dir
        self.files: dict[str, FileRef] = {}

    def fail(self, where: str, message: str):
        raise BadInputError(f"{self.source}: {where}: {message}")

    # -- shapes ------------------------------------------------------------------------------
    def object(self, raw, where: str, *, required=(), optional=()) -> dict:
        if not isinstance(raw, dict):
            self.fail(where, f"must be a JSON object, got {_kind_of(raw)}")
        unknown = [key for key in raw if key not in (*required, *optional)]
        if unknown:
            self.fail(where, unknown_name_message(unknown[0], (*required, *optional), what="field"))
        missing = [key for key in required if key not in raw]
        if missing:
            self.fail(where, f"missing field {missing[0]!r}")
        return raw

    def mapping(self, raw, where: str) -> dict:
        """An object of names the spec chooses (inputs, parameters, ...)."""
        if not isinstance(raw, dict):
            self.fail(where, f"must be a JSON object of names, got {_kind_of(raw)}")
        return raw

    def string(self, raw, where: str) -> str:
        if not isinstance(raw, str) or not raw:
            self.fail(where, f"must be a non-empty string, got {_kind_of(raw)}")
        return raw

    def whole(self, raw, where: str, *, minimum: int = 0) -> int:
        if isinstance(raw, bool) or not isinstance(raw, int) or raw < minimum:
            self.fail(where, f"must be a whole number, {minimum} or more, got {json.dumps(raw)}")
        return raw

    def boolean(self, raw, where: str) -> bool:
        if not isinstance(raw, bool):
            self.fail(where, f"must be true or false, got {json.dumps(raw)}")
        return raw

    def names(self, raw, where: str) -> list:
        if not isinstance(raw, list) or not raw or not all(isinstance(n, str) and n for n in raw):
            self.fail(where, "must be a non-empty list of names")
        return list(raw)

    # -- values that may vary -----------------------------------------------------------------
    def value(self, raw, where: str, *, element, numeric: bool):
        """A constant checked by ``element(value, where)``, or a :class:`Varying`."""
        if isinstance(raw, dict) and len(raw) == 1 and next(iter(raw)) in LAWS:
            law, args = next(iter(raw.items()))
            return self._varying(law, args, where, element=element, numeric=numeric)
        if isinstance(raw, dict) and any(key in LAWS for key in raw):
            self.fail(where, f"a varying value is one law with its arguments, e.g. {{\"uniform\": [0, 1]}}; "
                             f"got the fields {', '.join(raw)}")
        element(raw, where)
        return raw

    def _varying(self, law: str, args, where: str, *, element, numeric: bool) -> Varying:
        if LAWS[law] and not numeric:
            self.fail(where, f"{law!r} draws numbers; this field takes {{\"choice\": [...]}} or {{\"grid\": [...]}}")
        if not isinstance(args, list) or not args:
            self.fail(where, f"{law!r} needs a non-empty list, got {json.dumps(args)}")
        if law in ("choice", "grid"):
            for index, value in enumerate(args):
                element(value, f"{where}.{law}[{index}]")
            return Varying(law, tuple(args), where)
        if len(args) != 2 or not all(_is_number(a) and math.isfinite(a) for a in args):
            self.fail(where, f"{law!r} takes two finite numbers, got {json.dumps(args)}")
        first, second = (float(a) for a in args)
        if law == "normal" and not second > 0:
            self.fail(where, f"'normal' takes [mean, standard deviation > 0], got {json.dumps(args)}")
        if law in ("uniform", "loguniform") and not first < second:
            self.fail(where, f"{law!r} takes [low, high] with low < high, got {json.dumps(args)}")
        if law == "loguniform" and not first > 0:
            self.fail(where, f"'loguniform' takes 0 < low < high, got {json.dumps(args)}")
        return Varying(law, (first, second), where, check=element)

    def number(self, raw, where: str, *, minimum: float | None = None, above: float | None = None):
        def element(value, at):
            if not _is_number(value) or not math.isfinite(value):
                self.fail(at, f"must be a finite number, got {json.dumps(value)}")
            if minimum is not None and value < minimum:
                self.fail(at, f"must be at least {minimum:g}, got {value!r}")
            if above is not None and not value > above:
                self.fail(at, f"must be more than {above:g}, got {value!r}")
        return self.value(raw, where, element=element, numeric=True)

    def choice_of(self, raw, where: str, allowed):
        def element(value, at):
            if value not in allowed:
                self.fail(at, f"must be one of {', '.join(map(str, allowed))}, got {json.dumps(value)}")
        return self.value(raw, where, element=element, numeric=False)

    # -- files -------------------------------------------------------------------------------
    def file(self, raw, where: str, *, suffixes=None) -> str:
        """A path relative to the spec's folder that must exist; returns it as written."""
        self.string(raw, where)
        if suffixes and not raw.endswith(suffixes):
            self.fail(where, f"{raw!r} must end in {' or '.join(suffixes)}")
        path = self.base_dir / raw
        if not path.is_file():
            self.fail(where, f"no such file {raw!r} (paths are relative to the spec's folder, "
                             f"{self.base_dir.resolve()})")
        self.files.setdefault(raw, FileRef(raw, path=path))
        return raw

    def fmu(self, raw, where: str):
        def element(value, at):
            if isinstance(value, dict):
                self.object(value, at, required=("reference",))
                self.string(value["reference"], f"{at}.reference")
                label = file_label(value)
                self.files.setdefault(label, FileRef(label, reference=value["reference"]))
            else:
                self.file(value, at, suffixes=(".fmu",))
        return self.value(raw, where, element=element, numeric=False)

    def reference(self, raw, where: str, *, fmu_allowed: bool = True):
        """A registry name, or a ``.fmu`` (unless ``fmu_allowed`` is false: the study takes FMUs
        as its ``fmu``) or ``.json`` file (relative to the spec)."""
        def element(value, at):
            self.string(value, at)
            if not fmu_allowed and value.endswith(".fmu"):
                self.fail(at, f"{value!r} is an FMU; give it as 'fmu'")
            if is_file_reference(value):
                self.file(value, at)
        return self.value(raw, where, element=element, numeric=False)

    def qtg_spec(self, raw, where: str):
        """A QTG spec file (``.toml``), read and checked with its recordings, which travel with it
        (:attr:`FileRef.companions`)."""
        def element(value, at):
            from validation.qtg import read_spec as read_qtg_spec

            known = value in self.files
            self.file(value, at, suffixes=(".toml",))
            if known:
                return
            try:
                qtg = read_qtg_spec(self.files[value].path)
            except BadInputError as error:
                self.fail(at, str(error))
            recordings = tuple(dict.fromkeys(test.recording_path for test in qtg.tests))
            absolute = [name for name in recordings if Path(name).is_absolute()]
            if absolute:
                self.fail(at, f"recording {absolute[0]} is an absolute path; name it relative to the QTG spec, "
                              "so that the campaign can carry it to the workers")
            self.files[value] = replace(self.files[value], companions=recordings)
        return self.value(raw, where, element=element, numeric=False)

    def recordings(self, raw, where: str):
        def element(value, at):
            if not isinstance(value, list) or not value:
                self.fail(at, "must be a non-empty list of recording files (.csv)")
            for index, item in enumerate(value):
                self.file(item, f"{at}[{index}]", suffixes=(".csv",))
        return self.value(raw, where, element=element, numeric=False)

    # -- studies -----------------------------------------------------------------------------
    def study(self, raw, where: str) -> _Study:
        if not isinstance(raw, dict):
            self.fail(where, f"a study must be a JSON object, got {_kind_of(raw)}")
        if "kind" not in raw:
            self.fail(where, "missing field 'kind'")
        kind = raw["kind"]
        if kind not in KINDS:
            self.fail(f"{where}.kind", f"unknown kind {json.dumps(kind)}; known: {', '.join(KINDS)}")
        fields = _STUDY_FIELDS[kind]
        common = ("id", "kind", "samples", "seed")
        self.object(raw, where, required=("id", "kind", *fields[0]), optional=(*common[2:], *fields[1]))
        study_id = self.string(raw["id"], f"{where}.id")
        if not _ID.fullmatch(study_id):
            self.fail(f"{where}.id", f"{study_id!r} must be letters, digits, '_', '-' or '.' (it names folders)")
        where = f'{where} ("{study_id}")'
        samples = self.whole(raw.get("samples", 1), f"{where}.samples", minimum=1)
        seed = raw.get("seed")
        if isinstance(seed, dict) and list(seed) != ["grid"]:
            self.fail(f"{where}.seed", "a seed is a whole number or {\"grid\": [...]} of them, got "
                                       f"{json.dumps(seed)}")
        if seed is not None:
            seed = self.value(seed, f"{where}.seed", numeric=False,
                              element=lambda value, at: self.whole(value, at))
        template = getattr(self, f"_{kind.replace('-', '_')}")(raw, where)
        return _Study(study_id, kind, samples, template, seed, where)

    def _cosim(self, raw, where: str) -> dict:
        inputs = self.mapping(raw.get("inputs", {}), f"{where}.inputs")
        return {
            "fmu": self.fmu(raw["fmu"], f"{where}.fmu"),
            "duration": self.number(raw["duration"], f"{where}.duration", above=0),
            "step": None if raw.get("step") is None else self.number(raw["step"], f"{where}.step", above=0),
            "inputs": {name: self._input(signal, f"{where}.inputs.{name}") for name, signal in inputs.items()},
            **{key: {name: self.number(value, f"{where}.{key}.{name}", minimum=0 if key == "noise" else None)
                     for name, value in self.mapping(raw.get(key, {}), f"{where}.{key}").items()}
               for key in ("parameters", "start_values", "noise")},
            "outputs": None if raw.get("outputs") is None else self.names(raw["outputs"], f"{where}.outputs"),
            "compare_with": None if raw.get("compare_with") is None
            else self.string(raw["compare_with"], f"{where}.compare_with"),
        }

    def _input(self, raw, where: str):
        """A constant (a number) or a manoeuvre (docs/campaigns.md, "`cosim` studies")."""
        if not isinstance(raw, dict) or (len(raw) == 1 and next(iter(raw)) in LAWS):
            return self.number(raw, where)
        signal = self.object(raw, where, required=("manoeuvre",),
                             optional=("amplitude", "amplitude_deg", "step_time", "start"))
        if ("amplitude" in signal) == ("amplitude_deg" in signal):
            self.fail(where, "give the amplitude as 'amplitude' (the input's unit: rad for angles) or "
                             "'amplitude_deg' (deg), one of them")
        return {"manoeuvre": self.choice_of(signal["manoeuvre"], f"{where}.manoeuvre", MANOEUVRES),
                **{key: self.number(signal[key], f"{where}.{key}") for key in ("amplitude", "amplitude_deg")
                   if key in signal},
                "step_time": self.number(signal.get("step_time", 0.4), f"{where}.step_time", above=0),
                "start": self.number(signal.get("start", 1.0), f"{where}.start", minimum=0)}

    def _diagnose(self, raw, where: str) -> dict:
        return {"recordings": self.recordings(raw["recordings"], f"{where}.recordings"),
                "holdout": None if raw.get("holdout") is None
                else self.recordings(raw["holdout"], f"{where}.holdout"),
                "reference": self.reference(raw["reference"], f"{where}.reference"),
                "folds": None if raw.get("folds") is None
                else self.value(raw["folds"], f"{where}.folds", numeric=False,
                                element=lambda value, at: self.whole(value, at, minimum=2))}

    def _diagnose_bench(self, raw, where: str) -> dict:
        reference = self.reference(raw.get("reference", "bo105-80kt"), f"{where}.reference")
        cases = raw.get("cases", "all")
        if cases == "all":
            if isinstance(reference, Varying):
                self.fail(f"{where}.cases", "\"all\" needs one reference; name the cases to vary the reference")
            from validation.diagnose.bench import concealed_cases

            path = self.files[reference].path if reference in self.files else reference
            try:
                cases = [case.name for case in concealed_cases(reference=str(path))]
            except BadInputError as error:
                self.fail(f"{where}.reference", str(error))
        else:
            cases = self.names(cases, f"{where}.cases")
        return {"case": Varying("grid", tuple(cases), f"{where}.cases"),
                "reference": reference,
                "through": None if raw.get("through") is None
                else self.reference(raw["through"], f"{where}.through"),
                "duration": None if raw.get("duration") is None
                else self.number(raw["duration"], f"{where}.duration", minimum=5)}

    def _qtg(self, raw, where: str) -> dict:
        if ("fmu" in raw) == ("reference" in raw):
            self.fail(where, "give the model to qualify as 'fmu' (an FMU file, or {\"reference\": NAME} built by the "
                             "campaign) or as 'reference' (a registry name or a state-space FILE.json), one of them")
        return {"spec": self.qtg_spec(raw["spec"], f"{where}.spec"),
                "fmu": self.fmu(raw["fmu"], f"{where}.fmu") if "fmu" in raw else None,
                "reference": self.reference(raw["reference"], f"{where}.reference", fmu_allowed=False)
                if "reference" in raw else None}

    def _reproduce(self, raw, where: str) -> dict:
        paper = self.choice_of(raw["paper"], f"{where}.paper", PAPERS)
        return {"paper": paper,
                "runs": self.whole(raw.get("runs", 1000), f"{where}.runs", minimum=10),
                "paper_only": self.boolean(raw.get("paper_only", False), f"{where}.paper_only"),
                "quick": self.boolean(raw.get("quick", False), f"{where}.quick")}


#: Fields of each kind besides ``id``, ``kind``, ``samples`` and ``seed``: (required, optional).
_STUDY_FIELDS = {
    "cosim": (("fmu", "duration"),
              ("step", "inputs", "parameters", "start_values", "outputs", "noise", "compare_with")),
    "diagnose": (("recordings", "reference"), ("holdout", "folds")),
    "diagnose-bench": ((), ("cases", "reference", "through", "duration")),
    "reproduce": (("paper",), ("runs", "paper_only", "quick")),
    "qtg": (("spec",), ("fmu", "reference")),
}


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _kind_of(value) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "true/false",
            type(None): "null"}.get(type(value), json.dumps(value))
