"""The papers' experiments, reproduced end to end, and the demo (docs/reproductions.md)."""
