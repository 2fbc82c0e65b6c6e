"""``python -m maptidal.cli``: the same as the ``maptidal`` command."""

import sys

from maptidal.cli import main

sys.exit(main())
