"""The public engine API (issue 11: the cycle API is exported from ``contfil.engine``)."""

import contfil.engine as engine
from contfil.engine.linalg.floquet import floquet_multipliers
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.engine.switching.cycles import cycles_from_hopf


def test_every_public_name_resolves() -> None:
    missing = [n for n in engine.__all__ if not hasattr(engine, n)]
    assert not missing
    assert len(set(engine.__all__)) == len(engine.__all__)


def test_cycle_api_is_the_modules_own_objects() -> None:
    assert engine.PeriodicOrbitProblem is PeriodicOrbitProblem
    assert engine.RelativePeriodicOrbitProblem is RelativePeriodicOrbitProblem
    assert engine.floquet_multipliers is floquet_multipliers
    assert engine.cycles_from_hopf is cycles_from_hopf
    for name in ("RotatingWaveProblem", "cycle_events", "ContinuationState",
                 "hookstep_corrector", "rotating_wave_from_double_hopf"):
        assert name in engine.__all__
