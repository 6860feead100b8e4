/*
 * tc_mcap: the compression of MCAP chunks, through Debian's libzstd and
 * liblz4 (the lz4 *frame* format, as the MCAP specification requires).
 *
 * Every function runs on a dirty CPU scheduler: a 1 MB chunk takes a few
 * milliseconds. Compression takes iodata; decompression takes a binary
 * and the exact size it must give (the chunk's uncompressed_size, bounded
 * by the caller), and answers {ok, Binary} or {error, Reason}: its input
 * comes from files, so nothing in it may crash the VM or allocate more
 * than the size asked for.
 *
 * A chunk stream (chunk_new/2, chunk_add/2, chunk_message/6,
 * chunk_finish/1) takes a chunk's records as they come and keeps them in
 * a plain buffer, off the writer's heap; it writes the Message records
 * itself (header, sequence, index entry; chunk_messages/2 a list of them
 * in one call) and compresses the chunk once,
 * at its end, on a dirty scheduler (a few hundred KB: about a
 * millisecond), with its CRC-32 and its Message Index records. chunk_add
 * and chunk_message run on a normal scheduler (the writer gives them tens
 * of KB at most; each has a dirty twin for more).
 */
#include <erl_nif.h>
#include <lz4frame.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>
#include <zstd.h>
#include <zstd_errors.h>

#include "tc_json_etf.h"

/* an upper bound on any size asked for, whatever the caller checks */
#define MAX_SIZE ((ErlNifUInt64)1 << 32)

static ERL_NIF_TERM A_OK, A_ERROR, A_CORRUPT, A_SIZE_MISMATCH, A_NO_MEMORY, A_NEXT, A_NIL;

static ERL_NIF_TERM ok(ErlNifEnv *env, ERL_NIF_TERM t) { return enif_make_tuple2(env, A_OK, t); }

static ERL_NIF_TERM error(ErlNifEnv *env, ERL_NIF_TERM reason)
{
    return enif_make_tuple2(env, A_ERROR, reason);
}

/* Each dirty scheduler thread keeps one compression context: ZSTD_compress
 * makes and frees one per call, and with it its tables, which cost a 1 MB
 * chunk's compression about twice its CPU (measured on the recorder's
 * chunks). Threads live as long as the VM; a context is never shared. */
static __thread ZSTD_CCtx *zstd_cctx = NULL;

/* zstd_compress(IoData, Level) -> Binary */
static ERL_NIF_TERM nif_zstd_compress(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary in, out;
    int level;
    if (!enif_inspect_iolist_as_binary(env, argv[0], &in) || !enif_get_int(env, argv[1], &level) ||
        level < 1 || level > ZSTD_maxCLevel())
        return enif_make_badarg(env);
    if (zstd_cctx == NULL && (zstd_cctx = ZSTD_createCCtx()) == NULL)
        return enif_raise_exception(env, enif_make_string(env, "zstd: no memory", ERL_NIF_LATIN1));
    size_t bound = ZSTD_compressBound(in.size);
    if (!enif_alloc_binary(bound, &out)) return enif_make_badarg(env);
    size_t n = ZSTD_compressCCtx(zstd_cctx, out.data, out.size, in.data, in.size, level);
    if (ZSTD_isError(n)) {
        enif_release_binary(&out);
        return enif_raise_exception(env, enif_make_string(env, ZSTD_getErrorName(n), ERL_NIF_LATIN1));
    }
    enif_realloc_binary(&out, n);
    return enif_make_binary(env, &out);
}

