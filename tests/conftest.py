"""Fixtures shared by the test modules."""

import pytest

import torchcal


@pytest.fixture(scope="module")
def kr():
    """The KR 1000 Titan preset (a fresh Robot per test module)."""
    return torchcal.robot("kr1000titan")
