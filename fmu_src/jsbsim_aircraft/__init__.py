"""The JSBSim aircraft FMU (docs/fmus.md, "JSBSim aircraft"): its variables and slave, which flies
JSBSim inside the FMU, and its builder."""
