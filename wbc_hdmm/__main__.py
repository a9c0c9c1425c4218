"""``python -m wbc_hdmm``: the ``wbc`` command."""

import sys

from wbc_hdmm.cli import main

sys.exit(main())
