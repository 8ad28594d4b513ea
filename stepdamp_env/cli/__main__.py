"""``python -m stepdamp_env.cli``: the ``stepdamp`` command."""

import sys

from . import main

sys.exit(main())
