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
def free_flight(med, o, d, t0, t1, use_control, rng, counters, max_steps):
    """Next real collision along o + t d over [t0, t1]: (EVENT_SCATTER, t), (EVENT_ESCAPE,
    t1), or (EVENT_CAPPED, t) when the step cap ended the walk (counted)."""
    event, t, _ = track(med, o, d, t0, t1, TRACK_FREE_FLIGHT, use_control, rng, counters,
                        max_steps)
    return event, t
