"""``python -m contfil`` runs the command line (see :mod:`contfil.cli`)."""

import sys

from contfil.cli import main

sys.exit(main())
