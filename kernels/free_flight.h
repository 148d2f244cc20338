/* Free-flight sampling on the tracking loop. Twin of volmc/reference/free_flight.py. */
#ifndef VOLMC_FREE_FLIGHT_H
#define VOLMC_FREE_FLIGHT_H

#include "tracking.h"

/* Returns EVENT_SCATTER, EVENT_ESCAPE or EVENT_CAPPED per lane; writes the distance (t1 on
 * escape), the flight's weight w (spectral tracking; 1 when grey) and the emission gathered
 * per unit beta. The caller adds beta * E and multiplies beta by w; with a hero channel
 * (>= 0) beta is the path's decision-probability ratios and w their update (see
 * tracking.py). */
static inline lint free_flight(const MediumData *med, lvec3 o, lvec3 d, lfloat t0, lfloat t1,
                               int use_control, lvec3 beta, lint hero, EmisMis emis, Rng *rng,
                               lulong *counters, int max_steps, lmask active, lfloat *t_out,
                               spec *w_out, lvec3 *E_out) {
    return track(med, o, d, t0, t1, TRACK_FREE_FLIGHT, use_control, beta, hero, emis, rng, counters,
                 max_steps, active, t_out, w_out, E_out);
}

#endif