/* zstd_decompress(Binary, Size) -> {ok, Binary} | {error, Reason} */
static ERL_NIF_TERM nif_zstd_decompress(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary in, out;
    ErlNifUInt64 size;
    if (!enif_inspect_binary(env, argv[0], &in) || !enif_get_uint64(env, argv[1], &size) ||
        size > MAX_SIZE)
        return enif_make_badarg(env);
    if (!enif_alloc_binary((size_t)size, &out)) return error(env, A_NO_MEMORY);
    size_t n = ZSTD_decompress(out.data, out.size, in.data, in.size);
    if (ZSTD_isError(n)) {
        enif_release_binary(&out);
        return error(env, ZSTD_getErrorCode(n) == ZSTD_error_dstSize_tooSmall ? A_SIZE_MISMATCH
                                                                             : A_CORRUPT);
    }
    if (n != size) {
        enif_release_binary(&out);
        return error(env, A_SIZE_MISMATCH);
    }
    return ok(env, enif_make_binary(env, &out));
}

/* lz4_compress(IoData) -> Binary: one lz4 frame */
static ERL_NIF_TERM nif_lz4_compress(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary in, out;
    if (!enif_inspect_iolist_as_binary(env, argv[0], &in)) return enif_make_badarg(env);
    LZ4F_preferences_t prefs;
    memset(&prefs, 0, sizeof(prefs));
    prefs.frameInfo.contentSize = in.size;
    size_t bound = LZ4F_compressFrameBound(in.size, &prefs);
    if (!enif_alloc_binary(bound, &out)) return enif_make_badarg(env);
    size_t n = LZ4F_compressFrame(out.data, out.size, in.data, in.size, &prefs);
    if (LZ4F_isError(n)) {
        enif_release_binary(&out);
        return enif_raise_exception(env, enif_make_string(env, LZ4F_getErrorName(n), ERL_NIF_LATIN1));
    }
    enif_realloc_binary(&out, n);
    return enif_make_binary(env, &out);
}

/* lz4_decompress(Binary, Size) -> {ok, Binary} | {error, Reason}: one or
 * more lz4 frames, which must fill exactly Size bytes */
static ERL_NIF_TERM nif_lz4_decompress(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary in, out;
    ErlNifUInt64 size;
    if (!enif_inspect_binary(env, argv[0], &in) || !enif_get_uint64(env, argv[1], &size) ||
        size > MAX_SIZE)
        return enif_make_badarg(env);
    LZ4F_dctx *dctx;
    if (LZ4F_isError(LZ4F_createDecompressionContext(&dctx, LZ4F_VERSION)))
        return error(env, A_NO_MEMORY);
    if (!enif_alloc_binary((size_t)size, &out)) {
        LZ4F_freeDecompressionContext(dctx);
        return error(env, A_NO_MEMORY);
    }
    size_t src = 0, dst = 0;
    ERL_NIF_TERM reason = 0;
    while (src < in.size) {
        size_t src_n = in.size - src, dst_n = out.size - dst;
        size_t r = LZ4F_decompress(dctx, out.data + dst, &dst_n, in.data + src, &src_n, NULL);
        if (LZ4F_isError(r)) {
            reason = A_CORRUPT;
            break;
        }
        src += src_n;
        dst += dst_n;
        /* no progress: the output is full but the frame wants more room */
        if (src_n == 0 && dst_n == 0) {
            reason = A_SIZE_MISMATCH;
            break;
        }
        /* the input ended inside a frame */
        if (src == in.size && r != 0) reason = A_CORRUPT;
    }
    LZ4F_freeDecompressionContext(dctx);
    if (!reason && dst != size) reason = A_SIZE_MISMATCH;
    if (reason) {
        enif_release_binary(&out);
        return error(env, reason);
    }
    return ok(env, enif_make_binary(env, &out));
}


/* ---- chunk streams ---- */

enum { ALG_NONE = 0, ALG_ZSTD = 1, ALG_LZ4 = 2 };

/* A chunk's records are kept whole in a plain buffer (`raw`, reused chunk
 * after chunk), off the writer's heap, and compressed once, when the
 * chunk ends, on a dirty scheduler: zstd with that thread's context
 * (zstd_cctx). A stream's own zstd context (tables, window and buffers,
 * near 1 MB) for each of a hundred recorders was evicted from the caches
 * between their wake-ups. Message records are written here whole
 * (chunk_message/6): their header, their sequence (per channel, when not
 * given) and their entry in the chunk's message indexes, which
 * chunk_finish/1 writes. */
