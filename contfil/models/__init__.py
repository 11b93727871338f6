"""contfil.models."""
