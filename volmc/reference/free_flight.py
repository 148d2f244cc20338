"""Free-flight sampling: where a path's next real collision is. Twin of kernels/free_flight.h.

Written on the one tracking loop (tracking.py): delta tracking over the medium's majorant
segments, or decomposition tracking (Kutz et al. 2017) with each segment's minorant as the
control; a homogeneous medium or segment is sampled exactly (its first tentative collision
is real), so a homogeneous medium gets the analytic t = -ln(1 - u) / sigma_t.
"""

from numba import njit

from ..constants import TRACK_FREE_FLIGHT
from .tracking import track


@njit(cache=True)
def free_flight(med, o, d, t0, t1, use_control, beta, hero, emis, rng, counters, max_steps):
    """Next real collision along o + t d over [t0, t1], for a path of throughput ``beta``
    (RGB; with a ``hero`` channel >= 0: the path's decision-probability ratios, see
    tracking.track). Returns (event, t, w, E): (EVENT_SCATTER, t), (EVENT_ESCAPE, t1) or (EVENT_CAPPED,
    t) when the step cap ended the walk (counted); w the flight's weight (RGB: spectral
    tracking's, (1, 1, 1) for grey media), by which the caller multiplies beta; E the
    emission gathered on the way (RGB, per unit beta), weighed by ``emis``
    (tracking.emission_weight)."""
    return track(med, o, d, t0, t1, TRACK_FREE_FLIGHT, use_control, beta, hero, emis, rng,
                 counters, max_steps)
