"""Builds the optional C++/OpenMP extension ``liquidtwin._native`` at install time.

Install with ``pip install --no-build-isolation -e server`` so the extension compiles
against the torch already installed (a build-isolated install would fetch another torch).
Without a compiler the package still installs and runs on the pure-torch reference path.
"""

import os

from setuptools import setup

ext_modules, cmdclass = [], {}
if os.environ.get("LIQUIDTWIN_NO_NATIVE") != "1":
    try:
        from torch.utils.cpp_extension import BuildExtension, CppExtension

        ext_modules = [
            CppExtension(
                "liquidtwin._native",
                ["csrc/pbf_native.cpp"],
                extra_compile_args=["-O3", "-fopenmp", "-march=x86-64-v2", "-DAT_PARALLEL_OPENMP=1"],
                extra_link_args=["-fopenmp"],
            )
        ]
        cmdclass = {"build_ext": BuildExtension.with_options(use_ninja=True)}
    except ImportError:  # torch not importable at build time: pure-torch path only
        pass

setup(ext_modules=ext_modules, cmdclass=cmdclass)
