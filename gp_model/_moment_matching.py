"""Moment matching for fitted GPs: :func:`predict_uncertain_input` and :func:`moment_matcher`.

The mathematics (eqs. (1)-(6), Girard et al. 2003; Deisenroth & Rasmussen 2011) lives in
:mod:`gp_model.uncertain_input`, which needs numpy only so that FMUs can carry it; this module
checks fitted :class:`~gp_model.GaussianProcess` objects and expresses them in its common frame.
"""
from __future__ import annotations

import numpy as np

from ._gp import GaussianProcess
from ._kernels import StationaryKernel
from ._sparse_gp import SparseGaussianProcess
from .uncertain_input import FrameGP, MomentMatcher, frame_gp


def predict_uncertain_input(gps, mean, cov, *, include_noise: bool = True):
    """Exact mean and covariance of m GP predictions at a Gaussian input (moment matching).

    Implements eqs. (1)-(6) of :mod:`gp_model.uncertain_input` (Girard et al. 2003; Deisenroth
    & Rasmussen 2011).

    Parameters
    ----------
    gps : list of GaussianProcess or SparseGaussianProcess, length m
        Fitted single-output GPs on the same d inputs (for example ``PerOutputGP.gps``), each
        with kernel (1) of :mod:`gp_model._kernels`. The point hyperparameters ``theta_`` are used;
        ``theta_samples_`` is ignored. For a sparse GP the moments are those of its VFE
        predictive distribution.
    mean : array_like, shape (d,)
        Mean of the input distribution, in the raw input units of the GPs' training data.
    cov : array_like, shape (d, d)
        Covariance of the input distribution, in squared raw input units; symmetric positive
        semi-definite (zero gives the ordinary GP prediction at ``mean``).
    include_noise : bool, default True
        Predict noisy observations ``y`` (add each GP's noise variance ``exp(theta_[-1])``, in
        its standardised units, to the diagonal of ``out_cov``) instead of the latent ``f``.

    Returns
    -------
    out_mean : ndarray, shape (m,)
        ``E[f(x)]``, in output units.
    out_cov : ndarray, shape (m, m)
        ``Cov[f(x)]``, in products of output units: expected GP variances (plus noise) on the
        diagonal, and the covariances that the shared uncertain input induces between outputs.
    cross_cov : ndarray, shape (d, m)
        ``Cov[x, f(x)]``, in input units times output units.

    Raises
    ------
    TypeError
        If ``gps`` is not a list of GaussianProcess or SparseGaussianProcess objects.
    ValueError
        If a GP is unfitted, has several outputs or another input dimension, or if ``mean`` or
        ``cov`` has the wrong shape, is not finite, or ``cov`` is not symmetric positive
        semi-definite.

    Notes
    -----
    The cost is O(m n^3) to prepare the GPs and O(m^2 n^2 d) per input distribution. A free run
    predicting from many input distributions can prepare once with :func:`moment_matcher` and
    call it at every step.
    """
    return moment_matcher(gps)(mean, cov, include_noise=include_noise)


def moment_matcher(gps, *, use_samples: bool = False) -> MomentMatcher:
    """Prepare eqs. (1)-(6) of :mod:`gp_model.uncertain_input` for a list of fitted GPs.

    Parameters
    ----------
    gps : list of GaussianProcess or SparseGaussianProcess
        As in :func:`predict_uncertain_input`.
    use_samples : bool, default False
        Match the mixture over the GPs' hyperparameter samples (sample s of every GP forms
        model s, so all GPs need the same number of samples) instead of using ``theta_``.

    Returns
    -------
    MomentMatcher
        In the frame of ``gps[0]``; call it with an input mean and covariance.

    Raises
    ------
    TypeError, ValueError
        As :func:`predict_uncertain_input`.
    """
    if not isinstance(gps, (list, tuple)) or not all(
            isinstance(gp, (GaussianProcess, SparseGaussianProcess)) for gp in gps):
        raise TypeError("gps must be a list of fitted single-output GaussianProcess or "
                        "SparseGaussianProcess objects (for a PerOutputGP pass its .gps)")
    if not gps:
        raise ValueError("gps is empty; pass one fitted GaussianProcess per output")
    for a, gp in enumerate(gps):
        if not hasattr(gp, "theta_"):
            raise ValueError(f"gps[{a}] is not fitted; call fit() first")
        if gp.Y_train_.shape[1] != 1:
            raise ValueError(f"gps[{a}] has {gp.Y_train_.shape[1]} outputs; moment matching "
                             "needs one single-output GP per output (use PerOutputGP)")
        if not isinstance(gp.kernel, StationaryKernel):
            raise ValueError(f"gps[{a}] has kernel {type(gp.kernel).__name__}; moment "
                             "matching needs the squared-exponential form (1) of "
                             "gp_model._kernels")
        if gp.X_train_.shape[1] != gps[0].X_train_.shape[1]:
            raise ValueError(f"gps[{a}] has input dimension {gp.X_train_.shape[1]} but gps[0] "
                             f"has {gps[0].X_train_.shape[1]}; all GPs must share the input")
    input_mean = gps[0].input_scaler_.mean_  # (d,) mu_0 of the common frame
    input_scale = gps[0].input_scaler_.scale_  # (d,) s_0
    frames = [_to_frame(gp, input_mean, input_scale, use_samples=use_samples) for gp in gps]
    return MomentMatcher(frames, input_mean=input_mean, input_scale=input_scale)


def _to_frame(gp, input_mean, input_scale, *, use_samples: bool) -> FrameGP:
    """``gp`` in the frame ``(x - input_mean) / input_scale``, from its
    :class:`~gp_model.PredictiveForm` s (mean ``k @ weights``, latent variance ``s2 - k^T A k``
    with ``A = variance_factor^T variance_factor``: ``(K + sigma_n^2 I)^-1`` for an exact GP,
    ``K_mm^-1 - Sigma`` for a sparse one; eqs. (1)-(6) need nothing else, so they hold for both).
    """
    forms = gp.predictive_forms(use_samples=use_samples)
    thetas = np.array([form.theta for form in forms])
    return frame_gp(basis=forms[0].basis, weights=[form.weights for form in forms],
                    variance_factor=[form.variance_factor for form in forms],
                    kernel_weights=[gp.kernel.weights(theta[:-1]) for theta in thetas],
                    log_signal_variance=thetas[:, 0], noise_variance=np.exp(thetas[:, -1]),
                    input_mean=gp.input_scaler_.mean_, input_scale=gp.input_scaler_.scale_,
                    output_mean=gp.output_scaler_.mean_[0], output_scale=gp.output_scaler_.scale_[0],
                    frame_mean=input_mean, frame_scale=input_scale)
