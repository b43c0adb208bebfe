"""``python -m nmsid`` is the ``nmsid`` command."""

import sys

from nmsid.cli import main

sys.exit(main())
