"""MAVLink 2: sans-IO codec and session, one UDP transport, the asyncio link to a PX4."""
