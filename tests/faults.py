"""Fault injection for the crash tests, done from the tests (never from
production code): the ``contfil`` command line is run in a subprocess whose
store functions are wrapped to ``kill -9`` the process at a chosen moment.

``python -c WRAPPER SPEC -- contfil args...``, where SPEC is one of

- ``point:N`` / ``torn:N``: SIGKILL when the (N+1)-th point record of this
  process is about to be appended (``torn``: after writing half of it);
- ``call:MODULE:ATTR:N``: SIGKILL when the N-th call of ``MODULE.ATTR`` starts
  (e.g. the start-up window: the creation of the run directory);
- ``none``: no fault.
"""

from __future__ import annotations

import os
import subprocess
import sys

WRAPPER = r'''
import importlib, os, signal, sys

spec, argv = sys.argv[1], sys.argv[3:]
assert sys.argv[2] == "--"

def die():
    os.kill(os.getpid(), signal.SIGKILL)

if spec.startswith(("point:", "torn:")):
    from contfil.store import atomic
    after, torn = int(spec.split(":")[1]), spec.startswith("torn:")
    orig = atomic.RecordLog.append
    count = [0]
    def append(self, obj):
        if isinstance(obj, dict) and obj.get("t") == "point":
            count[0] += 1
            if count[0] > after:
                if torn and self._fh is not None:
                    rec = atomic.encode_record(obj)
                    self._fh.write(rec[: len(rec) // 2])
                    self._fh.flush()
                    os.fsync(self._fh.fileno())
                die()
        return orig(self, obj)
    atomic.RecordLog.append = append
elif spec.startswith("call:"):
    _, mod, attr, n = spec.split(":")
    m = importlib.import_module(mod)
    orig_fn = getattr(m, attr)
    calls = [0]
    def wrapped(*a, **k):
        calls[0] += 1
        if calls[0] == int(n):
            die()
        return orig_fn(*a, **k)
    setattr(m, attr, wrapped)

from contfil.app.cli import main
sys.exit(main(argv))
'''


#: Equilibria through a Hopf point onto its cycles: the smallest study with
#: an equilibrium branch and a cycle branch (seconds); the fault, fuzz and
#: crash tests all damage or kill runs of it.
HOPF_SPEC = """
[model]
name = "hopf_2d"

[continuation]
range = [-1.0, 0.6]
ds = 0.1
ds_max = 0.2
max_points = 12
tol = 1e-11

[explorer]
depth = 1

[output]
plots = false
graphml = false
"""


def contfil_process(args: list[str], fault: str = "none", **kw) -> subprocess.Popen:
    """Start ``contfil ARGS`` in a subprocess with ``fault`` injected."""
    env = dict(os.environ, MPLBACKEND="Agg")
    env.pop("CONTFIL_DEBUG", None)
    return subprocess.Popen([sys.executable, "-c", WRAPPER, fault, "--", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


def contfil_module_process(args: list[str]) -> subprocess.Popen:
    """``python -m contfil ARGS`` as a user starts it (signal tests)."""
    env = dict(os.environ, MPLBACKEND="Agg")
    env.pop("CONTFIL_DEBUG", None)
    return subprocess.Popen([sys.executable, "-m", "contfil", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
