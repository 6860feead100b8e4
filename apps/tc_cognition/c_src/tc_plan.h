/* tc_plan: A* and D* Lite for the grid NIF (see tc_plan.c). */
#ifndef TC_PLAN_H
#define TC_PLAN_H

#include <erl_nif.h>
#include <stdint.h>

int tc_plan_load(ErlNifEnv *env);
ERL_NIF_TERM tc_nif_astar(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_astar_cpu(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_costs(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_dsl_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_dsl_update(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_dsl_sync(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_dsl_move_start(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_dsl_forget_path(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_dsl_cpu_ns(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_dsl_queued(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_dsl_plan(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);

#endif
