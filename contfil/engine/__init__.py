"""contfil.engine."""
