"""Sealing the live Foxglove view's messages, so that only who holds the API token reads them.

foxglove-sdk's WebSocket server (0.30) cannot tell one client from another: nothing at its
handshake (no header, subprotocol or callback) can refuse a client, and every subscribed
client gets every message. Its loopback port is therefore open to any program on this
computer, and to any web page its browser shows. So the flight process seals each message's
payload before the SDK sends it, with keys derived from the API token, and the API process's
gateway (api/foxglove_gateway.py), which holds the token, opens each one on its way to an
admitted client. A client on the SDK's server directly gets the channel list (the topics and
schemas of docs/flight-logs.md, public) and ciphertext, never a state.

The construction is an AEAD of a well-kept library (pyca/cryptography), nothing of ours:

- key: HKDF-SHA256 of the token (``info`` names this use); the token is
  ``secrets.token_urlsafe(18)`` (144 bits) unless the operator sets one.
- ChaCha20-Poly1305 (RFC 8439): the payload encrypted and authenticated, so the gateway
  passes on nothing it cannot open (a key that does not match: the view of another
  ``serve``).
- nonce (12 bytes): a stream id of 4 random bytes drawn per view (a restarted flight process
  draws anew) and a 64-bit counter, so that no nonce is used twice with the key.

A sealed payload is ``nonce (12 bytes) ‖ ciphertext and tag (as long as the payload + 16)``.
"""

from __future__ import annotations

from dataclasses import dataclass

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

STREAM_ID_BYTES = 4
NONCE_BYTES = STREAM_ID_BYTES + 8
TAG_BYTES = 16
SEAL_OVERHEAD_BYTES = NONCE_BYTES + TAG_BYTES
KEY_INFO = b"uavbar-supervisor live Foxglove view"


@dataclass(frozen=True, repr=False)
class ViewKeys:
    """The view's AEAD key (32 bytes); ``repr`` does not show it."""

    key: bytes


def view_keys(token: str) -> ViewKeys:
    """The key both processes derive from the API token (``serve`` hands it to both)."""
    kdf = HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=KEY_INFO)
    return ViewKeys(kdf.derive(token.encode()))


class Sealer:
    """Seals one view's payloads; ``stream_id`` (4 bytes) must be drawn at random for each
    view, as the counter starts again with it."""

    def __init__(self, keys: ViewKeys, stream_id: bytes) -> None:
        if len(stream_id) != STREAM_ID_BYTES:
            raise ValueError(f"a stream id has {STREAM_ID_BYTES} bytes, not {len(stream_id)}")
        self._aead = ChaCha20Poly1305(keys.key)
        self._stream_id = stream_id
        self._count = 0

    def seal(self, payload: bytes) -> bytes:
        """``payload`` sealed: ``SEAL_OVERHEAD_BYTES`` longer."""
        self._count += 1
        nonce = self._stream_id + self._count.to_bytes(8, "little")
        return nonce + self._aead.encrypt(nonce, payload, None)


def unseal(keys: ViewKeys, sealed: bytes) -> bytes | None:
    """The payload of ``sealed``; None when it was not sealed with ``keys`` (or altered)."""
    if len(sealed) < SEAL_OVERHEAD_BYTES:
        return None
    nonce, body = sealed[:NONCE_BYTES], sealed[NONCE_BYTES:]
    try:
        return ChaCha20Poly1305(keys.key).decrypt(nonce, body, None)
    except InvalidTag:
        return None
