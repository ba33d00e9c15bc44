"""``python -m qz_drake.cli``: the ``qz`` command."""

import sys

from qz_drake.cli import main

sys.exit(main())
