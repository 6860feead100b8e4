/*
 * tc_grid: the grid NIF of ThinkingCap's navigation layer
 * (ThinkingCap.Navigation.Core.GridNif; see ThinkingCap.Navigation.Mapper
 * and ThinkingCap.Navigation.CostMap for what uses it).
 *
 * Two parts:
 *
 *  - A fuzzy grid map as a resource: per cell two degrees in [0, 1], how
 *    much it is believed empty (E) and occupied (O), kept as 16-bit
 *    fractions. Rays (angle, range, k_empty, k_occupied) from a sensor
 *    position are traversed cell by cell (Amanatides & Woo); within one
 *    call a cell takes the largest contribution of its rays (fuzzy union,
 *    max), then every touched cell is updated:
 *        O' = O (1 - le e),  E' = E (1 - lo o)           (fading)
 *        E'' = E' + e - E' e,    O'' = O' + o - O' o     (algebraic sum)
 *    so evidence accumulates as readings agree, and what the sensors now
 *    see empty (an obstacle that left) fades out of the occupied degree.
 *
 *  - A* and D* Lite (tc_plan.c), Monte Carlo localization (tc_mcl.c).
 *
 *  - Pure functions on byte grids (row-major from the bottom row): the
 *    exact Euclidean distance transform (Felzenszwalb & Huttenlocher),
 *    inflation, thresholds, downsampling, patches and the difference of
 *    two grids, the room segmentation of the topological map, the
 *    frontiers between known free and unknown space, and a map drawn
 *    crisp for saving.
 *
 * Every function checks its arguments and returns badarg, never crashes.
 * Work proportional to a whole map runs on a dirty CPU scheduler.
 */
#include <erl_nif.h>
#include <math.h>

#include "tc_mcl.h"
#include "tc_slam.h"
#include "tc_edt.h"
#include "tc_nif.h"
#include "tc_plan.h"
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define MAX_CELLS (64L * 1024 * 1024)
#define MAX_RAYS 8192
#define MAX_STEPS 20000
#define FRAC 65535.0

typedef struct {
    ErlNifMutex *lock;
    int w, h;
    double res, ox, oy;
    uint16_t *e, *o;   /* degrees */
    uint16_t *se, *so; /* this call's contributions (zero between calls) */
    int32_t *touched;
    long ntouched, cap;
    int bx0, by0, bx1, by1; /* bounding box of observed cells; bx1 < bx0: none */
} FMap;

static ErlNifResourceType *FMAP_TYPE;
static ERL_NIF_TERM ATOM_OK, ATOM_NIL, ATOM_ERROR;

static void fmap_free(ErlNifEnv *env, void *obj)
{
    (void)env;
    FMap *m = (FMap *)obj;
    free(m->e);
    free(m->o);
    free(m->se);
    free(m->so);
    free(m->touched);
    if (m->lock) enif_mutex_destroy(m->lock);
}

static int load(ErlNifEnv *env, void **priv, ERL_NIF_TERM info)
{
    (void)priv;
    (void)info;
    FMAP_TYPE = enif_open_resource_type(env, NULL, "tc_grid_fmap", fmap_free,
                                        ERL_NIF_RT_CREATE | ERL_NIF_RT_TAKEOVER, NULL);
    ATOM_OK = enif_make_atom(env, "ok");
    ATOM_NIL = enif_make_atom(env, "nil");
    ATOM_ERROR = enif_make_atom(env, "error");
    return FMAP_TYPE == NULL || tc_plan_load(env) || tc_mcl_load(env);
}

static int upgrade(ErlNifEnv *env, void **priv, void **old, ERL_NIF_TERM info)
{
    (void)old;
    return load(env, priv, info);
}

static void widen(FMap *m, int c, int r)
{
    if (m->bx1 < m->bx0) {
        m->bx0 = m->bx1 = c;
        m->by0 = m->by1 = r;
        return;
    }
    if (c < m->bx0) m->bx0 = c;
    if (c > m->bx1) m->bx1 = c;
    if (r < m->by0) m->by0 = r;
    if (r > m->by1) m->by1 = r;
}

/* fmap_new(width, height, resolution, origin_x, origin_y) */
static ERL_NIF_TERM nif_fmap_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    int w, h;
    double res, ox, oy;
    if (!enif_get_int(env, argv[0], &w) || !enif_get_int(env, argv[1], &h) || w <= 0 || h <= 0 ||
        (long)w * h > MAX_CELLS || !tc_number(env, argv[2], &res) || res <= 0 ||
        !tc_number(env, argv[3], &ox) || !tc_number(env, argv[4], &oy))
        return enif_make_badarg(env);

    FMap *m = enif_alloc_resource(FMAP_TYPE, sizeof(FMap));
    memset(m, 0, sizeof(FMap));
    size_t n = (size_t)w * h;
    m->w = w;
    m->h = h;
    m->res = res;
    m->ox = ox;
    m->oy = oy;
    m->e = calloc(n, sizeof(uint16_t));
    m->o = calloc(n, sizeof(uint16_t));
    m->se = calloc(n, sizeof(uint16_t));
    m->so = calloc(n, sizeof(uint16_t));
    m->cap = 4096;
    m->touched = malloc(m->cap * sizeof(int32_t));
    m->lock = enif_mutex_create("tc_grid_fmap");
    m->bx0 = 0;
    m->bx1 = -1;
    if (!m->e || !m->o || !m->se || !m->so || !m->touched || !m->lock) {
        enif_release_resource(m);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    ERL_NIF_TERM t = enif_make_resource(env, m);
    enif_release_resource(m);
    return t;
}

static int touch(FMap *m, long i)
{
    if (m->se[i] == 0 && m->so[i] == 0) {
        if (m->ntouched == m->cap) {
            long cap = m->cap * 2;
            int32_t *t = realloc(m->touched, cap * sizeof(int32_t));
            if (!t) return 0;
            m->touched = t;
            m->cap = cap;
        }
        m->touched[m->ntouched++] = (int32_t)i;
    }
    return 1;
}

