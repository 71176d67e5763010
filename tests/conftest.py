"""Fixtures shared by every test directory: simulated nodes and clients on a virtual bus."""

pytest_plugins = ["tests.support.canbus", "tests.support.nodes", "tests.support.user_dirs"]
