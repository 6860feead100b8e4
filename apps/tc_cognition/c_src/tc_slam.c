/*
 * tc_slam: the two numerical parts of pose-graph SLAM for the grid NIF
 * (see tc_grid.c; ThinkingCap.Navigation.Maps.PoseGraph wraps them).
 *
 * slam_match: correlative scan matching (Olson, "Real-time correlative
 * scan matching", ICRA 2009). The reference points (a submap, in the
 * world) are drawn into a likelihood grid: exp(-d^2 / 2 sigma^2), d the
 * exact distance to the nearest point (Felzenszwalb and Huttenlocher's
 * separable transform). The query scan (points in the robot's frame) is
 * scored at every pose of a window round a guess: every heading step
 * small enough to move the farthest point by at most a cell, every whole
 * cell offset. The best pose is then refined by hill climbing on the
 * bilinear likelihood, and the spread of the scores round it gives the
 * match's covariance (a wide spread along a corridor says the match
 * does not fix that direction).
 *
 * slam_optimize: Gauss-Newton on a 2-D pose graph (Grisetti et al., "A
 * tutorial on graph-based SLAM", 2010): each edge says where node j
 * lies seen from node i, with an information matrix; node 0 is held.
 * The sparse normal equations are solved by conjugate gradients,
 * preconditioned by the graph's chain (see chain_factor). Returns the poses and every edge's
 * chi-square, so that the caller can drop an edge that does not fit.
 */
#include "tc_slam.h"
#include "tc_edt.h"
#include "tc_nif.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define MAX_POINTS 100000
#define MAX_CELLS (8 * 1024 * 1024)
#define MAX_NODES 200000
#define INF 1e20

static int triple(ErlNifEnv *env, ERL_NIF_TERM t, double out[3])
{
    int a;
    const ERL_NIF_TERM *e;
    return enif_get_tuple(env, t, &a, &e) && a == 3 && tc_number(env, e[0], &out[0]) &&
           tc_number(env, e[1], &out[1]) && tc_number(env, e[2], &out[2]);
}

static int pair(ErlNifEnv *env, ERL_NIF_TERM t, double out[2])
{
    int a;
    const ERL_NIF_TERM *e;
    return enif_get_tuple(env, t, &a, &e) && a == 2 && tc_number(env, e[0], &out[0]) &&
           tc_number(env, e[1], &out[1]);
}

/* a binary of native doubles, k per item, all finite */
static int doubles(ErlNifEnv *env, ERL_NIF_TERM t, int k, int max, const double **out, int *n)
{
    ErlNifBinary b;
    if (!enif_inspect_binary(env, t, &b) || b.size % (k * sizeof(double)) != 0) return 0;
    size_t items = b.size / (k * sizeof(double));
    if (items > (size_t)max) return 0;
    const double *d = (const double *)b.data;
    for (size_t i = 0; i < items * k; i++)
        if (!isfinite(d[i])) return 0;
    *out = d;
    *n = (int)items;
    return 1;
}

/* ---- the likelihood grid ---- */

typedef struct {
    int w, h;
    double res, ox, oy;
    float *l; /* likelihood per cell */
} Lgrid;

/* The likelihood of a point at each cell's centre: a Gaussian of its
 * distance to the nearest reference point. The distance is to the point
 * itself, not to the centre of the cell it falls in: measured from cell
 * centres, a wall lying on a cells' border is moved half a cell, and each
 * node of a chain matched against the one before inherited that. */
