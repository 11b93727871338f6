"""contfil.plot."""
