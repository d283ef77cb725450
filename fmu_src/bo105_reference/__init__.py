"""The Bo105 physics reference FMU (docs/fmus.md, "Bo105 reference"): its variables and slave, the
zero-order-hold discretisation it carries and its builder."""
