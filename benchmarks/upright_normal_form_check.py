# ruff: noqa: E402  (BLAS thread count must be set before numpy is imported)
"""Check the O(2) normal form at the tip-FF double Hopf against time integration.

Run (about a minute after numba compilation of the stepper, which is cached)::

    python benchmarks/upright_normal_form_check.py [--model tip_ff] [--d 0.05 0.1]

For ``f = f* + d`` the normal form predicts a whirling (rotating-wave) state
with ``|z1|^2 = -Re(lambda') d / Re A``, ``z2 = 0`` and angular frequency
``omega + Im(lambda') d + Im A |z1|^2``, where ``z_i = y_i^T u`` are the
amplitudes on the two rotating critical modes. Starting near (80 % of) the
predicted state, the model's BDF2 flow is run until the amplitude settles,
and the measured amplitude and frequency are compared with the prediction:
their ratio must approach 1 as ``O(d)``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from upright_branches import DP_MAX, P_MAX, ROOT  # noqa: E402

from contfil.engine import Continuation, ContinuationSettings, EquilibriumProblem, hopf_normal_form
from contfil.engine.branch import DOUBLE_HOPF
from contfil.models.filament.integrators.bdf2 import BDF2Stepper
from contfil.models.filament.model import FilamentModel


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="tip_ff")
    ap.add_argument("--d", type=float, nargs="*", default=[0.05, 0.1])
    ap.add_argument("--T", type=float, default=12.0, help="integration time")
    ap.add_argument("--dt", type=float, default=1e-3)
    a = ap.parse_args()

    model = FilamentModel(ROOT / "branches" / f"{a.model}.toml")
    pb = EquilibriumProblem(model, model.param_names[0])
    ds = DP_MAX[a.model] * np.sqrt(0.5)
    run = Continuation(
        pb,
        model.initial_state(),
        0.0,
        ContinuationSettings(ds=ds / 4, ds_max=ds, p_max=P_MAX[a.model], compute_observables=False),
    )
    for _ in run:
        if any(s.kind == DOUBLE_HOPF for s in run.branch.special_points):
            break
    sp = [s for s in run.branch.special_points if s.kind == DOUBLE_HOPF][0]
    L = model.symmetries.continuous[0].generator
    nf = hopf_normal_form(pb, sp, L, h=2e-3)
    pstar, omega = sp.point.p, sp.data["omega"]
    sig, A = nf["dlambda_dp"], nf["A"]
    q1, y1, y2 = nf["q1"], nf["y1"], nf["y2"]
    print(
        f"{a.model}: p* = {pstar:.8f}, omega = {omega:.6f}, A = {A:.5f}, B = {nf['B']:.5f}, "
        f"lambda' = {sig:.5f}"
    )
    print(
        "| d | predicted abs z1 | measured abs z1 | ratio | measured abs z2 | predicted freq | "
        "measured freq | ratio | wall (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for d in a.d:
        z2_pred = -sig.real * d / A.real
        zp = np.sqrt(z2_pred)
        w_pred = omega + sig.imag * d + A.imag * z2_pred
        u = 2.0 * (0.8 * zp * q1).real
        p = np.array([pstar + d])
        t0 = time.perf_counter()
        # One continuous BDF2 run sampled every `chunk`: restarting the flow map
        # in short chunks would add a backward-Euler step each time, whose
        # damping (~ omega^2 dt / 2 per step) biases the amplitude.
        st = BDF2Stepper(model, a.dt, tol=1e-12, p=p)
        st.reset(u)
        chunk = 0.02
        nsub = int(round(chunk / a.dt))
        nchunks = int(round(a.T / chunk))
        zs = []
        for _ in range(nchunks):
            u = st.step(nsub)
            zs.append((y1 @ u, y2 @ u))
        wall = time.perf_counter() - t0
        zs = np.array(zs)
        tail = zs[int(0.8 * nchunks) :]
        z1m = float(np.mean(np.abs(tail[:, 0])))
        z2m = float(np.mean(np.abs(tail[:, 1])))
        ph = np.unwrap(np.angle(tail[:, 0]))
        w_meas = float(np.polyfit(np.arange(ph.size) * chunk, ph, 1)[0])
        print(
            f"| {d:g} | {zp:.5f} | {z1m:.5f} | {z1m / zp:.4f} | {z2m:.1e} | {w_pred:.5f} | "
            f"{abs(w_meas):.5f} | {abs(w_meas) / w_pred:.5f} | {wall:.1f} |"
        )


if __name__ == "__main__":
    main()
