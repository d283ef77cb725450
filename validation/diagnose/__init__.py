"""``flightgp diagnose``: where a simulation and recordings differ, what physics is missing,
the corrected model and the proof on held-out data (docs/diagnose.md)."""
