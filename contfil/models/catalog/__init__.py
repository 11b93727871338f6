"""contfil.models.catalog."""
