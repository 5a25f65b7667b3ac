"""stable-baselines3 training and deployment: ``train`` (the ``swarm-phd train`` command),
``adapter`` and ``batched`` (SwarmEnv -> VecEnv, parameter sharing), ``policy`` (trained models
as policies), ``recurrent_student`` / ``recurrent_ppo`` (the recurrent residual student, its
DAgger distillation and PPO fine-tuning; data and networks in ``sequences``)."""
