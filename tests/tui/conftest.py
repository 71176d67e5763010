"""The TUI reads the user's configuration: its tests run with directories of their own."""

import pytest

from tests.support.user_dirs import UserDirs


@pytest.fixture(autouse=True)
def _own_user_dirs(own_user_dirs: UserDirs) -> UserDirs:
    return own_user_dirs