static int lgrid_build(Lgrid *g, const double *pts, int n, double margin, double res, double sigma)
{
    double x0 = INF, y0 = INF, x1 = -INF, y1 = -INF;
    for (int i = 0; i < n; i++) {
        x0 = fmin(x0, pts[2 * i]);
        x1 = fmax(x1, pts[2 * i]);
        y0 = fmin(y0, pts[2 * i + 1]);
        y1 = fmax(y1, pts[2 * i + 1]);
    }
    g->res = res;
    g->ox = x0 - margin;
    g->oy = y0 - margin;
    g->w = (int)ceil((x1 - x0 + 2 * margin) / res) + 1;
    g->h = (int)ceil((y1 - y0 + 2 * margin) / res) + 1;
    if ((double)g->w * g->h > MAX_CELLS) return 0;
    int w = g->w, h = g->h;
    unsigned char *seeds = calloc((size_t)w * h, 1);
    /* a point of each seed cell (the last one in it) */
    int *point = malloc(sizeof(int) * w * h);
    g->l = malloc(sizeof(float) * w * h);
    if (!seeds || !point || !g->l) {
        free(seeds), free(point), free(g->l);
        return 0;
    }
    for (int i = 0; i < n; i++) {
        int c = (int)floor((pts[2 * i] - g->ox) / res), r = (int)floor((pts[2 * i + 1] - g->oy) / res);
        if (c >= 0 && r >= 0 && c < w && r < h) seeds[(size_t)r * w + c] = 1, point[(size_t)r * w + c] = i;
    }
    int *near = tc_edt2_nearest(seeds, w, h);
    free(seeds);
    if (!near) {
        free(point), free(g->l);
        return 0;
    }
    double k = 1.0 / (2 * sigma * sigma);
    for (int r = 0; r < h; r++) {
        double cy = g->oy + (r + 0.5) * res;
        for (int c = 0; c < w; c++) {
            size_t i = (size_t)r * w + c;
            if (near[i] < 0) {
                g->l[i] = 0.0f;
                continue;
            }
            const double *p = pts + 2 * point[near[i]];
            double dx = g->ox + (c + 0.5) * res - p[0], dy = cy - p[1];
            g->l[i] = (float)exp(-(dx * dx + dy * dy) * k);
        }
    }
    free(near), free(point);
    return 1;
}

/* the likelihood at a world point, bilinear */
static double lgrid_at(const Lgrid *g, double x, double y)
{
    double fc = (x - g->ox) / g->res - 0.5, fr = (y - g->oy) / g->res - 0.5;
    int c = (int)floor(fc), r = (int)floor(fr);
    if (c < 0 || r < 0 || c + 1 >= g->w || r + 1 >= g->h) return 0.0;
    double a = fc - c, b = fr - r;
    const float *p = g->l + (size_t)r * g->w + c;
    return (1 - a) * (1 - b) * p[0] + a * (1 - b) * p[1] + (1 - a) * b * p[g->w] + a * b * p[g->w + 1];
}

static double score_at(const Lgrid *g, const double *q, int n, double x, double y, double th)
{
    double c = cos(th), s = sin(th), sum = 0.0;
    for (int i = 0; i < n; i++)
        sum += lgrid_at(g, x + c * q[2 * i] - s * q[2 * i + 1], y + s * q[2 * i] + c * q[2 * i + 1]);
    return sum;
}

/* slam_match(ref, query, {x, y, th}, {window_m, window_rad}, res, sigma)
 *   -> {{x, y, th}, score, {cxx, cxy, cxt, cyy, cyt, ctt}, score_at_guess, ridge}
 *      | :none (nothing to match, or the best pose on the window's border,
 *        unless on a ridge of scores: see below)
 * ridge: true when the scores run level one way through the window (a
 * corridor): the match then fixes the pose only across that way
 * scores are mean likelihoods of the query's points, 0 to 1 */
