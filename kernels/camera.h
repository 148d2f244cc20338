/* Cameras: the primary ray of a film position. Twin of volmc/reference/camera.py, which
 * describes the projections, the thin lens and the panoramic convention. */
#ifndef VOLMC_CAMERA_H
#define VOLMC_CAMERA_H

#include "params.h" /* Params, CAMERA_*, PI, TWO_PI (volmc/constants.py) */
#include "lanes.h"
#include "sampling.h"
#include "medium.h" /* vec3 */

/* Direction (x right, y up, z forward) of film fraction (fx, fy) of the equirectangular image. */
static inline lvec3 panoramic_direction(lfloat fx, lfloat fy) {
    lfloat phi = TWO_PI * (fx - 0.5f);
    lfloat lat = PI * (0.5f - fy);
    lfloat cl, sl = sincos(lat, &cl);
    lfloat cp, sp = sincos(phi, &cp);
    return v3(cl * sp, sl, cl * cp);
}

/* Film fraction (fx, fy) that panoramic_direction maps to w. */
static inline lvec2 invert_panoramic_direction(lvec3 w) {
    lfloat phi = atan2(w.x, w.z);
    lfloat lat = atan2(w.y, sqrt(w.x * w.x + w.z * w.z));
    lvec2 f = {phi / TWO_PI + 0.5f, 0.5f - lat / PI};
    return f;
}

/* Returns the origin and writes the unit direction. Which projection, and whether a lens,
 * is one value for every lane (the Params), so the branches are uniform. */
static inline lvec3 camera_ray(const Params *prm, lint px, lint py, lfloat u1, lfloat u2,
                               lfloat v1, lfloat v2, lvec3 *dir) {
    lvec3 f = v3u(vec3(prm->forward)), r = v3u(vec3(prm->right)), u = v3u(vec3(prm->up));
    lvec3 e = v3u(vec3(prm->eye));
    if (prm->cam_type == CAMERA_PANORAMIC) {
        lvec3 w = panoramic_direction((to_lfloat(px) + u1) / (float)prm->width,
                                      (to_lfloat(py) + u2) / (float)prm->height);
        *dir = madd3(madd3(scale3(r, w.x), u, w.y), f, w.z);
        return e;
    }
    lfloat sx = (2.0f * (to_lfloat(px) + u1) / (float)prm->width - 1.0f) * prm->half_height *
                prm->aspect;
    lfloat sy = (1.0f - 2.0f * (to_lfloat(py) + u2) / (float)prm->height) * prm->half_height;
    lvec3 o, v;
    if (prm->cam_type == CAMERA_ORTHOGRAPHIC) {
        o = madd3(madd3(e, r, sx), u, sy);
        v = f;
        if (!(prm->aperture > 0.0f)) {
            *dir = f;
            return o;
        }
    } else {
        /* From the plane at near along f, where the pinhole ray from the camera meets it
         * (camera.py). */
        lfloat near = (lfloat)(prm->near);
        o = madd3(madd3(e, r, sx * near), u, sy * near);
        v = madd3(madd3(f, r, sx), u, sy);
        if (!(prm->aperture > 0.0f)) {
            *dir = scale3(v, rsqrt(dot3(v, v)));
            return o;
        }
    }
    /* The plane in focus meets the pinhole ray at o + F v; aim from the lens point there
     * without forming absolute positions (camera.py). */
    lfloat pdf;
    lvec2 l = sample_uniform_disc(v1, v2, &pdf);
    lvec3 q = madd3(scale3(r, l.x), u, l.y);
    lvec3 a = madd3(v, q, (lfloat)(-prm->lens_slope));
    a = scale3(a, 1.0f / fmax(fabs(a.x), fmax(fabs(a.y), fabs(a.z)))); /* no overflow below */
    *dir = scale3(a, rsqrt(dot3(a, a)));
    return madd3(o, q, (lfloat)(prm->aperture - prm->near * prm->lens_slope));
}

#endif
