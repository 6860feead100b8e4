/*
 * tc_raycast: the ray-casting NIF of the ThinkingCap simulator
 * (ThinkingCap.Sim.Raycast). See that module's documentation for the API.
 *
 * A world is a resource holding
 *   - static line segments (walls, doors) indexed by a uniform grid of
 *     buckets (~0.5-1 m), each segment with an enabled flag;
 *   - an optional occupancy grid, stored as one byte per cell (in 8x8-cell
 *     tiles, one cache line each): 255 for an obstacle cell, otherwise a
 *     conservative free-space skip distance in cells taken from an exact
 *     Euclidean distance transform (Felzenszwalb-Huttenlocher),
 *     floor(D - 1.5) clamped to 0..254 where D is the centre-to-centre
 *     distance to the nearest obstacle cell. Any point of a cell is more
 *     than D - sqrt(2) > code cells away from every obstacle cell, so a ray
 *     may jump ahead by `code` cells and land strictly in free space; where
 *     the code is 0 (within 2.5 cells of obstacles) rays step cell by cell
 *     (Amanatides-Woo), so the hit is the exact entry point of the first
 *     obstacle cell along the ray;
 *   - dynamic circular bodies, indexed by a uniform grid of buckets (by
 *     centre, rebuilt by every set_bodies), so that a scan, a cast or a
 *     clearance query looks only at the bodies near it: the cost does not
 *     grow with the number of bodies, only with their density. A scan
 *     then sorts the bodies within its reach into sectors of direction
 *     around the robot, so a ray's first leg tests only the bodies of its
 *     sector.
 * Readers (casts, clearance) take the world's read lock, setters the write
 * lock, so several processes cast concurrently.
 */
#include <erl_nif.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "tc_nif.h"

#define CODE_OBST 255u
#define CODE_MAX_SKIP 254.0
#define SKIP_MIN 1u
/* a tile's skip from which a ray jumps without reading the cell */
#define COARSE_SKIP_MIN 2u
/* rays (counting the bounce budget) above which a call goes to a dirty
 * CPU scheduler */
#define DIRTY_RAY_BUDGET 4000
/* restart points are nudged this far off a surface after a reflection */
#define NUDGE_CELLS 1e-6
#define NUDGE_M 1e-9
#define BIG 1e20
#define GROUP_DOUBLES 20
#define GROUP_BYTES (GROUP_DOUBLES * 8)
#define GROUPS_HEADER 16
#define MAX_BOUNCES_LIMIT 1000

enum { HIT_NONE = 0, HIT_GRID, HIT_SEG, HIT_BODY };

typedef struct {
    double ax, ay, ex, ey; /* a + s e, s in [0, 1] */
    double nx, ny;         /* unit normal (left of e), 0 if degenerate */
    double inv_len2;       /* 1/|e|^2, 0 if degenerate */
} Seg;

typedef struct {
    double x, y, r;
    int id;
} Body;

/* The bodies and their bucket grid. A body is listed in the bucket of its
 * centre (clamped to the grid, so bodies outside it sit in the edge
 * buckets); a query for everything within r of a point visits the buckets
 * within r + rmax, clamped the same way. */
typedef struct {
    int n;
    Body *b; /* by id */
    double rmax, x0, y0, inv;
    int w, h;
    int32_t *start, *items; /* bucket k: items[start[k] .. start[k + 1]) */
} BodyIndex;

typedef struct {
    ErlNifRWLock *lock;
    /* segments and their bucket index */
    int nseg, nseg_on;
    Seg *seg;
    uint8_t *seg_on;
    double sx0, sy0, sh, sinvh;
    int sw, sgh;
    int32_t *sstart, *sitems;
    /* occupancy grid */
    int has_grid, gw, gh, gtw; /* gtw: tiles per row */
    double res, inv_res, gox, goy, gc, gs;
    uint8_t *code; /* in 8x8-cell tiles of 64 bytes, see cell_index */
    /* per tile, the least skip of its cells (an obstacle counts 0): a ray
     * anywhere in the tile may jump that far. 64 times smaller than the
     * cells, so it stays in the caches when the map does not: a ray
     * crossing open space reads it and not the cells (at 1,000 robots in a
     * 150 m x 100 m map, most of a scan's time was spent waiting for
     * cells to come from memory) */
    uint8_t *coarse;
    /* bodies */
    BodyIndex bodies;
} World;

typedef struct {
    double t;
    int kind, id;
    const Body *body;
    /* grid hits, in the grid frame (cell units) */
    int cx, cy, face, stepx, stepy;
    double vx, vy;
} Hit;

typedef struct {
    const World *w;
    const Body *b;
    int nb;
} Ctx;

typedef struct {
    double range, px, py;
    int kind, id, bounces;
} RayResult;

static ErlNifResourceType *WORLD_RT;
static ERL_NIF_TERM A_OK, A_ERROR, A_NIL, A_TRUE, A_FALSE, A_NONE, A_GRID, A_SEGMENT,
    A_BODY, A_RANGE, A_HIT, A_BOUNCES, A_ID;

/* ------------------------------------------------------------------ */
/* helpers                                                              */

static inline double ld(const unsigned char *p)
{
    double d;
    memcpy(&d, p, 8);
    return d;
}

static ERL_NIF_TERM error_msg(ErlNifEnv *env, const char *msg)
{
    ERL_NIF_TERM bin;
    size_t n = strlen(msg);
    unsigned char *p = enif_make_new_binary(env, n, &bin);
    memcpy(p, msg, n);
    return enif_make_tuple2(env, A_ERROR, bin);
}

/* Cells are stored in 8x8 tiles (one 64-byte cache line each), so that a
 * ray stepping in any direction stays within a line for several cells. */
static inline size_t cell_index(int tw, int cx, int cy)
{
    return ((size_t)((cy >> 3) * tw + (cx >> 3)) << 6) | (size_t)((cy & 7) << 3) | (size_t)(cx & 7);
}

static inline int clampi(int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); }