typedef struct {
    ErlNifUInt64 time, offset;
    unsigned channel;
} index_entry;

typedef struct {
    ErlNifMutex *lock;
    int algorithm;
    int level;
    unsigned char *raw;      /* the chunk's records so far */
    size_t raw_len, raw_cap;
    index_entry *index;      /* the chunk's messages */
    size_t index_len, index_cap;
    ErlNifUInt64 start, end; /* their log times' span */
    uint32_t *sequence;  /* the last sequence by channel (the file's) */
    size_t sequence_cap;
} chunk_stream;

static ErlNifResourceType *CHUNK_STREAM;

static void chunk_stream_free(ErlNifEnv *env, void *obj)
{
    (void)env;
    chunk_stream *c = obj;
    if (c->raw) enif_free(c->raw);
    if (c->index) enif_free(c->index);
    if (c->sequence) enif_free(c->sequence);
    if (c->lock) enif_mutex_destroy(c->lock);
}

static ERL_NIF_TERM raise(ErlNifEnv *env, const char *what)
{
    return enif_raise_exception(env, enif_make_string(env, what, ERL_NIF_LATIN1));
}

/* room for `more` bytes in the chunk's buffer */
static int raw_room(chunk_stream *c, size_t more)
{
    if (c->raw_len + more <= c->raw_cap) return 1;
    size_t cap = c->raw_cap < 65536 ? 65536 : c->raw_cap * 2;
    while (cap < c->raw_len + more) cap *= 2;
    unsigned char *raw = enif_realloc(c->raw, cap);
    if (raw == NULL) return 0;
    c->raw = raw;
    c->raw_cap = cap;
    return 1;
}

static int keep_raw(chunk_stream *c, const unsigned char *data, size_t n)
{
    if (!raw_room(c, n)) return 0;
    if (n > 0) memcpy(c->raw + c->raw_len, data, n);
    c->raw_len += n;
    return 1;
}

static void put_le(unsigned char *p, ErlNifUInt64 v, int bytes)
{
    for (int i = 0; i < bytes; i++) p[i] = (unsigned char)(v >> (8 * i));
}

/* Tells the scheduler how much of a process's timeslice (about 1 ms) a
 * call on a normal scheduler took since `start` (µs), so that a process
 * whose calls write many messages is scheduled out as soon as one whose
 * work is in Erlang would be, and a higher-priority process queued on
 * its scheduler (a periodic module) waits less. A call counts as one
 * reduction otherwise, whatever it took. */
static void consume_since(ErlNifEnv *env, ErlNifTime start)
{
    ErlNifTime us = enif_monotonic_time(ERL_NIF_USEC) - start;
    if (us >= 10 && enif_thread_type() == ERL_NIF_THR_NORMAL_SCHEDULER)
        enif_consume_timeslice(env, us >= 1000 ? 100 : (int)(us / 10));
}

/* chunk_new(Algorithm, Level) -> Stream; Algorithm 0 none, 1 zstd, 2 lz4 */
static ERL_NIF_TERM nif_chunk_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    int algorithm, level;
    if (!enif_get_int(env, argv[0], &algorithm) || algorithm < ALG_NONE || algorithm > ALG_LZ4 ||
        !enif_get_int(env, argv[1], &level) || level < 1 || level > ZSTD_maxCLevel())
        return enif_make_badarg(env);
    chunk_stream *c = enif_alloc_resource(CHUNK_STREAM, sizeof(chunk_stream));
    if (c == NULL) return raise(env, "chunk stream: no memory");
    memset(c, 0, sizeof(*c));
    c->algorithm = algorithm;
    c->level = level;
    ERL_NIF_TERM term = enif_make_resource(env, c);
    enif_release_resource(c);
    if ((c->lock = enif_mutex_create("tc_mcap_chunk")) == NULL) return raise(env, "chunk stream: no memory");
    return term;
}

