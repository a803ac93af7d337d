"""Vehicle value types, the VehicleLink protocol, arm/disarm/kill sequences over both."""
