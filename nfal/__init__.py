"""nfal: near-field acoustic levitation physics, control and co-simulation."""

__version__ = "0.1.0"
