"""``python -m rangeseg_o3d.cli``: the ``rangeseg`` command."""

import sys

from . import main

sys.exit(main())
