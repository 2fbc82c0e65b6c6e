"""Action convention, thruster allocation, feedback controllers and the MAVLink bridge.

Imports nothing of ours, so the same code runs against the simulator and a real
ArduSub vehicle. Empty until the [world] issue lands.
"""
