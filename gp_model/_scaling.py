"""Affine standardisation of GP inputs and outputs."""
from __future__ import annotations

import numpy as np


class Standardizer:
    """``z = (x - mean_) / scale_`` per column; the identity when ``enabled`` is False.

    Columns with zero spread get scale 1 so that constant inputs do not divide by zero.
    """

    def __init__(self, *, enabled: bool = True) -> None:
        self.enabled = enabled

    def fit(self, X: np.ndarray) -> Standardizer:
        """Learn ``mean_`` and ``scale_`` from ``X``, shape (n, d)."""
        d = X.shape[1]
        if self.enabled:
            self.mean_ = X.mean(axis=0)
            spread = X.std(axis=0)
            self.scale_ = np.where(spread > 0, spread, 1.0)
        else:
            self.mean_, self.scale_ = np.zeros(d), np.ones(d)
        return self

    def transform(self, X: np.ndarray) -> np.ndarray:
        return (X - self.mean_) / self.scale_

    def inverse_transform(self, Z: np.ndarray) -> np.ndarray:
        return Z * self.scale_ + self.mean_

    @classmethod
    def from_arrays(cls, mean: np.ndarray, scale: np.ndarray) -> Standardizer:
        new = cls(enabled=True)
        new.mean_, new.scale_ = np.asarray(mean, float), np.asarray(scale, float)
        return new
