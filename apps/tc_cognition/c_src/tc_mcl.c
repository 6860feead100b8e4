/*
 * tc_mcl: Monte Carlo localization for the grid NIF (see tc_grid.c;
 * ThinkingCap.Navigation.ParticleFilter wraps it).
 *
 * A likelihood field (Thrun, Burgard & Fox, Probabilistic Robotics 6.4):
 * for every cell of an occupancy grid the distance to the nearest
 * occupied cell (exact distance transform), and whether the cell is
 * unknown. A beam's endpoint scores
 *     z_hit * exp(-d^2 / 2 sigma^2) + z_rand / range_max
 * where d is that distance. In a map still being built, an endpoint off
 * the map or in unknown space says nothing (it scores like the average
 * of a free beam, so the particles are not pulled towards what is
 * known). In a map given whole (`strict`), an endpoint in unknown space
 * is scored by its distance like any other, and one off the map as noise:
 * the laser stops only at what the map holds.
 *
 * A particle set: poses and log-weights, with its own random generator
 * (xoshiro256**, seeded by the caller: runs are deterministic), moved by
 * the odometry motion model (sample_motion_model_odometry, table 5.6),
 * weighed by a scan, resampled (low variance), summarised (mean, circular
 * mean heading, covariance). A global search scores a scan at every free
 * cell of a coarse lattice and every heading step, for relocalization.
 */
#include "tc_mcl.h"
#include "tc_edt.h"
#include "tc_nif.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define MAX_PARTICLES 200000
#define MAX_BEAMS 4096
#define TWO_PI 6.283185307179586

static ErlNifResourceType *FIELD_TYPE, *PF_TYPE;
static ERL_NIF_TERM M_OK;

typedef struct {
    int w, h;
    double res, ox, oy;
    float *dist;      /* metres to the nearest occupied cell */
    float *udist;     /* metres to the nearest unknown cell (or the map's edge) */
    uint8_t *unknown; /* 1 where the map does not know */
    int strict;       /* a map given whole: unknown endpoints are scored */
} Field;

typedef struct {
    ErlNifMutex *lock;
    int n;
    double *x, *y, *th, *lw; /* poses, log-weights */
    uint64_t s[4];           /* xoshiro256** state */
} Pf;

static void field_free(ErlNifEnv *env, void *obj)
{
    (void)env;
    Field *f = obj;
    free(f->dist);
    free(f->udist);
    free(f->unknown);
}

static void pf_free(ErlNifEnv *env, void *obj)
{
    (void)env;
    Pf *p = obj;
    free(p->x);
    free(p->y);
    free(p->th);
    free(p->lw);
    if (p->lock) enif_mutex_destroy(p->lock);
}

int tc_mcl_load(ErlNifEnv *env)
{
    FIELD_TYPE = enif_open_resource_type(env, NULL, "tc_mcl_field", field_free,
                                         ERL_NIF_RT_CREATE | ERL_NIF_RT_TAKEOVER, NULL);
    PF_TYPE = enif_open_resource_type(env, NULL, "tc_mcl_pf", pf_free,
                                      ERL_NIF_RT_CREATE | ERL_NIF_RT_TAKEOVER, NULL);
    M_OK = enif_make_atom(env, "ok");
    return FIELD_TYPE == NULL || PF_TYPE == NULL;
}

/* ---- random numbers ---- */

static uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

static uint64_t next(Pf *p)
{
    uint64_t *s = p->s;
    uint64_t r = rotl(s[1] * 5, 7) * 9, t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return r;
}

static double uniform(Pf *p) { return (next(p) >> 11) * (1.0 / 9007199254740992.0); }

static double gauss(Pf *p)
{
    double u = uniform(p), v = uniform(p);
    if (u < 1e-300) u = 1e-300;
    return sqrt(-2.0 * log(u)) * cos(TWO_PI * v);
}

static void seed(Pf *p, uint64_t seed)
{
    /* splitmix64 */
    for (int i = 0; i < 4; i++) {
        uint64_t z = (seed += 0x9e3779b97f4a7c15ULL);
        z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
        z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
        p->s[i] = z ^ (z >> 31);
    }
}

/* ---- the likelihood field ---- */