ERL_NIF_TERM tc_nif_slam_match(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    const double *ref, *q;
    int nr, nq;
    double guess[3], win[2], res, sigma;
    if (!doubles(env, argv[0], 2, MAX_POINTS, &ref, &nr) ||
        !doubles(env, argv[1], 2, MAX_POINTS, &q, &nq) || !triple(env, argv[2], guess) ||
        !pair(env, argv[3], win) || !tc_number(env, argv[4], &res) || !tc_number(env, argv[5], &sigma) ||
        res <= 0.005 || sigma <= 0 || win[0] < 0 || win[1] < 0 || win[0] > 5.0 || win[1] > M_PI)
        return enif_make_badarg(env);
    if (nr == 0 || nq == 0) return enif_make_atom(env, "none");

    double rmax = 0.0;
    for (int i = 0; i < nq; i++) rmax = fmax(rmax, hypot(q[2 * i], q[2 * i + 1]));
    /* the query must land on the grid anywhere in the window */
    Lgrid g;
    /* the likelihood at half the search's step: a point's place is known
     * to a quarter of a cell */
    if (!lgrid_build(&g, ref, nr, win[0] + 3 * sigma + res, res / 2, sigma))
        return enif_make_atom(env, "none");

    double dth = rmax > res ? res / rmax : 0.05;
    if (win[1] > 0 && dth > win[1]) dth = win[1];
    int K = win[1] > 0 ? (int)ceil(win[1] / dth) : 0;
    int U = (int)ceil(win[0] / res);
    int side = 2 * U + 1;
    size_t nposes = (size_t)(2 * K + 1) * side * side;
    float *scores = malloc(sizeof(float) * nposes);
    int *cells = malloc(sizeof(int) * 2 * nq);
    if (!scores || !cells) {
        free(scores), free(cells), free(g.l);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    double best = -1.0;
    int bk = 0, bu = 0, bv = 0;
    for (int k = -K; k <= K; k++) {
        double th = guess[2] + k * dth, c = cos(th), s = sin(th);
        for (int i = 0; i < nq; i++) {
            double x = guess[0] + c * q[2 * i] - s * q[2 * i + 1];
            double y = guess[1] + s * q[2 * i] + c * q[2 * i + 1];
            cells[2 * i] = (int)floor((x - g.ox) / g.res);
            cells[2 * i + 1] = (int)floor((y - g.oy) / g.res);
        }
        for (int v = -U; v <= U; v++)
            for (int u = -U; u <= U; u++) {
                double sum = 0.0;
                for (int i = 0; i < nq; i++) {
                    int cc = cells[2 * i] + 2 * u, rr = cells[2 * i + 1] + 2 * v;
                    if (cc >= 0 && rr >= 0 && cc < g.w && rr < g.h) sum += g.l[(size_t)rr * g.w + cc];
                }
                scores[((size_t)(k + K) * side + (v + U)) * side + (u + U)] = (float)sum;
                if (sum > best) best = sum, bk = k, bu = u, bv = v;
            }
    }

    /* a best heading on the window's border may be the slope of a peak
     * outside it: no match */
    if (K > 0 && (bk == -K || bk == K)) {
        free(scores), free(cells), free(g.l);
        return enif_make_atom(env, "none");
    }
    int xy_border = U > 0 && (bu == -U || bu == U || bv == -U || bv == U);
    double at_guess = scores[((size_t)K * side + U) * side + U];

    /* the spread of the scores round the best: weights exp(beta (s - best)),
     * beta from the beams' count (neighbouring beams are not independent:
     * a pose a few points worse is not much less likely) */
    double beta = 4.0 / fmax(1.0, nq / 20.0);
    double sw = 0, mx = 0, my = 0, mt = 0, sxx = 0, sxy = 0, sxt = 0, syy = 0, syt = 0, stt = 0;
    for (int k = -K; k <= K; k++)
        for (int v = -U; v <= U; v++)
            for (int u = -U; u <= U; u++) {
                double s = scores[((size_t)(k + K) * side + (v + U)) * side + (u + U)];
                double wgt = exp(beta * (s - best));
                if (wgt < 1e-6) continue;
                double x = (u - bu) * res, y = (v - bv) * res, t = (k - bk) * dth;
                sw += wgt;
                mx += wgt * x, my += wgt * y, mt += wgt * t;
                sxx += wgt * x * x, sxy += wgt * x * y, sxt += wgt * x * t;
                syy += wgt * y * y, syt += wgt * y * t, stt += wgt * t * t;
            }
    free(cells);
    mx /= sw, my /= sw, mt /= sw;
    double cxx = sxx / sw - mx * mx + res * res / 12, cxy = sxy / sw - mx * my;
    double cxt = sxt / sw - mx * mt, cyy = syy / sw - my * my + res * res / 12;
    double cyt = syt / sw - my * mt, ctt = stt / sw - mt * mt + dth * dth / 12;

    /* whether the scores form a ridge (a corridor: its length not fixed)
     * that runs level through the window: the spread much longer one way
     * than across, the best well inside the window across it, and along
     * it, at the best heading, the best score within a cell and a half of
     * its line at least 90 % of the best all the way, over at least the
     * window's width. The slope of a peak beyond the window's border
     * falls away from it instead. */
    int ridge = 0;
    {
        double tr = cxx + cyy, det = cxx * cyy - cxy * cxy;
        double disc = sqrt(fmax(0.0, tr * tr / 4 - det));
        double big = tr / 2 + disc, small = tr / 2 - disc;
        /* the ridge's direction: the eigenvector of the larger eigenvalue */
        double ex = cxy, ey = big - cxx;
        if (fabs(ex) + fabs(ey) < 1e-12) ex = big - cyy, ey = cxy;
        if (fabs(ex) + fabs(ey) < 1e-12) ex = 1.0, ey = 0.0;
        double en = hypot(ex, ey);
        ex /= en, ey /= en;
        double across = fabs(-ey * bu * res + ex * bv * res);
        int nb = 2 * side + 1;
        float *level = (U > 0 && big >= 9 * small && across <= win[0] - 2 * res)
                           ? calloc((size_t)nb, sizeof(float))
                           : NULL;
        if (level) {
            for (int v = -U; v <= U; v++)
                for (int u = -U; u <= U; u++) {
                    double du = (u - bu) * res, dv = (v - bv) * res;
                    if (fabs(-ey * du + ex * dv) > 1.5 * res) continue;
                    int b = (int)lround((ex * du + ey * dv) / res) + side;
                    float sc = scores[((size_t)(bk + K) * side + (v + U)) * side + (u + U)];
                    if (b >= 0 && b < nb && sc > level[b]) level[b] = sc;
                }
            int first = -1, last = -1;
            for (int b = 0; b < nb; b++)
                if (level[b] > 0) {
                    if (first < 0) first = b;
                    last = b;
                }
            ridge = first >= 0 && (last - first) * res >= win[0];
            /* (the best of three neighbouring steps: points spaced evenly
             * along a wall make the scores ripple along it) */
            for (int b = first; ridge && b <= last; b++) {
                float m = level[b];
                if (b > first && level[b - 1] > m) m = level[b - 1];
                if (b < last && level[b + 1] > m) m = level[b + 1];
                if (m < 0.9 * best) ridge = 0;
            }
            free(level);
        }
    }
    free(scores);

    /* a best place on the window's border may be the slope of a peak
     * outside it: no match, unless on a ridge */
    if (xy_border && !ridge) {
        free(g.l);
        return enif_make_atom(env, "none");
    }

    /* refine: hill climbing on the bilinear likelihood */
    double x = guess[0] + bu * res, y = guess[1] + bv * res, th = guess[2] + bk * dth;
    double cur = score_at(&g, q, nq, x, y, th), sl = res / 2, sa = dth / 2;
    while (sl > res / 16) {
        int moved = 0;
        double cand[6][3] = {{x + sl, y, th}, {x - sl, y, th}, {x, y + sl, th},
                             {x, y - sl, th}, {x, y, th + sa}, {x, y, th - sa}};
        for (int i = 0; i < 6; i++) {
            double s = score_at(&g, q, nq, cand[i][0], cand[i][1], cand[i][2]);
            if (s > cur) cur = s, x = cand[i][0], y = cand[i][1], th = cand[i][2], moved = 1;
        }
        if (!moved) sl /= 2, sa /= 2;
    }
    free(g.l);
    ERL_NIF_TERM cov[6] = {enif_make_double(env, cxx), enif_make_double(env, cxy),
                           enif_make_double(env, cxt), enif_make_double(env, cyy),
                           enif_make_double(env, cyt), enif_make_double(env, ctt)};
    return enif_make_tuple5(
        env,
        enif_make_tuple3(env, enif_make_double(env, x), enif_make_double(env, y),
                         enif_make_double(env, tc_wrap(th))),
        enif_make_double(env, cur / nq), enif_make_tuple_from_array(env, cov, 6),
        enif_make_double(env, at_guess / nq), enif_make_atom(env, ridge ? "true" : "false"));
}

/* ---- the pose graph ---- */

typedef struct {
    int i, j;
    double z[3];
    double om[9]; /* information, row-major, symmetric */
} Edge;

/* y = A x for 3x3 row-major */
static void mv3(const double *a, const double *x, double *y)
{
    for (int r = 0; r < 3; r++) y[r] = a[3 * r] * x[0] + a[3 * r + 1] * x[1] + a[3 * r + 2] * x[2];
}

/* an edge's error and its Jacobians A (wrt node i) and B (wrt node j) */
static void edge_error(const double *xi, const double *xj, const Edge *e, double err[3], double A[9],
                       double B[9])
{
    double ci = cos(xi[2]), si = sin(xi[2]), cz = cos(e->z[2]), sz = sin(e->z[2]);
    double dx = xj[0] - xi[0], dy = xj[1] - xi[1];
    /* Ri^T (tj - ti) */
    double lx = ci * dx + si * dy, ly = -si * dx + ci * dy;
    double ex = lx - e->z[0], ey = ly - e->z[1];
    err[0] = cz * ex + sz * ey;
    err[1] = -sz * ex + cz * ey;
    err[2] = tc_wrap(xj[2] - xi[2] - e->z[2]);
    /* d(Ri^T d)/d thi = [-si dx + ci dy; -ci dx - si dy] */
    double gx = -si * dx + ci * dy, gy = -ci * dx - si * dy;
    /* RzT RiT */
    double m00 = cz * ci - sz * si, m01 = cz * si + sz * ci; /* row 0 of RzT RiT */
    double m10 = -sz * ci - cz * si, m11 = -sz * si + cz * ci;
    A[0] = -m00, A[1] = -m01, A[2] = cz * gx + sz * gy;
    A[3] = -m10, A[4] = -m11, A[5] = -sz * gx + cz * gy;
    A[6] = 0, A[7] = 0, A[8] = -1;
    B[0] = m00, B[1] = m01, B[2] = 0;
    B[3] = m10, B[4] = m11, B[5] = 0;
    B[6] = 0, B[7] = 0, B[8] = 1;
}

/* C += P^T Q R (all 3x3) */
static void add_ptqr(double *C, const double *P, const double *Q, const double *R)
{
    double t[9];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            double s = 0;
            for (int k = 0; k < 3; k++) s += Q[3 * a + k] * R[3 * k + b];
            t[3 * a + b] = s;
        }
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            double s = 0;
            for (int k = 0; k < 3; k++) s += P[3 * k + a] * t[3 * k + b];
            C[3 * a + b] += s;
        }
}

