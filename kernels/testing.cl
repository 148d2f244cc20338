/* Test kernels: thin wrappers that feed explicit inputs to the kernel functions so tests can
 * compare them with their Numba twins value by value (tests/test_kernels.py). Built at every
 * lane width: lane l of work-item i takes element i W + l of the batch (lane_io.h), so each
 * element meets exactly the code a lane of the renderer runs; the last argument of every
 * kernel is the batch size n (tests/cl_harness.py appends it). */

#include "params.h"
#include "lanes.h"
#include "lane_io.h"
#include "rng.h"
#include "sampling.h"
#include "phase.h"
#include "grid.h"
#include "medium.h"
#include "tracking.h"
#include "dda.h"
#include "octree.h"
#include "sampler.h"
#include "camera.h"
#include "environment.h"
#include "lights.h"
#include "emitters.h"

kernel void t_philox(global const uint *ctr, global const uint *key, global uint *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    /* Counters per lane; the key is per element here but one per work-item in the renderer,
     * so each lane's key in turn, keeping that lane's words. */
    luint c0 = load_uint(ctr, i, 4, 0), c1 = load_uint(ctr, i, 4, 1);
    luint c2 = load_uint(ctr, i, 4, 2), c3 = load_uint(ctr, i, 4, 3);
    for (int l = 0; l < LANES; ++l) {
        if (!lane_on(on, l)) continue;
        lmask one = on & (LANE_IOTA == l);
        int e = lane_int(i, l);
        LaneWords w = philox4x32_10(c0, c1, c2, c3, key[2 * e], key[2 * e + 1]);
        store_uint(out, i, 4, 0, w.x, one);
        store_uint(out, i, 4, 1, w.y, one);
        store_uint(out, i, 4, 2, w.z, one);
        store_uint(out, i, 4, 3, w.w, one);
    }
}

/* Lane l draws from stream (seed, pixel + l, sample, stream): out[l][k], k < count. The
 * tests read lane 0 against the reference and every lane against its own stream. */
kernel void t_uniforms(ulong seed, uint pixel, uint sample, uint stream, uint count,
                       global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    Rng rng = rng_empty();
    rng_init(&rng, seed, pixel + as_luint(i), (luint)(sample), stream, on);
    for (uint k = 0; k < count; ++k)
        store_float(out, i, (int)count, (int)k, rng_next(&rng, on), on);
}

/* Ragged draws: plan[l][k] is lane l's step k, 0 nothing, 1 draw from stream A (stream id 0),
 * 2 draw from B (id 1), 3 exchange A and B then draw from A, 4 restart A at sample + 1 then
 * draw from it; out[l][k] is the draw (-1 for none). Lanes that draw at different times take
 * different paths through rng_next_u32 (its prefetch at W > 1), as the render's lanes do. */
kernel void t_uniforms_ragged(ulong seed, uint pixel, uint sample, uint count,
                              global const uint *plan, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    Rng a = rng_empty(), b = rng_empty();
    rng_init(&a, seed, pixel + as_luint(i), (luint)(sample), 0u, on);
    rng_init(&b, seed, pixel + as_luint(i), (luint)(sample), 1u, on);
    for (uint k = 0; k < count; ++k) {
        luint op = load_uint(plan, i, (int)count, (int)k);
        rng_swap(&a, &b, on & (op == 3u));
        rng_init(&a, seed, pixel + as_luint(i), (luint)(sample + 1u), 0u, on & (op == 4u));
        lmask from_a = on & (op == 1u || op == 3u || op == 4u), from_b = on & (op == 2u);
        lfloat u = (lfloat)(-1.0f);
        u = select(u, rng_next(&a, from_a), from_a);
        u = select(u, rng_next(&b, from_b), from_b);
        store_float(out, i, (int)count, (int)k, u, on);
    }
}

