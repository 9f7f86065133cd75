"""Which packages the distribution holds; everything else is in pyproject.toml.

The examples stay in the repository's top-level ``examples/`` (the README and the guide
name them so, and the tests read them there); a wheel carries the same files as the
package data ``instrument._examples``, which ``scatterlab examples copy DIR`` writes out
where no source tree is at hand. A folder mapped onto a package name needs ``package_dir``,
which pyproject's ``packages.find`` cannot combine with, hence this file (ADR 0094).
"""

from setuptools import find_packages, setup

setup(
    packages=[
        *find_packages(include=["instrument*", "drivers*", "analysis*", "gui*", "hw_mocks*"]),
        "instrument._examples",
    ],
    package_dir={"instrument._examples": "examples"},
)
