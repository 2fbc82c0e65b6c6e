"""Action convention, ArduSub's mixer and the feedback controllers (the MAVLink bridge comes with
issue [controllers]).

Imports nothing else of maptidal's, so a field engineer can install it alone and run the same code
against the simulator and a real ArduSub vehicle:

- ``convention``: the normalised 6-DOF pilot command;
- ``mixing``: ArduSub's AP_Motors6DOF mixer and the physical allocation matrix;
- ``pid``: one axis of PID with derivative on the measurement, anti-windup and limits;
- ``estimation``: attitude, depth and dead-reckoned position from IMU, depth sensor, DVL and compass;
- ``trajectory``: trapezoidal speed profiles and straight-line pose trajectories;
- ``pose``: depth hold, heading hold and 4-DOF go-to-pose / station keeping, gains by pole placement
  on the Fossen parameters;
- ``task``: fly to an inspection pose, hold it for a dwell, then capture (or time out);
- ``flight_modes``: ArduSub's MANUAL, STABILIZE, ALT_HOLD and POSHOLD on the estimated state.
"""
