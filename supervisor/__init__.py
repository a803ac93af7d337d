"""uavbar-supervisor: the flight service in rooms (see docs/architecture.md)."""
