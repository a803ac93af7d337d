"""Vehicle value types, the VehicleLink protocol, sequences over both (arm, kill, parameters)."""