static int get_stream(ErlNifEnv *env, ERL_NIF_TERM t, chunk_stream **c)
{
    return enif_get_resource(env, t, CHUNK_STREAM, (void **)c);
}

/* chunk_add(Stream, IoData) -> ok: records, as they are */
static ERL_NIF_TERM nif_chunk_add(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    chunk_stream *c;
    ErlNifBinary in;
    if (!get_stream(env, argv[0], &c) || !enif_inspect_iolist_as_binary(env, argv[1], &in))
        return enif_make_badarg(env);
    enif_mutex_lock(c->lock);
    int ok = keep_raw(c, in.data, in.size);
    enif_mutex_unlock(c->lock);
    if (!ok) return raise(env, "no memory");
    return enif_make_atom(env, "ok");
}

/* A Message record into the chunk (its lock held): its sequence the
 * channel's next when `sequence` is -1; NULL, or what failed */
static const char *put_message(chunk_stream *c, unsigned channel, ErlNifSInt64 sequence,
                               ErlNifUInt64 log_time, ErlNifUInt64 publish_time,
                               const unsigned char *data, size_t size)
{
    if (sequence < 0) {
        if (channel >= c->sequence_cap) {
            size_t cap = c->sequence_cap ? c->sequence_cap : 64;
            while (cap <= channel) cap *= 2;
            uint32_t *seq = enif_realloc(c->sequence, cap * sizeof(*seq));
            if (seq == NULL) return "no memory";
            memset(seq + c->sequence_cap, 0, (cap - c->sequence_cap) * sizeof(*seq));
            c->sequence = seq;
            c->sequence_cap = cap;
        }
        sequence = ++c->sequence[channel];
    }
    if (c->index_len == c->index_cap) {
        size_t cap = c->index_cap ? c->index_cap * 2 : 512;
        index_entry *index = enif_realloc(c->index, cap * sizeof(*index));
        if (index == NULL) return "no memory";
        c->index = index;
        c->index_cap = cap;
    }
    if (!raw_room(c, 31 + size)) return "no memory";
    index_entry *e = &c->index[c->index_len++];
    e->channel = channel;
    e->time = log_time;
    e->offset = c->raw_len;
    if (c->index_len == 1 || log_time < c->start) c->start = log_time;
    if (c->index_len == 1 || log_time > c->end) c->end = log_time;
    /* opcode, length, channel, sequence, log time, publish time, data */
    unsigned char *p = c->raw + c->raw_len;
    p[0] = 0x05;
    put_le(p + 1, 22 + (ErlNifUInt64)size, 8);
    put_le(p + 9, channel, 2);
    put_le(p + 11, (ErlNifUInt64)sequence, 4);
    put_le(p + 15, log_time, 8);
    put_le(p + 23, publish_time, 8);
    if (size) memcpy(p + 31, data, size);
    c->raw_len += 31 + size;
    return NULL;
}

/* a message's arguments, checked; the sequence `next` is -1 */
static int get_message(ErlNifEnv *env, const ERL_NIF_TERM *argv, unsigned *channel,
                       ErlNifSInt64 *sequence, ErlNifUInt64 *log_time,
                       ErlNifUInt64 *publish_time, ErlNifBinary *data)
{
    if (enif_is_identical(argv[1], A_NEXT)) *sequence = -1;
    else if (!enif_get_int64(env, argv[1], sequence) || *sequence < -1 || *sequence > 0xFFFFFFFFLL)
        return 0;
    if (!enif_get_uint(env, argv[0], channel) || *channel > 65535 ||
        !enif_get_uint64(env, argv[2], log_time) || !enif_get_uint64(env, argv[3], publish_time))
        return 0;
    return enif_is_binary(env, argv[4]) ? enif_inspect_binary(env, argv[4], data)
                                        : enif_inspect_iolist_as_binary(env, argv[4], data);
}

/* chunk_message(Stream, Channel, Sequence, LogTime, PublishTime, Data) ->
 * ChunkSize: a Message record, its sequence the channel's next when
 * Sequence is -1; answers the chunk's size so far */
