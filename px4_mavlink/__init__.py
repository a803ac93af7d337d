"""MAVLink as PX4 speaks it, below the supervisor and the simulator (the same bytes on both
ends): the sans-IO codec, PX4's event messages and catalog, signing; the UDP transport."""
