"""The supervisor's MAVLink (on px4_mavlink): PX4 session, parameters, vision; link, relay."""
