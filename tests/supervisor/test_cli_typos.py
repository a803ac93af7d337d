"""A mistyped command or option: a usage error (exit 2) that names the nearest one."""

from __future__ import annotations

import pytest

from supervisor.cli.main import main


@pytest.mark.parametrize(
    ("argv", "meant"),
    [
        (["stauts"], "'status'"),
        (["status", "--jsn"], "'--json'"),
        (["simulate", "--scenario", "paper", "--controler", "decentralized"], "'--controller'"),
    ],
)
def test_a_typo_is_answered_with_the_nearest_name(
    argv: list[str], meant: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 2
    assert f"did you mean {meant}?" in capsys.readouterr().err


def test_nothing_near_is_not_guessed(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["xyzzy"]) == 2
    assert "did you mean" not in capsys.readouterr().err
