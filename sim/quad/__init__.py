"""MuJoCo quadrotors that fly the swarm's functions (issue 4): model, controller,
functions, one robot's physics and health, and the robot link a daemon drives."""
