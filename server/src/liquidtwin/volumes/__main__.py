"""``python -m liquidtwin.volumes REC.mcap …``: the estimator measured on a recording
(see :mod:`liquidtwin.volumes.estimator`)."""

from .estimator import main

main()
