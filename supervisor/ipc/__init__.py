"""API ⇄ flight process: typed messages, the framed channel, its client and server."""
