"""The blimp RKGP FMU (docs/fmus.md, "Blimp RKGP"): its slave, the RK4-plus-GP model it
carries, its pythonfmu and native builders and ``blimp_model.c``."""
