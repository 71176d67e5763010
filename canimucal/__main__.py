"""`python -m canimucal` runs the same entry point as the `canimucal` script."""

import sys

from canimucal.cli.main import main

sys.exit(main())