static int contribute(FMap *m, int c, int r, double e, double o)
{
    if (c < 0 || r < 0 || c >= m->w || r >= m->h) return 1;
    long i = (long)r * m->w + c;
    uint16_t qe = (uint16_t)lround(fmin(fmax(e, 0.0), 1.0) * FRAC);
    uint16_t qo = (uint16_t)lround(fmin(fmax(o, 0.0), 1.0) * FRAC);
    if (qe == 0 && qo == 0) return 1;
    if (!touch(m, i)) return 0;
    if (qe > m->se[i]) m->se[i] = qe;
    if (qo > m->so[i]) m->so[i] = qo;
    return 1;
}

/* Walks the cells from (x0, y0) to (x1, y1), world metres: every cell
 * before the last gets e_near fading with distance, the last one e_end /
 * o_end. */
static int trace(FMap *m, double x0, double y0, double x1, double y1, double k_e, double k_o,
                 double fade, double range_max, int hit, double margin)
{
    double u0 = (x0 - m->ox) / m->res, v0 = (y0 - m->oy) / m->res;
    double u1 = (x1 - m->ox) / m->res, v1 = (y1 - m->oy) / m->res;
    long c = (long)floor(u0), r = (long)floor(v0);
    long ce = (long)floor(u1), re = (long)floor(v1);
    double du = u1 - u0, dv = v1 - v0;
    int sc = du > 0 ? 1 : (du < 0 ? -1 : 0), sr = dv > 0 ? 1 : (dv < 0 ? -1 : 0);
    double tdc = sc ? fabs(1.0 / du) : INFINITY, tdr = sr ? fabs(1.0 / dv) : INFINITY;
    double tmc = sc > 0 ? (c + 1 - u0) / du : (sc < 0 ? (u0 - c) / -du : INFINITY);
    double tmr = sr > 0 ? (r + 1 - v0) / dv : (sr < 0 ? (v0 - r) / -dv : INFINITY);
    long n = labs(ce - c) + labs(re - r);
    if (n > MAX_STEPS) n = MAX_STEPS;
    double ex = x1 - x0, ey = y1 - y0, length = sqrt(ex * ex + ey * ey);
    /* before an echo, free space ends `margin` short of it */
    double free_to = hit ? length - margin : length;
    for (long k = 0; k < n; k++) {
        double cx = m->ox + (c + 0.5) * m->res - x0, cy = m->oy + (r + 0.5) * m->res - y0;
        double d = sqrt(cx * cx + cy * cy);
        double f = fmax(0.0, 1.0 - fade * d / range_max);
        if (d < free_to && !contribute(m, (int)c, (int)r, k_e * f, 0.0)) return 0;
        if (tmc < tmr) {
            c += sc;
            tmc += tdc;
        } else {
            r += sr;
            tmr += tdr;
        }
    }
    double f = fmax(0.0, 1.0 - fade * length / range_max);
    return hit ? contribute(m, (int)c, (int)r, 0.0, k_o * f)
               : contribute(m, (int)c, (int)r, k_e * f, 0.0);
}

/* one reading's rays (a, range, k_e, k_o per ray) from (sx, sy), fused
 * into the map; the caller holds the lock. Returns the cells changed. */
static long integrate_rays(FMap *m, double sx, double sy, const double *ray, size_t n,
                           double range_max, double fade, double le, double lo, double margin,
                           int *okp)
{
    int ok = 1;
    m->ntouched = 0;
    for (size_t i = 0; i < n && ok; i++) {
        double a = ray[4 * i], range = ray[4 * i + 1], k_e = ray[4 * i + 2], k_o = ray[4 * i + 3];
        if (!isfinite(a) || !isfinite(range) || !isfinite(k_e) || !isfinite(k_o) || range < 0)
            continue;
        int hit = k_o > 0 && range < range_max;
        /* an echo marks the cell just beyond the surface it came from: a
         * surface on a cell boundary always lands on its own side */
        double d = hit ? range + 0.3 * m->res : fmin(range, range_max);
        ok = trace(m, sx, sy, sx + d * cos(a), sy + d * sin(a), k_e, k_o, fade, range_max, hit,
                   margin);
    }
    long changed = 0;
    for (long k = 0; k < m->ntouched; k++) {
        long i = m->touched[k];
        double e = m->se[i] / FRAC, o = m->so[i] / FRAC;
        double E = m->e[i] / FRAC, O = m->o[i] / FRAC;
        O *= 1.0 - le * e;
        E *= 1.0 - lo * o;
        E = E + e - E * e;
        O = O + o - O * o;
        uint16_t qe = (uint16_t)lround(E * FRAC), qo = (uint16_t)lround(O * FRAC);
        if (qe != m->e[i] || qo != m->o[i]) changed++;
        m->e[i] = qe;
        m->o[i] = qo;
        m->se[i] = m->so[i] = 0;
        widen(m, (int)(i % m->w), (int)(i / m->w));
    }
    m->ntouched = 0;
    *okp = ok;
    return changed;
}

/* fmap_integrate(map, sx, sy, rays, range_max, fade, {le, lo}, margin): rays
 * packs native doubles {angle, range, k_empty, k_occupied} per ray; a ray
 * with k_occupied > 0 and a range below range_max ends in an echo
 * (occupied), otherwise in free space. Returns the number of cells whose
 * degrees changed. */
