"""Device interfaces and drivers (actuators, force sensors, depth stages)."""
