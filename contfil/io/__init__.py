"""contfil.io: spec files (TOML) and the crash-safe, resumable run store."""

from contfil.io.spec import Spec, load_spec, loads_spec
from contfil.io.store import RunStore, load_run_graph

__all__ = ["RunStore", "Spec", "load_run_graph", "load_spec", "loads_spec"]
