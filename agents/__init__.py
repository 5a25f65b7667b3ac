"""Controllers for the swarm: scripted policies (``agents.scripted``) and SB3 training."""
