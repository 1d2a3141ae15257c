"""swarmd: failure handling for robot swarms (paper: "Handling Failures In A Swarm")."""

__version__ = "0.1.0"