static ERL_NIF_TERM nif_chunk_message(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    chunk_stream *c;
    unsigned channel;
    ErlNifSInt64 sequence;
    ErlNifUInt64 log_time, publish_time;
    ErlNifBinary data;
    if (!get_stream(env, argv[0], &c) ||
        !get_message(env, argv + 1, &channel, &sequence, &log_time, &publish_time, &data))
        return enif_make_badarg(env);
    enif_mutex_lock(c->lock);
    const char *failed = put_message(c, channel, sequence, log_time, publish_time, data.data, data.size);
    ErlNifUInt64 size = c->raw_len;
    enif_mutex_unlock(c->lock);
    if (failed) return raise(env, failed);
    return enif_make_uint64(env, size);
}

/* chunk_messages(Stream, [{Channel, Sequence, LogTime, PublishTime, Data}],
 * Limit) -> {ChunkSize, Written}: chunk_message/6 for each (Sequence may be
 * `next` too), in the list's order, in one call, until the chunk holds
 * Limit bytes (the one that reaches it written); every one is checked
 * before any is written */
static ERL_NIF_TERM nif_chunk_messages(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    chunk_stream *c;
    unsigned len;
    ErlNifUInt64 limit;
    if (!get_stream(env, argv[0], &c) || !enif_get_list_length(env, argv[1], &len) ||
        !enif_get_uint64(env, argv[2], &limit))
        return enif_make_badarg(env);
    typedef struct {
        unsigned channel;
        ErlNifSInt64 sequence;
        ErlNifUInt64 log_time, publish_time;
        ErlNifBinary data;
    } message;
    ErlNifTime start = enif_monotonic_time(ERL_NIF_USEC);
    message local[64];
    message *m = len <= 64 ? local : enif_alloc(len * sizeof(message));
    if (m == NULL) return raise(env, "no memory");
    ERL_NIF_TERM head, tail = argv[1];
    for (unsigned k = 0; k < len; k++) {
        int arity;
        const ERL_NIF_TERM *t;
        enif_get_list_cell(env, tail, &head, &tail);
        if (!enif_get_tuple(env, head, &arity, &t) || arity != 5 ||
            !get_message(env, t, &m[k].channel, &m[k].sequence, &m[k].log_time,
                         &m[k].publish_time, &m[k].data)) {
            if (m != local) enif_free(m);
            return enif_make_badarg(env);
        }
    }
    enif_mutex_lock(c->lock);
    const char *failed = NULL;
    unsigned written = 0;
    while (written < len && !failed && c->raw_len < limit) {
        message *k = &m[written++];
        failed = put_message(c, k->channel, k->sequence, k->log_time, k->publish_time,
                             k->data.data, k->data.size);
    }
    ErlNifUInt64 size = c->raw_len;
    enif_mutex_unlock(c->lock);
    if (m != local) enif_free(m);
    if (failed) return raise(env, failed);
    consume_since(env, start);
    return enif_make_tuple2(env, enif_make_uint64(env, size), enif_make_uint(env, written));
}

/* a tuple held as its external term, for chunk_held/4 */
typedef struct {
    unsigned channels[2], count; /* its Foxglove messages' channels */
    unsigned term_channel;
    int has_term;
    ErlNifUInt64 log_time, publish_time;
    ERL_NIF_TERM kind;
    ErlNifBinary etf;
} held_tuple;

static int known_kind(ERL_NIF_TERM kind)
{
    return kind == A_GENERIC || kind == A_SCAN || kind == A_POSE || kind == A_SIM_POSE;
}

