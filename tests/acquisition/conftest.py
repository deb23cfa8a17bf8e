"""Fixtures for the acquisition tests: a scripted transport (the package's) and a flat-wall stand-in scene."""

import pytest

from acquisition_helpers import wall_ranges

from rangeseg_o3d.acquisition.testing import ScriptedTransport

@pytest.fixture
def scripted():
    made = []

    def make(script, **kw):
        t = ScriptedTransport(script, **kw)
        made.append(t)
        return t

    yield make
    for t in made:
        t.verify()


@pytest.fixture
def wall():
    return wall_ranges
