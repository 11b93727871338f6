"""contfil: numerical continuation and bifurcation analysis for large, stiff models."""

__version__ = "0.1.0"
