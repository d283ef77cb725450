"""The RGBlimp RKGP FMU (docs/fmus.md, "RGBlimp RKGP"): its slave, the RK4-plus-GP model it
carries, its pythonfmu and native builders and ``rgblimp_model.c``."""