kernel void t_exponential(global const float *u, float a, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lfloat pdf;
    lfloat t = sample_exponential(load_float(u, i, 1, 0), (lfloat)(a), &pdf);
    store_float(out, i, 2, 0, t, on);
    store_float(out, i, 2, 1, pdf, on);
}

kernel void t_uniform_sphere(global const float *u, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lfloat pdf;
    lvec3 w = sample_uniform_sphere(load_float(u, i, 2, 0), load_float(u, i, 2, 1), &pdf);
    store_float3(out, i, 4, 0, w, on);
    store_float(out, i, 4, 3, pdf, on);
}

/* out[i] = (x, y, pdf) of the disc point of u[i], then the (u1, u2) invert_uniform_disc
 * gives for p[i] (the reference's points, so each direction is checked on its own), then
 * uniform_disc_pdf(). */
kernel void t_uniform_disc(global const float *u, global const float *p, global float *out,
                           int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lfloat pdf;
    lvec2 q = sample_uniform_disc(load_float(u, i, 2, 0), load_float(u, i, 2, 1), &pdf);
    lvec2 pt = {load_float(p, i, 2, 0), load_float(p, i, 2, 1)};
    lvec2 back = invert_uniform_disc(pt);
    store_float(out, i, 6, 0, q.x, on);
    store_float(out, i, 6, 1, q.y, on);
    store_float(out, i, 6, 2, pdf, on);
    store_float(out, i, 6, 3, back.x, on);
    store_float(out, i, 6, 4, back.y, on);
    store_float(out, i, 6, 5, (lfloat)(uniform_disc_pdf()), on);
}

/* out[i] = (direction of film fraction f[i], film fraction of direction w[i]). */
kernel void t_panoramic(global const float *f, global const float *w, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lvec3 d = panoramic_direction(load_float(f, i, 2, 0), load_float(f, i, 2, 1));
    lvec2 back = invert_panoramic_direction(load_float3(w, i, 3, 0));
    store_float3(out, i, 5, 0, d, on);
    store_float(out, i, 5, 3, back.x, on);
    store_float(out, i, 5, 4, back.y, on);
}

/* The primary ray of in[i] = (px, py, u1, u2, v1, v2): out[i] = (origin, direction). */
kernel void t_camera_ray(const Params prm, global const float *in, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lvec3 d;
    lvec3 o = camera_ray(&prm, to_lint_rtz(load_float(in, i, 6, 0)),
                         to_lint_rtz(load_float(in, i, 6, 1)), load_float(in, i, 6, 2),
                         load_float(in, i, 6, 3), load_float(in, i, 6, 4),
                         load_float(in, i, 6, 5), &d);
    store_float3(out, i, 6, 0, o, on);
    store_float3(out, i, 6, 3, d, on);
}

/* sample_environment of uniforms (u1, u2) = in[2 i ...] to out[8 i ...]: the direction, its
 * pdf, environment_pdf and the radiance there (env_radiance, RGB), and invert_environment of
 * the direction to inv[2 i ...]. */
kernel void t_environment(const Params prm, global const float *env, global const float *in,
                          global float *out, global float *inv, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lfloat pdf;
    lvec3 w = sample_environment(&prm, env, load_float(in, i, 2, 0), load_float(in, i, 2, 1),
                                 &pdf, on);
    store_float3(out, i, 8, 0, w, on);
    store_float(out, i, 8, 3, pdf, on);
    store_float(out, i, 8, 4, environment_pdf(&prm, env, w), on);
    store_float3(out, i, 8, 5, env_radiance(&prm, env, w), on);
    lvec2 u = invert_environment(&prm, env, w);
    store_float(inv, i, 2, 0, u.x, on);
    store_float(inv, i, 2, 1, u.y, on);
}

