"""``python -m skincal.cli``: the same as the ``skincal`` console script."""

import sys

from skincal.cli import main

sys.exit(main())
