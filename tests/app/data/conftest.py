"""Fixtures of the data-management tests: real server and node processes (see
:mod:`tests.integration.conftest`)."""

from tests.integration.conftest import make_rig  # noqa: F401  (fixture)
