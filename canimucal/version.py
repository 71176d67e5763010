"""The package version: the one place it is written.

setuptools reads it for the distribution's metadata (``pyproject.toml``: ``dynamic``), and
any module can name it without an import cycle.
"""

__version__ = "0.1.0"
