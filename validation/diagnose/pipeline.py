"""``flightgp diagnose``: locate where a simulation and recordings differ, name the missing
physics, model it, and prove the fit improves on data not used to fit it (docs/diagnose.md).

:func:`diagnose` runs the stages in order, each a module with its result object:

1. :mod:`~validation.diagnose.data`: the recordings checked against the reference, split into
   fitted and held-out samples, the sensor noise estimated
   (:class:`~validation.diagnose.data.PreparedData`);
2. :mod:`~validation.diagnose.locate`: where and at which frequencies the reference misfits
   (:class:`~validation.diagnose.locate.Location`);
3. :mod:`~validation.diagnose.explain`: named effects fitted and accepted stepwise
   (:class:`~validation.diagnose.explain.Explanation`); :mod:`~validation.diagnose.scope`: each
   shared by the diagnosed recordings or differing per recording
   (:class:`~validation.diagnose.scope.Scope`); :mod:`~validation.diagnose.carry_over`: each
   scored on the held-out recordings, alone and in the final model
   (:class:`~validation.diagnose.carry_over.CarryOver`);
4. :mod:`~validation.diagnose.model`: the corrected model of the shared effects that carry over,
   and residual GPs (:class:`~validation.diagnose.model.Models`);
5. :mod:`~validation.diagnose.prove`: the models scored and the explanation validated on the
   held-out samples (:class:`~validation.diagnose.prove.Proof`);
   with ``folds``, :mod:`~validation.diagnose.replicate`: the search repeated on folds of the
   diagnosed recordings (:class:`~validation.diagnose.replicate.Replication`);
   :mod:`~validation.diagnose.fidelity`: the scorecard (tolerance bands, Theil's U, the
   frequency-domain cost) of the held-out fit;
6. :mod:`~validation.diagnose.report`: the findings with their statements
   (:class:`~validation.diagnose.report.Diagnosis`, exactly diagnosis.json), which
   :func:`~validation.diagnose.report.write_diagnosis` writes with report.md and the corrected
   model.

The reference takes effects through its :class:`validation.vehicles.effects.EffectModel`
(:func:`validation.vehicles.effect_vehicle.effect_model`), which every stage receives as
``reference``, so no stage asks which reference it is.
"""
from __future__ import annotations

from validation.core.errors import BadInputError
from validation.diagnose.carry_over import carry_over
from validation.diagnose.data import prepare
from validation.diagnose.explain import explain
from validation.diagnose.fidelity import check_tolerance_outputs, scorecard
from validation.diagnose.locate import locate
from validation.diagnose.model import build_models
from validation.diagnose.prove import prove
from validation.diagnose.replicate import fold_recordings, replicate
from validation.diagnose.report import Diagnosis, assemble_diagnosis
from validation.diagnose.scope import scope
from validation.vehicles.effect_vehicle import effect_model


def take_input_terms(reference) -> None:
    """Let ``reference``'s residual search add terms through its inputs
    (:meth:`validation.vehicles.fmu_reference.FMUEffects.take_input_terms`); BadInputError for a
    reference that is not an FMU, whose search adds its terms to its equations."""
    if not hasattr(reference, "take_input_terms"):
        raise BadInputError(f"input terms are for an FMU reference; the {reference.name} reference's residual "
                            "search adds its terms to its equations")
    reference.take_input_terms()


