"""``python -m pipeline.cli``: the psrig command line."""

import sys

from . import main

sys.exit(main())
