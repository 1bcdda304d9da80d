"""Builds the optional C++/OpenMP extension ``liquidtwin._native`` at install time.

Install with ``pip install --no-build-isolation -e server`` so the extension compiles
against the torch already installed (a build-isolated install would fetch another torch).
Without a compiler, or when the build fails, the package still installs and runs on the
pure-torch reference path (``native_build.py``: flags per machine, the opt-outs).
"""

import os
import sys

from setuptools import setup

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import native_build  # noqa: E402

ext_modules, cmdclass = [], {}
if not native_build.skipped():
    try:
        from torch.utils.cpp_extension import BuildExtension, CppExtension

        ext_modules = [
            CppExtension(
                "liquidtwin._native",
                ["csrc/pbf_native.cpp"],
                extra_compile_args=native_build.compile_args(),
                extra_link_args=["-fopenmp"],
            )
        ]
        cmdclass = {"build_ext": native_build.optional_build(BuildExtension.with_options(use_ninja=True))}
    except ImportError:  # torch not importable at build time: pure-torch path only
        if native_build.required():
            raise
        print("liquidtwin: torch is not importable at build time; building without the C++ extension", flush=True)

setup(ext_modules=ext_modules, cmdclass=cmdclass)
