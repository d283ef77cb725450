"""The plumbing every other part of validation shares: the one error type for bad input,
atomic file writing, progress bars, plots, manoeuvres, recordings and the sampling rule."""
