/* tc_nif: small helpers shared by the NIFs (navigation, ray casting). */
#ifndef TC_NIF_H
#define TC_NIF_H

#include <erl_nif.h>
#include <math.h>

/* a finite number, integer or float */
static inline int tc_number(ErlNifEnv *env, ERL_NIF_TERM t, double *out)
{
    long l;
    if (enif_get_double(env, t, out)) return isfinite(*out);
    if (enif_get_long(env, t, &l)) {
        *out = (double)l;
        return 1;
    }
    return 0;
}

/* a grid's arguments: argv[0] its cells (a binary, one byte a cell,
 * row-major), argv[1] its width and argv[2] its height, both positive,
 * with at most max_cells cells */
static inline int tc_grid_args(ErlNifEnv *env, const ERL_NIF_TERM argv[], long max_cells,
                               ErlNifBinary *b, int *w, int *h)
{
    return enif_inspect_binary(env, argv[0], b) && enif_get_int(env, argv[1], w) &&
           enif_get_int(env, argv[2], h) && *w > 0 && *h > 0 && (long)*w * *h <= max_cells &&
           b->size == (size_t)*w * *h;
}

/* an angle wrapped to [-pi, pi) */
static inline double tc_wrap(double a)
{
    a = fmod(a + M_PI, 2 * M_PI);
    if (a < 0) a += 2 * M_PI;
    return a - M_PI;
}

#endif
