"""The package's version, its one home.

pyproject.toml reads it from here without importing the package (setuptools
evaluates the assignment statically), and it equals the repository's VERSION
file, which tests/server/python_client_test.py checks.
"""
__version__ = "0.2.0"