/* field_new(occupancy, w, h, resolution, ox, oy, threshold, strict) */
ERL_NIF_TERM tc_nif_field_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h, threshold, strict;
    double res, ox, oy;
    if (!tc_grid_args(env, argv, 1L << 27, &b, &w, &h) || !tc_number(env, argv[3], &res) ||
        res <= 0 || !tc_number(env, argv[4], &ox) || !tc_number(env, argv[5], &oy) ||
        !enif_get_int(env, argv[6], &threshold) || !enif_get_int(env, argv[7], &strict))
        return enif_make_badarg(env);
    size_t n = (size_t)w * h;
    Field *f = enif_alloc_resource(FIELD_TYPE, sizeof(Field));
    memset(f, 0, sizeof(Field));
    f->w = w, f->h = h, f->res = res, f->ox = ox, f->oy = oy, f->strict = strict != 0;
    f->dist = malloc(n * sizeof(float));
    f->udist = malloc(n * sizeof(float));
    f->unknown = malloc(n);
    /* seeds: the occupied cells; then the unknown ones and the map's edge
     * (a border of cells just outside it) */
    int pw = w + 2, ph = h + 2;
    unsigned char *seeds = malloc((size_t)pw * ph);
    if (!f->dist || !f->udist || !f->unknown || !seeds) {
        free(seeds);
        enif_release_resource(f);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (size_t i = 0; i < n; i++) {
        f->unknown[i] = (int8_t)b.data[i] < 0;
        seeds[i] = (int8_t)b.data[i] >= threshold;
    }
    double *g = tc_edt2(seeds, w, h);
    if (!g) {
        free(seeds);
        enif_release_resource(f);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (size_t i = 0; i < n; i++) f->dist[i] = isinf(g[i]) ? 1e6f : (float)(sqrt(g[i]) * res);
    free(g);
    for (int r = 0; r < ph; r++)
        for (int c = 0; c < pw; c++)
            seeds[(size_t)r * pw + c] = r == 0 || c == 0 || r == ph - 1 || c == pw - 1 ||
                                        f->unknown[(size_t)(r - 1) * w + (c - 1)];
    g = tc_edt2(seeds, pw, ph);
    free(seeds);
    if (!g) {
        enif_release_resource(f);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (int r = 0; r < h; r++)
        for (int c = 0; c < w; c++) {
            double dc = g[(size_t)(r + 1) * pw + (c + 1)];
            f->udist[(size_t)r * w + c] = isinf(dc) ? 1e6f : (float)(sqrt(dc) * res);
    }
    free(g);
    ERL_NIF_TERM t = enif_make_resource(env, f);
    enif_release_resource(f);
    return t;
}

typedef struct {
    double sigma, z_hit, z_rand, range_max;
} Model;

/* beams: native doubles {x, y, angle, range} per beam: the sensor's
 * position and the beam's direction in the robot frame, and its range
 * (at or beyond range_max: no echo, skipped) */
typedef struct {
    const double *b;
    int n;
} Beams;

/* log-likelihood of the beams from pose (x, y, th), and how many beams
 * fell on known map */
static double score(const Field *f, const Beams *bs, const Model *m, double x, double y,
                    double th, int *known)
{
    double c = cos(th), s = sin(th), sum = 0.0;
    double rand_p = m->z_rand / m->range_max;
    double two_s2 = 2.0 * m->sigma * m->sigma;
    /* what a beam into unknown space scores: the likelihood of a beam a
     * sigma off an obstacle */
    double neutral = log(m->z_hit * exp(-0.5) + rand_p);
    int k = 0;
    /* a robot off the map, in unknown space or in an obstacle: every beam
     * as unlikely as noise */
    {
        long col = (long)floor((x - f->ox) / f->res), row = (long)floor((y - f->oy) / f->res);
        size_t cell = (size_t)row * f->w + col;
        if (col < 0 || row < 0 || col >= f->w || row >= f->h || f->unknown[cell] ||
            f->dist[cell] < 0.5 * f->res) {
            int used = 0;
            for (int i = 0; i < bs->n; i++)
                if (bs->b[4 * i + 3] < m->range_max) used++;
            *known = 0;
            return used * log(rand_p);
        }
    }
    for (int i = 0; i < bs->n; i++) {
        const double *q = bs->b + 4 * i;
        double r = q[3];
        if (!(r < m->range_max)) continue;
        double sx = x + c * q[0] - s * q[1], sy = y + s * q[0] + c * q[1];
        double ex = sx + r * cos(th + q[2]), ey = sy + r * sin(th + q[2]);
        long col = (long)floor((ex - f->ox) / f->res), row = (long)floor((ey - f->oy) / f->res);
        if (col < 0 || row < 0 || col >= f->w || row >= f->h) {
            sum += f->strict ? log(rand_p) : neutral;
            continue;
        }
        size_t cell = (size_t)row * f->w + col;
        if (f->unknown[cell] && !f->strict) {
            sum += neutral;
            continue;
        }
        double dd = f->dist[cell];
        sum += log(m->z_hit * exp(-dd * dd / two_s2) + rand_p);
        if (!f->unknown[cell]) k++;
    }
    *known = k;
    return sum;
}

static int get_model(ErlNifEnv *env, ERL_NIF_TERM t, Model *m)
{
    int arity;
    const ERL_NIF_TERM *e;
    return enif_get_tuple(env, t, &arity, &e) && arity == 4 && tc_number(env, e[0], &m->sigma) &&
           m->sigma > 0 && tc_number(env, e[1], &m->z_hit) && tc_number(env, e[2], &m->z_rand) &&
           tc_number(env, e[3], &m->range_max) && m->range_max > 0;
}

static int get_beams(ErlNifEnv *env, ERL_NIF_TERM t, Beams *bs)
{
    ErlNifBinary b;
    if (!enif_inspect_binary(env, t, &b) || b.size % (4 * sizeof(double)) != 0 ||
        b.size / (4 * sizeof(double)) > MAX_BEAMS)
        return 0;
    bs->b = (const double *)b.data;
    bs->n = (int)(b.size / (4 * sizeof(double)));
    for (int i = 0; i < 4 * bs->n; i++)
        if (!isfinite(bs->b[i])) return 0;
    return 1;
}

/* the arguments the field functions share: field, beams, model, {x, y, th} */
static int get_field_pose(ErlNifEnv *env, const ERL_NIF_TERM argv[], Field **f, Beams *bs,
                          Model *m, double *x, double *y, double *th)
{
    int arity;
    const ERL_NIF_TERM *e;
    return enif_get_resource(env, argv[0], FIELD_TYPE, (void **)f) && get_beams(env, argv[1], bs) &&
           get_model(env, argv[2], m) && enif_get_tuple(env, argv[3], &arity, &e) && arity == 3 &&
           tc_number(env, e[0], x) && tc_number(env, e[1], y) && tc_number(env, e[2], th);
}

/* field_score(field, beams, model, {x, y, th}) -> {log_likelihood, known} */
ERL_NIF_TERM tc_nif_field_score(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Field *f;
    Beams bs;
    Model m;
    int known;
    double x, y, th;
    if (!get_field_pose(env, argv, &f, &bs, &m, &x, &y, &th)) return enif_make_badarg(env);
    double l = score(f, &bs, &m, x, y, th, &known);
    return enif_make_tuple2(env, enif_make_double(env, l), enif_make_int(env, known));
}

/* field_fit(field, beams, model, {x, y, th}, tolerance) -> {near, judged}:
 * of the beams with an echo ending on known map (`judged`), those that
 * end within `tolerance` metres of an occupied cell (`near`). A beam
 * ending in unknown space, off the map, or within `tolerance` of either
 * and not of an occupied cell is not judged: what the map does not know
 * (a box in a rack's unknown inside, the open end of a map) says nothing
 * of the pose, even in a map given whole. A beam without echo is
 * judged (and not near) when the map has an occupied cell on its way,
 * 0.5 m or more short of the range: the laser would have seen it. */
ERL_NIF_TERM tc_nif_field_fit(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Field *f;
    Beams bs;
    Model m;
    double x, y, th, tol;
    if (!get_field_pose(env, argv, &f, &bs, &m, &x, &y, &th) || !tc_number(env, argv[4], &tol))
        return enif_make_badarg(env);
    double c = cos(th), s = sin(th);
    int near = 0, judged = 0;
    for (int i = 0; i < bs.n; i++) {
        const double *q = bs.b + 4 * i;
        double r = q[3];
        double sx = x + c * q[0] - s * q[1], sy = y + s * q[0] + c * q[1];
        if (!(r < m.range_max)) {
            double dx = cos(th + q[2]), dy = sin(th + q[2]), step = f->res / 2;
            for (double t = 0; t < m.range_max - 0.5; t += step) {
                long col = (long)floor((sx + t * dx - f->ox) / f->res);
                long row = (long)floor((sy + t * dy - f->oy) / f->res);
                if (col < 0 || row < 0 || col >= f->w || row >= f->h) break;
                size_t cell = (size_t)row * f->w + col;
                if (f->unknown[cell] && !f->strict) break;
                if (!f->unknown[cell] && f->dist[cell] <= 0.0f) {
                    judged++;
                    break;
                }
            }
            continue;
        }
        double ex = sx + r * cos(th + q[2]), ey = sy + r * sin(th + q[2]);
        long col = (long)floor((ex - f->ox) / f->res), row = (long)floor((ey - f->oy) / f->res);
        if (col < 0 || row < 0 || col >= f->w || row >= f->h) continue;
        size_t cell = (size_t)row * f->w + col;
        if (f->unknown[cell]) continue;
        if (f->dist[cell] <= tol) {
            judged++, near++;
        } else if (f->udist[cell] > tol) {
            judged++;
        }
    }
    return enif_make_tuple2(env, enif_make_int(env, near), enif_make_int(env, judged));
}

/* field_through(field, beams, model, {x, y, th}) -> {through, judged}: of
 * the beams with an echo whose path lies on known map (`judged`), those
 * that pass through an occupied cell more than 0.25 m short of their end
 * (`through`): a laser does not see through walls, so such beams
 * contradict the pose. A beam that ends short of the map's wall (a box, a
 * person the map does not hold) contradicts nothing. */
ERL_NIF_TERM tc_nif_field_through(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Field *f;
    Beams bs;
    Model m;
    double x, y, th;
    if (!get_field_pose(env, argv, &f, &bs, &m, &x, &y, &th)) return enif_make_badarg(env);
    double c = cos(th), s = sin(th);
    int through = 0, judged = 0;
    for (int i = 0; i < bs.n; i++) {
        const double *q = bs.b + 4 * i;
        double r = q[3];
        if (!(r < m.range_max)) continue;
        double sx = x + c * q[0] - s * q[1], sy = y + s * q[0] + c * q[1];
        double dx = cos(th + q[2]), dy = sin(th + q[2]);
        double stop = r - 0.25, step = f->res / 2;
        int known = 1, hit = 0;
        for (double t = 0; t < stop; t += step) {
            long col = (long)floor((sx + t * dx - f->ox) / f->res);
            long row = (long)floor((sy + t * dy - f->oy) / f->res);
            if (col < 0 || row < 0 || col >= f->w || row >= f->h) {
                known = 0;
                break;
            }
            size_t cell = (size_t)row * f->w + col;
            if (f->unknown[cell]) {
                known = 0;
                break;
            }
            if (f->dist[cell] <= 0.0f) {
                hit = 1;
                break;
            }
        }
        if (hit) through++, judged++;
        else if (known) judged++;
    }
    return enif_make_tuple2(env, enif_make_int(env, through), enif_make_int(env, judged));
}

/* field_search(field, beams, model, step, heading_steps, top, {x0, y0, x1,
 * y1} | {x0, y0, x1, y1, th, half}) -> [{ll, x, y, th}]: the best `top`
 * poses of a lattice over the field's free known cells within the box
 * (every `step` metres, `heading_steps` headings; with th and half only
 * the headings within half of th), best first */
ERL_NIF_TERM tc_nif_field_search(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Field *f;
    Beams bs;
    Model m;
    double step, bx0, by0, bx1, by1, bth = 0.0, bhalf = 4.0;
    int headings, top, arity;
    const ERL_NIF_TERM *box;
    if (!enif_get_resource(env, argv[0], FIELD_TYPE, (void **)&f) || !get_beams(env, argv[1], &bs) ||
        !get_model(env, argv[2], &m) || !tc_number(env, argv[3], &step) || step <= 0 ||
        !enif_get_int(env, argv[4], &headings) || headings < 1 || headings > 720 ||
        !enif_get_int(env, argv[5], &top) || top < 1 || top > 10000 ||
        !enif_get_tuple(env, argv[6], &arity, &box) || (arity != 4 && arity != 6) ||
        !tc_number(env, box[0], &bx0) || !tc_number(env, box[1], &by0) || !tc_number(env, box[2], &bx1) ||
        !tc_number(env, box[3], &by1) ||
        (arity == 6 && (!tc_number(env, box[4], &bth) || !tc_number(env, box[5], &bhalf))))
        return enif_make_badarg(env);
    int c0 = (int)fmax(0.0, floor((bx0 - f->ox) / f->res)), r0 = (int)fmax(0.0, floor((by0 - f->oy) / f->res));
    int c1 = (int)fmin(f->w - 1.0, floor((bx1 - f->ox) / f->res));
    int r1 = (int)fmin(f->h - 1.0, floor((by1 - f->oy) / f->res));
    double *best_l = malloc(top * sizeof(double)), *best_p = malloc(3 * top * sizeof(double));
    if (!best_l || !best_p) {
        free(best_l), free(best_p);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    int kept = 0;
    int stride = (int)fmax(1.0, round(step / f->res));
    /* the lattice's poses: a robot in known free space, clear of obstacles */
    /* (a box off the map has no rows or columns) */
    size_t rows = r1 >= r0 ? (size_t)(r1 - r0) / stride + 1 : 0;
    size_t cols = c1 >= c0 ? (size_t)(c1 - c0) / stride + 1 : 0;
    size_t cells = 0, cap = rows * cols + 1;
    int *lc = malloc(cap * 2 * sizeof(int));
    /* per cell, what a beam ending there scores (score()'s terms) */
    size_t n = (size_t)f->w * f->h;
    float *ll = malloc(n * sizeof(float));
    /* per heading, each beam's endpoint from the robot's centre */
    double *off = malloc(2 * (size_t)bs.n * sizeof(double));
    if (!lc || !ll || !off) {
        free(best_l), free(best_p), free(lc), free(ll), free(off);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    for (int r = r0 + stride / 2; r <= r1; r += stride)
        for (int c = c0 + stride / 2; c <= c1; c += stride) {
            size_t i = (size_t)r * f->w + c;
            if (f->unknown[i] || f->dist[i] < 0.15) continue;
            lc[2 * cells] = c, lc[2 * cells + 1] = r, cells++;
        }
    double rand_p = m.z_rand / m.range_max, two_s2 = 2.0 * m.sigma * m.sigma;
    double neutral = log(m.z_hit * exp(-0.5) + rand_p), off_map = f->strict ? log(rand_p) : neutral;
    for (size_t i = 0; i < n; i++) {
        double dd = f->dist[i];
        ll[i] = f->unknown[i] && !f->strict ? (float)neutral
                                            : (float)log(m.z_hit * exp(-dd * dd / two_s2) + rand_p);
    }
    /* the best a beam can score: a pose whose sum cannot reach the
     * worst kept one with its remaining beams at that best is dropped */
    double top_beam = log(m.z_hit + rand_p);
    for (int k = 0; k < headings; k++) {
        double th = -M_PI + TWO_PI * k / headings;
        if (fabs(tc_wrap(th - bth)) > bhalf) continue;
        double ct = cos(th), st = sin(th);
        int e = 0;
        for (int i = 0; i < bs.n; i++) {
            const double *q = bs.b + 4 * i;
            if (!(q[3] < m.range_max)) continue;
            off[2 * e] = ct * q[0] - st * q[1] + q[3] * cos(th + q[2]);
            off[2 * e + 1] = st * q[0] + ct * q[1] + q[3] * sin(th + q[2]);
            e++;
        }
        for (size_t j = 0; j < cells; j++) {
            int c = lc[2 * j], r = lc[2 * j + 1];
            double x = f->ox + (c + 0.5) * f->res, y = f->oy + (r + 0.5) * f->res;
            double l = 0.0, floor_l = kept < top ? -INFINITY : best_l[kept - 1];
            int i = 0;
            for (; i < e; i++) {
                long col = (long)floor((x + off[2 * i] - f->ox) / f->res);
                long row = (long)floor((y + off[2 * i + 1] - f->oy) / f->res);
                l += col < 0 || row < 0 || col >= f->w || row >= f->h ? off_map
                                                                       : ll[(size_t)row * f->w + col];
                /* checked every 8 beams: it cannot make the kept ones */
                if ((i & 7) == 7 && l + (e - 1 - i) * top_beam <= floor_l) break;
            }
            if (i < e) continue;
            if (kept < top || l > best_l[kept - 1]) {
                int at = kept < top ? kept++ : top - 1;
                while (at > 0 && best_l[at - 1] < l) {
                    best_l[at] = best_l[at - 1];
                    memcpy(best_p + 3 * at, best_p + 3 * (at - 1), 3 * sizeof(double));
                    at--;
                }
                best_l[at] = l;
                best_p[3 * at] = x, best_p[3 * at + 1] = y, best_p[3 * at + 2] = th;
            }
        }
    }
    free(lc), free(ll), free(off);
    ERL_NIF_TERM list = enif_make_list(env, 0);
    for (int j = kept - 1; j >= 0; j--)
        list = enif_make_list_cell(
            env,
            enif_make_tuple4(env, enif_make_double(env, best_l[j]),
                             enif_make_double(env, best_p[3 * j]),
                             enif_make_double(env, best_p[3 * j + 1]),
                             enif_make_double(env, best_p[3 * j + 2])),
            list);
    free(best_l), free(best_p);
    return list;
}

/* ---- the particle set ---- */

static Pf *pf_alloc(int n)
{
    Pf *p = enif_alloc_resource(PF_TYPE, sizeof(Pf));
    memset(p, 0, sizeof(Pf));
    p->n = n;
    p->x = malloc(n * sizeof(double));
    p->y = malloc(n * sizeof(double));
    p->th = malloc(n * sizeof(double));
    p->lw = calloc(n, sizeof(double));
    p->lock = enif_mutex_create("tc_mcl_pf");
    if (!p->x || !p->y || !p->th || !p->lw || !p->lock) {
        enif_release_resource(p);
        return NULL;
    }
    return p;
}

/* pf_new(poses, seed): poses a binary of native doubles {x, y, th} */
ERL_NIF_TERM tc_nif_pf_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    ErlNifUInt64 s;
    if (!enif_inspect_binary(env, argv[0], &b) || b.size == 0 ||
        b.size % (3 * sizeof(double)) != 0 || b.size / (3 * sizeof(double)) > MAX_PARTICLES ||
        !enif_get_uint64(env, argv[1], &s))
        return enif_make_badarg(env);
    int n = (int)(b.size / (3 * sizeof(double)));
    const double *q = (const double *)b.data;
    for (int i = 0; i < 3 * n; i++)
        if (!isfinite(q[i])) return enif_make_badarg(env);
    Pf *p = pf_alloc(n);
    if (!p) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    for (int i = 0; i < n; i++) p->x[i] = q[3 * i], p->y[i] = q[3 * i + 1], p->th[i] = tc_wrap(q[3 * i + 2]);
    seed(p, s);
    ERL_NIF_TERM t = enif_make_resource(env, p);
    enif_release_resource(p);
    return t;
}

/* pf_spread(pf, {x, y, th}, {sx, sy, sth}): every particle drawn anew
 * around a pose, weights equal */
ERL_NIF_TERM tc_nif_pf_spread(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    int a1, a2;
    const ERL_NIF_TERM *e1, *e2;
    double x, y, th, sx, sy, sth;
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p) ||
        !enif_get_tuple(env, argv[1], &a1, &e1) || a1 != 3 || !tc_number(env, e1[0], &x) ||
        !tc_number(env, e1[1], &y) || !tc_number(env, e1[2], &th) || !enif_get_tuple(env, argv[2], &a2, &e2) ||
        a2 != 3 || !tc_number(env, e2[0], &sx) || !tc_number(env, e2[1], &sy) || !tc_number(env, e2[2], &sth))
        return enif_make_badarg(env);
    enif_mutex_lock(p->lock);
    for (int i = 0; i < p->n; i++) {
        p->x[i] = x + sx * gauss(p);
        p->y[i] = y + sy * gauss(p);
        p->th[i] = tc_wrap(th + sth * gauss(p));
        p->lw[i] = 0.0;
    }
    enif_mutex_unlock(p->lock);
    return M_OK;
}

/* pf_transform(pf, {x, y, th}, {x', y', th'}): every particle carried by
 * the rigid motion that takes the first pose to the second (a map
 * corrected under the robot: its frame moved) */
ERL_NIF_TERM tc_nif_pf_transform(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    int a1, a2;
    const ERL_NIF_TERM *e1, *e2;
    double fx, fy, fth, tx, ty, tth;
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p) ||
        !enif_get_tuple(env, argv[1], &a1, &e1) || a1 != 3 || !tc_number(env, e1[0], &fx) ||
        !tc_number(env, e1[1], &fy) || !tc_number(env, e1[2], &fth) || !enif_get_tuple(env, argv[2], &a2, &e2) ||
        a2 != 3 || !tc_number(env, e2[0], &tx) || !tc_number(env, e2[1], &ty) || !tc_number(env, e2[2], &tth))
        return enif_make_badarg(env);
    double d = tth - fth, c = cos(d), s = sin(d);
    enif_mutex_lock(p->lock);
    for (int i = 0; i < p->n; i++) {
        double rx = p->x[i] - fx, ry = p->y[i] - fy;
        p->x[i] = tx + c * rx - s * ry;
        p->y[i] = ty + s * rx + c * ry;
        p->th[i] = tc_wrap(p->th[i] + d);
    }
    enif_mutex_unlock(p->lock);
    return M_OK;
}

