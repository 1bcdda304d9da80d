"""``python -m liquidtwin_client`` is the ``liquidtwin-client`` command."""

import sys

from .cli import main

sys.exit(main())
