"""``flightgp bench``: speed and memory measured as ratios against a peer run in the same
process (docs/benchmarks.md)."""
