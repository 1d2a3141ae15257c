"""The daemon room: one robot's daemon and the base station (DESIGN section 1, "Layout").

The robot's daemon (`daemon`: config in, a running runtime until told to stop) and who
it waits for at start (`waiting`); the base station's passive listener and the takeovers
it believes (`monitor`, `monitor_claims`, `monitor_ros2`); the swarm file's checks
(`check`). It imports every room below it and nothing of the simulators or the commands.
"""
