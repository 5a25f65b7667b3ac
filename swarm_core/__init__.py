"""swarm_core: the contract every part of swarm-phd shares, and nothing else.

- :mod:`swarm_core.records`: the stamped measurement records a World hands to the localizers
  (odometry, lidar scans with their detections, camera bearings), robot body frame (REP-103).
- :mod:`swarm_core.world`: the World protocol (simulator, real robots, bag replay), a step's
  output (``WorldStep``) and ground truth.
- :mod:`swarm_core.aerial`: the UAV's contract: its camera frames, a step's UAV messages and
  their assembly into odometry increments and frames.
- :mod:`swarm_core.geometry`: angles and planar frames; :mod:`swarm_core.stamps`: message time
  stamps.
- :mod:`swarm_core.validation`: argument checks whose errors name the field and the value;
  :mod:`swarm_core.inputs`: the command line's (seeds, JSON objects, durations, output paths).
- :mod:`swarm_core.progress`: progress bars of the long commands;
  :mod:`swarm_core.atomic_files`: result files never half-written.
- :mod:`swarm_core.signal_chain`: the signal an exception chain was raised from (a signal's
  exception wrapped in a ``SystemError`` by a compiled kernel's callback).
- :mod:`swarm_core.threads`: the compiled kernels' threading defaults (set on import).
- :mod:`swarm_core.kernel_stamp`: the kernels' on-disk cache, invalidated when any kernel
  source of the project changes (installed on import).

It imports no simulator, filter, ROS or RL code, so the simulator (``swarm_env``), the
localizers (``localization``) and the bridge (``hardware_bridge``) all build on it without
importing each other.
"""

from swarm_core import threads as _threads  # noqa: F401  (OpenMP wait policy, before numba)

# isort: split
from swarm_core import kernel_stamp as _kernel_stamp  # after threads: it imports numba

_kernel_stamp.install()  # before any package's @njit(cache=True) picks its cache locator
