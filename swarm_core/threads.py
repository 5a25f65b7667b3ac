"""Threads of the compiled kernels: never spin, and one thread per env in worker processes.

The sensor and filter kernels run robots in parallel with numba's ``prange`` on the GNU OpenMP
layer (the one that loads from the pip wheel and is thread-safe for the bridge's loopback; see
``docs/concepts/architecture.md``). GNU OpenMP's default wait policy lets idle workers *spin*
for a while after each parallel region. An env step runs hundreds of short regions, so with
another process on the cores (a training job, a second env) the spinning threads steal the time
slices the working thread needs: measured, ``seed-sim`` fell from 28x to 2.1x real time beside
a training job, and ran at 26x with ``OMP_WAIT_POLICY=PASSIVE``. PASSIVE (idle workers sleep at
once) is therefore the default here, set before numba loads libgomp; a user who exports
``OMP_WAIT_POLICY`` keeps their own choice.

Worker processes that each run an env (vectorised training, Ray, evaluation sweeps) should use
one kernel thread each: :func:`set_kernel_threads` ``(1)``; the cores are then shared between
processes, not oversubscribed inside each one.
"""

from __future__ import annotations

import os

#: The value set when the user has not chosen one (see the module docstring).
DEFAULT_WAIT_POLICY = "PASSIVE"

# Must run before libgomp initialises (at numba's first parallel launch); importing this module
# is enough, and swarm_core/__init__ imports it, so every package of the project sets it.
if "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = DEFAULT_WAIT_POLICY


def set_kernel_threads(n: int | None) -> int:
    """Use ``n`` threads in the compiled kernels launched from the calling thread (numba's
    setting is per thread; call it in each worker's main thread). ``None``: all of the pool.

    Returns the number now in use. Raises ``ValueError`` naming ``n`` when it is not an int in
    ``[1, NUMBA_NUM_THREADS]``.
    """
    import numba

    limit = numba.config.NUMBA_NUM_THREADS
    if n is None:
        n = limit
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= limit:
        raise ValueError(f"kernel threads must be an int in [1, {limit}], got {n!r}")
    numba.set_num_threads(n)
    return n
