"""The package version (kept apart so that any module can name it without a cycle)."""

__version__ = "0.1.0"
