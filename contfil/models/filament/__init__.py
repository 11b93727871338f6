"""contfil.models.filament."""
