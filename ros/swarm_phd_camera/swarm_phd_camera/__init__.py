"""The swarm-phd robots' camera node (ROS 2): fisheye frames in, red-strip bearings out."""
