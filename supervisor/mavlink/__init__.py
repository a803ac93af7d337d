"""MAVLink 2: sans-IO codec, PX4 events, session, parameters; UDP transport; the asyncio link."""
