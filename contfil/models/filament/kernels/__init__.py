"""contfil.models.filament.kernels."""
