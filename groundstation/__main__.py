"""``python -m groundstation``: the same command line as the ``groundstation`` script."""

import sys

from groundstation.app.main import main

sys.exit(main())
