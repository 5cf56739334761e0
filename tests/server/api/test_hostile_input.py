"""The hostile requests' client under the name test_storage_faults.py imports it by; the hostile
input tests are in hostile_input/, their client in tests.support.hostile_requests."""

from __future__ import annotations

from tests.support.hostile_requests import AUTH, TOKEN, connect, make_home

__all__ = ["AUTH", "TOKEN", "connect", "make_home"]
