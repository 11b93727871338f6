"""contfil.io."""