/* pf_move(pf, {dx, dy, dth}, {a1, a2, a3, a4}): the odometry motion model
 * (rot1, trans, rot2 with noise from the alphas) */
ERL_NIF_TERM tc_nif_pf_move(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    int a1, a2;
    const ERL_NIF_TERM *e1, *e2;
    double dx, dy, dth, al[4];
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p) ||
        !enif_get_tuple(env, argv[1], &a1, &e1) || a1 != 3 || !tc_number(env, e1[0], &dx) ||
        !tc_number(env, e1[1], &dy) || !tc_number(env, e1[2], &dth) || !enif_get_tuple(env, argv[2], &a2, &e2) ||
        a2 != 4)
        return enif_make_badarg(env);
    for (int k = 0; k < 4; k++)
        if (!tc_number(env, e2[k], &al[k]) || al[k] < 0) return enif_make_badarg(env);
    double trans = sqrt(dx * dx + dy * dy);
    /* a backward move turns by pi less (Probabilistic Robotics' remark) */
    double rot1 = trans < 1e-6 ? 0.0 : atan2(dy, dx);
    int back = 0;
    if (fabs(rot1) > M_PI / 2) {
        back = 1;
        rot1 = tc_wrap(rot1 + M_PI);
    }
    double rot2 = tc_wrap(dth - rot1);
    enif_mutex_lock(p->lock);
    for (int i = 0; i < p->n; i++) {
        double r1 = rot1 - sqrt(al[0] * rot1 * rot1 + al[1] * trans * trans) * gauss(p);
        double t = trans - sqrt(al[2] * trans * trans + al[3] * (rot1 * rot1 + rot2 * rot2)) * gauss(p);
        double r2 = rot2 - sqrt(al[0] * rot2 * rot2 + al[1] * trans * trans) * gauss(p);
        double dir = back ? -1.0 : 1.0;
        p->x[i] += dir * t * cos(p->th[i] + r1);
        p->y[i] += dir * t * sin(p->th[i] + r1);
        p->th[i] = tc_wrap(p->th[i] + r1 + r2);
    }
    enif_mutex_unlock(p->lock);
    return M_OK;
}

