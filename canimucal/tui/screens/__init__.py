"""The TUI's screens, one module each; the app owns the flow between them (docs/design.md §1).

A screen imports neither the app nor another screen (import-linter contracts in
``pyproject.toml`` cover every module of this package, so a new screen is guarded too).
"""