def diagnose(recordings, *, reference: str, holdout=None, seed: int = 0, folds: int | None = None,
             file_format: str | None = None, tolerances: dict | None = None, column_map: dict | None = None,
             workers: int | None = None, input_terms: bool = False, progress=None) -> Diagnosis:
    """Locate, explain, model and prove (module docstring) on ``recordings``.

    Parameters
    ----------
    recordings : sequence of path-like or Recording
        Recordings of the vehicle ``reference`` describes, starting at trim (docs/conventions.md,
        "Recording files"). Paths are read with :func:`validation.vehicles.read_recording`.
        Evenly sampled if the reference needs it (a Bo105; the blimp's may be unevenly sampled,
        :mod:`validation.diagnose.data`). All share one nominal sample interval.
    reference : str
        The registry name of a reference that takes effects
        (:data:`validation.vehicles.effect_vehicle.EFFECT_MODELS`): ``bo105-<V>kt``, ``blimp`` or
        ``rgblimp``.
    holdout : sequence of path-like or Recording, optional
        Recordings used only to score the models. Default: the last recording, or the last 30 %
        of a single one (:mod:`validation.diagnose.data`).
    seed : int
        Seed of the residual GPs' hyperparameter restarts.
    folds : int, optional
        Also run the search on this many folds of the diagnosed recordings (2 or more; at least
        that many recordings besides the held-out ones) and say which findings every fold names
        (:mod:`validation.diagnose.replicate`). Default: no replication.
    file_format : {"flightgp", "rgblimp"}, optional
        Format of the recording files (:func:`validation.vehicles.read_recording`); default:
        recognised from each file's header.
    tolerances : dict, optional
        Output -> (band half-width in its SI unit, source) for the fidelity scorecard
        (:func:`validation.diagnose.fidelity.read_tolerances`); outputs not named keep the
        default bands (:data:`validation.diagnose.fidelity.DEFAULT_TOLERANCES`); naming an output
        the recordings do not hold is refused.
    column_map : dict of str to str, optional
        Recording column -> the reference's name for it (:func:`validation.diagnose.data.read_column_map`),
        for recordings whose columns are named otherwise than the reference's variables.
    workers : int, optional
        Processes that replay candidates side by side, for references that replay in processes
        of their own (an FMU, :class:`validation.vehicles.fmu_reference.FMUReference`); default:
        the cores this process may use.
    input_terms : bool
        Through an FMU, let the residual search add terms fed into its inputs
        (:meth:`validation.vehicles.fmu_reference.FMUEffects.take_input_terms`); off by default
        (they cost about 5x the time). Refused for any other reference, whose search needs no such
        terms.
    progress : callable, optional
        ``progress(n, **status)`` (:func:`validation.core.progress.progress_bar` yields one):
        advanced by one at the end of each of the :func:`stage_count` stages (``stage=`` the
        stage's name), and called with 0 and the fit in hand (``fitted=``) in between, so a bar
        with :func:`stage_count` as its total fills as the diagnosis goes.

    Returns
    -------
    Diagnosis

    Raises
    ------
    BadInputError
        Unknown or unsupported reference; recordings that miss its inputs, hold another
        vehicle's columns, have no outputs, hold NaN, or are too short to identify anything;
        unevenly sampled recordings of a reference that needs even sampling; recordings at
        different nominal sample rates; ``folds`` below 2 or above the number of diagnosed
        recordings.
    """
    reference = effect_model(reference, purpose="diagnose")  # the name's EffectModel from here on
    if workers is not None and hasattr(reference, "workers"):
        reference.workers = workers
    if input_terms:
        take_input_terms(reference)
    data = prepare(recordings, reference, holdout=holdout, file_format=file_format, column_map=column_map)
    check_tolerance_outputs(tolerances, data.output_names)
    if folds is not None:
        fold_recordings(data, folds)  # refuses impossible folds before the long stages
    fits, done = _stage_progress(progress)
    location = locate(data, reference)
    done("locate")
    explanation = explain(data, location, reference, progress=fits)
    done("explain")
    scopes = scope(data, explanation, reference, progress=fits)
    done("scope")
    carried = carry_over(data, location, explanation, reference, offered=scopes.offered, progress=fits)
    done("carry_over")
    models = build_models(data, location, explanation, reference, seed=seed, progress=fits, effects=carried.kept)
    done("models")
    proof = prove(data, location, explanation, models, reference, progress=fits)
    done("prove")
    replication = None
    if folds is not None:
        replication = replicate(data, location, explanation, reference, folds=folds, progress=fits)
        done("replicate")
    held_out = [(u, m, data.input_names) for u, m in zip(data.inputs, data.holdout_mask) if m.any()]
    fidelity = scorecard(proof.traces, proof.fit, held_out, step=data.step, tolerances=tolerances,
                         pose_score=getattr(reference, "pose_score", False))
    return assemble_diagnosis(reference, data, location, explanation, models, proof, scopes=scopes,
                              carried=carried, replication=replication, fidelity=fidelity)


#: The stages of :func:`diagnose`, in order (``replicate`` only with folds).
STAGES = ("locate", "explain", "scope", "carry_over", "models", "prove", "replicate")


def stage_count(*, folds: int | None = None) -> int:
    """How many stages :func:`diagnose` runs, the total of its progress bar: :data:`STAGES`
    without ``replicate`` unless ``folds`` is given."""
    return len(STAGES) - (folds is None)


def _stage_progress(progress):
    """``(fits, done)``: ``fits(n, **status)`` shows a stage's fit without advancing, ``done(stage)``
    advances by one stage; both do nothing without ``progress``."""
    if progress is None:
        return None, lambda stage: None
    return (lambda n, **status: progress(0, **status)), (lambda stage: progress(1, stage=stage))

