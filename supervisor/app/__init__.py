"""The composition root: typed config, assembly from it, serve, process entry points."""
