"""Package list for setuptools (everything else is in pyproject.toml).

Every ``jerklab`` package is found, as subpackages come and go; the folders a student opens
(``notebooks/``, ``data/``, ``app/``) are added as packages ``jerklab._share.*``, mapped by
``[tool.setuptools.package-dir]`` in pyproject.toml, so the wheel carries them without moving them.
"""

from setuptools import find_packages, setup

SHARED = ("notebooks", "data", "app")

setup(
    packages=find_packages(include=["jerklab", "jerklab.*"])
    + [f"jerklab._share.{n}" for n in SHARED]
)
