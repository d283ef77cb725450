"""The RGBlimp hybrid FMU (docs/fmus.md, "RGBlimp hybrid"): its slave, the model it carries (the
identified physics plus the rollout-trained correction), its pythonfmu and native builders and
``rgblimp_hybrid_model.c``."""