static inline double clampd(double v, double lo, double hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

/* splitmix64: a counter-based generator, seeded per group */
static inline uint64_t splitmix64(uint64_t *s)
{
    uint64_t z = (*s += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

/* uniform in [0, 1) */
static inline double uniform(uint64_t *s) { return (double)(splitmix64(s) >> 11) * 0x1.0p-53; }

/* Standard Gaussians by the ziggurat (Marsaglia & Tsang 2000): 128
 * layers of equal area under the density; a draw picks a layer and a
 * point across it, and is kept at once when the point lies inside the
 * layer's rectangle below the curve (98.8 % of draws: one splitmix64
 * draw and a multiply, where the polar method took a logarithm, a square
 * root and a division for every two). The layer comes from the draw's
 * low bits and the point from its high half: the original took both
 * from the same 32 bits, a known flaw. Tables made at load. */
#define ZIG_R 3.442619855899
static uint32_t ZIG_K[128];
static double ZIG_W[128], ZIG_F[128];

static void ziggurat_setup(void)
{
    const double m1 = 2147483648.0, v = 9.91256303526217e-3;
    double dn = ZIG_R, tn = dn, q = v / exp(-0.5 * dn * dn);
    ZIG_K[0] = (uint32_t)((dn / q) * m1);
    ZIG_K[1] = 0;
    ZIG_W[0] = q / m1;
    ZIG_W[127] = dn / m1;
    ZIG_F[0] = 1.0;
    ZIG_F[127] = exp(-0.5 * dn * dn);
    for (int i = 126; i >= 1; i--) {
        dn = sqrt(-2.0 * log(v / dn + exp(-0.5 * dn * dn)));
        ZIG_K[i + 1] = (uint32_t)((dn / tn) * m1);
        tn = dn;
        ZIG_F[i] = exp(-0.5 * dn * dn);
        ZIG_W[i] = dn / m1;
    }
}

static double gaussian(uint64_t *rng)
{
    for (;;) {
        const uint64_t b = splitmix64(rng);
        const int iz = (int)(b & 127);
        const int32_t hz = (int32_t)(uint32_t)(b >> 32);
        const uint32_t az = hz < 0 ? 0u - (uint32_t)hz : (uint32_t)hz;
        const double x = hz * ZIG_W[iz];
        if (az < ZIG_K[iz]) return x;
        if (iz == 0) {
            /* the tail beyond ZIG_R (Marsaglia 1964); 1 - uniform is in
             * (0, 1] */
            double t, y;
            do {
                t = -log(1.0 - uniform(rng)) / ZIG_R;
                y = -log(1.0 - uniform(rng));
            } while (y + y < t * t);
            return hz > 0 ? ZIG_R + t : -ZIG_R - t;
        }
        /* the wedge between the rectangle and the curve */
        if (ZIG_F[iz] + uniform(rng) * (ZIG_F[iz - 1] - ZIG_F[iz]) < exp(-0.5 * x * x)) return x;
    }
}

/* ------------------------------------------------------------------ */
/* world lifetime                                                       */

static void body_index_free(BodyIndex *x)
{
    if (x->b) enif_free(x->b);
    if (x->start) enif_free(x->start);
    if (x->items) enif_free(x->items);
    memset(x, 0, sizeof(*x));
}

/* the bucket of coordinate u (in bucket units) on an axis of n buckets;
 * outside (and NaN) clamps to the edges */
static inline int bucket_of(double u, int n)
{
    if (!(u >= 0)) return 0;
    if (u >= n) return n - 1;
    return (int)u;
}

/* Builds the bucket grid of x->n bodies x->b. Buckets cover the bounding
 * box of the centres within BODY_BOX of the origin, about one body per
 * bucket (at least 0.5 m), at most 4n + 16 of them. */
#define BODY_BOX 1e7
static int body_index_build(BodyIndex *x)
{
    const int n = x->n;
    double minx = BIG, miny = BIG, maxx = -BIG, maxy = -BIG, rmax = 0;
    int near = 0;
    for (int i = 0; i < n; i++) {
        const Body *b = &x->b[i];
        if (b->r > rmax) rmax = b->r;
        if (!(fabs(b->x) <= BODY_BOX && fabs(b->y) <= BODY_BOX)) continue;
        near++;
        minx = fmin(minx, b->x);
        maxx = fmax(maxx, b->x);
        miny = fmin(miny, b->y);
        maxy = fmax(maxy, b->y);
    }
    if (near == 0) minx = miny = maxx = maxy = 0;
    double ex = fmax(maxx - minx, 1e-3), ey = fmax(maxy - miny, 1e-3);
    double h = fmax(sqrt(ex * ey / (near > 0 ? near : 1)), 0.5);
    while ((floor(ex / h) + 1) * (floor(ey / h) + 1) > 4.0 * n + 16)
        h *= 2;
    x->rmax = rmax;
    x->x0 = minx;
    x->y0 = miny;
    x->inv = 1.0 / h;
    x->w = (int)floor(ex / h) + 1;
    x->h = (int)floor(ey / h) + 1;
    const int nb = x->w * x->h;
    x->start = enif_alloc(((size_t)nb + 1) * sizeof(int32_t));
    x->items = enif_alloc(((size_t)n + 1) * sizeof(int32_t));
    int32_t *cell = enif_alloc(((size_t)n + 1) * sizeof(int32_t));
    if (!x->start || !x->items || !cell) {
        if (cell) enif_free(cell);
        return 0;
    }
    memset(x->start, 0, ((size_t)nb + 1) * sizeof(int32_t));
    for (int i = 0; i < n; i++) {
        const Body *b = &x->b[i];
        /* a body parked far away (out of the box) is in no bucket: it
         * would crowd the corner bucket it is clamped to, and every
         * query near that corner would look at it */
        if (!(fabs(b->x) <= BODY_BOX && fabs(b->y) <= BODY_BOX)) {
            cell[i] = -1;
            continue;
        }
        cell[i] = bucket_of((b->y - miny) * x->inv, x->h) * x->w +
                  bucket_of((b->x - minx) * x->inv, x->w);
        x->start[cell[i] + 1]++;
    }
    for (int k = 0; k < nb; k++)
        x->start[k + 1] += x->start[k];
    /* ids ascending within a bucket */
    for (int i = 0; i < n; i++)
        if (cell[i] >= 0) x->items[x->start[cell[i]]++] = i;
    for (int k = nb; k > 0; k--)
        x->start[k] = x->start[k - 1];
    x->start[0] = 0;
    enif_free(cell);
    return 1;
}

/* Copies into `out` the bodies other than `exclude` that reach into the box
 * [x0, x1] x [y0, y1]; with `disc`, only those that also reach within
 * `radius` of (cx, cy). Returns the count. */
static int bodies_near(const BodyIndex *x, int exclude, double x0, double y0, double x1,
                       double y1, int disc, double cx, double cy, double radius, Body *out)
{
    if (x->n == 0) return 0;
    const double m = x->rmax;
    const int i0 = bucket_of((x0 - m - x->x0) * x->inv, x->w);
    const int i1 = bucket_of((x1 + m - x->x0) * x->inv, x->w);
    const int j0 = bucket_of((y0 - m - x->y0) * x->inv, x->h);
    const int j1 = bucket_of((y1 + m - x->y0) * x->inv, x->h);
    int n = 0;
    for (int j = j0; j <= j1; j++)
        for (int k = x->start[j * x->w + i0]; k < x->start[j * x->w + i1 + 1]; k++) {
            const Body *b = &x->b[x->items[k]];
            if (b->id == exclude) continue;
            if (b->x + b->r < x0 || b->x - b->r > x1 || b->y + b->r < y0 || b->y - b->r > y1)
                continue;
            if (disc) {
                double dx = b->x - cx, dy = b->y - cy, rr = radius + b->r;
                if (dx * dx + dy * dy > rr * rr) continue;
            }
            out[n++] = *b;
        }
    return n;
}

static void world_free(World *w)
{
    if (w->seg) enif_free(w->seg);
    if (w->seg_on) enif_free(w->seg_on);
    if (w->sstart) enif_free(w->sstart);
    if (w->sitems) enif_free(w->sitems);
    if (w->code) enif_free(w->code);
    if (w->coarse) enif_free(w->coarse);
    body_index_free(&w->bodies);
    w->seg = NULL;
    w->seg_on = NULL;
    w->sstart = w->sitems = NULL;
    w->code = NULL;
    w->coarse = NULL;
}

static void world_dtor(ErlNifEnv *env, void *obj)
{
    World *w = obj;
    (void)env;
    world_free(w);
    if (w->lock) enif_rwlock_destroy(w->lock);
}

/* ------------------------------------------------------------------ */
/* building                                                             */

/* 1-D squared Euclidean distance transform of a sampled function
 * (Felzenszwalb & Huttenlocher 2012). */
static void dt1d(const double *f, int n, double *d, int *v, double *z)
{
    int k = 0;
    v[0] = 0;
    z[0] = -BIG;
    z[1] = BIG;
    for (int q = 1; q < n; q++) {
        double s;
        for (;;) {
            int p = v[k];
            s = ((f[q] + (double)q * q) - (f[p] + (double)p * p)) / (2.0 * (q - p));
            if (s <= z[k] && k > 0)
                k--;
            else
                break;
        }
        if (s <= z[k]) {
            /* k == 0 and the new parabola is below everywhere */
            v[0] = q;
            z[0] = -BIG;
            z[1] = BIG;
            continue;
        }
        k++;
        v[k] = q;
        z[k] = s;
        z[k + 1] = BIG;
    }
    k = 0;
    for (int q = 0; q < n; q++) {
        while (z[k + 1] < q)
            k++;
        double dq = (double)(q - v[k]);
        d[q] = dq * dq + f[v[k]];
    }
}

static int build_grid(World *w, const signed char *data)
{
    const int W = w->gw, H = w->gh;
    const size_t n = (size_t)W * H;
    const int m = W > H ? W : H;
    double *d2 = enif_alloc(n * sizeof(double));
    double *f = enif_alloc((size_t)m * sizeof(double));
    double *d = enif_alloc((size_t)m * sizeof(double));
    double *z = enif_alloc((size_t)(m + 1) * sizeof(double));
    int *v = enif_alloc((size_t)m * sizeof(int));
    w->gtw = (W + 7) / 8;
    const size_t tiled = (size_t)w->gtw * ((H + 7) / 8) * 64;
    w->code = enif_alloc(tiled);
    w->coarse = enif_alloc(tiled / 64);
    if (!d2 || !f || !d || !z || !v || !w->code || !w->coarse) {
        if (d2) enif_free(d2);
        if (f) enif_free(f);
        if (d) enif_free(d);
        if (z) enif_free(z);
        if (v) enif_free(v);
        return 0;
    }
    for (size_t i = 0; i < n; i++)
        d2[i] = data[i] >= 50 ? 0.0 : BIG;
    for (int x = 0; x < W; x++) {
        for (int y = 0; y < H; y++)
            f[y] = d2[(size_t)y * W + x];
        dt1d(f, H, d, v, z);
        for (int y = 0; y < H; y++)
            d2[(size_t)y * W + x] = d[y];
    }
    for (int y = 0; y < H; y++) {
        double *row = d2 + (size_t)y * W;
        memcpy(f, row, (size_t)W * sizeof(double));
        dt1d(f, W, row, v, z);
    }
    memset(w->code, 0, tiled);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            size_t i = (size_t)y * W + x;
            uint8_t c;
            if (data[i] >= 50) {
                c = CODE_OBST;
            } else {
                double s = floor(sqrt(d2[i]) - 1.5);
                c = (uint8_t)clampd(s, 0.0, CODE_MAX_SKIP);
            }
            w->code[cell_index(w->gtw, x, y)] = c;
        }
    for (size_t tile = 0; tile < tiled / 64; tile++) {
        unsigned least = CODE_OBST;
        for (int k = 0; k < 64; k++) {
            unsigned c = w->code[tile * 64 + k];
            if (c == CODE_OBST) c = 0;
            if (c < least) least = c;
        }
        w->coarse[tile] = (uint8_t)least;
    }
    enif_free(d2);
    enif_free(f);
    enif_free(d);
    enif_free(z);
    enif_free(v);
    return 1;
}

/* does segment s touch the square [x0,x1]x[y0,y1]? (bounding boxes are
 * known to overlap) */
static int seg_box(const Seg *s, double x0, double y0, double x1, double y1)
{
    if (s->inv_len2 == 0.0) return 1;
    double cx[4] = {x0, x1, x0, x1}, cy[4] = {y0, y0, y1, y1};
    int pos = 0, neg = 0;
    for (int i = 0; i < 4; i++) {
        double side = (cx[i] - s->ax) * s->ey - (cy[i] - s->ay) * s->ex;
        if (side >= 0) pos++;
        if (side <= 0) neg++;
    }
    return pos > 0 && neg > 0;
}

static int build_seg_index(World *w)
{
    const int n = w->nseg;
    double minx = BIG, miny = BIG, maxx = -BIG, maxy = -BIG;
    for (int i = 0; i < n; i++) {
        const Seg *s = &w->seg[i];
        double xs[2] = {s->ax, s->ax + s->ex}, ys[2] = {s->ay, s->ay + s->ey};
        for (int k = 0; k < 2; k++) {
            minx = fmin(minx, xs[k]);
            maxx = fmax(maxx, xs[k]);
            miny = fmin(miny, ys[k]);
            maxy = fmax(maxy, ys[k]);
        }
    }
    double ex = fmax(maxx - minx, 1e-3), ey = fmax(maxy - miny, 1e-3);
    double h = clampd(sqrt(ex * ey / n), 0.5, 1.0);
    double pad = 1e-6 * (1.0 + fmax(fabs(minx), fabs(maxx)) + fmax(fabs(miny), fabs(maxy)));
    minx -= pad;
    miny -= pad;
    ex += 2 * pad;
    ey += 2 * pad;
    for (;;) {
        double cells = (floor(ex / h) + 1) * (floor(ey / h) + 1);
        if (cells <= 4.0e6) break;
        h *= 2;
    }
    w->sh = h;
    w->sinvh = 1.0 / h;
    w->sx0 = minx;
    w->sy0 = miny;
    w->sw = (int)floor(ex / h) + 1;
    w->sgh = (int)floor(ey / h) + 1;
    const int nb = w->sw * w->sgh;
    w->sstart = enif_alloc(((size_t)nb + 1) * sizeof(int32_t));
    if (!w->sstart) return 0;
    memset(w->sstart, 0, ((size_t)nb + 1) * sizeof(int32_t));
    int32_t *cursor = NULL;
    for (int pass = 0; pass < 2; pass++) {
        for (int i = 0; i < n; i++) {
            const Seg *s = &w->seg[i];
            double x0 = fmin(s->ax, s->ax + s->ex), x1 = fmax(s->ax, s->ax + s->ex);
            double y0 = fmin(s->ay, s->ay + s->ey), y1 = fmax(s->ay, s->ay + s->ey);
            int i0 = clampi((int)floor((x0 - w->sx0) * w->sinvh), 0, w->sw - 1);
            int i1 = clampi((int)floor((x1 - w->sx0) * w->sinvh), 0, w->sw - 1);
            int j0 = clampi((int)floor((y0 - w->sy0) * w->sinvh), 0, w->sgh - 1);
            int j1 = clampi((int)floor((y1 - w->sy0) * w->sinvh), 0, w->sgh - 1);
            double eps = 1e-9 * h;
            for (int j = j0; j <= j1; j++)
                for (int k = i0; k <= i1; k++) {
                    double bx = w->sx0 + k * h, by = w->sy0 + j * h;
                    if (!seg_box(s, bx - eps, by - eps, bx + h + eps, by + h + eps)) continue;
                    int b = j * w->sw + k;
                    if (pass == 0)
                        w->sstart[b + 1]++;
                    else
                        w->sitems[cursor[b]++] = i;
                }
        }
        if (pass == 0) {
            for (int b = 0; b < nb; b++)
                w->sstart[b + 1] += w->sstart[b];
            w->sitems = enif_alloc(((size_t)w->sstart[nb] + 1) * sizeof(int32_t));
            cursor = enif_alloc((size_t)nb * sizeof(int32_t));
            if (!w->sitems || !cursor) {
                if (cursor) enif_free(cursor);
                return 0;
            }
            memcpy(cursor, w->sstart, (size_t)nb * sizeof(int32_t));
        }
    }
    enif_free(cursor);
    return 1;
}

/* ------------------------------------------------------------------ */
/* tracing                                                              */

/* clips the ray's [t0, t1] to the slab 0 <= u + t v < n of one axis; the
 * entry face becomes `id` when the slab's entry is the later one; 0 when the
 * ray misses the slab */
static inline int slab(double u, double v, double iv, int n, int id, double *t0, double *t1, int *face)
{
    if (v == 0) return u >= 0 && u < n;
    double a = (v > 0 ? -u : n - u) * iv, b = (v > 0 ? n - u : -u) * iv;
    if (a > *t0) {
        *t0 = a;
        *face = id;
    }
    if (b < *t1) *t1 = b;
    return 1;
}

#define FIXED_ONE 4294967296.0

/* Marches the ray u + t v (grid frame, cell units, |v| = 1) up to tmax.
 * On a hit stores the exact entry parameter of the first obstacle cell.
 *
 * Each step reads the skip of the cell's tile (64 times smaller than the
 * cells, so it stays in the caches), else the cell's own. A skip moves
 * the ray that many cells at once: a run of skips moves the position in
 * 32.32 fixed point (X, Y; direction VX, VY), so the cell is a shift of
 * an integer sum, where doubles took a chain of conversions per step.
 * Where the skip is 0 the ray steps cell by cell (Amanatides-Woo). One
 * loop with the state in locals: the compiler keeps it in registers. */
static int grid_march(const World *w, double ux, double uy, double vx, double vy, double tmax,
                      double *t_out, Hit *h)
{
    const int W = w->gw, H = w->gh, tw = w->gtw;
    const uint8_t *coarse = w->coarse, *code = w->code;
    const double ivx = vx != 0 ? 1.0 / vx : INFINITY, ivy = vy != 0 ? 1.0 / vy : INFINITY;
    double t = 0.0, t1 = tmax;
    int face = 0;
    if (!slab(ux, vx, ivx, W, 1, &t, &t1, &face) || !slab(uy, vy, ivy, H, 2, &t, &t1, &face))
        return 0;
    if (!(t <= t1)) return 0;
    const int stepx = vx > 0 ? 1 : (vx < 0 ? -1 : 0);
    const int stepy = vy > 0 ? 1 : (vy < 0 ? -1 : 0);
    /* inside the grid up to rounding: truncation is floor, then clamp */
    int cx = clampi((int)(ux + t * vx), 0, W - 1);
    int cy = clampi((int)(uy + t * vy), 0, H - 1);
    const int64_t VX = (int64_t)(vx * FIXED_ONE), VY = (int64_t)(vy * FIXED_ONE);
    double tmx = INFINITY, tmy = INFINITY;
    int dda = 0;
    for (;;) {
        /* cells known empty round here: the tile's skip, else the cell's */
        unsigned skip = coarse[(cy >> 3) * tw + (cx >> 3)];
        if (skip < COARSE_SKIP_MIN) {
            unsigned c = code[cell_index(tw, cx, cy)];
            if (c == CODE_OBST) break;
            skip = c >= SKIP_MIN ? c : 0;
        }
        if (skip) {
            /* a run of skips; the landing points are more than 0.08 cells
             * from every obstacle cell, so rounding (below 1e-7 cells)
             * never lands in one */
            int64_t X = (int64_t)((ux + t * vx) * FIXED_ONE);
            int64_t Y = (int64_t)((uy + t * vy) * FIXED_ONE);
            do {
                double t2 = t + (double)skip;
                if (t2 >= t1) return 0;
                X += (int64_t)skip * VX;
                Y += (int64_t)skip * VY;
                t = t2;
                cx = (int)(X >> 32);
                cy = (int)(Y >> 32);
                if ((unsigned)cx >= (unsigned)W) cx = cx < 0 ? 0 : W - 1;
                if ((unsigned)cy >= (unsigned)H) cy = cy < 0 ? 0 : H - 1;
                skip = coarse[(cy >> 3) * tw + (cx >> 3)];
                if (skip < COARSE_SKIP_MIN) {
                    unsigned c = code[cell_index(tw, cx, cy)];
                    if (c == CODE_OBST) {
                        face = 0;
                        goto hit;
                    }
                    skip = c >= SKIP_MIN ? c : 0;
                }
            } while (skip);
            dda = 0;
            face = 0;
        }
        if (!dda) {
            tmx = vx > 0 ? (cx + 1 - ux) * ivx : (vx < 0 ? (cx - ux) * ivx : INFINITY);
            tmy = vy > 0 ? (cy + 1 - uy) * ivy : (vy < 0 ? (cy - uy) * ivy : INFINITY);
            dda = 1;
        }
        if (tmx < tmy) {
            if (tmx > t1) return 0;
            t = tmx;
            cx += stepx;
            if ((unsigned)cx >= (unsigned)W) return 0;
            tmx += fabs(ivx);
            face = 1;
        } else {
            if (tmy > t1) return 0;
            t = tmy;
            cy += stepy;
            if ((unsigned)cy >= (unsigned)H) return 0;
            tmy += fabs(ivy);
            face = 2;
        }
    }
hit:
    /* on an obstacle cell: its exact entry parameter (the incremental one
     * carries rounding) */
    if (face == 1)
        t = ((stepx > 0 ? cx : cx + 1) - ux) / vx;
    else if (face == 2)
        t = ((stepy > 0 ? cy : cy + 1) - uy) / vy;
    *t_out = t;
    h->cx = cx;
    h->cy = cy;
    h->face = face;
    h->stepx = stepx;
    h->stepy = stepy;
    h->vx = vx;
    h->vy = vy;
    return 1;
}

static inline int seg_hit(const Seg *s, double px, double py, double dx, double dy, double *t)
{
    double den = dx * s->ey - dy * s->ex;
    if (fabs(den) < 1e-300) return 0;
    double wx = s->ax - px, wy = s->ay - py;
    double tt = (wx * s->ey - wy * s->ex) / den;
    double u = (wx * dy - wy * dx) / den;
    if (tt < 0 || u < 0 || u > 1) return 0;
    *t = tt;
    return 1;
}

/* Narrows [t0, t1] to where u + t v lies in [0, n]; 0 when it never does
 * (v = 0 and u outside). */
static inline int clip_axis(double u, double v, double n, double *t0, double *t1)
{
    if (v > 0) {
        *t0 = fmax(*t0, -u / v);
        *t1 = fmin(*t1, (n - u) / v);
    } else if (v < 0) {
        *t0 = fmax(*t0, (n - u) / v);
        *t1 = fmin(*t1, -u / v);
    } else if (!(u >= 0 && u <= n)) {
        return 0;
    }
    return 1;
}

static void seg_trace(const World *w, double px, double py, double dx, double dy, Hit *h)
{
    const double ih = w->sinvh;
    const int W = w->sw, H = w->sgh;
    const double ux = (px - w->sx0) * ih, uy = (py - w->sy0) * ih;
    const double vx = dx * ih, vy = dy * ih;
    double t0 = 0.0, t1 = h->t;
    if (!clip_axis(ux, vx, W, &t0, &t1) || !clip_axis(uy, vy, H, &t0, &t1) || !(t0 <= t1)) return;
    const int stepx = vx > 0 ? 1 : (vx < 0 ? -1 : 0);
    const int stepy = vy > 0 ? 1 : (vy < 0 ? -1 : 0);
    const double tdx = vx != 0 ? fabs(1.0 / vx) : INFINITY;
    const double tdy = vy != 0 ? fabs(1.0 / vy) : INFINITY;
    int cx = clampi((int)(ux + t0 * vx), 0, W - 1);
    int cy = clampi((int)(uy + t0 * vy), 0, H - 1);
    double tmx = vx > 0 ? (cx + 1 - ux) / vx : (vx < 0 ? (cx - ux) / vx : INFINITY);
    double tmy = vy > 0 ? (cy + 1 - uy) / vy : (vy < 0 ? (cy - uy) / vy : INFINITY);
    for (;;) {
        int b = cy * W + cx;
        for (int k = w->sstart[b]; k < w->sstart[b + 1]; k++) {
            int id = w->sitems[k];
            double t;
            if (!w->seg_on[id]) continue;
            /* (a segment wins a tie with a body, see trace) */
            if (seg_hit(&w->seg[id], px, py, dx, dy, &t) &&
                (t < h->t || (t == h->t && h->kind == HIT_BODY))) {
                h->t = t;
                h->kind = HIT_SEG;
                h->id = id;
            }
        }
        if (tmx < tmy) {
            if (tmx > h->t || tmx > t1) return;
            cx += stepx;
            if ((unsigned)cx >= (unsigned)W) return;
            tmx += tdx;
        } else {
            if (tmy > h->t || tmy > t1) return;
            cy += stepy;
            if ((unsigned)cy >= (unsigned)H) return;
            tmy += tdy;
        }
    }
}

/* the ray p + t d in the grid's frame (cell units) */
static inline void grid_frame(const World *w, double px, double py, double dx, double dy,
                              double *ux, double *uy, double *vx, double *vy)
{
    double rx = px - w->gox, ry = py - w->goy;
    *ux = (rx * w->gc + ry * w->gs) * w->inv_res;
    *uy = (-rx * w->gs + ry * w->gc) * w->inv_res;
    *vx = dx * w->gc + dy * w->gs;
    *vy = -dx * w->gs + dy * w->gc;
}

/* Nearest hit along p + t d (|d| = 1), 0 <= t <= tmax. The bodies are
 * tested first: a ray that meets one (one in six in the raycast
 * benchmark) marches the grid only up to it, not on to the wall behind.
 * The grid and the segments win ties, as when they were tested first. A
 * grid hit found and then refused (rounding put it past the body) leaves
 * its cell fields in h; they are read only for grid hits. */
static void trace(const Ctx *c, double px, double py, double dx, double dy, double tmax, Hit *h)
{
    const World *w = c->w;
    h->t = tmax;
    h->kind = HIT_NONE;
    h->id = -1;
    h->body = NULL;
    h->cx = h->cy = h->face = h->stepx = h->stepy = 0;
    h->vx = dx;
    h->vy = dy;
    for (int i = 0; i < c->nb; i++) {
        const Body *b = &c->b[i];
        double mx = px - b->x, my = py - b->y;
        double bb = mx * dx + my * dy;
        double cc = mx * mx + my * my - b->r * b->r;
        if (cc > 0 && bb > 0) continue;
        if (-bb - b->r > h->t) continue;
        double disc = bb * bb - cc;
        if (disc < 0) continue;
        double t = cc > 0 ? -bb - sqrt(disc) : 0.0;
        if (t < h->t) {
            h->t = t;
            h->kind = HIT_BODY;
            h->id = b->id;
            h->body = b;
        }
    }
    if (w->has_grid) {
        double ux, uy, vx, vy, tc;
        grid_frame(w, px, py, dx, dy, &ux, &uy, &vx, &vy);
        if (grid_march(w, ux, uy, vx, vy, h->t * w->inv_res, &tc, h) && tc * w->res <= h->t) {
            h->t = tc * w->res;
            h->kind = HIT_GRID;
            h->id = -1;
            h->body = NULL;
        }
    }
    if (w->nseg_on > 0) seg_trace(w, px, py, dx, dy, h);
}

/* Surface normal at a hit (unit, facing the incoming ray) and the nudge
 * that moves a restart point off the surface. */
static void surface(const World *w, const Hit *h, double dx, double dy, double hx, double hy,
                    double *nx, double *ny, double *fx, double *fy)
{
    double x = -dx, y = -dy;
    if (h->kind == HIT_SEG) {
        const Seg *s = &w->seg[h->id];
        if (s->inv_len2 > 0) {
            x = s->nx;
            y = s->ny;
            if (x * dx + y * dy > 0) {
                x = -x;
                y = -y;
            }
        }
        *fx = x * NUDGE_M;
        *fy = y * NUDGE_M;
    } else if (h->kind == HIT_BODY) {
        double rx = hx - h->body->x, ry = hy - h->body->y, l = sqrt(rx * rx + ry * ry);
        if (h->t > 0 && l > 0) {
            x = rx / l;
            y = ry / l;
        }
        *fx = x * NUDGE_M;
        *fy = y * NUDGE_M;
    } else {
        /* grid: away from the occupied mass of the 5x5 neighbourhood */
        const int W = w->gw, H = w->gh, X0 = h->cx, Y0 = h->cy;
        double sx = 0, sy = 0;
        if (X0 >= 2 && X0 + 2 < W && Y0 >= 2 && Y0 + 2 < H) {
            /* inside the grid: a cell's index is the sum of a part of its
             * row and a part of its column (see cell_index) */
            size_t col[5];
            int isx = 0, isy = 0;
            for (int i = 0; i < 5; i++)
                col[i] = ((size_t)((X0 + i - 2) >> 3) << 6) | (size_t)((X0 + i - 2) & 7);
            for (int j = -2; j <= 2; j++) {
                const int Y = Y0 + j;
                const uint8_t *row =
                    w->code + (((size_t)(Y >> 3) * w->gtw) << 6) + (size_t)((Y & 7) << 3);
                /* no branch on the cells: a sonar echo's neighbourhood is
                 * a mix a predictor cannot learn (a third of a cast's
                 * mispredictions, cachegrind). The centre cell counts 0 in
                 * both sums. */
                for (int i = -2; i <= 2; i++) {
                    const int o = row[col[i + 2]] == CODE_OBST;
                    isx -= i * o;
                    isy -= j * o;
                }
            }
            sx = isx;
            sy = isy;
        } else {
            for (int j = -2; j <= 2; j++) {
                int Y = Y0 + j;
                if (Y < 0 || Y >= H) continue;
                for (int i = -2; i <= 2; i++) {
                    int X = X0 + i;
                    if (X < 0 || X >= W || (i == 0 && j == 0)) continue;
                    if (w->code[cell_index(w->gtw, X, Y)] == CODE_OBST) {
                        sx -= i;
                        sy -= j;
                    }
                }
            }
        }
        double l2 = sx * sx + sy * sy;
        double gx, gy; /* face normal, grid frame */
        if (h->face == 1) {
            gx = -h->stepx;
            gy = 0;
        } else if (h->face == 2) {
            gx = 0;
            gy = -h->stepy;
        } else {
            gx = -h->vx;
            gy = -h->vy;
        }
        if (l2 < 1e-12 || sx * h->vx + sy * h->vy >= -1e-12 * sqrt(l2)) {
            sx = gx;
            sy = gy;
            l2 = 1;
        }
        double l = sqrt(l2);
        sx /= l;
        sy /= l;
        x = w->gc * sx - w->gs * sy;
        y = w->gs * sx + w->gc * sy;
        double k = NUDGE_CELLS * w->res;
        *fx = (w->gc * gx - w->gs * gy) * k;
        *fy = (w->gs * gx + w->gc * gy) * k;
    }
    *nx = x;
    *ny = y;
}

/* One sonar/laser ray with the reflection model. cos_crit < -1 means the
 * critical angle is >= pi/2: every hit echoes. `first` holds the bodies the
 * first leg may hit, `c` those of the legs after a reflection. */
static void cast_one(const Ctx *first, const Ctx *c, double px, double py, double dx, double dy,
                     double max_range, int max_bounces, double cos_crit, RayResult *r)
{
    double travelled = 0;
    int bounces = 0;
    for (;;) {
        double remaining = max_range - travelled;
        Hit h;
        if (!(remaining > 0)) break;
        trace(bounces ? c : first, px, py, dx, dy, remaining, &h);
        if (h.kind == HIT_NONE) break;
        travelled += h.t;
        double hx = px + h.t * dx, hy = py + h.t * dy;
        if (cos_crit < -1.0) {
            r->range = travelled;
            r->kind = h.kind;
            r->id = h.kind == HIT_GRID ? -1 : h.id;
            r->bounces = bounces;
            r->px = hx;
            r->py = hy;
            return;
        }
        double nx, ny, fx, fy;
        surface(c->w, &h, dx, dy, hx, hy, &nx, &ny, &fx, &fy);
        double dn = dx * nx + dy * ny;
        if (-dn >= cos_crit) {
            r->range = travelled;
            r->kind = h.kind;
            r->id = h.kind == HIT_GRID ? -1 : h.id;
            r->bounces = bounces;
            r->px = hx;
            r->py = hy;
            return;
        }
        if (bounces >= max_bounces) break;
        bounces++;
        dx -= 2 * dn * nx;
        dy -= 2 * dn * ny;
        double l = sqrt(dx * dx + dy * dy);
        dx /= l;
        dy /= l;
        px = hx + fx;
        py = hy + fy;
    }
    r->range = max_range;
    r->kind = HIT_NONE;
    r->id = -1;
    r->bounces = bounces;
    r->px = r->py = 0;
}

/* ------------------------------------------------------------------ */
/* NIFs                                                                 */

static int get_world(ErlNifEnv *env, ERL_NIF_TERM t, World **w)
{
    return enif_get_resource(env, t, WORLD_RT, (void **)w);
}

/* Indexes the n bodies b (taking them) and makes them the world's, in
 * place of the bodies it had. */
static ERL_NIF_TERM install_bodies(ErlNifEnv *env, World *w, Body *b, int n)
{
    BodyIndex x;
    memset(&x, 0, sizeof(x));
    x.n = n;
    x.b = b;
    if (!body_index_build(&x)) {
        body_index_free(&x);
        return enif_make_badarg(env);
    }
    enif_rwlock_rwlock(w->lock);
    BodyIndex old = w->bodies;
    w->bodies = x;
    enif_rwlock_rwunlock(w->lock);
    body_index_free(&old);
    return A_OK;
}

/* new(segments :: binary of 4 native doubles each,
 *     grid :: nil | {w, h, res, ox, oy, yaw, data}) */
static ERL_NIF_TERM nif_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary sb;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &sb) || sb.size % 32 != 0)
        return error_msg(env, "segments: expected a binary of 4 float64 per segment");
    int gw = 0, gh = 0;
    double res = 0, ox = 0, oy = 0, yaw = 0;
    ErlNifBinary data;
    int has_grid = 0;
    if (enif_compare(argv[1], A_NIL) != 0) {
        int arity;
        const ERL_NIF_TERM *el;
        if (!enif_get_tuple(env, argv[1], &arity, &el) || arity != 7 ||
            !enif_get_int(env, el[0], &gw) || !enif_get_int(env, el[1], &gh) ||
            !tc_number(env, el[2], &res) || !tc_number(env, el[3], &ox) ||
            !tc_number(env, el[4], &oy) || !tc_number(env, el[5], &yaw) ||
            !enif_inspect_binary(env, el[6], &data))
            return error_msg(env, "grid: malformed");
        if (gw <= 0 || gh <= 0) return error_msg(env, "grid: width and height must be positive");
        if (!(res > 0) || !isfinite(res)) return error_msg(env, "grid: resolution must be positive");
        if ((size_t)gw * (size_t)gh != data.size)
            return error_msg(env, "grid: data size does not match width * height");
        if ((double)gw * gh > 2.0e9) return error_msg(env, "grid: too large");
        has_grid = 1;
    }

    World *w = enif_alloc_resource(WORLD_RT, sizeof(World));
    if (!w) return error_msg(env, "out of memory");
    memset(w, 0, sizeof(World));
    ERL_NIF_TERM term = enif_make_resource(env, w);
    enif_release_resource(w);
    w->lock = enif_rwlock_create("tc_raycast.world");
    if (!w->lock) return error_msg(env, "cannot create a lock");

    w->nseg = (int)(sb.size / 32);
    if (w->nseg > 0) {
        w->seg = enif_alloc((size_t)w->nseg * sizeof(Seg));
        w->seg_on = enif_alloc((size_t)w->nseg);
        if (!w->seg || !w->seg_on) return error_msg(env, "out of memory");
        for (int i = 0; i < w->nseg; i++) {
            const unsigned char *p = sb.data + (size_t)i * 32;
            double x1 = ld(p), y1 = ld(p + 8), x2 = ld(p + 16), y2 = ld(p + 24);
            if (!isfinite(x1) || !isfinite(y1) || !isfinite(x2) || !isfinite(y2))
                return error_msg(env, "segments: coordinates must be finite");
            Seg *s = &w->seg[i];
            s->ax = x1;
            s->ay = y1;
            s->ex = x2 - x1;
            s->ey = y2 - y1;
            double l2 = s->ex * s->ex + s->ey * s->ey;
            if (l2 > 0) {
                double l = sqrt(l2);
                s->nx = -s->ey / l;
                s->ny = s->ex / l;
                s->inv_len2 = 1.0 / l2;
            } else {
                s->nx = s->ny = s->inv_len2 = 0;
            }
            w->seg_on[i] = 1;
        }
        w->nseg_on = w->nseg;
        if (!build_seg_index(w)) return error_msg(env, "out of memory");
    }
    if (has_grid) {
        w->has_grid = 1;
        w->gw = gw;
        w->gh = gh;
        w->res = res;
        w->inv_res = 1.0 / res;
        w->gox = ox;
        w->goy = oy;
        w->gc = cos(yaw);
        w->gs = sin(yaw);
        if (!build_grid(w, (const signed char *)data.data)) return error_msg(env, "out of memory");
    }
    return enif_make_tuple2(env, A_OK, term);
}

