"""Robot links: the paper's black-box wire between swarmd and the robot (Fig. 4)."""
