"""One swarm-phd robot's localizer on board (ROS 2)."""