static ERL_NIF_TERM nif_set_segment(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    World *w;
    int id;
    (void)argc;
    if (!get_world(env, argv[0], &w) || !enif_get_int(env, argv[1], &id))
        return enif_make_badarg(env);
    int on;
    if (enif_compare(argv[2], A_TRUE) == 0)
        on = 1;
    else if (enif_compare(argv[2], A_FALSE) == 0)
        on = 0;
    else
        return enif_make_badarg(env);
    if (id < 0 || id >= w->nseg) return enif_make_badarg(env);
    enif_rwlock_rwlock(w->lock);
    if (w->seg_on[id] != on) {
        w->seg_on[id] = (uint8_t)on;
        w->nseg_on += on ? 1 : -1;
    }
    enif_rwlock_rwunlock(w->lock);
    return A_OK;
}

static ERL_NIF_TERM nif_set_bodies(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    World *w;
    unsigned len;
    (void)argc;
    if (!get_world(env, argv[0], &w) || !enif_get_list_length(env, argv[1], &len))
        return enif_make_badarg(env);
    Body *b = enif_alloc((size_t)(len ? len : 1) * sizeof(Body));
    if (!b) return enif_make_badarg(env);
    ERL_NIF_TERM list = argv[1], head;
    for (unsigned i = 0; i < len; i++) {
        int arity;
        const ERL_NIF_TERM *el;
        enif_get_list_cell(env, list, &head, &list);
        if (!enif_get_tuple(env, head, &arity, &el) || arity != 3 ||
            !tc_number(env, el[0], &b[i].x) || !tc_number(env, el[1], &b[i].y) ||
            !tc_number(env, el[2], &b[i].r) || !(b[i].r >= 0)) {
            enif_free(b);
            return enif_make_badarg(env);
        }
        b[i].id = (int)i;
    }
    return install_bodies(env, w, b, (int)len);
}

