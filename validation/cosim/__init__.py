"""Co-simulation: FMUs run in fmpy against recordings, and the second hosts (libcosim, a
plain C program)."""
