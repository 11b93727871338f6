"""contfil.analysis."""