static int inv3(const double *m, double *o)
{
    double d = m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6]) +
               m[2] * (m[3] * m[7] - m[4] * m[6]);
    if (fabs(d) < 1e-300) return 0;
    o[0] = (m[4] * m[8] - m[5] * m[7]) / d;
    o[1] = (m[2] * m[7] - m[1] * m[8]) / d;
    o[2] = (m[1] * m[5] - m[2] * m[4]) / d;
    o[3] = (m[5] * m[6] - m[3] * m[8]) / d;
    o[4] = (m[0] * m[8] - m[2] * m[6]) / d;
    o[5] = (m[2] * m[3] - m[0] * m[5]) / d;
    o[6] = (m[3] * m[7] - m[4] * m[6]) / d;
    o[7] = (m[1] * m[6] - m[0] * m[7]) / d;
    o[8] = (m[0] * m[4] - m[1] * m[3]) / d;
    return 1;
}

/* y = H x, H given by diagonal blocks D (n) and one off-diagonal block per
 * edge (O, the (i, j) block; (j, i) is its transpose) */
static void hmul(int n, const double *D, int m, const Edge *es, const double *O, const double *x,
                 double *y)
{
    for (int i = 0; i < n; i++) mv3(D + 9 * i, x + 3 * i, y + 3 * i);
    for (int k = 0; k < m; k++) {
        const double *o = O + 9 * k;
        const double *xi = x + 3 * es[k].i, *xj = x + 3 * es[k].j;
        double *yi = y + 3 * es[k].i, *yj = y + 3 * es[k].j;
        for (int r = 0; r < 3; r++) {
            yi[r] += o[3 * r] * xj[0] + o[3 * r + 1] * xj[1] + o[3 * r + 2] * xj[2];
            yj[r] += o[r] * xi[0] + o[3 + r] * xi[1] + o[6 + r] * xi[2];
        }
    }
}

