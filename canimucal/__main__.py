"""`python -m canimucal` runs the same entry point as the `canimucal` script."""

from canimucal.cli.entry import run

run()
