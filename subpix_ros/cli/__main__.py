import sys

from subpix_ros.cli import main

sys.exit(main())
