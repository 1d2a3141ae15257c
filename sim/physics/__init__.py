"""MuJoCo quadrotors that fly the swarm's functions (model, controller, one robot's physics
and health, the robot link a daemon drives) and the pictures of a run (plots, rendering).

Needs the `sim` extra (`pip install 'swarmd[sim]'`): MuJoCo, matplotlib, imageio."""
