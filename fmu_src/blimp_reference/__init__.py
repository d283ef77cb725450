"""The blimp physics reference FMU (docs/fmus.md, "Blimp reference"): its variables and slave over
the blimp's equations of motion, and its builder."""