kernel void t_hg_sample(global const float *u, global const float *g, float3 d_in,
                        global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    /* g is per element here, the medium's (one value) in the renderer: lanes one by one. */
    for (int l = 0; l < LANES; ++l) {
        if (!lane_on(on, l)) continue;
        lmask one = on & (LANE_IOTA == l);
        lfloat pdf;
        lvec3 w = hg_sample(load_float(u, i, 2, 0), load_float(u, i, 2, 1), v3u(d_in),
                            g[lane_int(i, l)], &pdf);
        store_float3(out, i, 5, 0, w, one);
        store_float(out, i, 5, 3, pdf, one);
        store_float(out, i, 5, 4, phase_eval(PHASE_HG, g[lane_int(i, l)], v3u(d_in), w), one);
    }
}

kernel void t_hg_sample_cos(global const float *u, global const float *g, global float *out,
                            int n) {
    lmask on;
    lint i = lane_element(n, &on);
    for (int l = 0; l < LANES; ++l) {
        if (!lane_on(on, l)) continue;
        lmask one = on & (LANE_IOTA == l);
        lfloat s, pdf;
        lfloat c = hg_sample_cos(load_float(u, i, 1, 0), g[lane_int(i, l)], &s, &pdf);
        store_float(out, i, 3, 0, c, one);
        store_float(out, i, 3, 1, s, one);
        store_float(out, i, 3, 2, pdf, one);
    }
}

kernel void t_phase_eval(global const float *d, global const float *w, float g,
                         global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    store_float(out, i, 1, 0,
                phase_eval(PHASE_HG, g, load_float3(d, i, 3, 0), load_float3(w, i, 3, 0)), on);
}

kernel void t_hg_eval(global const float *mu, global const float *g, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    for (int l = 0; l < LANES; ++l) {
        if (!lane_on(on, l)) continue;
        store_float(out, i, 1, 0, hg_eval(load_float(mu, i, 1, 0), g[lane_int(i, l)]),
                    on & (LANE_IOTA == l));
    }
}

kernel void t_coordinate_system(global const float *nv, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lvec3 s, t;
    coordinate_system(load_float3(nv, i, 3, 0), &s, &t);
    store_float3(out, i, 6, 0, s, on);
    store_float3(out, i, 6, 3, t, on);
}

/* Inverse samplers: out[i] = (u1, u2) for direction i (uniform sphere; HG about d_in with g[i]),
 * and u for the exponential distance t[i] at rate a. */
kernel void t_invert_uniform_sphere(global const float *w, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lvec2 u = invert_uniform_sphere(load_float3(w, i, 3, 0));
    store_float(out, i, 2, 0, u.x, on);
    store_float(out, i, 2, 1, u.y, on);
}

kernel void t_invert_hg_sample(global const float *w, float3 d_in, global const float *g,
                               global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    for (int l = 0; l < LANES; ++l) {
        if (!lane_on(on, l)) continue;
        lmask one = on & (LANE_IOTA == l);
        lvec2 u = invert_hg_sample(load_float3(w, i, 3, 0), v3u(d_in), g[lane_int(i, l)]);
        store_float(out, i, 2, 0, u.x, one);
        store_float(out, i, 2, 1, u.y, one);
    }
}

kernel void t_invert_exponential(global const float *t, float a, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    store_float(out, i, 1, 0, invert_exponential_sample(load_float(t, i, 1, 0), (lfloat)(a)), on);
}

kernel void t_equiangular(global const float *u, float h, float D, float ta, float tb,
                          global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lfloat pdf;
    lfloat t = sample_equiangular(load_float(u, i, 1, 0), (lfloat)(h), (lfloat)(D), (lfloat)(ta),
                                  (lfloat)(tb), &pdf);
    store_float(out, i, 3, 0, t, on);
    store_float(out, i, 3, 1, pdf, on);
    store_float(out, i, 3, 2,
                invert_equiangular_sample(t, (lfloat)(h), (lfloat)(D), (lfloat)(ta), (lfloat)(tb)),
                on);
}

kernel void t_grid_lookup(global const float *grid, int3 dims, float3 bmin, float3 inv_extent,
                          global const float *p, global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    store_float(out, i, 1, 0, grid_lookup(grid, dims, bmin, inv_extent, load_float3(p, i, 3, 0), on),
                on);
}

