import os
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import sys; sys.path.insert(0, "benchmarks")
import orbit_cost as oc
from contfil.models.filament import FilamentModel
m = FilamentModel(oc.ROOT / "branches" / "tip_sf.toml")
import json, numpy as np
x0 = oc.start_orbit(m)
oc.unit_costs(m, x0, oc.P0)
print(oc.unit_costs(m, x0, oc.P0))
