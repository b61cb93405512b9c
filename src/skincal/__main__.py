"""``python -m skincal``: the same as the ``skincal`` console script."""

import sys

from skincal.cli import main

sys.exit(main())
