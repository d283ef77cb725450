"""Errors raised by :mod:`gp_model`."""


class ModelFileError(ValueError):
    """A model file is missing, corrupt, of another format version, or not a flightgp model."""


class GPNumericalError(ArithmeticError):
    """The kernel matrix stayed non positive definite after the bounded jitter escalation."""
