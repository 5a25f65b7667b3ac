"""The simulated World: pymunk physics of the UGVs in a walled arena with obstacles.

- :mod:`~swarm_env.world.sim`: :class:`SimWorld`, the simulator's implementation of the
  :class:`swarm_core.world.World` contract (commands in, stamped records and ground truth out).
- :mod:`~swarm_env.world.arena`: arena bounds, walls and the seeded obstacle layout.
- :mod:`~swarm_env.world.diagnostics`: per-sensor detection statistics against the truth.

The world builds a :class:`~swarm_env.sensors.scene.Scene` of its bodies each step and hands it
to the sensor models; the sensors never import the world.
"""