static ERL_NIF_TERM nif_fmap_integrate(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    FMap *m;
    ErlNifBinary rays;
    double sx, sy, range_max, fade, le, lo, margin;
    int arity;
    const ERL_NIF_TERM *lambdas;
    if (!enif_get_resource(env, argv[0], FMAP_TYPE, (void **)&m) ||
        !tc_number(env, argv[1], &sx) || !tc_number(env, argv[2], &sy) ||
        !enif_inspect_binary(env, argv[3], &rays) || rays.size % (4 * sizeof(double)) != 0 ||
        rays.size / (4 * sizeof(double)) > MAX_RAYS || !tc_number(env, argv[4], &range_max) ||
        range_max <= 0 || range_max / m->res > MAX_STEPS || !tc_number(env, argv[5], &fade) ||
        !enif_get_tuple(env, argv[6], &arity, &lambdas) || arity != 2 ||
        !tc_number(env, lambdas[0], &le) || le < 0 || le > 1 ||
        !tc_number(env, lambdas[1], &lo) || lo < 0 || lo > 1 ||
        !tc_number(env, argv[7], &margin) || margin < 0)
        return enif_make_badarg(env);

    size_t n = rays.size / (4 * sizeof(double));
    int ok = 1;
    enif_mutex_lock(m->lock);
    long changed = integrate_rays(m, sx, sy, (const double *)rays.data, n, range_max, fade, le, lo,
                                  margin, &ok);
    enif_mutex_unlock(m->lock);
    if (!ok) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    return enif_make_long(env, changed);
}

/* fmap_replay(map, poses, ranges, beams, {angle_min, angle_increment,
 * range_min, range_max}, {k_e, k_o}, fade, {le, lo}, margin): laser scans
 * drawn again, in order: poses the sensor's {x, y, th} per scan (native
 * doubles), ranges `beams` 32-bit floats per scan (below range_min: no
 * reading). Returns the cells changed. */
static ERL_NIF_TERM nif_fmap_replay(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    FMap *m;
    ErlNifBinary poses, ranges;
    int beams, a1, a2, a3;
    const ERL_NIF_TERM *meta, *ks, *lambdas;
    double amin, ainc, rmin, rmax, k_e, k_o, fade, le, lo, margin;
    if (!enif_get_resource(env, argv[0], FMAP_TYPE, (void **)&m) ||
        !enif_inspect_binary(env, argv[1], &poses) || poses.size % (3 * sizeof(double)) != 0 ||
        !enif_inspect_binary(env, argv[2], &ranges) || !enif_get_int(env, argv[3], &beams) ||
        beams <= 0 || beams > MAX_RAYS ||
        ranges.size != poses.size / (3 * sizeof(double)) * beams * sizeof(float) ||
        !enif_get_tuple(env, argv[4], &a1, &meta) || a1 != 4 || !tc_number(env, meta[0], &amin) ||
        !tc_number(env, meta[1], &ainc) || !tc_number(env, meta[2], &rmin) ||
        !tc_number(env, meta[3], &rmax) || rmax <= 0 || rmax / m->res > MAX_STEPS ||
        !enif_get_tuple(env, argv[5], &a2, &ks) || a2 != 2 || !tc_number(env, ks[0], &k_e) ||
        !tc_number(env, ks[1], &k_o) || !tc_number(env, argv[6], &fade) ||
        !enif_get_tuple(env, argv[7], &a3, &lambdas) || a3 != 2 ||
        !tc_number(env, lambdas[0], &le) || le < 0 || le > 1 ||
        !tc_number(env, lambdas[1], &lo) || lo < 0 || lo > 1 ||
        !tc_number(env, argv[8], &margin) || margin < 0)
        return enif_make_badarg(env);
    size_t scans = poses.size / (3 * sizeof(double));
    const double *p = (const double *)poses.data;
    const float *r = (const float *)ranges.data;
    double *ray = malloc(sizeof(double) * 4 * beams);
    if (!ray) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    long changed = 0;
    int ok = 1;
    enif_mutex_lock(m->lock);
    for (size_t s = 0; s < scans && ok; s++) {
        double x = p[3 * s], y = p[3 * s + 1], th = p[3 * s + 2];
        if (!isfinite(x) || !isfinite(y) || !isfinite(th)) continue;
        size_t n = 0;
        for (int b = 0; b < beams; b++) {
            double range = r[s * beams + b];
            if (!isfinite(range) || range < rmin) continue;
            int echo = range < rmax;
            ray[4 * n] = th + amin + b * ainc;
            ray[4 * n + 1] = echo ? range : rmax;
            ray[4 * n + 2] = k_e;
            ray[4 * n + 3] = echo ? k_o : 0.0;
            n++;
        }
        changed += integrate_rays(m, x, y, ray, n, rmax, fade, le, lo, margin, &ok);
    }
    enif_mutex_unlock(m->lock);
    free(ray);
    if (!ok) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    return enif_make_long(env, changed);
}

/* fmap_occupancy(map, c0, r0, w, h, known): the window's cells as signed
 * bytes: -1 where neither degree reaches `known`, else
 * round(100 min(O, 1 - E)). */
static ERL_NIF_TERM nif_fmap_occupancy(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    FMap *m;
    int c0, r0, w, h;
    double known;
    if (!enif_get_resource(env, argv[0], FMAP_TYPE, (void **)&m) ||
        !enif_get_int(env, argv[1], &c0) || !enif_get_int(env, argv[2], &r0) ||
        !enif_get_int(env, argv[3], &w) || !enif_get_int(env, argv[4], &h) || w <= 0 || h <= 0 ||
        c0 < 0 || r0 < 0 || c0 + w > m->w || r0 + h > m->h || !tc_number(env, argv[5], &known))
        return enif_make_badarg(env);
    ERL_NIF_TERM out;
    int8_t *p = (int8_t *)enif_make_new_binary(env, (size_t)w * h, &out);
    uint16_t qk = (uint16_t)lround(fmin(fmax(known, 0.0), 1.0) * FRAC);
    enif_mutex_lock(m->lock);
    for (int r = 0; r < h; r++) {
        const uint16_t *E = m->e + (long)(r0 + r) * m->w + c0;
        const uint16_t *O = m->o + (long)(r0 + r) * m->w + c0;
        for (int c = 0; c < w; c++) {
            if (E[c] < qk && O[c] < qk) {
                p[(long)r * w + c] = -1;
            } else {
                double occ = fmin(O[c] / FRAC, 1.0 - E[c] / FRAC);
                p[(long)r * w + c] = (int8_t)lround(100.0 * fmax(occ, 0.0));
            }
        }
    }
    enif_mutex_unlock(m->lock);
    return out;
}

