/* tc_nif: small helpers shared by the navigation NIF's files. */
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

/* an angle wrapped to [-pi, pi) */
static inline double tc_wrap(double a)
{
    a = fmod(a + M_PI, 2 * M_PI);
    if (a < 0) a += 2 * M_PI;
    return a - M_PI;
}

#endif
