"""``python -m contfil`` runs the command line (see :mod:`contfil.app.cli`)."""

import sys

from contfil.app.cli import main

sys.exit(main())
