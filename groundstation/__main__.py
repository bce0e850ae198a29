"""``python -m groundstation``: the same command line as the ``groundstation`` script."""

import sys

from groundstation.app.cli import main

sys.exit(main())
