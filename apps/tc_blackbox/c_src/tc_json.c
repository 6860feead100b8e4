/*
 * tc_json: the recorder's JSON of a term (ThinkingCap.BlackBox.Core.JSON's
 * rules) written in C, into one binary, for the terms it meets most:
 * atoms, small integers, floats, ASCII binaries, lists, tuples, maps and
 * structs. The recorder writes a JSON message for most tuples, and the
 * same JSON built as iodata in Erlang filled its heap (a few KB a tuple).
 *
 * value(Term) -> Binary | false. `false` when the term holds anything
 * written otherwise, or whose bytes are not sure to be Core.JSON's: a
 * big integer, a binary or an atom that is not ASCII, an improper list,
 * a map of more than 32 keys (their order), a struct whose module is
 * not a plain alias, pids and the like, a term nested too deep. The
 * caller then writes it in Erlang, so the bytes are always the same
 * (the tests compare the two on random terms).
 *
 * tuple(Tag, Id, Payload) -> Binary | false: the JSON of a
 * thinkingcap.Tuple message, the three written as value/1 writes them.
 *
 * messages_etf(Kind, Binary, Ns) -> [Binary] | false: a tuple's Foxglove
 * messages (Kind generic: its thinkingcap.Tuple message, as tuple/3;
 * scan, pose, sim_pose: BlackBox.Foxglove's), from the tuple's external
 * term (term_to_binary/1), read without decoding it (the recorder holds
 * the tuples so, and its chunk stream writes them straight into its
 * chunk: tc_mcap.c's chunk_held/4).
 */
#include "tc_json_etf.h"


/* made once, at load: an atom's term is the same in every environment,
 * and an immediate, so that == compares it */
static ERL_NIF_TERM A_NIL, A_TRUE, A_FALSE, A_STRUCT;

static int put_atom_string(ErlNifEnv *env, buf *b, ERL_NIF_TERM t)
{
    char name[256];
    int n = enif_get_atom(env, t, name, sizeof(name), ERL_NIF_LATIN1);
    if (n <= 0) return 0;
    return put_string(b, (unsigned char *)name, (size_t)(n - 1));
}

static int value(ErlNifEnv *env, buf *b, ERL_NIF_TERM t, int depth);

/* a map's members in the order Core.JSON writes them (the reverse of
 * :maps.fold's), after `first` (a struct's name) if any */
static int object(ErlNifEnv *env, buf *b, ERL_NIF_TERM map, ERL_NIF_TERM skip, int has_first,
                  int depth)
{
    size_t n;
    if (!enif_get_map_size(env, map, &n) || n > 32) return 0;
    ErlNifMapIterator it;
    if (!enif_map_iterator_create(env, map, &it, ERL_NIF_MAP_ITERATOR_LAST)) return 0;
    int ok = 1, members = has_first;
    ERL_NIF_TERM k, v;
    while (ok && enif_map_iterator_get_pair(env, &it, &k, &v)) {
        if (!(has_first && enif_is_identical(k, skip))) {
            if (members++ > 0) ok = put_c(b, ',');
            if (ok) {
                ErlNifSInt64 i;
                double f;
                ErlNifBinary bin;
                if (enif_is_atom(env, k)) ok = put_atom_string(env, b, k);
                else if (enif_get_int64(env, k, &i)) ok = put_c(b, '"') && put_int(b, i) && put_c(b, '"');
                else if (enif_get_double(env, k, &f)) ok = put_c(b, '"') && put_float(b, f) && put_c(b, '"');
                else if (enif_is_binary(env, k) && enif_inspect_binary(env, k, &bin))
                    ok = put_string(b, bin.data, bin.size);
                else ok = 0;
            }
            ok = ok && put_c(b, ':') && value(env, b, v, depth + 1);
        }
        enif_map_iterator_prev(env, &it);
    }
    enif_map_iterator_destroy(env, &it);
    return ok && put_c(b, '}');
}

static int value(ErlNifEnv *env, buf *b, ERL_NIF_TERM t, int depth)
{
    if (depth > MAX_DEPTH) return 0;
    ErlNifSInt64 i;
    double f;
    ErlNifBinary bin;
    unsigned len;
    int arity;
    const ERL_NIF_TERM *elems;

    if (enif_is_atom(env, t)) {
        if (t == A_NIL) return put(b, "null", 4);
        if (t == A_TRUE) return put(b, "true", 4);
        if (t == A_FALSE) return put(b, "false", 5);
        char name[256];
        int n = enif_get_atom(env, t, name, sizeof(name), ERL_NIF_LATIN1);
        if (n <= 0) return 0;
        return put_string(b, (unsigned char *)name, (size_t)(n - 1));
    }
    if (enif_get_double(env, t, &f)) return put_float(b, f);
    if (enif_is_number(env, t)) return enif_get_int64(env, t, &i) && put_int(b, i);
    if (enif_is_binary(env, t)) return enif_inspect_binary(env, t, &bin) && put_string(b, bin.data, bin.size);
    if (enif_get_list_length(env, t, &len)) {
        if (len == 0) return put(b, "[]", 2);
        ERL_NIF_TERM head, tail = t;
        if (!put_c(b, '[')) return 0;
        for (unsigned k = 0; k < len; k++) {
            enif_get_list_cell(env, tail, &head, &tail);
            if ((k > 0 && !put_c(b, ',')) || !value(env, b, head, depth + 1)) return 0;
        }
        return put_c(b, ']');
    }
    if (enif_get_tuple(env, t, &arity, &elems)) {
        if (arity == 0) return put(b, "[]", 2);
        if (!put_c(b, '[')) return 0;
        for (int k = 0; k < arity; k++) {
            if ((k > 0 && !put_c(b, ',')) || !value(env, b, elems[k], depth + 1)) return 0;
        }
        return put_c(b, ']');
    }
    if (enif_is_map(env, t)) {
        ERL_NIF_TERM key = A_STRUCT, module;
        if (enif_get_map_value(env, t, key, &module) && enif_is_atom(env, module)) {
            /* a struct: its module as inspect/1 prints an Elixir module */
            char name[256];
            int n = enif_get_atom(env, module, name, sizeof(name), ERL_NIF_LATIN1);
            if (n <= 7 || strncmp(name, "Elixir.", 7) != 0 || !alias(name + 7)) return 0;
            return put(b, "{\"__struct__\":", 14) && put_string(b, (unsigned char *)name + 7, (size_t)(n - 8)) &&
                   object(env, b, t, key, 1, depth);
        }
        return put_c(b, '{') && object(env, b, t, 0, 0, depth);
    }
    return 0;
}

