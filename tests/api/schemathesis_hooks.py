"""Hooks for the schemathesis runs (named by ``SCHEMATHESIS_HOOKS``)."""

from __future__ import annotations

from typing import Any

import schemathesis

# A request's ?wait_s= answers once its outcome is known, up to 600 s: each example would
# wait that long. The waits themselves are test_api's; here they stay short.
LONGEST_WAIT_S = 0.2


@schemathesis.hook
def map_query(context: Any, query: dict[str, Any] | None) -> dict[str, Any] | None:
    wait_s = query.get("wait_s") if query else None
    if query and isinstance(wait_s, int | float) and not isinstance(wait_s, bool):
        query["wait_s"] = min(wait_s, LONGEST_WAIT_S)
    return query
