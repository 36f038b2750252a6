"""``python -m compass``: the same as the ``compass`` console script."""

import sys

from .cli import main

sys.exit(main())
