"""The GP-NARX rate predictor FMU (docs/fmus.md, "GP-NARX rate predictor"): its variables and
slave, the GP-NARX prediction it carries, its pythonfmu and native builders and ``narx_model.c``."""
