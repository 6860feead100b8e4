/* tc_mcl: Monte Carlo localization for the grid NIF (see tc_mcl.c). */
#ifndef TC_MCL_H
#define TC_MCL_H

#include <erl_nif.h>
#include <stdint.h>

int tc_mcl_load(ErlNifEnv *env);
ERL_NIF_TERM tc_nif_field_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_field_score(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_field_fit(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_field_through(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_field_search(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_spread(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_transform(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_move(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_weigh(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_resample(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_estimate(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_mode(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_best(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_pf_sample(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);

#endif
