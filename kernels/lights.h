/* Lights other than the environment: what each sends to a point, how next-event estimation
 * samples a sun disc or a sphere, and where a ray meets a sphere light. Twin of
 * volmc/reference/lights.py, which states the conventions of the light record (one light is
 * the same for every lane; points and directions are per lane). NO_LIMIT stands for the
 * reference's math.inf. */
#ifndef VOLMC_LIGHTS_H
#define VOLMC_LIGHTS_H

#include "params.h"
#include "lanes.h"
#include "guards.h"
#include "sampling.h"

static inline float3 vec3g(global const float v[3]) { return (float3)(v[0], v[1], v[2]); }

static inline int is_area_light(global const Light *lt) {
    return lt->type == LIGHT_SPHERE || (lt->type == LIGHT_DIRECTIONAL && lt->size > 0.0f);
}

static inline float sun_radiance(global const Light *lt) {
    float omc = lt->size;
    return 1.0f / (PI * omc * (2.0f - omc));
}

static inline lfloat spot_falloff(global const Light *lt, lvec3 wl) {
    lfloat cos_t = -dot3(wl, v3u(vec3g(lt->axis)));
    lfloat x = (cos_t - lt->size) / (lt->inner - lt->size); /* not read at blend 0 */
    lfloat s = select(x * x * (3.0f - 2.0f * x), (lfloat)(1.0f), cos_t >= lt->inner);
    return select(s, (lfloat)(0.0f), cos_t <= lt->size);
}

static inline lfloat sphere_hit(global const Light *lt, lvec3 o, lvec3 d) {
    lvec3 v = sub3(o, v3u(vec3g(lt->vec)));
    float r = lt->size;
    lfloat b = dot3(v, d);
    lvec3 f = sub3(v, scale3(d, b));
    lfloat disc = r * r - dot3(f, f);
    lfloat sq = sqrt(fmax(disc, 0.0f));
    lfloat cc = dot3(v, v) - r * r;
    lfloat t_in = sq - b; /* inside: the far root */
    lfloat t = select(select(t_in, (lfloat)(NO_LIMIT), !(t_in > 0.0f)),
                      select(cc / (sq - b), (lfloat)(NO_LIMIT), b >= 0.0f), cc > 0.0f);
    return select(t, (lfloat)(NO_LIMIT), disc < 0.0f);
}

/* Returns the unit direction from p to sphere lt's centre; writes 1 - cos theta_max of its
 * cone and whether p is not outside it (then the rest is meaningless). */
static inline lvec3 sphere_cone(global const Light *lt, lvec3 p, lfloat *omc, lmask *inside) {
    lvec3 v = sub3(v3u(vec3g(lt->vec)), p);
    lfloat dc2 = dot3(v, v);
    float r2 = lt->size * lt->size;
    *inside = !(dc2 > r2);
    lfloat dc = sqrt(dc2);
    lfloat s2 = r2 / dc2;
    *omc = select(s2 / (1.0f + sqrt(1.0f - s2)), (lfloat)(2.0f), *inside);
    return sel3(div3(v, dc), v3(0.0f, 0.0f, 1.0f), *inside);
}

/* Returns a direction from p towards sphere lt; writes the distance to the sphere along it
 * and its density per steradian (0: no sample). */
static inline lvec3 sample_sphere_light(global const Light *lt, lvec3 p, lfloat u1, lfloat u2,
                                        lfloat *dist, lfloat *pdf) {
    lfloat omc;
    lmask inside;
    lvec3 axis = sphere_cone(lt, p, &omc, &inside);
    float r = lt->size;
    lvec3 w = sample_cone(u1, u2, axis, omc, pdf);
    lvec3 v = sub3(v3u(vec3g(lt->vec)), p);
    lfloat dc2 = dot3(v, v);
    lfloat x = u1 * omc;
    *dist = sqrt(dc2) * (1.0f - x) - sqrt(fmax(0.0f, r * r - dc2 * x * (2.0f - x)));
    if (ANY(inside)) { /* a point uniform on the surface */
        lfloat pa;
        lvec3 n = sample_uniform_sphere(u1, u2, &pa);
        lvec3 q = sub3(add3(v3u(vec3g(lt->vec)), scale3(n, r)), p);
        lfloat di = sqrt(dot3(q, q));
        lvec3 wi = div3(q, di);
        lfloat c = fabs(dot3(n, wi));
        lfloat pi = select((lfloat)(0.0f), di * di * INV_4PI / (r * r * c),
                           (di > 0.0f) & (c > 0.0f));
        w = sel3(w, sel3(v3(0.0f, 0.0f, 1.0f), wi, di > 0.0f), inside);
        *dist = select(*dist, select((lfloat)(0.0f), di, di > 0.0f), inside);
        *pdf = select(*pdf, pi, inside);
    }
    return w;
}

static inline lfloat sphere_light_pdf(global const Light *lt, lvec3 p, lvec3 w, lfloat t) {
    lfloat omc;
    lmask inside;
    lvec3 axis = sphere_cone(lt, p, &omc, &inside);
    float r = lt->size;
    lvec3 x = sub3(madd3(p, w, t), v3u(vec3g(lt->vec)));
    lfloat c = fabs(dot3(x, w)) / r;
    lfloat pi = select((lfloat)(0.0f), t * t * INV_4PI / (r * r * c), c > 0.0f);
    return select(cone_pdf(w, axis, omc), pi, inside);
}

/* Returns a direction from p towards area light lt; writes the distance (NO_LIMIT for a
 * sun), the density per steradian (0: no sample) and the radiance per unit of lt->color. */
static inline lvec3 sample_area_light(global const Light *lt, lvec3 p, lfloat u1, lfloat u2,
                                      lfloat *dist, lfloat *pdf, lfloat *radiance) {
    if (lt->type == LIGHT_DIRECTIONAL) {
        *dist = (lfloat)(NO_LIMIT);
        *radiance = (lfloat)(sun_radiance(lt));
        return sample_cone(u1, u2, v3u(-vec3g(lt->vec)), (lfloat)(lt->size), pdf);
    }
    *radiance = (lfloat)(1.0f);
    return sample_sphere_light(lt, p, u1, u2, dist, pdf);
}

/* Returns the distance to the first sphere light the ray o + t d meets (NO_LIMIT: none);
 * writes its index (-1: none). */
static inline lfloat nearest_sphere(const Params *prm, global const Light *lights, lvec3 o,
                                    lvec3 d, lint *index) {
    lfloat t_best = (lfloat)(NO_LIMIT);
    *index = (lint)(-1);
    for (int i = 0; i < prm->n_lights; ++i) {
        if (lights[i].type != LIGHT_SPHERE) continue;
        lfloat t = sphere_hit(&lights[i], o, d);
        lmask closer = t < t_best;
        t_best = select(t_best, t, closer);
        *index = select(*index, (lint)(i), closer);
    }
    return t_best;
}

#endif
