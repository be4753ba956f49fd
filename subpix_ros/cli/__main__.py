"""``python -m subpix_ros.cli``: the ``subpix`` command."""

from subpix_ros.cli import console

console()
