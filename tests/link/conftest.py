from __future__ import annotations

from typing import Any

import pytest

from merlin.link.dialect import mavlink_module


@pytest.fixture(scope="session")
def M() -> Any:
    return mavlink_module()
