"""contfil.graph."""