/* set_bodies_packed(world, n, records): bodies 0..n-1, each record four
 * native float64 (id, x, y, r); an id no record names is parked far away
 * (r 0), as ThinkingCap.Sim does with a removed robot. A later record of
 * the same id wins. */
#define FAR_AWAY 1e9
static ERL_NIF_TERM nif_set_bodies_packed(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    World *w;
    int n;
    ErlNifBinary rb;
    (void)argc;
    if (!get_world(env, argv[0], &w) || !enif_get_int(env, argv[1], &n) || n < 0 ||
        n > 10000000 || !enif_inspect_binary(env, argv[2], &rb) || rb.size % 32 != 0)
        return enif_make_badarg(env);
    Body *b = enif_alloc((size_t)(n ? n : 1) * sizeof(Body));
    if (!b) return enif_make_badarg(env);
    for (int i = 0; i < n; i++) {
        b[i].x = b[i].y = FAR_AWAY;
        b[i].r = 0;
        b[i].id = i;
    }
    const size_t nrec = rb.size / 32;
    for (size_t k = 0; k < nrec; k++) {
        const unsigned char *p = rb.data + k * 32;
        double id = ld(p), bx = ld(p + 8), by = ld(p + 16), br = ld(p + 24);
        if (!(id >= 0 && id < n && id == floor(id)) || !isfinite(bx) || !isfinite(by) ||
            !(br >= 0) || !isfinite(br)) {
            enif_free(b);
            return enif_make_badarg(env);
        }
        Body *t = &b[(int)id];
        t->x = bx;
        t->y = by;
        t->r = br;
    }
    return install_bodies(env, w, b, n);
}