static ERL_NIF_TERM nif_fmap_bbox(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    FMap *m;
    if (!enif_get_resource(env, argv[0], FMAP_TYPE, (void **)&m)) return enif_make_badarg(env);
    enif_mutex_lock(m->lock);
    ERL_NIF_TERM t = m->bx1 < m->bx0
                         ? ATOM_NIL
                         : enif_make_tuple4(env, enif_make_int(env, m->bx0),
                                            enif_make_int(env, m->by0), enif_make_int(env, m->bx1),
                                            enif_make_int(env, m->by1));
    enif_mutex_unlock(m->lock);
    return t;
}

static ERL_NIF_TERM nif_fmap_degrees(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    FMap *m;
    int c, r;
    if (!enif_get_resource(env, argv[0], FMAP_TYPE, (void **)&m) ||
        !enif_get_int(env, argv[1], &c) || !enif_get_int(env, argv[2], &r))
        return enif_make_badarg(env);
    if (c < 0 || r < 0 || c >= m->w || r >= m->h)
        return enif_make_tuple2(env, enif_make_double(env, 0.0), enif_make_double(env, 0.0));
    enif_mutex_lock(m->lock);
    long i = (long)r * m->w + c;
    ERL_NIF_TERM t = enif_make_tuple2(env, enif_make_double(env, m->e[i] / FRAC),
                                      enif_make_double(env, m->o[i] / FRAC));
    enif_mutex_unlock(m->lock);
    return t;
}

/* fmap_seed(map, occupancy, strength): an a priori map of the same size
 * (signed bytes): cells of occupancy >= 50 get O = strength, free cells
 * (0..49) E = strength, unknown cells (-1) nothing. */
static ERL_NIF_TERM nif_fmap_seed(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    FMap *m;
    ErlNifBinary occ;
    double s;
    if (!enif_get_resource(env, argv[0], FMAP_TYPE, (void **)&m) ||
        !enif_inspect_binary(env, argv[1], &occ) || occ.size != (size_t)m->w * m->h ||
        !tc_number(env, argv[2], &s) || s < 0 || s > 1)
        return enif_make_badarg(env);
    uint16_t q = (uint16_t)lround(s * FRAC);
    enif_mutex_lock(m->lock);
    for (long i = 0; i < (long)occ.size; i++) {
        int8_t v = (int8_t)occ.data[i];
        if (v < 0) continue;
        if (v >= 50) {
            m->o[i] = q;
            m->e[i] = 0;
        } else {
            m->e[i] = q;
            m->o[i] = 0;
        }
        widen(m, (int)(i % m->w), (int)(i / m->w));
    }
    enif_mutex_unlock(m->lock);
    return ATOM_OK;
}

/* fmap_export(map) -> binary of E then O (native 16-bit); fmap_import(map,
 * binary) sets them back (a standby resumes from it). */
static ERL_NIF_TERM nif_fmap_export(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    FMap *m;
    if (!enif_get_resource(env, argv[0], FMAP_TYPE, (void **)&m)) return enif_make_badarg(env);
    size_t n = (size_t)m->w * m->h;
    ERL_NIF_TERM out;
    unsigned char *p = enif_make_new_binary(env, 4 * n, &out);
    enif_mutex_lock(m->lock);
    memcpy(p, m->e, 2 * n);
    memcpy(p + 2 * n, m->o, 2 * n);
    enif_mutex_unlock(m->lock);
    return out;
}

static ERL_NIF_TERM nif_fmap_import(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    FMap *m;
    ErlNifBinary b;
    if (!enif_get_resource(env, argv[0], FMAP_TYPE, (void **)&m) ||
        !enif_inspect_binary(env, argv[1], &b) || b.size != 4 * (size_t)m->w * m->h)
        return enif_make_badarg(env);
    size_t n = (size_t)m->w * m->h;
    enif_mutex_lock(m->lock);
    memcpy(m->e, b.data, 2 * n);
    memcpy(m->o, b.data + 2 * n, 2 * n);
    m->bx0 = 0;
    m->bx1 = -1;
    for (size_t i = 0; i < n; i++)
        if (m->e[i] || m->o[i]) widen(m, (int)(i % m->w), (int)(i / m->w));
    enif_mutex_unlock(m->lock);
    return ATOM_OK;
}

/* ---- pure grid functions ---- */

static int get_grid(ErlNifEnv *env, const ERL_NIF_TERM argv[], ErlNifBinary *b, int *w, int *h)
{
    return tc_grid_args(env, argv, MAX_CELLS, b, w, h);
}

/* edt(cells, w, h) -> native float32 distances in cells (centre to
 * centre) to the nearest non-zero cell; a very large value if none */
static ERL_NIF_TERM nif_edt(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h;
    if (!get_grid(env, argv, &b, &w, &h)) return enif_make_badarg(env);
    double *g = tc_edt2(b.data, w, h);
    if (!g) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    ERL_NIF_TERM out;
    float *p = (float *)enif_make_new_binary(env, (size_t)w * h * sizeof(float), &out);
    for (size_t i = 0; i < (size_t)w * h; i++) p[i] = isinf(g[i]) ? 1e30f : (float)sqrt(g[i]);
    free(g);
    return out;
}

/* The byte of a cell d2 (squared cells) from the nearest obstacle: 1
 * within the radius, then a cost falling from `peak` at the radius to 0
 * at radius + band as the square of the way left (at least 2: a cost
 * under 2 is 0), 0 beyond. */
static inline unsigned char banded(double d2, double radius, double band, double peak)
{
    if (d2 <= radius * radius + 1e-9) return 1;
    if (band <= 0 || peak < 2) return 0;
    double t = (radius + band - sqrt(d2)) / band;
    if (t <= 0) return 0;
    long v = lround(peak * t * t);
    return v >= 2 ? (unsigned char)(v > 255 ? 255 : v) : 0;
}

