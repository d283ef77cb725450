"""``flightgp qtg``: a qualification test guide run against a model (docs/qtg.md): the spec
(:mod:`validation.qtg.spec`), the runs and their scores (:mod:`validation.qtg.run`) and the
files a reviewer and a CI system read (:mod:`validation.qtg.report`).
"""
from validation.qtg.report import write_qtg
from validation.qtg.run import QtgResult, open_model, run_qtg
from validation.qtg.spec import QtgSpec, read_spec

__all__ = ["QtgResult", "QtgSpec", "open_model", "read_spec", "run_qtg", "write_qtg"]
