"""Ray RLlib training of the shared policy (``swarm-phd train --engine rllib``, see
``docs/scaling.md``): ``env`` (SwarmEnv as an RLlib multi-agent env: kernel threads per worker,
the ``render()`` fix), ``train`` (the engine), ``engine`` (``--engine sb3|rllib`` dispatch),
``policy`` (a trained module as a policy callable), ``bench`` (sampling throughput, N runners)."""
