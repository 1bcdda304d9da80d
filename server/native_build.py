"""How ``server/setup.py`` builds the optional C++/OpenMP extension ``liquidtwin._native``.

Kept apart from setup.py so the tests can check it without running a build.

- Flags per machine: x86-64 builds for ``x86-64-v2`` (SSE4.2, any x86 CPU since 2009;
  ``x86-64-v3`` (AVX2) with ``-ffp-contract=off`` ran a full-size pour 2 % faster, bit for bit
  the same: not worth leaving older machines behind). Other machines (aarch64: Jetson,
  Graviton, Raspberry Pi; ppc64le …) get the compiler's default target: an
  ``-march=x86-64-v2`` there is a compile error.
- A failed build does not fail the install: the package runs on the pure-torch reference path
  (the same physics, equal step by step to rounding, but ~23x slower: the first 150 steps of a
  full-size pour took 72.7 s against 3.2 s on one thread, ``bench/pour_rollout.py --steps 150
  [--backend torch]``), and the build prints why. ``LIQUIDTWIN_REQUIRE_NATIVE=1`` makes
  a failed build an error (``make venv`` sets it, so CI and developers never test the
  fallback by accident); ``LIQUIDTWIN_NO_NATIVE=1`` skips the build.
"""

from __future__ import annotations

import os
import platform

X86 = ("x86_64", "amd64")                 # 64-bit x86 only: -march=x86-64-v2 refuses 32-bit targets


def compile_args(machine: str | None = None) -> list[str]:
    """The C++ flags for ``machine`` (``platform.machine()`` by default)."""
    machine = (platform.machine() if machine is None else machine).lower()
    args = ["-O3", "-fopenmp", "-DAT_PARALLEL_OPENMP=1"]
    if machine in X86:
        args.insert(2, "-march=x86-64-v2")
    return args


def required(environ=None) -> bool:
    """Whether a failed build must fail the install (``LIQUIDTWIN_REQUIRE_NATIVE=1``)."""
    return (os.environ if environ is None else environ).get("LIQUIDTWIN_REQUIRE_NATIVE") == "1"


def skipped(environ=None) -> bool:
    """Whether to skip the build (``LIQUIDTWIN_NO_NATIVE=1``)."""
    return (os.environ if environ is None else environ).get("LIQUIDTWIN_NO_NATIVE") == "1"


def optional_build(base):
    """A subclass of the build_ext class ``base`` whose failure leaves the package without
    the extension (with a message saying why and what it costs) unless :func:`required`."""

    class OptionalBuild(base):
        def run(self):
            try:
                super().run()
            except Exception as e:  # noqa: BLE001 - compiler, ninja and linker errors all land here
                if required():
                    raise
                print(f"\nliquidtwin: the C++ extension liquidtwin._native did not build ({type(e).__name__}: {e}).\n"
                      "liquidtwin will run on its pure-torch path: the same physics, about 23x slower on a full-size pour.\n"
                      "Install a C++ compiler with OpenMP (Debian: g++) and reinstall, or set "
                      "LIQUIDTWIN_REQUIRE_NATIVE=1 to make this an error.\n", flush=True)

    return OptionalBuild