/* inflate(cells, w, h, radius_cells) -> cells within radius (centre to
 * centre) of a non-zero cell set to 1, the others 0. */
static ERL_NIF_TERM nif_inflate(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h;
    double radius;
    if (!get_grid(env, argv, &b, &w, &h) || !tc_number(env, argv[3], &radius) || radius < 0)
        return enif_make_badarg(env);
    size_t n = (size_t)w * h;
    double *g = tc_edt2(b.data, w, h);
    if (!g) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    ERL_NIF_TERM out;
    unsigned char *p = enif_make_new_binary(env, n, &out);
    for (size_t i = 0; i < n; i++) p[i] = banded(g[i], radius, 0, 0);
    free(g);
    return out;
}

/* cost_map(cells, w, h, radius_cells, band_cells, peak, old, max) ->
 * {costs, changed, distances}, from one distance transform of the
 * non-zero cells: `costs` the cells within radius set to 1 and the band
 * round them (banded above); `changed` the cells where costs differ from
 * `old` (a grid of the same size), as native 32-bit indices found while
 * costs is written, `too_many` when more than max differ, nil when old
 * is nil; `distances` each cell's distance (cells, native float32, 1e30
 * where no cell is set) to the nearest set cell. */
static ERL_NIF_TERM nif_cost_map(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b, old;
    int w, h;
    double radius, band, peak;
    long max = 0;
    if (!get_grid(env, argv, &b, &w, &h) || !tc_number(env, argv[3], &radius) || radius < 0 ||
        !tc_number(env, argv[4], &band) || band < 0 || !tc_number(env, argv[5], &peak) ||
        peak < 0 || peak > 255 || !enif_get_long(env, argv[7], &max) || max < 0)
        return enif_make_badarg(env);
    size_t n = (size_t)w * h;
    int diff = !enif_is_atom(env, argv[6]);
    if (diff && (!enif_inspect_binary(env, argv[6], &old) || old.size != n))
        return enif_make_badarg(env);
    double *g = tc_edt2(b.data, w, h);
    if (!g) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    ERL_NIF_TERM out, field, list;
    unsigned char *p = enif_make_new_binary(env, n, &out);
    float *dist = (float *)enif_make_new_binary(env, n * sizeof(float), &field);
    size_t m = 0, cap = 256;
    int32_t *changed = diff ? malloc(cap * sizeof(int32_t)) : NULL;
    if (diff && !changed) {
        free(g);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (size_t i = 0; i < n; i++) {
        dist[i] = isinf(g[i]) ? 1e30f : (float)sqrt(g[i]);
        p[i] = banded(g[i], radius, band, peak);
        if (!diff || p[i] == old.data[i] || m > (size_t)max) continue;
        if (m == cap) {
            int32_t *more = realloc(changed, 2 * cap * sizeof(int32_t));
            if (!more) {
                free(g);
                free(changed);
                return enif_raise_exception(env, enif_make_atom(env, "enomem"));
            }
            changed = more;
            cap *= 2;
        }
        changed[m++] = (int32_t)i;
    }
    free(g);
    if (!diff) {
        list = enif_make_atom(env, "nil");
    } else if (m > (size_t)max) {
        list = enif_make_atom(env, "too_many");
    } else {
        unsigned char *q = enif_make_new_binary(env, m * sizeof(int32_t), &list);
        memcpy(q, changed, m * sizeof(int32_t));
    }
    free(changed);
    return enif_make_tuple3(env, out, list, field);
}

/* diff(a, b, max) -> {count, [index]} the indices where a and b differ
 * (at most max of them listed) */
static ERL_NIF_TERM nif_diff(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary a, b;
    long max;
    if (!enif_inspect_binary(env, argv[0], &a) || !enif_inspect_binary(env, argv[1], &b) ||
        a.size != b.size || !enif_get_long(env, argv[2], &max) || max < 0)
        return enif_make_badarg(env);
    ERL_NIF_TERM list = enif_make_list(env, 0);
    long count = 0;
    for (long i = (long)a.size - 1; i >= 0; i--) {
        if (a.data[i] != b.data[i]) {
            if (count < max) list = enif_make_list_cell(env, enif_make_long(env, i), list);
            count++;
        }
    }
    return enif_make_tuple2(env, enif_make_long(env, count), list);
}

/* overlay(data, mask, value) -> a copy of data with `value` (0..255)
 * wherever mask is non-zero (both the same size) */
static ERL_NIF_TERM nif_overlay(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary d, m;
    int value;
    if (!enif_inspect_binary(env, argv[0], &d) || !enif_inspect_binary(env, argv[1], &m) ||
        d.size != m.size || !enif_get_int(env, argv[2], &value) || value < 0 || value > 255)
        return enif_make_badarg(env);
    ERL_NIF_TERM out;
    unsigned char *p = enif_make_new_binary(env, d.size, &out);
    for (size_t i = 0; i < d.size; i++) p[i] = m.data[i] ? (unsigned char)value : d.data[i];
    return out;
}

/* blocked(occupancy, threshold, unknown) -> 1 where the signed byte is
 * >= threshold, `unknown` (0 or 1) where it is -1, else 0 */
static ERL_NIF_TERM nif_blocked(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int threshold, unknown;
    if (!enif_inspect_binary(env, argv[0], &b) || !enif_get_int(env, argv[1], &threshold) ||
        !enif_get_int(env, argv[2], &unknown) || (unknown != 0 && unknown != 1))
        return enif_make_badarg(env);
    ERL_NIF_TERM out;
    unsigned char *p = enif_make_new_binary(env, b.size, &out);
    for (size_t i = 0; i < b.size; i++) {
        int8_t v = (int8_t)b.data[i];
        p[i] = v < 0 ? (unsigned char)unknown : (v >= threshold ? 1 : 0);
    }
    return out;
}

/* patch(cells, changes) -> a copy of cells with each {index, value} of
 * changes (native int32 pairs) set; indices outside are ignored */
static ERL_NIF_TERM nif_patch(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b, ch;
    if (!enif_inspect_binary(env, argv[0], &b) || !enif_inspect_binary(env, argv[1], &ch) ||
        ch.size % 8 != 0)
        return enif_make_badarg(env);
    ERL_NIF_TERM out;
    unsigned char *p = enif_make_new_binary(env, b.size, &out);
    memcpy(p, b.data, b.size);
    const int32_t *c = (const int32_t *)ch.data;
    for (size_t k = 0; k < ch.size / 8; k++)
        if (c[2 * k] >= 0 && (size_t)c[2 * k] < b.size) p[c[2 * k]] = (unsigned char)c[2 * k + 1];
    return out;
}

/* rooms(occupancy, w, h, free_below, half_door, min_core) -> {regions,
 * contacts}: the room segmentation of ThinkingCap.Navigation.Maps.Rooms.
 * Free cells (0 <= v < free_below) farther than half_door cells from any
 * other cell are cores; 8-connected cores of fewer than min_core cells
 * are dropped; every free cell joins the core it reaches first (4-
 * connected, breadth first). regions: [{label, count, sum_c, sum_r,
 * sum_cc, sum_cr, sum_rr, [{row, col_min, col_max}]}]; contacts: [{a, b,
 * x2, y2}] for every pair of 4-neighbours of regions a < b, at the
 * doubled coordinates of the edge between them (cell {c, r} spans
 * [2c, 2c + 2] x [2r, 2r + 2]). */
static ERL_NIF_TERM nif_rooms(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h, free_below;
    double half, min_core;
    if (!get_grid(env, argv, &b, &w, &h) || !enif_get_int(env, argv[3], &free_below) ||
        !tc_number(env, argv[4], &half) || !tc_number(env, argv[5], &min_core))
        return enif_make_badarg(env);
    size_t n = (size_t)w * h;
    unsigned char *blocked = calloc(n, 1);
    int32_t *lab = calloc(n, sizeof(int32_t));
    int32_t *queue = malloc(n * sizeof(int32_t));
    if (!blocked || !lab || !queue) {
        free(blocked);
        free(lab);
        free(queue);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (size_t i = 0; i < n; i++) {
        int8_t v = (int8_t)b.data[i];
        blocked[i] = !(v >= 0 && v < free_below);
    }
    double *g = tc_edt2(blocked, w, h);
    if (!g) {
        free(blocked);
        free(lab);
        free(queue);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    double h2 = half * half;
    /* cores, labelled 8-connected; small ones dropped */
    int32_t next = 0;
    for (size_t s0 = 0; s0 < n; s0++) {
        if (blocked[s0] || lab[s0] || !(g[s0] > h2)) continue;
        next++;
        size_t head = 0, tail = 0;
        queue[tail++] = (int32_t)s0;
        lab[s0] = next;
        while (head < tail) {
            int32_t i = queue[head++];
            int c = i % w, r = i / w;
            for (int dr = -1; dr <= 1; dr++)
                for (int dc = -1; dc <= 1; dc++) {
                    int cc = c + dc, rr = r + dr;
                    if ((dc || dr) && cc >= 0 && rr >= 0 && cc < w && rr < h) {
                        size_t j = (size_t)rr * w + cc;
                        if (!blocked[j] && !lab[j] && g[j] > h2) {
                            lab[j] = next;
                            queue[tail++] = (int32_t)j;
                        }
                    }
                }
        }
        if ((double)tail < min_core)
            for (size_t k = 0; k < tail; k++) lab[queue[k]] = -1; /* dropped */
    }
    free(g);
    /* grow over the free cells, breadth first from every core at once */
    size_t head = 0, tail = 0;
    for (size_t i = 0; i < n; i++) {
        if (lab[i] < 0) lab[i] = 0;
        if (lab[i] > 0) queue[tail++] = (int32_t)i;
    }
    static const int dc4[4] = {1, -1, 0, 0}, dr4[4] = {0, 0, 1, -1};
    while (head < tail) {
        int32_t i = queue[head++];
        int c = i % w, r = i / w;
        for (int k = 0; k < 4; k++) {
            int cc = c + dc4[k], rr = r + dr4[k];
            if (cc < 0 || rr < 0 || cc >= w || rr >= h) continue;
            size_t j = (size_t)rr * w + cc;
            if (!blocked[j] && lab[j] == 0) {
                lab[j] = lab[i];
                queue[tail++] = (int32_t)j;
            }
        }
    }
    free(queue);
    free(blocked);
    /* statistics per label, and row extents */
    double *st = calloc((size_t)(next + 1) * 6, sizeof(double));
    int32_t *rmin = malloc((size_t)(next + 1) * h * sizeof(int32_t));
    int32_t *rmax = malloc((size_t)(next + 1) * h * sizeof(int32_t));
    if (!st || !rmin || !rmax) {
        free(st);
        free(rmin);
        free(rmax);
        free(lab);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (size_t k = 0; k < (size_t)(next + 1) * h; k++) rmin[k] = w, rmax[k] = -1;
    ERL_NIF_TERM contacts = enif_make_list(env, 0);
    for (int r = 0; r < h; r++)
        for (int c = 0; c < w; c++) {
            int32_t a = lab[(size_t)r * w + c];
            if (a <= 0) continue;
            double *t = st + (size_t)a * 6;
            t[0] += 1, t[1] += c, t[2] += r, t[3] += (double)c * c, t[4] += (double)c * r,
                t[5] += (double)r * r;
            size_t e = (size_t)a * h + r;
            if (c < rmin[e]) rmin[e] = c;
            if (c > rmax[e]) rmax[e] = c;
            int32_t right = c + 1 < w ? lab[(size_t)r * w + c + 1] : 0;
            int32_t up = r + 1 < h ? lab[(size_t)(r + 1) * w + c] : 0;
            if (right > 0 && right != a)
                contacts = enif_make_list_cell(
                    env,
                    enif_make_tuple4(env, enif_make_int(env, a < right ? a : right),
                                     enif_make_int(env, a < right ? right : a),
                                     enif_make_int(env, 2 * c + 2), enif_make_int(env, 2 * r + 1)),
                    contacts);
            if (up > 0 && up != a)
                contacts = enif_make_list_cell(
                    env,
                    enif_make_tuple4(env, enif_make_int(env, a < up ? a : up),
                                     enif_make_int(env, a < up ? up : a),
                                     enif_make_int(env, 2 * c + 1), enif_make_int(env, 2 * r + 2)),
                    contacts);
        }
    ERL_NIF_TERM regions = enif_make_list(env, 0);
    for (int32_t a = next; a >= 1; a--) {
        double *t = st + (size_t)a * 6;
        if (t[0] == 0) continue;
        ERL_NIF_TERM rows = enif_make_list(env, 0);
        for (int r = h - 1; r >= 0; r--) {
            size_t e = (size_t)a * h + r;
            if (rmax[e] >= 0)
                rows = enif_make_list_cell(env,
                                           enif_make_tuple3(env, enif_make_int(env, r),
                                                            enif_make_int(env, rmin[e]),
                                                            enif_make_int(env, rmax[e])),
                                           rows);
        }
        ERL_NIF_TERM fields[8] = {enif_make_int(env, a),
                                  enif_make_long(env, (long)t[0]),
                                  enif_make_double(env, t[1]),
                                  enif_make_double(env, t[2]),
                                  enif_make_double(env, t[3]),
                                  enif_make_double(env, t[4]),
                                  enif_make_double(env, t[5]),
                                  rows};
        regions = enif_make_list_cell(env, enif_make_tuple_from_array(env, fields, 8), regions);
    }
    free(st);
    free(rmin);
    free(rmax);
    free(lab);
    return enif_make_tuple2(env, regions, contacts);
}

/* crisp(occupancy, w, h) -> occupancy: the map as map_saver's trinary
 * thresholds read it (free at most 19, occupied from 65, else unknown),
 * drawn to the surfaces the sensors saw. First, an occupied cell facing a
 * free 4-neighbour, with an occupied cell behind it and no free cell
 * behind that, is free: noise on the echoes grows a wall by a cell
 * towards free space, and the wall keeps at least one cell (two cells
 * between free space on both sides are left alone). Then an unknown cell
 * with a free 4-neighbour and an occupied 8-neighbour is free: the band
 * before a wall that the beams crossed but the map's margin left
 * unknown. Values out: 0, 100 or -1. */
static ERL_NIF_TERM nif_crisp(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h;
    if (!get_grid(env, argv, &b, &w, &h)) return enif_make_badarg(env);
    size_t n = (size_t)w * h;
    const int8_t *v = (const int8_t *)b.data;
    int8_t *t = malloc(n), *e = malloc(n);
    if (!t || !e) {
        free(t);
        free(e);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (size_t i = 0; i < n; i++) t[i] = v[i] < 0 ? -1 : v[i] <= 19 ? 0 : v[i] >= 65 ? 100 : -1;
#define AT(g, c, r) (((c) < 0 || (r) < 0 || (c) >= w || (r) >= h) ? -1 : (g)[(size_t)(r) * w + (c)])
    static const int d4[4][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
    for (int r = 0; r < h; r++)
        for (int c = 0; c < w; c++) {
            size_t i = (size_t)r * w + c;
            e[i] = t[i];
            if (t[i] != 100) continue;
            for (int k = 0; k < 4; k++) {
                int dc = d4[k][0], dr = d4[k][1];
                if (AT(t, c + dc, r + dr) == 0 && AT(t, c - dc, r - dr) == 100 &&
                    AT(t, c - 2 * dc, r - 2 * dr) != 0) {
                    e[i] = 0;
                    break;
                }
            }
        }
    ERL_NIF_TERM out;
    int8_t *o = (int8_t *)enif_make_new_binary(env, n, &out);
    for (int r = 0; r < h; r++)
        for (int c = 0; c < w; c++) {
            size_t i = (size_t)r * w + c;
            o[i] = e[i];
            if (e[i] != -1) continue;
            int free4 = 0, occupied8 = 0;
            for (int k = 0; k < 4; k++) free4 |= AT(e, c + d4[k][0], r + d4[k][1]) == 0;
            for (int dr = -1; dr <= 1; dr++)
                for (int dc = -1; dc <= 1; dc++) occupied8 |= AT(e, c + dc, r + dr) == 100;
            if (free4 && occupied8) o[i] = 0;
        }
#undef AT
    free(t);
    free(e);
    return out;
}

/* frontiers(occupancy, w, h, free_below, min_size) -> [{size, {c, r}}]:
 * the frontiers between known free space (0 <= v < free_below) and
 * unknown space (-1): free cells with an unknown 4-neighbour, grouped
 * 8-connected; for each group of at least min_size cells, its size and
 * its cell nearest its centroid. */
static ERL_NIF_TERM nif_frontiers(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h, free_below, min_size;
    if (!get_grid(env, argv, &b, &w, &h) || !enif_get_int(env, argv[3], &free_below) ||
        !enif_get_int(env, argv[4], &min_size))
        return enif_make_badarg(env);
    size_t n = (size_t)w * h;
    const int8_t *v = (const int8_t *)b.data;
    unsigned char *front = calloc(n, 1);
    int32_t *queue = malloc(n * sizeof(int32_t));
    if (!front || !queue) {
        free(front);
        free(queue);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (int r = 0; r < h; r++)
        for (int c = 0; c < w; c++) {
            size_t i = (size_t)r * w + c;
            if (!(v[i] >= 0 && v[i] < free_below)) continue;
            int unknown = (c > 0 && v[i - 1] < 0) || (c < w - 1 && v[i + 1] < 0) ||
                          (r > 0 && v[i - w] < 0) || (r < h - 1 && v[i + w] < 0);
            front[i] = unknown ? 1 : 0;
        }
    ERL_NIF_TERM list = enif_make_list(env, 0);
    for (size_t s0 = 0; s0 < n; s0++) {
        if (front[s0] != 1) continue;
        size_t head = 0, tail = 0;
        queue[tail++] = (int32_t)s0;
        front[s0] = 2;
        double sc = 0, sr = 0;
        while (head < tail) {
            int32_t i = queue[head++];
            int c = i % w, r = i / w;
            sc += c;
            sr += r;
            for (int dr = -1; dr <= 1; dr++)
                for (int dc = -1; dc <= 1; dc++) {
                    int cc = c + dc, rr = r + dr;
                    if ((dc || dr) && cc >= 0 && rr >= 0 && cc < w && rr < h) {
                        size_t j = (size_t)rr * w + cc;
                        if (front[j] == 1) {
                            front[j] = 2;
                            queue[tail++] = (int32_t)j;
                        }
                    }
                }
        }
        if ((long)tail < min_size) continue;
        double mc = sc / tail, mr = sr / tail, best = 1e300;
        int32_t at = queue[0];
        for (size_t k = 0; k < tail; k++) {
            double dc = queue[k] % w - mc, dr = queue[k] / w - mr;
            if (dc * dc + dr * dr < best) best = dc * dc + dr * dr, at = queue[k];
        }
        list = enif_make_list_cell(
            env,
            enif_make_tuple2(env, enif_make_long(env, (long)tail),
                             enif_make_tuple2(env, enif_make_int(env, at % w),
                                              enif_make_int(env, at / w))),
            list);
    }
    free(front);
    free(queue);
    return list;
}

/* shrink(occupancy, w, h, k) -> {w', h', occupancy'}: each k x k block
 * one cell, the largest of its signed values (unknown, -1, only where
 * every cell of the block is; the blocks at the right and top edges may
 * be partial). On blocked cells (0 or 1) a block is blocked if any of
 * its cells is. */
static ERL_NIF_TERM nif_shrink(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h, k;
    if (!get_grid(env, argv, &b, &w, &h) || !enif_get_int(env, argv[3], &k) || k < 1 || k > 64)
        return enif_make_badarg(env);
    int cw = (w + k - 1) / k, ch = (h + k - 1) / k;
    ERL_NIF_TERM out;
    int8_t *p = (int8_t *)enif_make_new_binary(env, (size_t)cw * ch, &out);
    memset(p, -1, (size_t)cw * ch);
    for (int r = 0; r < h; r++)
        for (int c = 0; c < w; c++) {
            int8_t v = (int8_t)b.data[(size_t)r * w + c];
            int8_t *q = p + (size_t)(r / k) * cw + c / k;
            if (v > *q) *q = v;
        }
    return enif_make_tuple3(env, enif_make_int(env, cw), enif_make_int(env, ch), out);
}

static ErlNifFunc funcs[] = {
    {"fmap_new", 5, nif_fmap_new, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"fmap_integrate", 8, nif_fmap_integrate, 0},
    {"fmap_replay", 9, nif_fmap_replay, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"fmap_occupancy", 6, nif_fmap_occupancy, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"fmap_bbox", 1, nif_fmap_bbox, 0},
    {"fmap_degrees", 3, nif_fmap_degrees, 0},
    {"fmap_seed", 3, nif_fmap_seed, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"fmap_export", 1, nif_fmap_export, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"fmap_import", 2, nif_fmap_import, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"edt", 3, nif_edt, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"inflate", 4, nif_inflate, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"cost_map", 8, nif_cost_map, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"diff", 3, nif_diff, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"blocked", 3, nif_blocked, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"overlay", 3, nif_overlay, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"patch", 2, nif_patch, 0},
    {"rooms", 6, nif_rooms, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"frontiers", 5, nif_frontiers, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"crisp", 3, nif_crisp, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"shrink", 4, nif_shrink, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"astar", 5, tc_nif_astar, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"astar_cpu", 5, tc_nif_astar_cpu, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"costs", 5, tc_nif_costs, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"field_new", 8, tc_nif_field_new, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"field_score", 4, tc_nif_field_score, 0},
    {"field_through", 4, tc_nif_field_through, 0},
    {"field_fit", 5, tc_nif_field_fit, 0},
    {"field_search", 7, tc_nif_field_search, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"pf_new", 2, tc_nif_pf_new, 0},
    {"pf_spread", 3, tc_nif_pf_spread, 0},
    {"pf_move", 3, tc_nif_pf_move, 0},
    {"pf_weigh", 5, tc_nif_pf_weigh, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"pf_resample", 3, tc_nif_pf_resample, 0},
    {"pf_estimate", 1, tc_nif_pf_estimate, 0},
    {"pf_mode", 2, tc_nif_pf_mode, 0},
    {"pf_best", 1, tc_nif_pf_best, 0},
    {"pf_sample", 2, tc_nif_pf_sample, 0},
    {"pf_transform", 3, tc_nif_pf_transform, 0},
    {"slam_match", 6, tc_nif_slam_match, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"slam_optimize", 3, tc_nif_slam_optimize, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"dsl_new", 5, tc_nif_dsl_new, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"dsl_update", 2, tc_nif_dsl_update, 0},
    {"dsl_sync", 3, tc_nif_dsl_sync, 0},
    {"dsl_sync", 4, tc_nif_dsl_sync, 0},
    {"dsl_move_start", 2, tc_nif_dsl_move_start, 0},
    {"dsl_plan", 1, tc_nif_dsl_plan, 0},
    {"dsl_forget_path", 1, tc_nif_dsl_forget_path, 0},
    {"dsl_cpu_ns", 1, tc_nif_dsl_cpu_ns, 0},
    {"dsl_queued", 1, tc_nif_dsl_queued, 0},
};

ERL_NIF_INIT(Elixir.ThinkingCap.Navigation.Core.GridNif, funcs, load, NULL, upgrade, NULL)
