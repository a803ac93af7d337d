"""The flight process: deadline scheduler, phase lock, CPU set-up, the shared tick driver."""
