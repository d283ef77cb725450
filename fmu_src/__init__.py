"""flightgp's FMI 2.0 co-simulation units (docs/fmus.md; layers in docs/architecture.md).

Layout, as the Modelica Reference-FMUs: one generic FMI layer, :mod:`fmu_src.fmi` (the Python
base slave and its C twin ``fmi2_slave.c``, the runtime every pythonfmu FMU carries, pythonfmu
packaging and native compilation), and one folder per FMU model holding only its identity,
variable table, equations and builders: :mod:`fmu_src.rate_predictor`,
:mod:`fmu_src.blimp_rkgp`, :mod:`fmu_src.rgblimp_rkgp`, :mod:`fmu_src.rgblimp_hybrid`, :mod:`fmu_src.bo105_reference`,
:mod:`fmu_src.blimp_reference`, :mod:`fmu_src.jsbsim_aircraft`.

The public API is what this package exports.
"""
from fmu_src.blimp_reference.build import build_blimp_reference_fmu
from fmu_src.blimp_rkgp.build import build_blimp_rkgp_fmu
from fmu_src.blimp_rkgp.native import build_native_blimp_rkgp_fmu
from fmu_src.bo105_reference.build import build_bo105_reference_fmu
from fmu_src.build import build_model_fmu, build_reference_fmu, reference_fmu_names
from fmu_src.fmi.native import fmi_headers
from fmu_src.jsbsim_aircraft.build import build_jsbsim_fmu
from fmu_src.rate_predictor.build import build_rate_predictor_fmu
from fmu_src.rate_predictor.native import build_native_rate_predictor_fmu
from fmu_src.rgblimp_hybrid.build import build_rgblimp_hybrid_fmu
from fmu_src.rgblimp_hybrid.native import build_native_rgblimp_hybrid_fmu
from fmu_src.rgblimp_rkgp.build import build_rgblimp_rkgp_fmu
from fmu_src.rgblimp_rkgp.native import build_native_rgblimp_rkgp_fmu

__all__ = ["build_blimp_reference_fmu", "build_blimp_rkgp_fmu", "build_bo105_reference_fmu", "build_jsbsim_fmu",
           "build_model_fmu", "build_native_blimp_rkgp_fmu", "build_native_rate_predictor_fmu",
           "build_native_rgblimp_hybrid_fmu", "build_native_rgblimp_rkgp_fmu", "build_rate_predictor_fmu",
           "build_reference_fmu", "build_rgblimp_hybrid_fmu", "build_rgblimp_rkgp_fmu", "fmi_headers",
           "reference_fmu_names"]
