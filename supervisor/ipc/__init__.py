"""API ⇄ flight and world processes: typed messages, framed channels, clients, servers."""
