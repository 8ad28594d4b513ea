"""``python -m stepdamp_env.cli``: the ``stepdamp`` command."""

from . import run

run()
