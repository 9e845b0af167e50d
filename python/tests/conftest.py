"""Fixtures of the Python client's tests. ctest sets HSCLOC_BINARY, HSCLOC_CLIENT_BINARY and
HSCLOC_TRAINED_SMALL_CITY; run by hand without them, the tests that need a server skip and say
why, and with them set to something missing, they fail."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import pytest
from harness import City, Tools, serve


def _required_path(variable: str) -> Path:
    value = os.environ.get(variable)
    if not value:
        pytest.skip(f"{variable} is not set: run these tests through ctest")
    path = Path(value)
    if not path.exists():
        pytest.fail(f"{variable}={path} does not exist")
    return path


@pytest.fixture(scope="session")
def tools() -> Tools:
    return Tools(_required_path("HSCLOC_BINARY"), _required_path("HSCLOC_CLIENT_BINARY"))


@pytest.fixture(scope="session")
def city() -> City:
    city = City(_required_path("HSCLOC_TRAINED_SMALL_CITY"))
    if not (city.map / "manifest.json").is_file():
        pytest.fail(f"{city.map} holds no trained map: ctest's fixture.trained_small_city makes it")
    return city


@pytest.fixture(scope="session")
def server(tools: Tools, city: City, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The endpoint of a server of the trained small city, shared by the session's tests."""
    with serve(tools, city.map, tmp_path_factory.mktemp("serve") / "serve.log") as endpoint:
        yield endpoint
