"""``python -m volmc.cli``: the ``volmc`` command."""

import sys

from . import main

sys.exit(main())