static double dot(const double *a, const double *b, int n)
{
    double s = 0;
    for (int i = 0; i < n; i++) s += a[i] * b[i];
    return s;
}

/* C = A B, or A^T B with ta (3x3, row-major) */
static void mm3(const double *A, int ta, const double *B, double *C)
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double s = 0;
            for (int k = 0; k < 3; k++) s += (ta ? A[3 * k + r] : A[3 * r + k]) * B[3 * k + c];
            C[3 * r + c] = s;
        }
}

/* The chain preconditioner (Dellaert et al., subgraph-preconditioned
 * conjugate gradients, 2010): H's diagonal blocks and its blocks between
 * consecutive nodes (the graph's chain), factored as block LDL^T. With
 * it, conjugate gradients need about as many steps as there are loops,
 * not as there are nodes. U: the (i, i+1) blocks; Si: the pivots'
 * inverses. Returns 0 if a pivot is singular. */
static int chain_factor(int n, const double *D, int m, const Edge *es, const double *O, double *U,
                        double *Si)
{
    for (int k = 0; k < m; k++) {
        int i = es[k].i, j = es[k].j;
        const double *o = O + 9 * k;
        if (j == i + 1)
            for (int a = 0; a < 9; a++) U[9 * i + a] += o[a];
        else if (i == j + 1)
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++) U[9 * j + 3 * r + c] += o[3 * c + r];
    }
    double S[9], T[9], V[9];
    memcpy(S, D, sizeof(S));
    for (int i = 0;; i++) {
        for (int a = 0; a < 3; a++) S[4 * a] += 1e-9;
        if (!inv3(S, Si + 9 * i)) return 0;
        if (i == n - 1) return 1;
        /* S_{i+1} = D_{i+1} - U_i^T Si_i U_i */
        mm3(Si + 9 * i, 0, U + 9 * i, T);
        mm3(U + 9 * i, 1, T, V);
        for (int a = 0; a < 9; a++) S[a] = D[9 * (i + 1) + a] - V[a];
    }
}

