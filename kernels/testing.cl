/* Test kernels: thin wrappers that feed explicit inputs to the kernel functions so tests can
 * compare them with their Numba twins value by value (tests/test_kernels.py). */

#include "params.h"
#include "rng.h"
#include "sampling.h"
#include "phase.h"
#include "grid.h"
#include "medium.h"
#include "tracking.h"
#include "dda.h"
#include "sampler.h"

kernel void t_philox(global const uint *ctr, global const uint *key, global uint *out) {
    int i = get_global_id(0);
    uint4 w = philox4x32_10(vload4(i, ctr), vload2(i, key));
    vstore4(w, i, out);
}

kernel void t_uniforms(ulong seed, uint pixel, uint sample, uint stream, uint n,
                       global float *out) {
    Rng rng;
    rng_init(&rng, seed, pixel, sample, stream);
    for (uint i = 0; i < n; ++i) out[i] = rng_next(&rng);
}

kernel void t_exponential(global const float *u, float a, global float *out) {
    int i = get_global_id(0);
    float pdf;
    float t = sample_exponential(u[i], a, &pdf);
    out[2 * i] = t;
    out[2 * i + 1] = pdf;
}

kernel void t_uniform_sphere(global const float *u, global float *out) {
    int i = get_global_id(0);
    float pdf;
    float3 w = sample_uniform_sphere(u[2 * i], u[2 * i + 1], &pdf);
    vstore4((float4)(w, pdf), i, out);
}

kernel void t_hg_sample(global const float *u, global const float *g, float3 d_in,
                        global float *out) {
    int i = get_global_id(0);
    float pdf;
    float3 w = hg_sample(u[2 * i], u[2 * i + 1], d_in, g[i], &pdf);
    vstore4((float4)(w, pdf), i, out);
}

kernel void t_hg_sample_cos(global const float *u, global const float *g, global float *out) {
    int i = get_global_id(0);
    float s, pdf;
    float c = hg_sample_cos(u[i], g[i], &s, &pdf);
    out[3 * i] = c;
    out[3 * i + 1] = s;
    out[3 * i + 2] = pdf;
}

kernel void t_hg_eval(global const float *mu, global const float *g, global float *out) {
    int i = get_global_id(0);
    out[i] = hg_eval(mu[i], g[i]);
}

kernel void t_coordinate_system(global const float *n, global float *out) {
    int i = get_global_id(0);
    float3 s, t;
    coordinate_system(vload3(i, n), &s, &t);
    vstore3(s, 2 * i, out);
    vstore3(t, 2 * i + 1, out);
}

/* Inverse samplers: out[i] = (u1, u2) for direction i (uniform sphere; HG about d_in with g[i]),
 * and u for the exponential distance t[i] at rate a. */
kernel void t_invert_uniform_sphere(global const float *w, global float *out) {
    int i = get_global_id(0);
    vstore2(invert_uniform_sphere(vload3(i, w)), i, out);
}

kernel void t_invert_hg_sample(global const float *w, float3 d_in, global const float *g,
                               global float *out) {
    int i = get_global_id(0);
    vstore2(invert_hg_sample(vload3(i, w), d_in, g[i]), i, out);
}

kernel void t_invert_exponential(global const float *t, float a, global float *out) {
    int i = get_global_id(0);
    out[i] = invert_exponential_sample(t[i], a);
}

kernel void t_equiangular(global const float *u, float h, float D, float ta, float tb,
                          global float *out) {
    int i = get_global_id(0);
    float pdf;
    float t = sample_equiangular(u[i], h, D, ta, tb, &pdf);
    out[3 * i] = t;
    out[3 * i + 1] = pdf;
    out[3 * i + 2] = invert_equiangular_sample(t, h, D, ta, tb);
}

kernel void t_grid_lookup(global const float *grid, int3 dims, float3 bmin, float3 inv_extent,
                          global const float *p, global float *out) {
    int i = get_global_id(0);
    out[i] = grid_lookup(grid, dims, bmin, inv_extent, vload3(i, p));
}

/* The tracking loop with technique TRACK_* (use_control: the minorant as control in free
 * flight). One work item per walk; ray r = i / n_per_ray (9 floats: o, d, t0, t1, pad) goes
 * through media[r] and uses sample index i % n_per_ray. Writes the distance (-1 on escape,
 * -2 if capped), the transmittance estimate and the lookups of each walk. */