/* pf_weigh(pf, field, beams, model, scale) -> {mean_likelihood, n_eff,
 * known}: every particle's log-weight grows by its scan's log-likelihood
 * times scale (below 1: tempered, while hypotheses should live on); the
 * weights are then normalised. mean_likelihood is the mean over
 * particles of exp(log-likelihood / beams), a per-beam figure for the
 * augmented-MCL averages; known the best particle's beams on known map */
ERL_NIF_TERM tc_nif_pf_weigh(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    Field *f;
    Beams bs;
    Model m;
    double scale;
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p) ||
        !enif_get_resource(env, argv[1], FIELD_TYPE, (void **)&f) || !get_beams(env, argv[2], &bs) ||
        !get_model(env, argv[3], &m) || !tc_number(env, argv[4], &scale) || scale <= 0 || scale > 1)
        return enif_make_badarg(env);
    enif_mutex_lock(p->lock);
    double mean = 0.0, top = -INFINITY;
    int used = 0, best_known = 0;
    for (int i = 0; i < bs.n; i++)
        if (bs.b[4 * i + 3] < m.range_max) used++;
    for (int i = 0; i < p->n; i++) {
        int known;
        double l = score(f, &bs, &m, p->x[i], p->y[i], p->th[i], &known);
        mean += used ? exp(l / used) : 1.0;
        p->lw[i] += scale * l;
        if (p->lw[i] > top) top = p->lw[i], best_known = known;
    }
    mean /= p->n;
    double sum = 0.0, sum2 = 0.0;
    for (int i = 0; i < p->n; i++) {
        p->lw[i] -= top;
        double w = exp(p->lw[i]);
        sum += w;
        sum2 += w * w;
    }
    double lsum = log(sum);
    for (int i = 0; i < p->n; i++) p->lw[i] -= lsum;
    double n_eff = sum * sum / sum2;
    enif_mutex_unlock(p->lock);
    return enif_make_tuple3(env, enif_make_double(env, mean), enif_make_double(env, n_eff),
                            enif_make_int(env, best_known));
}