/* z = M^-1 r for the factored chain */
static void chain_solve(int n, const double *U, const double *Si, const double *r, double *z)
{
    double t[3], u[3];
    memcpy(z, r, sizeof(double) * 3);
    for (int i = 1; i < n; i++) {
        /* y_i = r_i - U_{i-1}^T Si_{i-1} y_{i-1} */
        mv3(Si + 9 * (i - 1), z + 3 * (i - 1), t);
        const double *Ub = U + 9 * (i - 1);
        for (int a = 0; a < 3; a++)
            z[3 * i + a] = r[3 * i + a] - (Ub[a] * t[0] + Ub[3 + a] * t[1] + Ub[6 + a] * t[2]);
    }
    mv3(Si + 9 * (n - 1), z + 3 * (n - 1), t);
    memcpy(z + 3 * (n - 1), t, sizeof(t));
    for (int i = n - 2; i >= 0; i--) {
        /* z_i = Si_i (y_i - U_i z_{i+1}) */
        mv3(U + 9 * i, z + 3 * (i + 1), u);
        for (int a = 0; a < 3; a++) u[a] = z[3 * i + a] - u[a];
        mv3(Si + 9 * i, u, z + 3 * i);
    }
}

/* one Gauss-Newton step; returns the largest change, or -1 on failure */
static double gn_step(int n, double *x, int m, const Edge *es)
{
    int N = 3 * n;
    double *D = calloc((size_t)9 * n, sizeof(double)), *O = calloc((size_t)9 * m, sizeof(double));
    double *b = calloc(N, sizeof(double)), *Si = malloc(sizeof(double) * 9 * n);
    double *U = calloc((size_t)9 * n, sizeof(double));
    double *dx = calloc(N, sizeof(double)), *r = malloc(sizeof(double) * N);
    double *z = malloc(sizeof(double) * N), *p = malloc(sizeof(double) * N);
    double *hp = malloc(sizeof(double) * N);
    double result = -1;
    if (!D || !O || !b || !Si || !U || !dx || !r || !z || !p || !hp) goto done;
    for (int k = 0; k < m; k++) {
        const Edge *e = es + k;
        double err[3], A[9], B[9], oe[3];
        edge_error(x + 3 * e->i, x + 3 * e->j, e, err, A, B);
        add_ptqr(D + 9 * e->i, A, e->om, A);
        add_ptqr(D + 9 * e->j, B, e->om, B);
        add_ptqr(O + 9 * k, A, e->om, B);
        mv3(e->om, err, oe);
        for (int a = 0; a < 3; a++) {
            b[3 * e->i + a] += A[a] * oe[0] + A[3 + a] * oe[1] + A[6 + a] * oe[2];
            b[3 * e->j + a] += B[a] * oe[0] + B[3 + a] * oe[1] + B[6 + a] * oe[2];
        }
    }
    /* node 0 held: a stiff prior */
    for (int a = 0; a < 3; a++) D[4 * a] += 1e9;
    if (!chain_factor(n, D, m, es, O, U, Si)) goto done;
    /* solve H dx = -b */
    for (int i = 0; i < N; i++) r[i] = -b[i];
    chain_solve(n, U, Si, r, z);
    memcpy(p, z, sizeof(double) * N);
    double rz = dot(r, z, N), r0 = sqrt(dot(r, r, N));
    int maxit = N < 300 ? 300 : N;
    for (int it = 0; it < maxit && sqrt(dot(r, r, N)) > 1e-9 * (r0 + 1e-30); it++) {
        hmul(n, D, m, es, O, p, hp);
        double php = dot(p, hp, N);
        if (php <= 0) break;
        double alpha = rz / php;
        for (int i = 0; i < N; i++) dx[i] += alpha * p[i], r[i] -= alpha * hp[i];
        chain_solve(n, U, Si, r, z);
        double rz2 = dot(r, z, N);
        for (int i = 0; i < N; i++) p[i] = z[i] + (rz2 / rz) * p[i];
        rz = rz2;
    }
    result = 0;
    for (int i = 0; i < n; i++) {
        x[3 * i] += dx[3 * i];
        x[3 * i + 1] += dx[3 * i + 1];
        x[3 * i + 2] = tc_wrap(x[3 * i + 2] + dx[3 * i + 2]);
        for (int a = 0; a < 3; a++) result = fmax(result, fabs(dx[3 * i + a]));
    }
done:
    free(D), free(O), free(b), free(Si), free(U), free(dx), free(r), free(z), free(p), free(hp);
    return result;
}

