"""``python -m touchloc``: the ``touchloc`` command."""

from .cli import run

run()
