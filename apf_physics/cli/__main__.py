"""``python -m apf_physics.cli``: the ``apf-physics`` command, where no script is installed."""

import sys

from apf_physics.cli import main

sys.exit(main())
