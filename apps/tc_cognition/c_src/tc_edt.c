/*
 * tc_edt: the exact Euclidean distance transform (Felzenszwalb and
 * Huttenlocher, "Distance transforms of sampled functions", 2012): two
 * passes of the one-dimensional transform of squared distances, columns
 * then rows. Used by the planner's inflation, the likelihood field of
 * Monte Carlo localization and the scan matcher.
 */
#include "tc_edt.h"

#include <math.h>
#include <stdlib.h>

/* squared distance transform of one line (Felzenszwalb & Huttenlocher):
 * d[q] = min over p of (q - p)^2 + f[p]; f is 0 at seeds, 1e20 elsewhere */
static void dt1_arg(const double *f, double *d, int *arg, int n, int *v, double *z)
{
    int k = 0;
    v[0] = 0;
    z[0] = -INFINITY;
    z[1] = INFINITY;
    for (int q = 1; q < n; q++) {
        double s = ((f[q] + (double)q * q) - (f[v[k]] + (double)v[k] * v[k])) / (2.0 * (q - v[k]));
        while (s <= z[k]) {
            k--;
            s = ((f[q] + (double)q * q) - (f[v[k]] + (double)v[k] * v[k])) / (2.0 * (q - v[k]));
        }
        k++;
        v[k] = q;
        z[k] = s;
        z[k + 1] = INFINITY;
    }
    k = 0;
    for (int q = 0; q < n; q++) {
        while (z[k + 1] < q) k++;
        double dq = q - v[k];
        d[q] = dq * dq + f[v[k]];
        if (arg) arg[q] = v[k];
    }
}

static void dt1(const double *f, double *d, int n, int *v, double *z) { dt1_arg(f, d, NULL, n, v, z); }

/* squared distances (cells) from every cell to the nearest cell with a
 * non-zero byte; INFINITY where there is none */
double *tc_edt2(const unsigned char *cells, int w, int h)
{
    size_t n = (size_t)w * h;
    int m = w > h ? w : h;
    double *g = malloc(n * sizeof(double));
    double *f = calloc(m, sizeof(double)), *d = calloc(m, sizeof(double));
    double *z = malloc((m + 1) * sizeof(double));
    int *v = malloc(m * sizeof(int));
    if (!g || !f || !d || !z || !v) {
        free(g);
        free(f);
        free(d);
        free(z);
        free(v);
        return NULL;
    }
    const double big = 1e20;
    for (int c = 0; c < w; c++) {
        for (int r = 0; r < h; r++) f[r] = cells[(size_t)r * w + c] ? 0.0 : big;
        dt1(f, d, h, v, z);
        for (int r = 0; r < h; r++) g[(size_t)r * w + c] = d[r];
    }
    for (int r = 0; r < h; r++) {
        for (int c = 0; c < w; c++) f[c] = g[(size_t)r * w + c];
        dt1(f, d, w, v, z);
        for (int c = 0; c < w; c++) g[(size_t)r * w + c] = d[c] >= big / 2 ? INFINITY : d[c];
    }
    free(f);
    free(d);
    free(z);
    free(v);
    return g;
}


/* the nearest seed of every cell (its index r * w + c; -1 where there is
 * none): the same two passes, each keeping where its minimum came from */
int *tc_edt2_nearest(const unsigned char *cells, int w, int h)
{
    size_t n = (size_t)w * h;
    int m = w > h ? w : h;
    double *g = malloc(n * sizeof(double));
    int *rows = malloc(n * sizeof(int)), *out = malloc(n * sizeof(int));
    double *f = calloc(m, sizeof(double)), *d = calloc(m, sizeof(double));
    double *z = malloc((m + 1) * sizeof(double));
    int *v = malloc(m * sizeof(int)), *a = malloc(m * sizeof(int));
    if (!g || !rows || !out || !f || !d || !z || !v || !a) {
        free(g), free(rows), free(out), free(f), free(d), free(z), free(v), free(a);
        return NULL;
    }
    const double big = 1e20;
    for (int c = 0; c < w; c++) {
        for (int r = 0; r < h; r++) f[r] = cells[(size_t)r * w + c] ? 0.0 : big;
        dt1_arg(f, d, a, h, v, z);
        for (int r = 0; r < h; r++) g[(size_t)r * w + c] = d[r], rows[(size_t)r * w + c] = a[r];
    }
    for (int r = 0; r < h; r++) {
        for (int c = 0; c < w; c++) f[c] = g[(size_t)r * w + c];
        dt1_arg(f, d, a, w, v, z);
        for (int c = 0; c < w; c++) {
            int cc = a[c];
            out[(size_t)r * w + c] = d[c] >= big / 2 ? -1 : rows[(size_t)r * w + cc] * w + cc;
        }
    }
    free(g), free(rows), free(f), free(d), free(z), free(v), free(a);
    return out;
}