/* ---- contacts ---- */

/* contacts(moves): moves are records of six native float64 (id, x0, y0,
 * x1, y1, r): a disc that moved from (x0, y0) to (x1, y1) this step. Two
 * moves clash when the discs end overlapping and nearer than they were;
 * returns the ids of every move in a clash, ascending. A bucket grid over
 * the new positions, buckets as wide as the largest contact distance, so
 * each move is tested against the moves in its 3 x 3 buckets only. */
#define MOVE_DOUBLES 6
static int cmp_int(const void *a, const void *b)
{
    int x = *(const int *)a, y = *(const int *)b;
    return (x > y) - (x < y);
}

static inline int clash(const double *a, const double *b)
{
    double now = (a[3] - b[3]) * (a[3] - b[3]) + (a[4] - b[4]) * (a[4] - b[4]);
    double was = (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]);
    double rr = a[5] + b[5];
    return now < rr * rr && now < was;
}

static ERL_NIF_TERM contacts_impl(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary mb;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &mb) || mb.size % (8 * MOVE_DOUBLES) != 0)
        return enif_make_badarg(env);
    const int n = (int)(mb.size / (8 * MOVE_DOUBLES));
    if (n == 0) return enif_make_list(env, 0);
    double *m = enif_alloc((size_t)n * MOVE_DOUBLES * sizeof(double));
    int32_t *cell = enif_alloc((size_t)n * sizeof(int32_t) * 3);
    uint8_t *hit = enif_alloc((size_t)n);
    if (!m || !cell || !hit) {
        if (m) enif_free(m);
        if (cell) enif_free(cell);
        if (hit) enif_free(hit);
        return enif_make_badarg(env);
    }
    memcpy(m, mb.data, (size_t)n * MOVE_DOUBLES * sizeof(double));
    memset(hit, 0, (size_t)n);
    int32_t *items = cell + n, *ids = cell + 2 * n;
    double rmax = 0, minx = BIG, miny = BIG, maxx = -BIG, maxy = -BIG;
    for (int i = 0; i < n; i++) {
        const double *a = m + (size_t)i * MOVE_DOUBLES;
        for (int k = 0; k < MOVE_DOUBLES; k++)
            if (!isfinite(a[k])) goto bad;
        if (!(a[5] >= 0) || !(a[0] >= 0 && a[0] <= 2147483647.0 && a[0] == floor(a[0])))
            goto bad;
        ids[i] = (int32_t)a[0];
        if (a[5] > rmax) rmax = a[5];
        minx = fmin(minx, a[3]);
        maxx = fmax(maxx, a[3]);
        miny = fmin(miny, a[4]);
        maxy = fmax(maxy, a[4]);
    }
    double h = rmax > 0 ? 2 * rmax : 1.0;
    double ex = maxx - minx, ey = maxy - miny;
    while ((floor(ex / h) + 1) * (floor(ey / h) + 1) > 4.0 * n + 16)
        h *= 2;
    const int W = (int)floor(ex / h) + 1, H = (int)floor(ey / h) + 1;
    const double inv = 1.0 / h;
    int32_t *start = enif_alloc(((size_t)W * H + 1) * sizeof(int32_t));
    if (!start) goto bad;
    memset(start, 0, ((size_t)W * H + 1) * sizeof(int32_t));
    for (int i = 0; i < n; i++) {
        const double *a = m + (size_t)i * MOVE_DOUBLES;
        cell[i] = bucket_of((a[4] - miny) * inv, H) * W + bucket_of((a[3] - minx) * inv, W);
        start[cell[i] + 1]++;
    }
    for (int k = 0; k < W * H; k++)
        start[k + 1] += start[k];
    {
        int32_t *fill = enif_alloc(((size_t)W * H + 1) * sizeof(int32_t));
        if (!fill) {
            enif_free(start);
            goto bad;
        }
        memcpy(fill, start, ((size_t)W * H + 1) * sizeof(int32_t));
        for (int i = 0; i < n; i++)
            items[fill[cell[i]]++] = i;
        enif_free(fill);
    }
    for (int i = 0; i < n; i++) {
        const double *a = m + (size_t)i * MOVE_DOUBLES;
        const int ci = cell[i] % W, cj = cell[i] / W;
        for (int j = cj - 1; j <= cj + 1; j++) {
            if (j < 0 || j >= H) continue;
            for (int k = ci - 1; k <= ci + 1; k++) {
                if (k < 0 || k >= W) continue;
                const int bkt = j * W + k;
                for (int q = start[bkt]; q < start[bkt + 1]; q++) {
                    const int o = items[q];
                    if (o <= i) continue;
                    if (clash(a, m + (size_t)o * MOVE_DOUBLES)) {
                        hit[i] = hit[o] = 1;
                    }
                }
            }
        }
    }
    enif_free(start);
    int32_t *out = cell; /* reused: the cells are no longer needed */
    int c = 0;
    for (int i = 0; i < n; i++)
        if (hit[i]) out[c++] = ids[i];
    qsort(out, (size_t)c, sizeof(int32_t), cmp_int);
    ERL_NIF_TERM list = enif_make_list(env, 0);
    for (int i = c - 1; i >= 0; i--)
        if (i == c - 1 || out[i] != out[i + 1])
            list = enif_make_list_cell(env, enif_make_int(env, out[i]), list);
    enif_free(m);
    enif_free(cell);
    enif_free(hit);
    return list;
bad:
    enif_free(m);
    enif_free(cell);
    enif_free(hit);
    return enif_make_badarg(env);
}

static ERL_NIF_TERM nif_contacts(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary mb;
    if (enif_inspect_binary(env, argv[0], &mb) && mb.size / (8 * MOVE_DOUBLES) > 20000)
        return enif_schedule_nif(env, "contacts_dirty", ERL_NIF_DIRTY_JOB_CPU_BOUND,
                                 contacts_impl, argc, argv);
    return contacts_impl(env, argc, argv);
}

/* walkers_step(robots, walkers, dt, gap) -> one step of the walkers
 * (Core.Walkers): robots are three native float64 each (x, y, radius),
 * walkers six (x, y, radius, the target's x and y, speed), in the order
 * they step. Each walker in turn goes straight to its target at its
 * speed: onto it when within this step (arrived, no check), else by
 * speed * dt if the new place keeps more than `gap` from every robot
 * and every other walker as they stand by then (earlier walkers where
 * they moved), else it waits. Returns three native float64 per walker:
 * x, y and 0 (waited), 1 (stepped) or 2 (arrived). Buckets of the
 * discs' places at the start, wide enough that a walker looks at its
 * 3 x 3 only: linear in robots + walkers. */
static ERL_NIF_TERM walkers_step_impl(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary rb, wb;
    double dt, gap;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &rb) || !enif_inspect_binary(env, argv[1], &wb) ||
        rb.size % (8 * 3) || wb.size % (8 * 6) || !enif_get_double(env, argv[2], &dt) ||
        !enif_get_double(env, argv[3], &gap) || !(dt >= 0) || !(gap >= 0))
        return enif_make_badarg(env);
    const int nr = (int)(rb.size / 24), nw = (int)(wb.size / 48), n = nr + nw;
    ERL_NIF_TERM out;
    double *o = (double *)enif_make_new_binary(env, (size_t)nw * 3 * sizeof(double), &out);
    if (nw == 0) return out;
    double *px = enif_alloc((size_t)n * 3 * sizeof(double));
    int32_t *cell = enif_alloc((size_t)n * 2 * sizeof(int32_t));
    if (!px || !cell) {
        if (px) enif_free(px);
        if (cell) enif_free(cell);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    double *py = px + n, *pr = px + 2 * n;
    int32_t *items = cell + n;
    const double *r = (const double *)rb.data, *w = (const double *)wb.data;
    double rmax = 0, wmax = 0, smax = 0, minx = BIG, miny = BIG, maxx = -BIG, maxy = -BIG;
    for (int i = 0; i < n; i++) {
        const double *d = i < nr ? r + (size_t)i * 3 : w + (size_t)(i - nr) * 6;
        int k = i < nr ? 3 : 6;
        for (int j = 0; j < k; j++)
            if (!isfinite(d[j])) goto bad;
        if (!(d[2] >= 0) || (i >= nr && !(d[5] >= 0))) goto bad;
        px[i] = d[0];
        py[i] = d[1];
        pr[i] = d[2];
        if (d[2] > rmax) rmax = d[2];
        if (i >= nr) {
            if (d[2] > wmax) wmax = d[2];
            if (d[5] * dt > smax) smax = d[5] * dt;
        }
        minx = fmin(minx, d[0]);
        maxx = fmax(maxx, d[0]);
        miny = fmin(miny, d[1]);
        maxy = fmax(maxy, d[1]);
    }
    /* a disc stands within smax of where it was bucketed */
    double h = rmax + wmax + gap + smax;
    if (!(h > 0) || !isfinite(h)) h = 1.0;
    double ex = maxx - minx, ey = maxy - miny;
    while ((floor(ex / h) + 1) * (floor(ey / h) + 1) > 4.0 * n + 16)
        h *= 2;
    const int W = (int)floor(ex / h) + 1, H = (int)floor(ey / h) + 1;
    const double inv = 1.0 / h;
    int32_t *start = enif_alloc(((size_t)W * H + 2) * sizeof(int32_t) * 2);
    if (!start) goto bad;
    int32_t *fill = start + (size_t)W * H + 2;
    memset(start, 0, ((size_t)W * H + 2) * sizeof(int32_t));
    for (int i = 0; i < n; i++) {
        cell[i] = bucket_of((py[i] - miny) * inv, H) * W + bucket_of((px[i] - minx) * inv, W);
        start[cell[i] + 1]++;
    }
    for (int k = 0; k < W * H; k++)
        start[k + 1] += start[k];
    memcpy(fill, start, ((size_t)W * H + 1) * sizeof(int32_t));
    for (int i = 0; i < n; i++)
        items[fill[cell[i]]++] = i;
    for (int k = 0; k < nw; k++) {
        const int i = nr + k;
        const double *d = w + (size_t)k * 6;
        const double x = px[i], y = py[i], tx = d[3], ty = d[4];
        const double dist = sqrt((tx - x) * (tx - x) + (ty - y) * (ty - y));
        const double step = d[5] * dt;
        double *ok = o + (size_t)k * 3;
        if (dist <= step) {
            px[i] = tx;
            py[i] = ty;
            ok[0] = tx, ok[1] = ty, ok[2] = 2;
            continue;
        }
        const double nx = x + (tx - x) * step / dist, ny = y + (ty - y) * step / dist;
        const int ci = bucket_of((nx - minx) * inv, W), cj = bucket_of((ny - miny) * inv, H);
        int clear = 1;
        for (int j = cj - 1; j <= cj + 1 && clear; j++) {
            if (j < 0 || j >= H) continue;
            for (int c = ci - 1; c <= ci + 1 && clear; c++) {
                if (c < 0 || c >= W) continue;
                const int b = j * W + c;
                for (int q = start[b]; q < start[b + 1]; q++) {
                    const int e = items[q];
                    if (e == i) continue;
                    const double rr = pr[e] + pr[i] + gap;
                    if ((px[e] - nx) * (px[e] - nx) + (py[e] - ny) * (py[e] - ny) <= rr * rr) {
                        clear = 0;
                        break;
                    }
                }
            }
        }
        if (clear) px[i] = nx, py[i] = ny;
        ok[0] = px[i], ok[1] = py[i], ok[2] = clear;
    }
    enif_free(start);
    enif_free(px);
    enif_free(cell);
    return out;
bad:
    enif_free(px);
    enif_free(cell);
    return enif_make_badarg(env);
}

