"""The rule a stored attractor-state node's label must follow from its own
evidence (decisions 31, 43), shared by the tests that read stored states."""

from __future__ import annotations

import math
from typing import Any


def assert_label_follows_from_evidence(state: dict[str, Any]) -> None:
    """Chaotic: a positive exponent beyond three errors on a spectrum that is
    not all lines. Otherwise quasiperiodic: the exponent zero within three
    errors, and all lines or a bound below the spectrum's resolution rate."""
    ev, sid = state["evidence"], state["id"]
    assert ev["label"] == state["kind"], sid
    lam, err = ev["lyapunov"], ev["lyapunov_error"]
    if state["kind"] == "chaotic":
        assert lam > 3 * err > 0, sid
        assert ev["discrete_fraction"] < 0.98, sid
        return
    assert state["kind"] == "quasiperiodic", sid
    assert abs(lam) <= 3 * err, sid
    resolved = lam + 3 * err < 2 * math.pi * ev["frequency_resolution"]
    assert ev["discrete_fraction"] >= 0.98 or resolved, sid
