"""``python -m subpix_ros.cli``: the ``subpix`` command."""

import sys

from subpix_ros.cli import main

sys.exit(main())
