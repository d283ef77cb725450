"""Gaussian-process mathematics for flightgp.

numpy/scipy only; imports nothing from ``validation`` or ``fmu_src``. The public API is what this
module exports; everything else lives in private modules.
"""
from ._errors import GPNumericalError, ModelFileError
from ._gp import GaussianProcess, PerOutputGP, PredictiveForm
from ._greybox import PROPAGATION_STEP, GreyBoxGP, PropagatedRollout
from ._inference import (
                         AnnealingResult,
                         MaximumLikelihoodResult,
                         MCMCResult,
                         anneal_hyperparameters,
                         maximize_marginal_likelihood,
                         metropolis,
                         simulated_annealing,
)
from ._kernels import HigdonKernel, SquaredExponentialARD, alpha_from_length_scale, length_scale_from_alpha
from ._model_file import load_model, model_bytes, read_header, save_model
from ._moment_matching import moment_matcher, predict_uncertain_input
from ._narx import FreeRunResult, GPNarx, NarxStructure
from ._priors import IndependentPrior
from ._sparse_gp import SparseGaussianProcess

__all__ = [
    "AnnealingResult", "FreeRunResult", "GaussianProcess", "GPNarx", "GPNumericalError", "GreyBoxGP",
    "HigdonKernel", "IndependentPrior",
    "MaximumLikelihoodResult", "MCMCResult", "ModelFileError", "NarxStructure", "PerOutputGP", "PredictiveForm",
    "PROPAGATION_STEP", "PropagatedRollout",
    "SparseGaussianProcess", "SquaredExponentialARD", "alpha_from_length_scale", "anneal_hyperparameters",
    "length_scale_from_alpha", "load_model", "maximize_marginal_likelihood", "metropolis", "model_bytes",
    "moment_matcher", "predict_uncertain_input", "read_header", "save_model", "simulated_annealing",
]
