"""The OpenAPI document against the answers, by schemathesis (every check, with and
without the token), against ``serve`` on the embedded simulator (a test on the wall clock;
the API beyond loopback is checked in process, beside the suite:
test_openapi_contract_beyond_loopback.py)."""

from __future__ import annotations

import asyncio
import os
import sys
from pathlib import Path

import pytest

from benchmarks.service import running_service

pytest.importorskip("schemathesis")
pytestmark = pytest.mark.slow

SERVE_TOKEN = "contract-token-0123"
ROOT = Path(__file__).resolve().parents[2]


async def schemathesis(
    url: str,
    token: str | None,
    workdir: Path,
    examples_with_token: int = 20,
    phases: str = "examples,coverage,fuzzing,stateful",
) -> tuple[int, str]:
    """``schemathesis run`` over ``url``'s /openapi.json with every check, in ``phases``;
    its exit status and output."""
    arguments = ["-m", "schemathesis.cli", "run", f"{url}/openapi.json", "--checks", "all"]
    # Without the token the gate answers before any body is read: a few examples of each
    # operation say it, and boundaries or sequences of bodies would say nothing more.
    arguments += ["--phases", phases if token is not None else "examples,fuzzing"]
    examples = str(examples_with_token) if token is not None else "5"
    arguments += ["--max-examples", examples, "--seed", "18", "--no-color"]
    arguments += ["--request-timeout", "10"]
    if token is not None:
        arguments += ["-H", f"Authorization: Bearer {token}"]
    hooks = {"SCHEMATHESIS_HOOKS": "tests.api.schemathesis_hooks", "PYTHONPATH": str(ROOT)}
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        *arguments,
        env={**os.environ, **hooks},
        cwd=workdir,  # its example database stays in the test's folder
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
    )
    output, _ = await process.communicate()
    assert process.returncode is not None
    return process.returncode, output.decode(errors="replace")


def assert_no_failure(status: int, output: str) -> None:
    assert status == 0 and "FAILURES" not in output, output[-6000:]
    assert "server error" not in output.lower(), output[-6000:]


async def test_schemathesis_finds_nothing_against_serve(tmp_path: Path) -> None:
    async with running_service(SERVE_TOKEN, tmp_path) as service:
        for token in (SERVE_TOKEN, None):
            assert_no_failure(*await schemathesis(service.url, token, tmp_path))
