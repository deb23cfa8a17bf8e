import doctest

import pytest

from rangeseg_o3d.fitting import cylinder, plane, sphere


@pytest.mark.parametrize("module", [plane, sphere, cylinder])
def test_docstring_examples_run(module):
    result = doctest.testmod(module)
    assert result.attempted > 0 and result.failed == 0