/* to_medium of point i (p[6 i ...]) and to_medium_dir of direction i (p[6 i + 3 ...]) in
 * media[0], to out in the same layout. */
kernel void t_to_medium(global const Medium *media, global const float *p, global float *out,
                        int n) {
    lmask on;
    lint i = lane_element(n, &on);
    Medium m = media[0];
    store_float3(out, i, 6, 0, to_medium(&m, load_float3(p, i, 6, 0)), on);
    store_float3(out, i, 6, 3, to_medium_dir(&m, load_float3(p, i, 6, 3)), on);
}

/* The tracking loop with technique TRACK_* (use_control: the minorant as control in free
 * flight). Walk j of ray r (ray_lanes: the lanes of a work-item share a ray) goes through
 * media[r] with sample index j; rays are 9 floats (o, d, t0, t1, pad). Writes, at
 * r n_per_ray + j, the distance (-1 on escape, -2 if capped), the transmittance estimate and
 * the lookups of each walk. */
kernel void t_track(int technique, int use_control, global const Medium *media,
                    global const float *grid, global const float *maj, global const float *mnr,
                    global const float *rays, int n_per_ray, ulong seed, int max_steps,
                    global float *out_t, global float *out_T, global ulong *lookups, int n) {
    int r;
    lmask on;
    lint j = ray_lanes(n_per_ray, &r, &on);
    if (!ANY(on)) return;
    MediumData med = {{media[r]}, grid, maj, mnr, grid, grid, 0, grid, 0, 0, 0, (lint)(-1)};
    lvec3 o = v3u(vload3(3 * r, rays)), d = v3u(vload3(3 * r + 1, rays));
    lfloat t0 = (lfloat)(rays[9 * r + 6]), t1 = (lfloat)(rays[9 * r + 7]);
    Rng rng = rng_empty();
    rng_init(&rng, seed, (luint)(r), as_luint(j), STREAM_TEST, on);
    lulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = (lulong)(0);
    lfloat t;
    spec T;
    lvec3 E;
    lint ev = track(&med, o, d, t0, t1, technique, use_control, v3s(1.0f), (lint)(-1),
                    emis_plain(), &rng, cnt, max_steps, on, &t, &T, &E);
    lint idx = r * n_per_ray + j;
    store_float(out_t, idx, 1, 0,
                select(select((lfloat)(-1.0f), (lfloat)(-2.0f), ev == EVENT_CAPPED), t,
                       ev == EVENT_SCATTER),
                on);
    store_float3(out_T, idx, 3, 0, spec_rgb(T), on);
    store_ulong(lookups, idx, 1, 0, cnt[C_LOOKUPS], on);
}

/* DDA walks of rays (9 floats each, as t_track) into out[r][k] = (ta, tb, iz, iy, ix). */
kernel void t_dda(global const float *rays, float3 bmin, float3 bmax, int3 res_zyx,
                  int max_segments, global float *out, global int *count, int n) {
    lmask on;
    lint r = lane_element(n, &on);
    Dda s = {0};
    dda_init(&s, load_float3(rays, r, 9, 0), load_float3(rays, r, 9, 3), load_float(rays, r, 9, 6),
             load_float(rays, r, 9, 7), bmin, bmax, res_zyx, on);
    lfloat ta, tb;
    lint3 cell;
    lint k = (lint)(0);
    lmask go = on;
    for (int step = 0; step < max_segments && ANY(go); ++step) {
        go = dda_next(&s, &ta, &tb, &cell, go, res_zyx);
        lint row = r * max_segments + k;
        store_float(out, row, 5, 0, ta, go);
        store_float(out, row, 5, 1, tb, go);
        store_float(out, row, 5, 2, to_lfloat(cell.z), go);
        store_float(out, row, 5, 3, to_lfloat(cell.y), go);
        store_float(out, row, 5, 4, to_lfloat(cell.x), go);
        k = k + (go & 1);
    }
    store_uint((global uint *)count, r, 1, 0, as_luint(k), on);
}

