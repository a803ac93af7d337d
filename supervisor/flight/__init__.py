"""The pure tick core: modes, phases, safety, setpoints, estimation, the core, telemetry view."""