/* pf_resample(pf, random_share, {x0, y0, x1, y1} | poses): low-variance
 * resampling; a share of the particles (augmented MCL's) replaced by
 * poses drawn from `poses` (a binary of {x, y, th} doubles) */
ERL_NIF_TERM tc_nif_pf_resample(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    double share;
    ErlNifBinary poses;
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p) || !tc_number(env, argv[1], &share) ||
        share < 0 || share > 1 || !enif_inspect_binary(env, argv[2], &poses) ||
        poses.size % (3 * sizeof(double)) != 0)
        return enif_make_badarg(env);
    const double *q = (const double *)poses.data;
    int nq = (int)(poses.size / (3 * sizeof(double)));
    enif_mutex_lock(p->lock);
    int n = p->n;
    double *x = malloc(n * sizeof(double)), *y = malloc(n * sizeof(double)),
           *th = malloc(n * sizeof(double));
    if (!x || !y || !th) {
        free(x), free(y), free(th);
        enif_mutex_unlock(p->lock);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    double step = 1.0 / n, u = uniform(p) * step, c = exp(p->lw[0]);
    int j = 0;
    for (int i = 0; i < n; i++) {
        double target = u + i * step;
        while (target > c && j < n - 1) c += exp(p->lw[++j]);
        if (nq > 0 && uniform(p) < share) {
            int k = (int)(uniform(p) * nq);
            if (k >= nq) k = nq - 1;
            x[i] = q[3 * k], y[i] = q[3 * k + 1], th[i] = tc_wrap(q[3 * k + 2]);
        } else {
            x[i] = p->x[j], y[i] = p->y[j], th[i] = p->th[j];
        }
    }
    memcpy(p->x, x, n * sizeof(double));
    memcpy(p->y, y, n * sizeof(double));
    memcpy(p->th, th, n * sizeof(double));
    double lw = -log((double)n);
    for (int i = 0; i < n; i++) p->lw[i] = lw;
    free(x), free(y), free(th);
    enif_mutex_unlock(p->lock);
    return M_OK;
}