/* Octree walks of rays (9 floats each, as t_track) into out[r][k] = (ta, tb, node). */
kernel void t_octree(global const float *rays, float3 bmin, float3 bmax,
                     global const int *children, int depth, int max_segments,
                     global float *out, global int *count, int n) {
    lmask on;
    lint r = lane_element(n, &on);
    OctreeWalk s = {0};
    octree_init(&s, load_float3(rays, r, 9, 0), load_float3(rays, r, 9, 3),
                load_float(rays, r, 9, 6), load_float(rays, r, 9, 7), bmin, bmax, depth, on);
    lfloat ta, tb;
    lint node;
    lint k = (lint)(0);
    lmask go = on;
    for (int step = 0; step < max_segments && ANY(go); ++step) {
        go = octree_next(&s, children, bmin, bmax, depth, &ta, &tb, &node, go);
        lint row = r * max_segments + k;
        store_float(out, row, 3, 0, ta, go);
        store_float(out, row, 3, 1, tb, go);
        store_float(out, row, 3, 2, to_lfloat(node), go);
        k = k + (go & 1);
    }
    store_uint((global uint *)count, r, 1, 0, as_luint(k), on);
}

kernel void t_sparse_lookup(global const int *table, global const float *pool, int3 dims,
                            float3 bmin, float3 inv_extent, global const float *p,
                            global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    store_float(out, i, 1, 0,
                sparse_lookup(table, pool, dims, bmin, inv_extent, load_float3(p, i, 3, 0), on),
                on);
}

/* The sampler's parts on in[i] = (a, b, c, d): out[i] = (sobol_u32(a, 0), sobol_u32(a, 1),
 * owen_scramble(a, b), hash_u32(a, b), permute_index(a % (c % 4096 + 1), c % 4096 + 1, b),
 * sobol_pair(a, b, c, d), stratified_pair(a, c, b, d, a ^ b)). permute_index and
 * stratified_pair take the point count as one value for all lanes (the renderer's spp): lanes
 * one by one. */
kernel void t_sampler_parts(global const uint *in, global uint *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    luint a = load_uint(in, i, 4, 0), b = load_uint(in, i, 4, 1);
    luint c = load_uint(in, i, 4, 2), d = load_uint(in, i, 4, 3);
    store_uint(out, i, 9, 0, sobol_u32(a, 0), on);
    store_uint(out, i, 9, 1, sobol_u32(a, 1), on);
    store_uint(out, i, 9, 2, owen_scramble(a, b), on);
    store_uint(out, i, 9, 3, hash_u32(a, b), on);
    LanePair sp = sobol_pair(a, b, c, d);
    store_uint(out, i, 9, 5, sp.x, on);
    store_uint(out, i, 9, 6, sp.y, on);
    for (int l = 0; l < LANES; ++l) {
        if (!lane_on(on, l)) continue;
        lmask one = on & (LANE_IOTA == l);
        uint np = lane_uint(c, l) % 4096u + 1u;
        store_uint(out, i, 9, 4, permute_index(a % np, np, b), one);
        LanePair st = stratified_pair(a, lane_uint(c, l), b, d, a ^ b);
        store_uint(out, i, 9, 7, st.x, one);
        store_uint(out, i, 9, 8, st.y, one);
    }
}

/* sampler_pair on rows of 7 words (kind, key0, key1, pixel, index, pair, n): out[i] = (ux, uy).
 * The kind, key and n are the renderer's (one value for all lanes): lanes one by one. */
