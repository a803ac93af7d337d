"""Who may connect to the flight process and what each connection may ask, over a real
listening Unix socket (supervisor/ipc/server.py, supervisor/ipc/channel.py)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from supervisor.cli.direct import DirectPathError, direct_request
from supervisor.flight.operator_requests import ModeRequest, Outcome, Reply, Request
from supervisor.ipc.channel import Channel, ChannelServer
from supervisor.ipc.messages import HelloMessage, ReplyMessage, RequestMessage
from supervisor.ipc.rendezvous import listen_unix, write_discovery
from supervisor.ipc.server import Admission, admit, refusal, serve_requests

TOKEN = "the-token"


def test_only_the_operator_role_connects_without_the_token() -> None:
    assert admit(HelloMessage(role="operator"), TOKEN) == Admission("operator", False)
    assert admit(HelloMessage(role="commands", token=TOKEN), TOKEN) == Admission("commands", True)
    for role in ("commands", "urgent"):
        refused = admit(HelloMessage(role=role, token="wrong"), TOKEN)
        assert refused == f"the {role} connection needs the API token"
    first = RequestMessage(id=1, request=ModeRequest(kind="abort"))
    assert admit(first, TOKEN) == "a connection must begin with a hello, not a request"


def test_the_direct_path_aborts_kills_with_the_token_and_nothing_else() -> None:
    anonymous, trusted = Admission("operator", False), Admission("operator", True)
    assert refusal(anonymous, ModeRequest(kind="abort")) is None
    assert refusal(anonymous, ModeRequest(kind="kill")) == "kill needs the API token"
    assert refusal(trusted, ModeRequest(kind="kill")) is None
    for kind in ("arm", "takeoff", "land", "disarm"):
        assert refusal(trusted, ModeRequest(kind=kind)) is not None
    assert refusal(Admission("commands", True), ModeRequest(kind="arm")) is None


async def _serve_one(channel: Channel, asked: list[Request]) -> None:
    hello = await channel.receive()
    admission = admit(hello, TOKEN)
    if isinstance(admission, str):
        channel.send(ReplyMessage(id=0, reply=Reply(outcome=Outcome.REFUSED, reason=admission)))
        return

    async def handle(request: Request) -> Reply:
        refused = refusal(admission, request)
        if refused is not None:
            return Reply(outcome=Outcome.REFUSED, reason=refused)
        asked.append(request)
        return Reply(outcome=Outcome.OK, data={"mode": "abort"})

    try:
        await serve_requests(channel, handle)
    except ConnectionError:
        return


@pytest.fixture
def runtime_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    return tmp_path


async def test_the_terminal_clients_direct_abort_speaks_the_channels_framing(
    runtime_dir: Path,
) -> None:
    """``direct_request`` (standard library only) against a ChannelServer answering with
    the flight process's admission rules: abort without the token, kill only with it, and
    no service on the port is an error that says so."""
    socket_path = runtime_dir / "flight.sock"
    listener = listen_unix(socket_path)
    asked: list[Request] = []
    server = ChannelServer()
    await server.start(listener, Channel, lambda channel: _serve_one(channel, asked))
    write_discovery(8765, {"url": "http://127.0.0.1:8765", "operator_socket": str(socket_path)})
    try:
        url = "http://127.0.0.1:8765"
        reply, took_s = await asyncio.to_thread(direct_request, url, None, "abort")
        assert reply["outcome"] == "ok" and reply["data"] == {"mode": "abort"} and took_s > 0
        reply, _ = await asyncio.to_thread(direct_request, url, None, "kill")
        assert reply == {"outcome": "refused", "reason": "kill needs the API token", "data": {}}
        reply, _ = await asyncio.to_thread(direct_request, url, TOKEN, "kill")
        assert reply["outcome"] == "ok"
        assert [r.kind for r in asked] == ["abort", "kill"]
        with pytest.raises(DirectPathError, match="no service on port 8766"):
            await asyncio.to_thread(direct_request, "http://127.0.0.1:8766", None, "abort")
    finally:
        await server.close()
        listener.close()