/* {Channels, TermChannel, LogTime, PublishTime, Kind, Etf}, checked */
static int get_held(ErlNifEnv *env, ERL_NIF_TERM term, held_tuple *h)
{
    int arity;
    const ERL_NIF_TERM *t;
    ERL_NIF_TERM head, tail;
    if (!enif_get_tuple(env, term, &arity, &t) || arity != 6) return 0;
    h->count = 0;
    for (tail = t[0]; enif_get_list_cell(env, tail, &head, &tail);) {
        if (h->count == 2 || !enif_get_uint(env, head, &h->channels[h->count]) ||
            h->channels[h->count] > 65535)
            return 0;
        h->count++;
    }
    if (!enif_is_empty_list(env, tail)) return 0;
    h->has_term = !enif_is_identical(t[1], A_NIL);
    if (h->has_term && (!enif_get_uint(env, t[1], &h->term_channel) || h->term_channel > 65535)) return 0;
    h->kind = t[4];
    return enif_get_uint64(env, t[2], &h->log_time) && enif_get_uint64(env, t[3], &h->publish_time) &&
           known_kind(h->kind) && enif_inspect_binary(env, t[5], &h->etf);
}

/* chunk_held(Stream, [{Channels, TermChannel, LogTime, PublishTime, Kind,
 * Etf}], Limit, Skip) -> {ChunkSize, Done, Partial, Written}: tuples held
 * as their external terms (the recorder's), each written straight into
 * the chunk: its Foxglove messages' JSON made from the term
 * (messages_into/5, Kind as there), one on each of Channels, then the
 * term itself on TermChannel (nil: not written), each as chunk_message/6
 * writes it with the channel's next sequence. The JSON is never a
 * binary or a term. In the list's order, until the chunk holds Limit
 * bytes (the message that reaches it is written) or a tuple comes whose
 * JSON C leaves to Erlang (not as many messages as Channels): Done
 * tuples written whole, Partial messages of the next (Skip of the
 * first were written by an earlier call, stopped by the limit), Written
 * messages in this call. Every tuple is checked before any is written. */
static ERL_NIF_TERM nif_chunk_held(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    chunk_stream *c;
    unsigned len, skip;
    ErlNifUInt64 limit;
    if (!get_stream(env, argv[0], &c) || !enif_get_list_length(env, argv[1], &len) ||
        !enif_get_uint64(env, argv[2], &limit) || !enif_get_uint(env, argv[3], &skip))
        return enif_make_badarg(env);
    ErlNifTime start = enif_monotonic_time(ERL_NIF_USEC);
    held_tuple local[64];
    held_tuple *h = len <= 64 ? local : enif_alloc(len * sizeof(held_tuple));
    if (h == NULL) return raise(env, "no memory");
    ERL_NIF_TERM head, tail = argv[1];
    for (unsigned k = 0; k < len; k++) {
        enif_get_list_cell(env, tail, &head, &tail);
        if (!get_held(env, head, &h[k]) || (k == 0 && skip > h[k].count + h[k].has_term)) {
            if (h != local) enif_free(h);
            return enif_make_badarg(env);
        }
    }
    buf b;
    buf_init(&b);
    const char *failed = NULL;
    unsigned done = 0, part = done == 0 ? skip : 0, written = 0;
    enif_mutex_lock(c->lock);
    for (; done < len && !failed; done++, part = 0) {
        held_tuple *t = &h[done];
        size_t ends[2];
        if (c->raw_len >= limit) break;
        b.len = 0;
        if (messages_into(t->kind, &t->etf, t->publish_time, &b, ends) != (int)t->count) break;
        unsigned total = t->count + (unsigned)t->has_term;
        for (; part < total && !failed && c->raw_len < limit; part++, written++) {
            if (part < t->count) {
                size_t at = part == 0 ? 0 : ends[part - 1];
                failed = put_message(c, t->channels[part], -1, t->log_time, t->publish_time, b.data + at,
                                     ends[part] - at);
            } else {
                failed = put_message(c, t->term_channel, -1, t->log_time, t->publish_time, t->etf.data,
                                     t->etf.size);
            }
        }
        if (part < total) break;
    }
    ErlNifUInt64 size = c->raw_len;
    enif_mutex_unlock(c->lock);
    buf_free(&b);
    if (h != local) enif_free(h);
    if (failed) return raise(env, failed);
    consume_since(env, start);
    return enif_make_tuple4(env, enif_make_uint64(env, size), enif_make_uint(env, done),
                            enif_make_uint(env, done < len ? part : 0), enif_make_uint(env, written));
}

