"""``uavbar-supervisor bench --json``: the object the issue names, from a real (short) run."""

from __future__ import annotations

import json

import pytest

from supervisor.cli.main import main


def test_bench_json_has_the_named_keys_and_backends_agree(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["bench", "--json", "--ticks", "60"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["default"] in result["centralized"]
    assert result["hpipm_build"]
    for problem in ("centralized", "decentralized"):
        for backend in ("hpipm", "osqp", "daqp"):
            row = result[problem][backend]
            assert {"p50_ms", "p99_ms", "max_ms", "max_err"} <= set(row)
            assert 0 < row["p50_ms"] <= row["p99_ms"] <= row["max_ms"]
            assert row["max_err"] <= 1e-4, (problem, backend, row["max_err"])


def test_bench_refuses_an_unknown_backend(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--backends", "hpipm,cplex"]) == 2
    assert "cplex" in capsys.readouterr().err