kernel void t_track(int technique, int use_control, global const Medium *media,
                    global const float *grid, global const float *maj, global const float *mnr,
                    global const float *rays, int n_per_ray, ulong seed, int max_steps,
                    global float *out_t, global float *out_T, global ulong *lookups) {
    int i = get_global_id(0);
    int r = i / n_per_ray;
    Medium m = media[r];
    MediumData med = {m, grid, maj, mnr, grid, grid, 0, grid, 0, 0};
    float3 o = vload3(3 * r, rays), d = vload3(3 * r + 1, rays);
    float t0 = rays[9 * r + 6], t1 = rays[9 * r + 7];
    Rng rng;
    rng_init(&rng, seed, (uint)r, (uint)(i % n_per_ray), STREAM_TEST);
    ulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = 0;
    float t;
    spec T;
    float3 E;
    int ev = track(&med, o, d, t0, t1, technique, use_control, (float3)(1.0f), -1, &rng, cnt,
                   max_steps, &t, &T, &E);
    out_t[i] = ev == EVENT_SCATTER ? t : (ev == EVENT_CAPPED ? -2.0f : -1.0f);
    vstore3(spec_rgb(T), i, out_T);
    lookups[i] = cnt[C_LOOKUPS];
}

/* DDA walks of rays (9 floats each, as t_track) into out[r][k] = (ta, tb, iz, iy, ix). */
kernel void t_dda(global const float *rays, float3 bmin, float3 bmax, int3 res_zyx,
                  int max_segments, global float *out, global int *count) {
    int r = get_global_id(0);
    float3 o = vload3(3 * r, rays), d = vload3(3 * r + 1, rays);
    Dda s;
    dda_init(&s, o, d, rays[9 * r + 6], rays[9 * r + 7], bmin, bmax, res_zyx);
    float ta, tb;
    int3 cell;
    int k = 0;
    while (k < max_segments && dda_next(&s, &ta, &tb, &cell)) {
        global float *row = out + ((size_t)r * max_segments + k) * 5;
        row[0] = ta;
        row[1] = tb;
        row[2] = (float)cell.z;
        row[3] = (float)cell.y;
        row[4] = (float)cell.x;
        ++k;
    }
    count[r] = k;
}

/* Octree walks of rays (9 floats each, as t_track) into out[r][k] = (ta, tb, node). */
kernel void t_octree(global const float *rays, float3 bmin, float3 bmax,
                     global const int *children, int depth, int max_segments,
                     global float *out, global int *count) {
    int r = get_global_id(0), node, k = 0;
    OctreeWalk s;
    octree_init(&s, vload3(3 * r, rays), vload3(3 * r + 1, rays), rays[9 * r + 6],
                rays[9 * r + 7], bmin, bmax, depth);
    float ta, tb;
    while (k < max_segments && octree_next(&s, children, bmin, bmax, depth, &ta, &tb, &node))
        vstore3((float3)(ta, tb, (float)node), (size_t)r * max_segments + k++, out);
    count[r] = k;
}

kernel void t_sparse_lookup(global const int *table, global const float *pool, int3 dims,
                            float3 bmin, float3 inv_extent, global const float *p,
                            global float *out) {
    int i = get_global_id(0);
    out[i] = sparse_lookup(table, pool, dims, bmin, inv_extent, vload3(i, p));
}

/* The sampler's parts on in[i] = (a, b, c, d): out[i] = (sobol_u32(a, 0), sobol_u32(a, 1),
 * owen_scramble(a, b), hash_u32(a, b), permute_index(a % (c % 4096 + 1), c % 4096 + 1, b),
 * sobol_pair(a, b, c, d), stratified_pair(a, c, b, d, a ^ b)). */
kernel void t_sampler_parts(global const uint *in, global uint *out) {
    int i = get_global_id(0);
    uint4 v = vload4(i, in);
    uint np = v.z % 4096u + 1u;
    global uint *o = out + (size_t)i * 9;
    o[0] = sobol_u32(v.x, 0);
    o[1] = sobol_u32(v.x, 1);
    o[2] = owen_scramble(v.x, v.y);
    o[3] = hash_u32(v.x, v.y);
    o[4] = permute_index(v.x % np, np, v.y);
    vstore2(sobol_pair(v.x, v.y, v.z, v.w), 0, o + 5);
    vstore2(stratified_pair(v.x, v.z, v.y, v.w, v.x ^ v.y), 0, o + 7);
}

/* sampler_pair on rows of 7 words (kind, key0, key1, pixel, index, pair, n): out[i] = (ux, uy). */
kernel void t_sampler_pairs(global const uint *in, global uint *out) {
    int i = get_global_id(0);
    global const uint *a = in + (size_t)i * 7;
    vstore2(sampler_pair((int)a[0], a[1], a[2], a[3], a[4], a[5], a[6]), i, out);
}
