/* tc_slam: scan matching and pose-graph optimization for the grid NIF
 * (see tc_slam.c). */
#ifndef TC_SLAM_H
#define TC_SLAM_H

#include <erl_nif.h>

ERL_NIF_TERM tc_nif_slam_match(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM tc_nif_slam_optimize(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);

#endif
