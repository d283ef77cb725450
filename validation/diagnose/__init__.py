"""``flightgp diagnose``: where a simulation and recordings differ, what physics is missing,
the corrected model and the proof on held-out data (docs/diagnose.md).

The stages are modules (:mod:`validation.diagnose.pipeline` lists them); the concealed-effect
benchmark is :mod:`validation.diagnose.bench`.
"""
from validation.diagnose.pipeline import diagnose
from validation.diagnose.report import Diagnosis, diagnosis_files, write_diagnosis

__all__ = ["Diagnosis", "diagnose", "diagnosis_files", "write_diagnosis"]
