"""Data the GP-model tests share: a smooth regression problem and a model-file header editor."""
import json

import numpy as np


def make_data(n=30, d=2, seed=0, noise=0.05, n_outputs=1):
    """``n`` uniform inputs in [-2, 2]^d and a smooth target plus white noise of sd ``noise``:
    ``y`` (n,), or (n, n_outputs) with output j the target scaled by ``j + 1`` and shifted by j."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, size=(n, d))
    y = np.sin(1.5 * X[:, 0]) + 0.3 * X[:, -1] ** 2 + noise * rng.standard_normal(n)
    if n_outputs == 1:
        return X, y
    return X, np.column_stack([y * (j + 1) + j for j in range(n_outputs)])


def rewrite_header(path, change):
    """Apply ``change(header)`` to the JSON header of the model file at ``path`` in place."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    header = json.loads(str(arrays["__header__"]))
    change(header)
    arrays["__header__"] = np.array(json.dumps(header))
    np.savez(path, **arrays)
