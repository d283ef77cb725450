"""Vehicles, manoeuvres, recordings, co-simulation, paper reproductions, diagnose and the CLI."""
