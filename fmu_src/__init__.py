"""pythonfmu slave classes and the FMU builders (see DESIGN.md, "FMU rules")."""
