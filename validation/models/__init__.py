"""Models trained on recordings: GP-NARX rate predictors and the blimp's physical parameters."""
