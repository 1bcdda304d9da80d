"""``python -m liquidtwin_viewer`` is the ``liquidtwin-viewer`` command."""

import sys

from .cli import main

sys.exit(main())
