"""``python -m hec``: the hec command line."""

import sys

from hec.cli import main

sys.exit(main())
