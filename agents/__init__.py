"""Controllers for the swarm: scripted policies (``agents.scripted``), policies by name
(``agents.policies``), scoring and comparing them on held-out seeds (``agents.evaluation``),
and training (``agents.sb3``: SB3 PPO and the recurrent student; ``agents.rllib``: RLlib)."""
