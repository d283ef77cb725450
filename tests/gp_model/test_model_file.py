"""Portable model files: exact round trip, no pickle, clear errors."""
import zipfile

import numpy as np
import pytest

from gp_model import (
    GaussianProcess,
    HigdonKernel,
    ModelFileError,
    SquaredExponentialARD,
    load_model,
    read_header,
    save_model,
)
from tests.gp_model.data import rewrite_header


@pytest.fixture
def data():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(25, 3))
    return X, np.column_stack([np.sin(X[:, 0]), X[:, 1] * X[:, 2]])


def test_model_file_name_and_meta(tmp_path, data):
    X, Y = data
    gp = GaussianProcess(HigdonKernel(1.2, [0.3, 0.6, 0.8]), noise_variance=0.03).fit(X, Y)
    gp.set_hyperparameters(gp.theta_, samples=gp.theta_ + np.random.default_rng(1).normal(0, 0.1, (5, 5)))
    path = save_model(tmp_path / "model", gp, meta={"trained_on": "id.csv"})
    assert path.name == "model.npz"
    # Identical predictions after a round trip: the contract (tests/gp_model/contract.py).
    np.testing.assert_array_equal(load_model(path).theta_samples_, gp.theta_samples_)
    assert read_header(path)["meta"] == {"trained_on": "id.csv"}


def test_file_loads_without_pickle(tmp_path, data):
    X, Y = data
    path = save_model(tmp_path / "m.npz", GaussianProcess(SquaredExponentialARD(1.0, [1.0] * 3)).fit(X, Y))
    with np.load(path, allow_pickle=False) as npz:  # raises if any object array were stored
        assert "__header__" in npz.files


def test_missing_file(tmp_path):
    with pytest.raises(ModelFileError, match="no such model file"):
        load_model(tmp_path / "nope.npz")


def test_corrupt_file(tmp_path):
    path = tmp_path / "bad.npz"
    path.write_bytes(b"PK\x03\x04 this is not a zip archive")
    with pytest.raises(ModelFileError, match="not a readable"):
        load_model(path)


def test_npz_that_is_not_a_model(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, x=np.arange(3))
    with pytest.raises(ModelFileError, match="no flightgp header"):
        load_model(path)


def test_wrong_version_says_which(tmp_path, data):
    X, Y = data
    path = save_model(tmp_path / "m.npz", GaussianProcess(SquaredExponentialARD(1.0, [1.0] * 3)).fit(X, Y))
    rewrite_header(path, lambda h: h.update(version=99))
    with pytest.raises(ModelFileError, match="version 99.*reads version 1"):
        load_model(path)


def test_truncated_arrays_are_inconsistent(tmp_path, data):
    X, Y = data
    path = save_model(tmp_path / "m.npz", GaussianProcess(SquaredExponentialARD(1.0, [1.0] * 3)).fit(X, Y))
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["gp0/theta"] = arrays["gp0/theta"][:2]
    np.savez(path, **arrays)
    with pytest.raises(ModelFileError, match="inconsistent"):
        load_model(path)


def test_failed_save_leaves_existing_file_untouched(tmp_path, data, monkeypatch):
    X, Y = data
    gp = GaussianProcess(SquaredExponentialARD(1.0, [1.0] * 3)).fit(X, Y)
    path = save_model(tmp_path / "m.npz", gp)
    before = path.read_bytes()

    def fail(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("gp_model._model_file.os.replace", fail)  # the last step of a save
    gp.set_hyperparameters(gp.theta_ + 0.1)
    with pytest.raises(OSError, match="No space"):
        save_model(path, gp)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.npz"]  # no temporary left behind
    assert zipfile.is_zipfile(path)


def test_round_trip_narx_model_free_runs_identically(tmp_path):
    from gp_model import GPNarx, NarxStructure

    rng = np.random.default_rng(3)
    u = np.repeat(rng.uniform(-1, 1, 30), 4)[:, None]
    y = np.zeros((len(u), 1))
    for k in range(1, len(u)):
        y[k] = 0.8 * y[k - 1] + 0.3 * np.tanh(u[k - 1])
    structure = NarxStructure(("u",), ("y",), input_lags=(1, 2), output_lags=(1,))
    model = GPNarx.fit(structure, [(u, y + 0.01 * rng.standard_normal(y.shape))], stride=3, n_samples=32)
    loaded = load_model(save_model(tmp_path / "narx.npz", model))
    assert isinstance(loaded, GPNarx) and loaded.structure == structure
    a = model.free_run(u, y[:2], n_runs=50, seed=1, keep_runs=True)
    b = loaded.free_run(u, y[:2], n_runs=50, seed=1, keep_runs=True)
    np.testing.assert_array_equal(a.runs, b.runs)


@pytest.mark.parametrize("corrupt, message", [
    (lambda a: a.update({"gp0/theta": np.full_like(a["gp0/theta"], np.nan)}), "NaN or inf"),
    (lambda a: a["gp0/X_train"].__setitem__((0, 0), np.inf), "NaN or inf"),
    (lambda a: a.update({"__header__": np.array("[1, 2]")}), "not a JSON object"),
    (lambda a: a.update({"gp0/theta": np.array([0.0, 0.0, 0.0, 0.0, 800.0])}), "cannot be factorised|inconsistent"),
])
@pytest.mark.filterwarnings("ignore:overflow encountered in exp:RuntimeWarning")  # exp(800) is the corruption
def test_corrupt_content_is_a_model_file_error(tmp_path, data, corrupt, message):
    X, Y = data
    path = save_model(tmp_path / "m.npz", GaussianProcess(SquaredExponentialARD(1.0, [1.0] * 3)).fit(X, Y))
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k].copy() for k in npz.files}
    corrupt(arrays)
    np.savez(path, **arrays)
    with pytest.raises(ModelFileError, match=message):
        load_model(path)
