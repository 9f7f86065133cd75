"""``python -m instrument.cli`` runs the ``scatterlab`` command line."""

import sys

from instrument.cli import main

sys.exit(main())