static ERL_NIF_TERM nif_walkers_step(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary wb;
    if (enif_inspect_binary(env, argv[1], &wb) && wb.size / 48 > 20000)
        return enif_schedule_nif(env, "walkers_step_dirty", ERL_NIF_DIRTY_JOB_CPU_BOUND,
                                 walkers_step_impl, argc, argv);
    return walkers_step_impl(env, argc, argv);
}

/* records_box(records) -> {min_x, min_y, max_x, max_y} of the centres of
 * body records (four native float64 each: id, x, y, radius), nil for
 * none. records_within(records, min_x, min_y, max_x, max_y) -> the
 * records whose disc reaches into that box (Core.Ghosts). */
static ERL_NIF_TERM nif_records_box(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary b;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &b) || b.size % 32) return enif_make_badarg(env);
    const double *r = (const double *)b.data;
    size_t n = b.size / 32;
    if (n == 0) return enif_make_atom(env, "nil");
    double ax = r[1], ay = r[2], bx = r[1], by = r[2];
    for (size_t i = 1; i < n; i++) {
        const double x = r[i * 4 + 1], y = r[i * 4 + 2];
        ax = x < ax ? x : ax;
        ay = y < ay ? y : ay;
        bx = x > bx ? x : bx;
        by = y > by ? y : by;
    }
    return enif_make_tuple4(env, enif_make_double(env, ax), enif_make_double(env, ay),
                            enif_make_double(env, bx), enif_make_double(env, by));
}

static ERL_NIF_TERM nif_records_within(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary b;
    double ax, ay, bx, by;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &b) || b.size % 32 ||
        !enif_get_double(env, argv[1], &ax) || !enif_get_double(env, argv[2], &ay) ||
        !enif_get_double(env, argv[3], &bx) || !enif_get_double(env, argv[4], &by))
        return enif_make_badarg(env);
    const double *r = (const double *)b.data;
    size_t n = b.size / 32, m = 0;
    double *keep = enif_alloc(b.size ? b.size : 1);
    if (!keep) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    for (size_t i = 0; i < n; i++) {
        const double *d = r + i * 4;
        if (d[1] + d[3] >= ax && d[1] - d[3] <= bx && d[2] + d[3] >= ay && d[2] - d[3] <= by)
            memcpy(keep + 4 * m++, d, 32);
    }
    ERL_NIF_TERM out;
    unsigned char *o = enif_make_new_binary(env, m * 32, &out);
    memcpy(o, keep, m * 32);
    enif_free(keep);
    return out;
}

static ERL_NIF_TERM kind_atom(int kind)
{
    switch (kind) {
    case HIT_GRID:
        return A_GRID;
    case HIT_SEG:
        return A_SEGMENT;
    case HIT_BODY:
        return A_BODY;
    default:
        return A_NONE;
    }
}

/* cast_rays(world, rays, exclude, max_bounces, cos_crit) */
static ERL_NIF_TERM cast_rays_impl(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    World *w;
    unsigned len;
    int exclude, max_bounces;
    double cos_crit;
    (void)argc;
    if (!get_world(env, argv[0], &w) || !enif_get_list_length(env, argv[1], &len) ||
        !enif_get_int(env, argv[2], &exclude) || !enif_get_int(env, argv[3], &max_bounces) ||
        !enif_get_double(env, argv[4], &cos_crit) || max_bounces < 0 ||
        max_bounces > MAX_BOUNCES_LIMIT)
        return enif_make_badarg(env);
    double *rays = len ? enif_alloc((size_t)len * 4 * sizeof(double)) : NULL;
    if (len && !rays) return enif_make_badarg(env);
    ERL_NIF_TERM list = argv[1], head;
    for (unsigned i = 0; i < len; i++) {
        int arity;
        const ERL_NIF_TERM *el;
        double *r = rays + 4 * (size_t)i;
        enif_get_list_cell(env, list, &head, &list);
        if (!enif_get_tuple(env, head, &arity, &el) || arity != 4 || !tc_number(env, el[0], &r[0]) ||
            !tc_number(env, el[1], &r[1]) || !tc_number(env, el[2], &r[2]) ||
            !tc_number(env, el[3], &r[3])) {
            enif_free(rays);
            return enif_make_badarg(env);
        }
    }
    RayResult *res = len ? enif_alloc((size_t)len * sizeof(RayResult)) : NULL;
    if (len && !res) {
        enif_free(rays);
        return enif_make_badarg(env);
    }
    /* a ray (with its reflections) stays within its range of its origin */
    double bx0 = BIG, by0 = BIG, bx1 = -BIG, by1 = -BIG;
    for (unsigned i = 0; i < len; i++) {
        const double *r = rays + 4 * (size_t)i, reach = fmax(r[3], 0);
        bx0 = fmin(bx0, r[0] - reach);
        bx1 = fmax(bx1, r[0] + reach);
        by0 = fmin(by0, r[1] - reach);
        by1 = fmax(by1, r[1] + reach);
    }
    enif_rwlock_rlock(w->lock);
    const BodyIndex *bi = &w->bodies;
    Body *bodies = bi->n && len ? enif_alloc((size_t)bi->n * sizeof(Body)) : NULL;
    Ctx c = {w, bodies,
             bodies ? bodies_near(bi, exclude, bx0, by0, bx1, by1, 0, 0, 0, 0, bodies) : 0};
    for (unsigned i = 0; i < len; i++) {
        const double *r = rays + 4 * (size_t)i;
        cast_one(&c, &c, r[0], r[1], cos(r[2]), sin(r[2]), r[3], max_bounces, cos_crit, &res[i]);
    }
    enif_rwlock_runlock(w->lock);
    if (bodies) enif_free(bodies);
    ERL_NIF_TERM out = enif_make_list(env, 0);
    ERL_NIF_TERM keys[4] = {A_BOUNCES, A_HIT, A_ID, A_RANGE};
    for (unsigned k = len; k-- > 0;) {
        ERL_NIF_TERM vals[4] = {enif_make_int(env, res[k].bounces), kind_atom(res[k].kind),
                                enif_make_int(env, res[k].id), enif_make_double(env, res[k].range)};
        ERL_NIF_TERM map;
        enif_make_map_from_arrays(env, keys, vals, 4, &map);
        out = enif_make_list_cell(env, map, out);
    }
    if (rays) enif_free(rays);
    if (res) enif_free(res);
    return out;
}

static ERL_NIF_TERM nif_cast_rays(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    unsigned len;
    int max_bounces;
    if (enif_get_list_length(env, argv[1], &len) && enif_get_int(env, argv[3], &max_bounces) &&
        (double)len * (1.0 + (max_bounces > 0 ? max_bounces : 0)) > DIRTY_RAY_BUDGET)
        return enif_schedule_nif(env, "cast_rays_dirty", ERL_NIF_DIRTY_JOB_CPU_BOUND,
                                 cast_rays_impl, argc, argv);
    return cast_rays_impl(env, argc, argv);
}

/* ---- scan ---- */

/* The groups binary written by ThinkingCap.Sim.Raycast.pack_groups/1 (all
 * native-endian): "TCG1", u32 group count, u32 ray count, u32 0; one
 * record of GROUP_DOUBLES float64 per group, fields below (G_FOV and
 * G_SIN_HALF_FOV are informational); then (cos, sin) float64 pairs, the
 * rays' directions in the robot frame, each group's rays at G_RAY_OFF. */
enum {
    G_X = 0,
    G_Y,
    G_HC,
    G_HS,
    G_COS_HALF_FOV,
    G_NRAYS,
    G_RAY_OFF,
    G_MIN,
    G_MAX,
    G_BOUNCES,
    G_COS_CRIT,
    G_RING,
    G_NOISE_STD,
    G_NOISE_PROP,
    G_DROPOUT,
    G_SPIKE,
    G_SPIKE_MAG,
    G_BIAS,
    G_FOV,
    G_SIN_HALF_FOV
};

typedef struct {
    const unsigned char *rec; /* the group's record in the packed binary */
    double px, py, hx, hy;    /* world position and heading of the sensor */
    double raw;
    int echo;
} GroupState;

/* field f of a group's record */
#define GF(s, f) ld((s)->rec + 8 * (f))

typedef struct {
    double px, py, path;
    int ring, emitter;
} Event;

/* a ray of a scan: its direction in the world, its sector (below) */
typedef struct {
    double dx, dy;
    int sec;
} RayDir;

/* Bodies by direction, for the first legs of a scan's rays: the circle
 * around the robot is cut into SECTORS sectors of pseudo-angle, and each
 * sector lists the bodies that a ray leaving in a direction of that sector
 * from any sensor of the robot may hit. */
#define SECTORS 64

/* a pseudo-angle of direction (x, y) in [0, 4]: monotonic in the angle
 * (counter-clockwise from +x), no trigonometry */
static inline double pseudo_angle(double x, double y)
{
    double p = x / (fabs(x) + fabs(y));
    return y < 0 ? 3 + p : 1 - p;
}

static inline int sector_of(double x, double y)
{
    return (int)(pseudo_angle(x, y) * (SECTORS / 4.0)) & (SECTORS - 1);
}

/* The sectors body b may be hit from: a ray from a sensor at most `off`
 * from (x, y) that hits the body passes within r + off of its centre
 * along a parallel ray from (x, y), so its direction is within
 * asin((r + off) / d) of the body's. Sets [*s0, *s1] (counter-clockwise,
 * possibly wrapping); returns 0 when every sector applies. */
static int body_sectors(const Body *b, double x, double y, double off, int *s0, int *s1)
{
    double vx = b->x - x, vy = b->y - y, d = sqrt(vx * vx + vy * vy);
    double rho = (b->r + off) * (1 + 1e-9) + 1e-9;
    if (d <= rho * 1.0000001) return 0;
    double sn = rho / d, cs = sqrt(1 - sn * sn);
    vx /= d;
    vy /= d;
    *s0 = sector_of(vx * cs + vy * sn, vy * cs - vx * sn);
    *s1 = sector_of(vx * cs - vy * sn, vy * cs + vx * sn);
    return 1;
}

typedef struct {
    int start[SECTORS + 1];
    Body *b;
} SectorTable;

static int build_sectors(SectorTable *t, const Body *b, int nb, double x, double y, double off)
{
    int *s0 = enif_alloc((size_t)2 * (nb > 0 ? nb : 1) * sizeof(int)), *s1 = s0 + nb;
    if (!s0) return 0;
    memset(t->start, 0, sizeof(t->start));
    for (int i = 0; i < nb; i++) {
        if (!body_sectors(&b[i], x, y, off, &s0[i], &s1[i])) {
            s0[i] = 0;
            s1[i] = SECTORS - 1;
        }
        for (int k = s0[i];; k = (k + 1) & (SECTORS - 1)) {
            t->start[k + 1]++;
            if (k == s1[i]) break;
        }
    }
    for (int k = 0; k < SECTORS; k++)
        t->start[k + 1] += t->start[k];
    t->b = enif_alloc((size_t)(t->start[SECTORS] > 0 ? t->start[SECTORS] : 1) * sizeof(Body));
    if (!t->b) {
        enif_free(s0);
        return 0;
    }
    int fill[SECTORS];
    memcpy(fill, t->start, sizeof(fill));
    for (int i = 0; i < nb; i++)
        for (int k = s0[i];; k = (k + 1) & (SECTORS - 1)) {
            t->b[fill[k]++] = b[i];
            if (k == s1[i]) break;
        }
    enif_free(s0);
    return 1;
}

