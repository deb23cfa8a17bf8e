"""Fixtures for tests/viz."""

import pytest
from viz_scan import make_scan


@pytest.fixture
def scan():
    """(cloud, result): the hand-built 20 x 30 scan of viz_scan.make_scan."""
    return make_scan()
