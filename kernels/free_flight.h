/* Free-flight sampling on the tracking loop. Twin of volmc/reference/free_flight.py. */
#ifndef VOLMC_FREE_FLIGHT_H
#define VOLMC_FREE_FLIGHT_H

#include "tracking.h"

/* Returns EVENT_SCATTER, EVENT_ESCAPE or EVENT_CAPPED; writes the distance (t1 on escape). */
inline int free_flight(const MediumData *med, float3 o, float3 d, float t0, float t1,
                       int use_control, Rng *rng, ulong *counters, int max_steps, float *t_out) {
    float T;
    return track(med, o, d, t0, t1, TRACK_FREE_FLIGHT, use_control, rng, counters, max_steps,
                 t_out, &T);
}

#endif