static ERL_NIF_TERM to_binary(ErlNifEnv *env, buf *b);


/* the messages of each item as parts of one binary */
typedef struct {
    int count;
    size_t start, ends[2];
} parts;

static ERL_NIF_TERM parts_list(ErlNifEnv *env, ERL_NIF_TERM whole, const parts *p)
{
    if (p->count == 0) return A_FALSE;
    ERL_NIF_TERM items[2];
    size_t at = p->start;
    for (int k = 0; k < p->count; k++) {
        items[k] = enif_make_sub_binary(env, whole, at, p->ends[k] - at);
        at = p->ends[k];
    }
    return enif_make_list_from_array(env, items, (unsigned)p->count);
}

/* messages_etf(Kind, Binary, Ns) -> [Binary] | false: the Foxglove
 * messages of a tuple given as its external term, Kind generic, scan,
 * pose or sim_pose (Ns the time of a message: the payload's stamp, else
 * the log time); false when the tuple is not of that kind's shape or
 * holds what value/1 leaves to Erlang */
static ERL_NIF_TERM nif_messages_etf(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary in;
    ErlNifUInt64 ns;
    if (!enif_inspect_binary(env, argv[1], &in)) return enif_make_badarg(env);
    if (!enif_get_uint64(env, argv[2], &ns)) return A_FALSE;
    buf b;
    buf_init(&b);
    parts p = {0, 0, {0, 0}};
    p.count = messages_into(argv[0], &in, ns, &b, p.ends);
    if (p.count < 0) {
        buf_free(&b);
        return enif_make_badarg(env);
    }
    return parts_list(env, to_binary(env, &b), &p);
}

static ERL_NIF_TERM to_binary(ErlNifEnv *env, buf *b)
{
    ERL_NIF_TERM out;
    unsigned char *d = enif_make_new_binary(env, b->len, &out);
    if (b->len) memcpy(d, b->data, b->len);
    buf_free(b);
    return out;
}

/* value(Term) -> Binary | false */
static ERL_NIF_TERM nif_value(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    buf b;
    buf_init(&b);
    if (!value(env, &b, argv[0], 0)) {
        buf_free(&b);
        return A_FALSE;
    }
    return to_binary(env, &b);
}

/* tuple(Tag, Id, Payload) -> Binary | false: a thinkingcap.Tuple
 * message, `{"tag":T,"robot":I,"payload":P}`, each as value/1 writes it */
static ERL_NIF_TERM nif_tuple(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    buf b;
    buf_init(&b);
    if (!(put(&b, "{\"tag\":", 7) && value(env, &b, argv[0], 0) && put(&b, ",\"robot\":", 9) &&
          value(env, &b, argv[1], 0) && put(&b, ",\"payload\":", 11) && value(env, &b, argv[2], 0) &&
          put_c(&b, '}'))) {
        buf_free(&b);
        return A_FALSE;
    }
    return to_binary(env, &b);
}

/* millimetres(List) -> Binary */
static ERL_NIF_TERM nif_millimetres(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    unsigned len;
    if (!enif_get_list_length(env, argv[0], &len)) return enif_make_badarg(env);
    buf b;
    buf_init(&b);
    ERL_NIF_TERM head, tail = argv[0];
    int ok = put_c(&b, '[');
    for (unsigned k = 0; ok && k < len; k++) {
        double f;
        ErlNifSInt64 i;
        enif_get_list_cell(env, tail, &head, &tail);
        if (k > 0) ok = put_c(&b, ',');
        if (!ok) break;
        if (enif_get_double(env, head, &f)) ok = put_fixed(&b, f, 3);
        else if (enif_get_int64(env, head, &i)) ok = put_int(&b, i);
        else ok = 0;
    }
    if (!ok || !put_c(&b, ']')) {
        buf_free(&b);
        return enif_make_badarg(env);
    }
    return to_binary(env, &b);
}

static ErlNifFunc funcs[] = {
    {"nif_value", 1, nif_value, 0},
    {"nif_millimetres", 1, nif_millimetres, 0},
    {"nif_tuple", 3, nif_tuple, 0},
    {"nif_messages_etf", 3, nif_messages_etf, 0},
};

static int load(ErlNifEnv *env, void **priv, ERL_NIF_TERM info)
{
    (void)priv;
    (void)info;
    A_NIL = enif_make_atom(env, "nil");
    A_TRUE = enif_make_atom(env, "true");
    A_FALSE = enif_make_atom(env, "false");
    A_STRUCT = enif_make_atom(env, "__struct__");
    json_etf_load(env);
    return 0;
}

static int upgrade(ErlNifEnv *env, void **priv, void **old_priv, ERL_NIF_TERM info)
{
    (void)old_priv;
    return load(env, priv, info);
}

ERL_NIF_INIT(Elixir.ThinkingCap.BlackBox.Core.JSON.Native, funcs, load, NULL, upgrade, NULL)
