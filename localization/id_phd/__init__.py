"""ID-PHD: a robot-centric GM-PHD whose components carry teammate identities.

Stegagno et al. (ICRA 2013) let a supervisor that sees *anonymous* positions of
its teammates recover *who is who* from the odometry each teammate broadcasts with its ID.
Here the observer is a ground robot of the swarm: it sees anonymous lidar detections in its own
body frame (as :class:`~localization.RobotCentricPHD` does) and receives, by radio, every
teammate's own odometry increment with its ID.

Each component has a **tag** (``-1`` not yet associated, ``i >= 0`` robot ``i``, ``-2`` static
false positive, whose odometry is null) and a Gaussian over the teammate's pose
``(x, y, psi)`` in the observer frame (3x3 covariance).

Time update (Stegagno 2013 eqs. 14-19, derived from total probability in Stegagno 2012, 13.2).
The teammate moves by its own increment ``u_i = (d_i, dpsi_i)`` (expressed in its frame at the
start of the interval); the observer moves by ``u_0 = (d_0, dpsi_0)`` (in its frame). In the
old observer frame the teammate ends at ``p + R(psi) d_i`` with heading ``psi + dpsi_i``; the new
observer frame has origin ``d_0`` and is turned by ``+dpsi_0``, so::

    p'   = R(dpsi_0)^T (p + R(psi) d_i - d_0)
    psi' = psi + dpsi_i - dpsi_0

(Stegagno 2013 eq. 18). The covariance is ``F P F^T + J_i C_i J_i^T + J_0 C_0 J_0^T`` (eq. 19)
with the Jacobians of that map (:func:`compose_relative`). A static object (tag ``-2``) has
``u_i = 0``.

Untagged components (births) are split into one copy per *candidate* robot (every robot
whose odometry has been received, except those already "recovered": tag weight >=
``recovered_weight``, Stegagno 2012 13.2) plus one copy for the static class, the weight divided
equally (eq. 15). Since a single position says nothing about the teammate's heading, each
robot copy is further split into ``birth_heading_hypotheses`` evenly spaced headings (sharing
that robot's share of the weight). Every copy is tagged from then on.

Measurement update: GM-PHD on the ``(x, y)`` part (eqs. 20-21). The weights, the position
posterior and the likelihoods come from :func:`localization.phd.lidar_update`; the heading row
follows from the same gain: with ``H = [I 0]``, ``S = P_xy + R``,
``psi+ = psi + P_psi,xy S^-1 (z - m)``, and ``S^-1 (z - m) = (z - m+) / r``.

Reduction: prune, Vo & Ma greedy merge **within each tag** (3-D Mahalanobis distance with the
candidate's covariance, wrapped heading difference; clusters from
:func:`localization.reducer.greedy_clusters`), cap.

Estimate: per ID, the mean of its highest-weight component.

Modules, along the roles of the GM-PHD's: :mod:`.config` (``IDPHDConfig``, tags), :mod:`.motion`
(time update), :mod:`.update` (measurement update), :mod:`.reducer` (prune / merge per tag) and
:mod:`.filter` (``IDPHD``, the orchestrator).
"""

from __future__ import annotations

from .aerial import AerialIDPHD, CameraModel
from .config import STATIC, UNTAGGED, IDPHDConfig
from .filter import IDPHD
from .motion import compose_relative, split_untagged
from .reducer import reduce_tagged
from .update import lidar_update_3d

__all__ = [
    "UNTAGGED",
    "STATIC",
    "IDPHDConfig",
    "IDPHD",
    "compose_relative",
    "split_untagged",
    "lidar_update_3d",
    "reduce_tagged",
    "AerialIDPHD",
    "CameraModel",
]