/* pf_estimate(pf) -> {{x, y, th}, [[cxx, cxy, cxt], [..], [..]], n_eff} */
ERL_NIF_TERM tc_nif_pf_estimate(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p)) return enif_make_badarg(env);
    enif_mutex_lock(p->lock);
    double mx = 0, my = 0, mc = 0, ms = 0, sw = 0, sw2 = 0;
    for (int i = 0; i < p->n; i++) {
        double w = exp(p->lw[i]);
        mx += w * p->x[i], my += w * p->y[i];
        mc += w * cos(p->th[i]), ms += w * sin(p->th[i]);
        sw += w, sw2 += w * w;
    }
    mx /= sw, my /= sw;
    double mt = atan2(ms, mc);
    double c[3][3] = {{0}};
    for (int i = 0; i < p->n; i++) {
        double w = exp(p->lw[i]) / sw;
        double d[3] = {p->x[i] - mx, p->y[i] - my, tc_wrap(p->th[i] - mt)};
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) c[a][b] += w * d[a] * d[b];
    }
    enif_mutex_unlock(p->lock);
    ERL_NIF_TERM rows[3];
    for (int a = 0; a < 3; a++)
        rows[a] = enif_make_list3(env, enif_make_double(env, c[a][0]), enif_make_double(env, c[a][1]),
                                  enif_make_double(env, c[a][2]));
    return enif_make_tuple3(
        env,
        enif_make_tuple3(env, enif_make_double(env, mx), enif_make_double(env, my),
                         enif_make_double(env, mt)),
        enif_make_list3(env, rows[0], rows[1], rows[2]), enif_make_double(env, sw * sw / sw2));
}

