"""``python -m acquisition.cli`` runs the ``gonio`` command."""

import sys

from acquisition.cli import main

sys.exit(main())