/* chunk_size(Stream) -> {Bytes, Messages}: the open chunk's */
static ERL_NIF_TERM nif_chunk_size(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    chunk_stream *c;
    if (!get_stream(env, argv[0], &c)) return enif_make_badarg(env);
    enif_mutex_lock(c->lock);
    ERL_NIF_TERM r = enif_make_tuple2(env, enif_make_uint64(env, c->raw_len), enif_make_uint64(env, c->index_len));
    enif_mutex_unlock(c->lock);
    return r;
}

static int by_channel_time(const void *a, const void *b)
{
    const index_entry *x = a, *y = b;
    if (x->channel != y->channel) return x->channel < y->channel ? -1 : 1;
    if (x->time != y->time) return x->time < y->time ? -1 : 1;
    return x->offset < y->offset ? -1 : (x->offset > y->offset);
}

/* the chunk's records compressed into `out` (allocated here) */
static const char *compress_raw(chunk_stream *c, ErlNifBinary *out)
{
    size_t n;
    if (c->algorithm == ALG_ZSTD) {
        if (zstd_cctx == NULL && (zstd_cctx = ZSTD_createCCtx()) == NULL) return "zstd: no memory";
        if (!enif_alloc_binary(ZSTD_compressBound(c->raw_len), out)) return "no memory";
        n = ZSTD_compressCCtx(zstd_cctx, out->data, out->size, c->raw, c->raw_len, c->level);
        if (ZSTD_isError(n)) {
            enif_release_binary(out);
            return ZSTD_getErrorName(n);
        }
    } else if (c->algorithm == ALG_LZ4) {
        LZ4F_preferences_t prefs;
        memset(&prefs, 0, sizeof(prefs));
        if (!enif_alloc_binary(LZ4F_compressFrameBound(c->raw_len, &prefs), out)) return "no memory";
        n = LZ4F_compressFrame(out->data, out->size, c->raw, c->raw_len, &prefs);
        if (LZ4F_isError(n)) {
            enif_release_binary(out);
            return LZ4F_getErrorName(n);
        }
    } else {
        if (!enif_alloc_binary(c->raw_len, out)) return "no memory";
        if (c->raw_len) memcpy(out->data, c->raw, c->raw_len);
        n = c->raw_len;
    }
    if (!enif_realloc_binary(out, n)) {
        enif_release_binary(out);
        return "no memory";
    }
    return NULL;
}

/* chunk_finish(Stream) -> {Compressed, Crc32, UncompressedSize, StartTime,
 * EndTime, MessageIndexes, [{Channel, Count, IndexOffset}]}: the chunk,
 * and its Message Index records (one per channel, by channel, entries in
 * log time order), IndexOffset where each begins in MessageIndexes. The
 * stream is then empty, ready for the next chunk (sequences go on). */