kernel void t_sampler_pairs(global const uint *in, global uint *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    for (int l = 0; l < LANES; ++l) {
        if (!lane_on(on, l)) continue;
        lmask one = on & (LANE_IOTA == l);
        global const uint *w = in + (size_t)lane_int(i, l) * 7;
        LanePair p = sampler_pair((int)w[0], w[1], w[2], load_uint(in, i, 7, 3),
                                  load_uint(in, i, 7, 4), load_uint(in, i, 7, 5), w[6]);
        store_uint(out, i, 2, 0, p.x, one);
        store_uint(out, i, 2, 1, p.y, one);
    }
}

/* sample_cone of in[2 i ...] about axis: out[6 i ...] = w, pdf, cone_pdf(w); inv[2 i ...] =
 * invert_cone(w). */
kernel void t_cone(global const float *in, float3 axis, float omc, global float *out,
                   global float *inv, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lfloat pdf;
    lvec3 w = sample_cone(load_float(in, i, 2, 0), load_float(in, i, 2, 1), v3u(axis),
                          (lfloat)(omc), &pdf);
    store_float3(out, i, 6, 0, w, on);
    store_float(out, i, 6, 3, pdf, on);
    store_float(out, i, 6, 4, cone_pdf(w, v3u(axis), (lfloat)(omc)), on);
    lvec2 u = invert_cone(w, v3u(axis), (lfloat)(omc));
    store_float(inv, i, 2, 0, u.x, on);
    store_float(inv, i, 2, 1, u.y, on);
}

/* Light li from point p with uniforms u and direction w (in[8 i ...] = p, u, w): out[12 i
 * ...] = sample_area_light's direction, distance, pdf and radiance (an area light), then
 * sphere_hit and sphere_light_pdf along w (a sphere), spot_falloff of w (a spot). */
kernel void t_lights(global const Light *lights, int li, global const float *in,
                     global float *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    global const Light *lt = &lights[li];
    lvec3 p = load_float3(in, i, 8, 0), w = load_float3(in, i, 8, 5);
    if (is_area_light(lt)) {
        lfloat dist, pdf, le;
        lvec3 ws = sample_area_light(lt, p, load_float(in, i, 8, 3), load_float(in, i, 8, 4),
                                     &dist, &pdf, &le);
        store_float3(out, i, 12, 0, ws, on);
        store_float(out, i, 12, 3, dist, on);
        store_float(out, i, 12, 4, pdf, on);
        store_float(out, i, 12, 5, le, on);
    }
    if (lt->type == LIGHT_SPHERE) {
        lfloat t = sphere_hit(lt, p, w);
        store_float(out, i, 12, 6, t, on);
        store_float(out, i, 12, 7, sphere_light_pdf(lt, p, w, t), on);
    }
    if (lt->type == LIGHT_SPOT) store_float(out, i, 12, 8, spot_falloff(lt, w), on);
}

/* Medium 0's majorant at points p (3 floats each) and emission sampling's density there,
 * and sample_emitter of uniforms u (5 floats each): out holds 6 floats an element
 * (majorant_at, emitter_pdf, the sampled point, its pdf). maj (an octree's: per node),
 * nodes and the table (blackbody rows, then the emitter's cells) are medium 0's. */
kernel void t_emitters(global const Medium *media, global const float *maj,
                       global const int *nodes, global const float *table,
                       global const float *p, global const float *u, global float *out,
                       int n) {
    lmask on;
    lint i = lane_element(n, &on);
    MediumData med = {{media[0]}, maj, maj, maj, maj, table, 0, maj, nodes, 0, 0, (lint)(-1)};
    lvec3 x = load_float3(p, i, 3, 0);
    store_float(out, i, 6, 0, majorant_at(&med, x, on), on);
    store_float(out, i, 6, 1, emitter_pdf(&med, x, on), on);
    lfloat pdf;
    lvec3 y = sample_emitter(&med, load_float(u, i, 5, 0), load_float(u, i, 5, 1),
                             load_float(u, i, 5, 2), load_float(u, i, 5, 3),
                             load_float(u, i, 5, 4), &pdf, on);
    store_float3(out, i, 6, 2, y, on);
    store_float(out, i, 6, 5, pdf, on);
}