/* pf_mode(pf, radius) -> {{x, y, th}, share}: the weighted mean pose
 * (circular mean heading) of the particles within `radius` metres of the
 * particle of the largest weight, and their share of the weight: the
 * place the cloud holds most likely, when it is split between places */
ERL_NIF_TERM tc_nif_pf_mode(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    double radius;
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p) || !tc_number(env, argv[1], &radius) ||
        radius < 0)
        return enif_make_badarg(env);
    enif_mutex_lock(p->lock);
    int best = 0;
    for (int i = 1; i < p->n; i++)
        if (p->lw[i] > p->lw[best]) best = i;
    double bx = p->x[best], by = p->y[best], r2 = radius * radius;
    double mx = 0, my = 0, mc = 0, ms = 0, sw = 0, all = 0;
    for (int i = 0; i < p->n; i++) {
        double w = exp(p->lw[i]);
        all += w;
        double dx = p->x[i] - bx, dy = p->y[i] - by;
        if (dx * dx + dy * dy > r2) continue;
        mx += w * p->x[i], my += w * p->y[i];
        mc += w * cos(p->th[i]), ms += w * sin(p->th[i]);
        sw += w;
    }
    if (!(sw > 0)) {
        /* weights too small to sum: the best particle alone */
        mx = bx, my = by, mc = cos(p->th[best]), ms = sin(p->th[best]), sw = 1.0, all = 1.0;
    } else {
        mx /= sw, my /= sw;
    }
    enif_mutex_unlock(p->lock);
    return enif_make_tuple2(
        env,
        enif_make_tuple3(env, enif_make_double(env, mx), enif_make_double(env, my),
                         enif_make_double(env, atan2(ms, mc))),
        enif_make_double(env, all > 0 ? sw / all : 1.0));
}

