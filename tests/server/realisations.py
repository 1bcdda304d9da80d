"""Realisations of chaotic rollouts for tests whose claim is about an average, not one run.

A splashing pour amplifies float rounding: the same physics summed in another order parts
within a second, and a tracker's IOU gain or a catcher's share on one short pour moves by
0.05–0.2 between such runs (``bench/perturbed.py``; README, "Chaos in the tests"). These
tests average over ``SKINS``: the neighbour-list skin of every model made inside
:func:`realisation`, which changes the rounding and nothing else.
"""

from __future__ import annotations

import contextlib

from liquidtwin.sim import pbf

#: Neighbour skins, in units of h: three realisations (0 is the default).
SKINS = (0.0, 0.1, 0.2)


@contextlib.contextmanager
def realisation(skin: float):
    """Models created inside use neighbour lists with this skin (units of h)."""
    old = pbf.DEFAULT_SKIN
    pbf.DEFAULT_SKIN = skin
    try:
        yield
    finally:
        pbf.DEFAULT_SKIN = old
