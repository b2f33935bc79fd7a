"""`torchcal.threads`: the heap policy (`heap_policy`) set on glibc, left alone where the user set MALLOC_*."""

import ctypes
import os
import sys

import pytest

from torchcal import threads


def _glibc() -> bool:
    try:
        ctypes.CDLL(None).gnu_get_libc_version
    except (OSError, AttributeError):
        return False
    return sys.platform.startswith("linux")


def test_environment_wins(monkeypatch):
    monkeypatch.setenv("MALLOC_ARENA_MAX", "2")
    assert threads.heap_policy() is False


@pytest.mark.skipif(not _glibc(), reason="glibc only")
def test_set_on_glibc(monkeypatch):
    for k in [k for k in os.environ if k.startswith("MALLOC_")]:
        monkeypatch.delenv(k)
    assert threads.heap_policy() is True
