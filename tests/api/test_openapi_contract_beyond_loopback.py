"""The OpenAPI document against the answers of an API that listens beyond loopback (reads
need the token), by schemathesis: the in-process API, so not a test on the wall clock."""

from __future__ import annotations

from pathlib import Path

import pytest

from api.guard import HttpPolicy
from tests.api.conftest import TOKEN, serve_api
from tests.api.test_openapi_contract import assert_no_failure, schemathesis

pytest.importorskip("schemathesis")
pytestmark = pytest.mark.slow


async def test_schemathesis_finds_nothing_beyond_loopback(tmp_path: Path) -> None:
    async with serve_api(HttpPolicy(TOKEN, reads_need_token=True)) as api:
        for token in (TOKEN, None):
            # What differs from loopback is the gate on reads: the bodies' boundaries and
            # sequences are the serve test's (test_openapi_contract.py); a few examples of
            # every operation suffice here.
            answer = await schemathesis(api.url, token, tmp_path, 5, "examples,fuzzing")
            assert_no_failure(*answer)