/* pf_best(pf) -> {x, y, th}: the particle of the largest weight */
ERL_NIF_TERM tc_nif_pf_best(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p)) return enif_make_badarg(env);
    enif_mutex_lock(p->lock);
    int best = 0;
    for (int i = 1; i < p->n; i++)
        if (p->lw[i] > p->lw[best]) best = i;
    ERL_NIF_TERM t = enif_make_tuple3(env, enif_make_double(env, p->x[best]),
                                      enif_make_double(env, p->y[best]),
                                      enif_make_double(env, p->th[best]));
    enif_mutex_unlock(p->lock);
    return t;
}

/* pf_sample(pf, k) -> [{x, y, th}]: k particles spread evenly over the set */
ERL_NIF_TERM tc_nif_pf_sample(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Pf *p;
    int k;
    if (!enif_get_resource(env, argv[0], PF_TYPE, (void **)&p) || !enif_get_int(env, argv[1], &k) ||
        k < 0)
        return enif_make_badarg(env);
    enif_mutex_lock(p->lock);
    if (k > p->n) k = p->n;
    ERL_NIF_TERM list = enif_make_list(env, 0);
    for (int j = k - 1; j >= 0; j--) {
        int i = (int)((long)j * p->n / (k ? k : 1));
        list = enif_make_list_cell(env,
                                   enif_make_tuple3(env, enif_make_double(env, p->x[i]),
                                                    enif_make_double(env, p->y[i]),
                                                    enif_make_double(env, p->th[i])),
                                   list);
    }
    enif_mutex_unlock(p->lock);
    return list;
}
