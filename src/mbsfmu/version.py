"""The package version (pyproject.toml gives the same to pip): a module of its own, below every other, so that
what writes files (the animation page) names it without importing the package API."""

__version__ = "0.1.0"
