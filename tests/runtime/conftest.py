"""Sessions read the user's configuration (mounting maps): these tests have their own."""

import pytest

from tests.support.user_dirs import UserDirs


@pytest.fixture(autouse=True)
def _own_user_dirs(own_user_dirs: UserDirs) -> UserDirs:
    return own_user_dirs