static ERL_NIF_TERM nif_chunk_finish(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    chunk_stream *c;
    if (!get_stream(env, argv[0], &c)) return enif_make_badarg(env);
    enif_mutex_lock(c->lock);
    ErlNifBinary out;
    const char *failed = compress_raw(c, &out);
    if (failed) {
        enif_mutex_unlock(c->lock);
        return raise(env, failed);
    }
    unsigned long crc = crc32(0L, Z_NULL, 0);
    if (c->raw_len) crc = crc32(crc, c->raw, (uInt)c->raw_len);

    /* the message indexes: 15 bytes a channel, 16 an entry */
    qsort(c->index, c->index_len, sizeof(index_entry), by_channel_time);
    size_t channels = 0;
    for (size_t i = 0; i < c->index_len; i++)
        if (i == 0 || c->index[i].channel != c->index[i - 1].channel) channels++;
    ERL_NIF_TERM indexes, list = enif_make_list(env, 0);
    unsigned char *p = enif_make_new_binary(env, channels * 15 + c->index_len * 16, &indexes);
    ERL_NIF_TERM *groups = enif_alloc(sizeof(ERL_NIF_TERM) * (channels ? channels : 1));
    size_t at = 0, g = 0;
    for (size_t i = 0; i < c->index_len;) {
        size_t j = i;
        while (j < c->index_len && c->index[j].channel == c->index[i].channel) j++;
        size_t k = j - i;
        groups[g++] = enif_make_tuple3(env, enif_make_uint(env, c->index[i].channel),
                                       enif_make_uint64(env, k), enif_make_uint64(env, at));
        p[at] = 0x07;
        put_le(p + at + 1, 6 + 16 * (ErlNifUInt64)k, 8);
        put_le(p + at + 9, c->index[i].channel, 2);
        put_le(p + at + 11, 16 * (ErlNifUInt64)k, 4);
        at += 15;
        for (; i < j; i++) {
            put_le(p + at, c->index[i].time, 8);
            put_le(p + at + 8, c->index[i].offset, 8);
            at += 16;
        }
    }
    list = enif_make_list_from_array(env, groups, (unsigned)g);
    enif_free(groups);
    ERL_NIF_TERM items[7] = {enif_make_binary(env, &out), enif_make_uint(env, (unsigned)crc),
                             enif_make_uint64(env, c->raw_len), enif_make_uint64(env, c->index_len ? c->start : 0),
                             enif_make_uint64(env, c->index_len ? c->end : 0), indexes, list};
    c->raw_len = 0;
    c->index_len = 0;
    enif_mutex_unlock(c->lock);
    return enif_make_tuple_from_array(env, items, 7);
}

static int load(ErlNifEnv *env, void **priv, ERL_NIF_TERM info)
{
    (void)priv;
    (void)info;
    A_OK = enif_make_atom(env, "ok");
    A_ERROR = enif_make_atom(env, "error");
    A_CORRUPT = enif_make_atom(env, "corrupt");
    A_SIZE_MISMATCH = enif_make_atom(env, "size_mismatch");
    A_NO_MEMORY = enif_make_atom(env, "no_memory");
    A_NEXT = enif_make_atom(env, "next");
    A_NIL = enif_make_atom(env, "nil");
    json_etf_load(env);
    CHUNK_STREAM = enif_open_resource_type(env, NULL, "tc_mcap_chunk_stream", chunk_stream_free,
                                           ERL_NIF_RT_CREATE | ERL_NIF_RT_TAKEOVER, NULL);
    return CHUNK_STREAM == NULL ? 1 : 0;
}

static int upgrade(ErlNifEnv *env, void **priv, void **old_priv, ERL_NIF_TERM info)
{
    (void)old_priv;
    return load(env, priv, info);
}

static ErlNifFunc funcs[] = {
    {"zstd_compress", 2, nif_zstd_compress, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"nif_zstd_decompress", 2, nif_zstd_decompress, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"lz4_compress", 1, nif_lz4_compress, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"nif_lz4_decompress", 2, nif_lz4_decompress, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"chunk_new", 2, nif_chunk_new, 0},
    {"chunk_add", 2, nif_chunk_add, 0},
    {"chunk_add_dirty", 2, nif_chunk_add, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"chunk_message", 6, nif_chunk_message, 0},
    {"chunk_message_dirty", 6, nif_chunk_message, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"chunk_messages", 3, nif_chunk_messages, 0},
    {"chunk_messages_dirty", 3, nif_chunk_messages, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"chunk_held", 4, nif_chunk_held, 0},
    {"chunk_size", 1, nif_chunk_size, 0},
    {"chunk_finish", 1, nif_chunk_finish, ERL_NIF_DIRTY_JOB_CPU_BOUND},
};

ERL_NIF_INIT(Elixir.ThinkingCap.MCAP.Compression, funcs, load, NULL, upgrade, NULL)