/* slam_optimize(nodes, edges, iterations) -> {nodes', chi2s}
 *   nodes: doubles {x, y, th} per node; edges: doubles {i, j, zx, zy, zth,
 *   ixx, ixy, ixt, iyy, iyt, itt} per edge (the information's upper half) */
ERL_NIF_TERM tc_nif_slam_optimize(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    const double *nd, *ed;
    int n, m, iters;
    if (!doubles(env, argv[0], 3, MAX_NODES, &nd, &n) ||
        !doubles(env, argv[1], 11, 4 * MAX_NODES, &ed, &m) || !enif_get_int(env, argv[2], &iters) ||
        iters < 0 || iters > 100 || n == 0)
        return enif_make_badarg(env);
    Edge *es = malloc(sizeof(Edge) * (m ? m : 1));
    if (!es) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    for (int k = 0; k < m; k++) {
        const double *d = ed + 11 * k;
        if (d[0] < 0 || d[1] < 0 || d[0] >= n || d[1] >= n || d[0] == d[1]) {
            free(es);
            return enif_make_badarg(env);
        }
        es[k].i = (int)d[0];
        es[k].j = (int)d[1];
        memcpy(es[k].z, d + 2, sizeof(double) * 3);
        double *o = es[k].om;
        o[0] = d[5], o[1] = d[6], o[2] = d[7];
        o[3] = d[6], o[4] = d[8], o[5] = d[9];
        o[6] = d[7], o[7] = d[9], o[8] = d[10];
    }
    ERL_NIF_TERM out, chis;
    double *x = (double *)enif_make_new_binary(env, sizeof(double) * 3 * n, &out);
    memcpy(x, nd, sizeof(double) * 3 * n);
    for (int it = 0; it < iters; it++) {
        double change = gn_step(n, x, m, es);
        if (change < 0) {
            free(es);
            return enif_raise_exception(env, enif_make_atom(env, "enomem"));
        }
        if (change < 1e-5) break;
    }
    double *c = (double *)enif_make_new_binary(env, sizeof(double) * (m ? m : 0), &chis);
    for (int k = 0; k < m; k++) {
        double err[3], A[9], B[9], oe[3];
        edge_error(x + 3 * es[k].i, x + 3 * es[k].j, es + k, err, A, B);
        mv3(es[k].om, err, oe);
        c[k] = dot(err, oe, 3);
    }
    free(es);
    return enif_make_tuple2(env, out, chis);
}