/* Checks the packed groups' header (magic, counts, size) and reads the
 * ray budget it claims; returns the group count or -1. The groups
 * themselves are checked as scan_cast reads them (group_ok), which
 * refuses the scan when they do not add up to the claimed budget: one
 * pass over the groups, not two. */
static int groups_header(const ErlNifBinary *gb, unsigned *nrays, double *budget)
{
    uint32_t ng, nr, b;
    if (gb->size < GROUPS_HEADER || memcmp(gb->data, "TCG1", 4) != 0) return -1;
    memcpy(&ng, gb->data + 4, 4);
    memcpy(&nr, gb->data + 8, 4);
    memcpy(&b, gb->data + 12, 4);
    if (ng > 1000000 || nr > 100000000) return -1;
    if (gb->size != GROUPS_HEADER + (size_t)ng * GROUP_BYTES + (size_t)nr * 16) return -1;
    *nrays = nr;
    *budget = b;
    return (int)ng;
}

/* whether a group's rays lie within the nr rays of the binary, with a
 * whole count of rays and of bounces (at most MAX_BOUNCES_LIMIT); adds
 * its rays x (1 + bounces) to *budget */
static int group_ok(const unsigned char *rec, uint32_t nr, double *budget)
{
    double n = ld(rec + 8 * G_NRAYS), off = ld(rec + 8 * G_RAY_OFF), mb = ld(rec + 8 * G_BOUNCES);
    double ring = ld(rec + 8 * G_RING);
    /* in range first, so the whole-number checks and the casts' int
     * conversions are defined (a conversion, not a call to floor: this
     * runs for every group of every scan) */
    if (!(n >= 1) || !(off >= 0) || !(off + n <= nr) || !(mb >= 0 && mb <= MAX_BOUNCES_LIMIT) ||
        !(ring >= -1 && ring <= INT32_MAX) || n != (double)(int64_t)n ||
        off != (double)(int64_t)off || mb != (double)(int64_t)mb)
        return 0;
    *budget += n * (1 + mb);
    return 1;
}

/* Casts the rays of the ng groups at `groups` (header checked) from a
 * robot at (X, Y, TH), not seeing body `exclude`: sets each group's state
 * in gs (its position, heading, nearest echo) and appends the bounced
 * echoes to ev (room for every ray). The caller holds the world's read
 * lock. Returns 1, 0 when out of memory, -1 when a group is malformed or
 * the groups do not add up to the header's budget. */
static int scan_cast(const World *w, double X, double Y, double TH, const unsigned char *groups,
                     int ng, int exclude, GroupState *gs, Event *ev, RayDir *dirs, int *nev_out)
{
    const double ct = cos(TH), st = sin(TH);
    const unsigned char *rays = groups + GROUPS_HEADER + (size_t)ng * GROUP_BYTES;
    uint32_t nr, claimed;
    memcpy(&nr, groups + 8, 4);
    memcpy(&claimed, groups + 12, 4);
    double budget = 0;
    int nev = 0;
    double reach = 0, offset = 0;
    /* a laser's groups share their sensor's place: its offset is worked
     * out once */
    double lx = NAN, ly = NAN, o = 0;
    for (int i = 0; i < ng; i++) {
        GroupState *s = &gs[i];
        s->rec = groups + GROUPS_HEADER + (size_t)i * GROUP_BYTES;
        /* the records come from memory at every scan (the traces of the
         * scan before pushed them out of the caches): ask for those a few
         * groups ahead, the loads of each stalled this loop */
        if (i + 8 < ng) {
            const unsigned char *ahead = s->rec + 8 * GROUP_BYTES;
            __builtin_prefetch(ahead);
            __builtin_prefetch(ahead + 64);
            __builtin_prefetch(ahead + GROUP_BYTES - 1);
        }
        if (!group_ok(s->rec, nr, &budget)) return -1;
        const double gx = GF(s, G_X), gy = GF(s, G_Y), maxr = GF(s, G_MAX);
        s->px = X + ct * gx - st * gy;
        s->py = Y + st * gx + ct * gy;
        s->hx = ct * GF(s, G_HC) - st * GF(s, G_HS);
        s->hy = st * GF(s, G_HC) + ct * GF(s, G_HS);
        s->raw = maxr;
        s->echo = 0;
        if (!(gx == lx && gy == ly)) {
            o = sqrt(gx * gx + gy * gy);
            lx = gx;
            ly = gy;
        }
        if (o + maxr > reach) reach = o + maxr;
        if (o > offset) offset = o;
    }

    /* the bodies within reach of the scan (a ray never gets farther than its
     * max range from its sensor) for the legs after a reflection, and by
     * sector for the first legs */
    const BodyIndex *bi = &w->bodies;
    Body *bodies = NULL;
    SectorTable sectors;
    sectors.b = NULL;
    int nscan = 0;
    if (bi->n > 0) {
        bodies = enif_alloc((size_t)bi->n * sizeof(Body));
        if (bodies)
            nscan = bodies_near(bi, exclude, X - reach, Y - reach, X + reach, Y + reach, 1, X, Y,
                                reach, bodies);
        if (!bodies || (nscan > 0 && !build_sectors(&sectors, bodies, nscan, X, Y, offset))) {
            if (bodies) enif_free(bodies);
            return 0;
        }
    }
    Ctx c = {w, bodies, nscan};
    Ctx first = {w, NULL, 0};
    /* every ray's direction in the world and its sector, before any is
     * traced: the divisions of sector_of then overlap one another, where
     * each stalled the trace after it (a quarter of a scan's own time) */
    for (uint32_t j = 0; j < nr; j++) {
        const unsigned char *p = rays + (size_t)j * 16;
        double rc = ld(p), rs = ld(p + 8);
        dirs[j].dx = ct * rc - st * rs;
        dirs[j].dy = st * rc + ct * rs;
        dirs[j].sec = nscan > 0 ? sector_of(dirs[j].dx, dirs[j].dy) : 0;
    }
    for (int i = 0; i < ng; i++) {
        GroupState *s = &gs[i];
        const int n = (int)GF(s, G_NRAYS), off = (int)GF(s, G_RAY_OFF);
        const int mb = (int)GF(s, G_BOUNCES), ring = (int)GF(s, G_RING);
        const double maxr = GF(s, G_MAX), cc = GF(s, G_COS_CRIT);
        for (int k = 0; k < n; k++) {
            const double dx = dirs[off + k].dx, dy = dirs[off + k].dy;
            RayResult r;
            if (nscan > 0) {
                int sec = dirs[off + k].sec;
                first.b = sectors.b + sectors.start[sec];
                first.nb = sectors.start[sec + 1] - sectors.start[sec];
            }
            if (cc < -1.0) {
                /* every hit echoes (a laser beam): the first leg's hit is
                 * the reading, as cast_one would find it */
                Hit h;
                trace(&first, s->px, s->py, dx, dy, maxr, &h);
                if (h.kind == HIT_NONE) continue;
                if (h.t < s->raw) s->raw = h.t;
                s->echo = 1;
                continue;
            }
            cast_one(&first, &c, s->px, s->py, dx, dy, maxr, mb, cc, &r);
            if (r.kind == HIT_NONE) continue;
            if (r.range < s->raw) s->raw = r.range;
            s->echo = 1;
            if (ring >= 0 && r.bounces > 0) {
                Event *e = &ev[nev++];
                e->px = r.px;
                e->py = r.py;
                e->path = r.range;
                e->ring = ring;
                e->emitter = i;
            }
        }
    }
    if (bodies) enif_free(bodies);
    if (sectors.b) enif_free(sectors.b);
    *nev_out = nev;
    return budget == (double)claimed ? 1 : -1;
}

/* crosstalk: a bounced echo from P reaches every other transducer of the
 * ring whose cone contains P (no line-of-sight check on the return) */
static void scan_crosstalk(GroupState *gs, int ng, const Event *ev, int nev)
{
    for (int e = 0; e < nev; e++) {
        for (int j = 0; j < ng; j++) {
            GroupState *s = &gs[j];
            if (j == ev[e].emitter || (int)GF(s, G_RING) != ev[e].ring) continue;
            double vx = ev[e].px - s->px, vy = ev[e].py - s->py;
            double d = sqrt(vx * vx + vy * vy);
            if (vx * s->hx + vy * s->hy < d * GF(s, G_COS_HALF_FOV)) continue;
            double arrival = 0.5 * (ev[e].path + d);
            if (arrival < s->raw && arrival < GF(s, G_MAX)) {
                s->raw = arrival;
                s->echo = 1;
            }
        }
    }
}

/* The groups' readings after noise and faults, into out[0 .. ng). One
 * splitmix64 stream from the hashed seed, drawn from in group order and
 * only as needed: a Gaussian (the ziggurat) for a noisy echo, a uniform
 * for the fault when the group has faults, another for a spike's
 * value. */
static void scan_readings(const GroupState *gs, int ng, uint64_t seed, double *out)
{
    uint64_t rng = seed;
    rng = splitmix64(&rng);
    for (int i = 0; i < ng; i++) {
        const GroupState *s = &gs[i];
        const double minr = GF(s, G_MIN), maxr = GF(s, G_MAX);
        const double pd = GF(s, G_DROPOUT), ps = GF(s, G_SPIKE);
        double r = s->raw;
        if (s->echo) {
            const double sigma = GF(s, G_NOISE_STD) + GF(s, G_NOISE_PROP) * r;
            const double z = sigma > 0 ? gaussian(&rng) : 0.0;
            r = clampd(r + GF(s, G_BIAS) + sigma * z, minr, maxr);
        }
        /* faults: one uniform draw, dropout and spike are exclusive */
        if (pd > 0 || ps > 0) {
            double uf = uniform(&rng);
            if (uf < pd) {
                if (s->echo) r = maxr;
            } else if (uf < pd + ps) {
                double m = GF(s, G_SPIKE_MAG), uv = uniform(&rng);
                r = m > 0 ? clampd(r + (2 * uv - 1) * m, minr, maxr) : minr + uv * (maxr - minr);
            }
        }
        out[i] = r;
    }
}

