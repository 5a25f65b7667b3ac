"""stable-baselines3 training and deployment: ``train`` (the ``swarm-phd train`` command),
``adapter`` (SwarmEnv -> VecEnv, parameter sharing), ``policy`` (trained models as policies)."""
