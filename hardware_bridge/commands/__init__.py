"""``swarm-phd`` subcommands of the hardware bridge: ``bridge``, ``replay``, ``export-bag``."""
