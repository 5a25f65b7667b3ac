"""Simulated sensor models of the Cherokey UGV, each with its noise, rate and failure modes.

- :mod:`~swarm_env.sensors.odometry`: wheel encoders (pulse quantisation, slip) to
  ``[dx, dy, dpsi]`` increments.
- :mod:`~swarm_env.sensors.lidar`: the YDLidar X4 scan (beams, noise, blind sectors from the
  camera pillars, inter-lidar interference).
- :mod:`~swarm_env.sensors.camera`: the two fisheye cameras' red-blob bearings (range-limited
  detection, occlusion, red decoys as false positives).
- :mod:`~swarm_env.sensors.noise`: seeded noise tables; :mod:`~swarm_env.sensors.kernels`: the
  compiled casting kernels.
- :mod:`~swarm_env.sensors.scene`: the geometry snapshot the models cast against (the world
  builds it from its bodies; :mod:`~swarm_env.sensors.scene_builder` builds one without
  physics), and :mod:`~swarm_env.sensors.spatial_index`, the grid that keeps big swarms' cost
  per robot flat.

What runs on real robots too (lidar feature extraction, null bearings) lives in
:mod:`swarm_core.perception`.
"""