/* the readings as a binary of float64s (as_list 0) or a list of floats */
static ERL_NIF_TERM scan_core(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[], int as_list)
{
    World *w;
    ErlNifBinary gb;
    int arity, exclude;
    const ERL_NIF_TERM *pose;
    double X, Y, TH;
    ErlNifUInt64 seed;
    unsigned nr;
    (void)argc;
    if (!get_world(env, argv[0], &w) || !enif_get_tuple(env, argv[1], &arity, &pose) ||
        arity != 3 || !tc_number(env, pose[0], &X) || !tc_number(env, pose[1], &Y) ||
        !tc_number(env, pose[2], &TH) || !enif_inspect_binary(env, argv[2], &gb) ||
        !enif_get_int(env, argv[3], &exclude) || !enif_get_uint64(env, argv[4], &seed))
        return enif_make_badarg(env);
    /* the header was checked by nif_scan / nif_scan_list (scan_check):
     * only the counts are read again here; scan_cast checks the groups */
    uint32_t ng32, nr32;
    memcpy(&ng32, gb.data + 4, 4);
    memcpy(&nr32, gb.data + 8, 4);
    int ng = (int)ng32;
    nr = nr32;

    size_t scratch = (size_t)ng * (sizeof(GroupState) + sizeof(double)) +
                     (size_t)nr * (sizeof(Event) + sizeof(RayDir));
    GroupState *gs = enif_alloc(scratch > 0 ? scratch : 1);
    if (!gs) return enif_make_badarg(env);
    Event *ev = (Event *)(gs + ng);
    double *readings = (double *)(ev + nr);
    RayDir *dirs = (RayDir *)(readings + ng);
    int nev = 0;
    enif_rwlock_rlock(w->lock);
    int ok = scan_cast(w, X, Y, TH, gb.data, ng, exclude, gs, ev, dirs, &nev);
    enif_rwlock_runlock(w->lock);
    if (ok != 1) {
        enif_free(gs);
        return enif_make_badarg(env);
    }
    scan_crosstalk(gs, ng, ev, nev);
    scan_readings(gs, ng, (uint64_t)seed, readings);

    ERL_NIF_TERM out;
    if (as_list) {
        ERL_NIF_TERM *cells = enif_alloc((size_t)(ng > 0 ? ng : 1) * sizeof(ERL_NIF_TERM));
        if (!cells) {
            enif_free(gs);
            return enif_make_badarg(env);
        }
        for (int i = 0; i < ng; i++)
            cells[i] = enif_make_double(env, readings[i]);
        out = enif_make_list_from_array(env, cells, (unsigned)ng);
        enif_free(cells);
    } else {
        unsigned char *o = enif_make_new_binary(env, (size_t)ng * 8, &out);
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
        memcpy(o, readings, (size_t)ng * 8);
#else
        for (int i = 0; i < ng; i++) {
            uint64_t bits;
            memcpy(&bits, &readings[i], 8);
            for (int b = 0; b < 8; b++)
                o[8 * i + b] = (unsigned char)(bits >> (8 * b));
        }
#endif
    }
    enif_free(gs);
    return out;
}

static ERL_NIF_TERM scan_impl(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    return scan_core(env, argc, argv, 0);
}

static ERL_NIF_TERM scan_list_impl(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    return scan_core(env, argc, argv, 1);
}

/* -1: malformed groups; 1: a call long enough for a dirty scheduler; 0:
 * short. Every scan is checked here once, before scan_core. */
static int scan_check(ErlNifEnv *env, ERL_NIF_TERM groups)
{
    ErlNifBinary gb;
    unsigned nr;
    double budget;
    if (!enif_inspect_binary(env, groups, &gb) || groups_header(&gb, &nr, &budget) < 0) return -1;
    return budget > DIRTY_RAY_BUDGET;
}

static ERL_NIF_TERM nif_scan(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    int k = scan_check(env, argv[2]);
    if (k < 0) return enif_make_badarg(env);
    if (k)
        return enif_schedule_nif(env, "scan_dirty", ERL_NIF_DIRTY_JOB_CPU_BOUND, scan_impl, argc,
                                 argv);
    return scan_impl(env, argc, argv);
}

static ERL_NIF_TERM nif_scan_list(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    int k = scan_check(env, argv[2]);
    if (k < 0) return enif_make_badarg(env);
    if (k)
        return enif_schedule_nif(env, "scan_list_dirty", ERL_NIF_DIRTY_JOB_CPU_BOUND,
                                 scan_list_impl, argc, argv);
    return scan_list_impl(env, argc, argv);
}

/* ---- clearance ---- */

static double seg_dist(const Seg *s, double x, double y)
{
    double qx = x - s->ax, qy = y - s->ay;
    double u = clampd((qx * s->ex + qy * s->ey) * s->inv_len2, 0, 1);
    double rx = qx - u * s->ex, ry = qy - u * s->ey;
    return sqrt(rx * rx + ry * ry);
}

static double grid_clearance(const World *w, double x, double y, double best)
{
    const int W = w->gw, H = w->gh;
    double rx = x - w->gox, ry = y - w->goy;
    double qx = (rx * w->gc + ry * w->gs) * w->inv_res;
    double qy = (-rx * w->gs + ry * w->gc) * w->inv_res;
    double lim = best * w->inv_res; /* in cells */
    /* distance to the grid's rectangle */
    double ox = fmax(fmax(-qx, qx - W), 0), oy = fmax(fmax(-qy, qy - H), 0);
    if (ox * ox + oy * oy >= lim * lim) return best;
    int ci = (int)floor(qx), cj = (int)floor(qy);
    int k0 = 0;
    if (ci >= 0 && ci < W && cj >= 0 && cj < H) {
        unsigned c = w->code[cell_index(w->gtw, ci, cj)];
        if (c == CODE_OBST) return 0;
        if ((double)c >= lim) return best;
        k0 = (int)floor(c / M_SQRT2) - 1;
        if (k0 < 0) k0 = 0;
    }
    double kmax = ceil(lim) + 1;
    for (int k = k0; k <= kmax; k++) {
        if (k - 1 >= lim) break;
        for (int j = cj - k; j <= cj + k; j++) {
            if (j < 0 || j >= H) continue;
            int edge = (j == cj - k || j == cj + k);
            int step = edge ? 1 : 2 * k;
            for (int i = ci - k; i <= ci + k; i += (step > 0 ? step : 1)) {
                if (i < 0 || i >= W || w->code[cell_index(w->gtw, i, j)] != CODE_OBST) continue;
                double dx = fmax(fmax(i - qx, qx - (i + 1)), 0);
                double dy = fmax(fmax(j - qy, qy - (j + 1)), 0);
                double d = sqrt(dx * dx + dy * dy);
                if (d < lim) lim = d;
            }
        }
    }
    return lim * w->res;
}

/* ranges_min(readings, first, count): the least of count float64s of a
 * scan/5 binary from index first (count >= 1, within the binary) */
static ERL_NIF_TERM nif_ranges_min(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary b;
    unsigned long first, count;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &b) || !enif_get_ulong(env, argv[1], &first) ||
        !enif_get_ulong(env, argv[2], &count) || count == 0 || b.size % 8 != 0 ||
        first >= b.size / 8 || count > b.size / 8 - first)
        return enif_make_badarg(env);
    double least = ld(b.data + 8 * first);
    for (unsigned long i = 1; i < count; i++) {
        double r = ld(b.data + 8 * (first + i));
        if (r < least) least = r;
    }
    return enif_make_double(env, least);
}

static ERL_NIF_TERM nif_clearance(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    World *w;
    double x, y, max;
    int exclude;
    (void)argc;
    if (!get_world(env, argv[0], &w) || !tc_number(env, argv[1], &x) ||
        !tc_number(env, argv[2], &y) || !enif_get_int(env, argv[3], &exclude) ||
        !tc_number(env, argv[4], &max))
        return enif_make_badarg(env);
    if (!(max > 0)) return enif_make_double(env, 0.0);
    double best = max;
    enif_rwlock_rlock(w->lock);
    if (w->nseg_on > 0) {
        int i0 = (int)floor((x - best - w->sx0) * w->sinvh), i1 = (int)floor((x + best - w->sx0) * w->sinvh);
        int j0 = (int)floor((y - best - w->sy0) * w->sinvh), j1 = (int)floor((y + best - w->sy0) * w->sinvh);
        i0 = clampi(i0, 0, w->sw - 1);
        i1 = clampi(i1, 0, w->sw - 1);
        j0 = clampi(j0, 0, w->sgh - 1);
        j1 = clampi(j1, 0, w->sgh - 1);
        int overlaps = (x + best >= w->sx0 && x - best <= w->sx0 + w->sw * w->sh &&
                        y + best >= w->sy0 && y - best <= w->sy0 + w->sgh * w->sh);
        if (overlaps) {
            if ((double)(i1 - i0 + 1) * (j1 - j0 + 1) > w->nseg) {
                for (int s = 0; s < w->nseg; s++)
                    if (w->seg_on[s]) best = fmin(best, seg_dist(&w->seg[s], x, y));
            } else {
                for (int j = j0; j <= j1; j++)
                    for (int i = i0; i <= i1; i++) {
                        int b = j * w->sw + i;
                        for (int k = w->sstart[b]; k < w->sstart[b + 1]; k++) {
                            int s = w->sitems[k];
                            if (w->seg_on[s]) best = fmin(best, seg_dist(&w->seg[s], x, y));
                        }
                    }
            }
        }
    }
    const BodyIndex *bi = &w->bodies;
    if (bi->n > 0) {
        /* the bodies whose bucket is within best + rmax; the others are
         * farther than best */
        const double m = best + bi->rmax;
        const int i0 = bucket_of((x - m - bi->x0) * bi->inv, bi->w);
        const int i1 = bucket_of((x + m - bi->x0) * bi->inv, bi->w);
        const int j0 = bucket_of((y - m - bi->y0) * bi->inv, bi->h);
        const int j1 = bucket_of((y + m - bi->y0) * bi->inv, bi->h);
        for (int j = j0; j <= j1; j++)
            for (int k = bi->start[j * bi->w + i0]; k < bi->start[j * bi->w + i1 + 1]; k++) {
                const Body *b = &bi->b[bi->items[k]];
                if (b->id == exclude) continue;
                double d = hypot(x - b->x, y - b->y) - b->r;
                best = fmin(best, d > 0 ? d : 0);
            }
    }
    if (w->has_grid && best > 0) best = grid_clearance(w, x, y, best);
    enif_rwlock_runlock(w->lock);
    return enif_make_double(env, best);
}

/* ------------------------------------------------------------------ */

static int load(ErlNifEnv *env, void **priv, ERL_NIF_TERM info)
{
    (void)priv;
    (void)info;
    WORLD_RT = enif_open_resource_type(env, NULL, "tc_raycast_world", world_dtor,
                                       ERL_NIF_RT_CREATE | ERL_NIF_RT_TAKEOVER, NULL);
    if (!WORLD_RT) return 1;
    A_OK = enif_make_atom(env, "ok");
    A_ERROR = enif_make_atom(env, "error");
    A_NIL = enif_make_atom(env, "nil");
    A_TRUE = enif_make_atom(env, "true");
    A_FALSE = enif_make_atom(env, "false");
    A_NONE = enif_make_atom(env, "none");
    A_GRID = enif_make_atom(env, "grid");
    A_SEGMENT = enif_make_atom(env, "segment");
    A_BODY = enif_make_atom(env, "body");
    A_RANGE = enif_make_atom(env, "range");
    A_HIT = enif_make_atom(env, "hit");
    A_BOUNCES = enif_make_atom(env, "bounces");
    A_ID = enif_make_atom(env, "id");
    ziggurat_setup();
    return 0;
}

static int upgrade(ErlNifEnv *env, void **priv, void **old_priv, ERL_NIF_TERM info)
{
    (void)old_priv;
    return load(env, priv, info);
}

static ErlNifFunc funcs[] = {
    {"nif_new", 2, nif_new, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"set_segment", 3, nif_set_segment, 0},
    {"set_bodies", 2, nif_set_bodies, 0},
    {"set_bodies_packed", 3, nif_set_bodies_packed, 0},
    {"contacts", 1, nif_contacts, 0},
    {"walkers_step", 4, nif_walkers_step, 0},
    {"records_box", 1, nif_records_box, 0},
    {"records_within", 5, nif_records_within, 0},
    {"nif_cast_rays", 5, nif_cast_rays, 0},
    {"scan", 5, nif_scan, 0},
    {"scan_list", 5, nif_scan_list, 0},
    {"ranges_min", 3, nif_ranges_min, 0},
    {"clearance", 5, nif_clearance, 0},
};

ERL_NIF_INIT(Elixir.ThinkingCap.Sim.Raycast, funcs, load, NULL, upgrade, NULL)
