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
 * A chunk stream (chunk_new/2, chunk_add/2, chunk_finish/1) takes a chunk's
 * records as they come, a few KB at a time, so that they never pile up on
 * the writer's heap nor are flattened into one big binary. zstd keeps them
 * in a plain buffer and compresses the chunk once, at its end, on a dirty
 * scheduler (a few hundred KB: about a millisecond); lz4 compresses them
 * as they come. The CRC-32 of the records is kept too. chunk_add runs on
 * a normal scheduler (the writer gives it tens of KB at most; it has a
 * dirty twin for more).
 */
#include <erl_nif.h>
#include <lz4frame.h>
#include <string.h>
#include <zlib.h>
#include <zstd.h>
#include <zstd_errors.h>

/* an upper bound on any size asked for, whatever the caller checks */
#define MAX_SIZE ((ErlNifUInt64)1 << 32)

static ERL_NIF_TERM A_OK, A_ERROR, A_CORRUPT, A_SIZE_MISMATCH, A_NO_MEMORY;

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

/* A zstd chunk is kept whole in a plain buffer (`raw`, reused chunk after
 * chunk) and compressed once, when it ends, on a dirty scheduler with
 * that thread's context (zstd_cctx): a stream's own context (tables,
 * window and buffers, near 1 MB) for each of a hundred recorders was
 * evicted from the caches between their wake-ups, and its tables were
 * sized for any input, not for the chunk. */
typedef struct {
    ErlNifMutex *lock;
    int algorithm;
    int level;
    unsigned char *raw;  /* zstd: the chunk's bytes so far */
    size_t raw_len, raw_cap;
    LZ4F_cctx *lz4;
    LZ4F_preferences_t lz4_prefs;
    int begun;           /* a frame begun (lz4: its header written) */
    ErlNifBinary out;    /* the compressed chunk so far */
    int has_out;
    size_t out_len;
    unsigned long crc;   /* of the uncompressed records */
    ErlNifUInt64 size;   /* uncompressed bytes given */
} chunk_stream;

static ErlNifResourceType *CHUNK_STREAM;

static void chunk_stream_free(ErlNifEnv *env, void *obj)
{
    (void)env;
    chunk_stream *c = obj;
    if (c->raw) enif_free(c->raw);
    if (c->lz4) LZ4F_freeCompressionContext(c->lz4);
    if (c->has_out) enif_release_binary(&c->out);
    if (c->lock) enif_mutex_destroy(c->lock);
}

/* room for `more` bytes after out_len */
static int reserve(chunk_stream *c, size_t more)
{
    size_t want = c->out_len + more;
    if (!c->has_out) {
        size_t cap = want < 65536 ? 65536 : want;
        if (!enif_alloc_binary(cap, &c->out)) return 0;
        c->has_out = 1;
        return 1;
    }
    if (want <= c->out.size) return 1;
    size_t cap = c->out.size * 2;
    if (cap < want) cap = want;
    return enif_realloc_binary(&c->out, cap);
}

static ERL_NIF_TERM raise(ErlNifEnv *env, const char *what)
{
    return enif_raise_exception(env, enif_make_string(env, what, ERL_NIF_LATIN1));
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
    c->crc = crc32(0L, Z_NULL, 0);
    ERL_NIF_TERM term = enif_make_resource(env, c);
    enif_release_resource(c);
    if ((c->lock = enif_mutex_create("tc_mcap_chunk")) == NULL) return raise(env, "chunk stream: no memory");
    if (algorithm == ALG_LZ4) {
        if (LZ4F_isError(LZ4F_createCompressionContext(&c->lz4, LZ4F_VERSION)))
            return raise(env, "lz4: no memory");
        memset(&c->lz4_prefs, 0, sizeof(c->lz4_prefs));
    }
    return term;
}

/* zstd: `n` more bytes of the chunk, kept */
static const char *keep_raw(chunk_stream *c, const unsigned char *data, size_t n)
{
    if (c->raw_len + n > c->raw_cap) {
        size_t cap = c->raw_cap < 65536 ? 65536 : c->raw_cap * 2;
        while (cap < c->raw_len + n) cap *= 2;
        unsigned char *raw = enif_realloc(c->raw, cap);
        if (raw == NULL) return "no memory";
        c->raw = raw;
        c->raw_cap = cap;
    }
    if (n > 0) memcpy(c->raw + c->raw_len, data, n);
    c->raw_len += n;
    return NULL;
}

/* zstd: the chunk compressed in one frame (its size in its header), with
 * the calling thread's context; the chunk's buffer is kept for the next */
static const char *zstd_end(chunk_stream *c)
{
    if (zstd_cctx == NULL && (zstd_cctx = ZSTD_createCCtx()) == NULL) return "zstd: no memory";
    if (!reserve(c, ZSTD_compressBound(c->raw_len))) return "no memory";
    size_t n = ZSTD_compressCCtx(zstd_cctx, c->out.data + c->out_len, c->out.size - c->out_len,
                                 c->raw, c->raw_len, c->level);
    if (ZSTD_isError(n)) return ZSTD_getErrorName(n);
    c->out_len += n;
    c->raw_len = 0;
    return NULL;
}

/* compresses `n` bytes at `data` into the stream (end: and ends the frame) */
static const char *stream_in(chunk_stream *c, const unsigned char *data, size_t n, int end)
{
    if (c->algorithm == ALG_NONE) {
        if (!reserve(c, n)) return "no memory";
        memcpy(c->out.data + c->out_len, data, n);
        c->out_len += n;
        return NULL;
    }
    if (c->algorithm == ALG_ZSTD) return end ? zstd_end(c) : keep_raw(c, data, n);
    /* lz4 */
    if (!c->begun) {
        if (!reserve(c, LZ4F_HEADER_SIZE_MAX)) return "no memory";
        size_t h = LZ4F_compressBegin(c->lz4, c->out.data + c->out_len, c->out.size - c->out_len,
                                      &c->lz4_prefs);
        if (LZ4F_isError(h)) return LZ4F_getErrorName(h);
        c->out_len += h;
        c->begun = 1;
    }
    if (n > 0) {
        if (!reserve(c, LZ4F_compressBound(n, &c->lz4_prefs))) return "no memory";
        size_t k = LZ4F_compressUpdate(c->lz4, c->out.data + c->out_len, c->out.size - c->out_len,
                                       data, n, NULL);
        if (LZ4F_isError(k)) return LZ4F_getErrorName(k);
        c->out_len += k;
    }
    if (end) {
        if (!reserve(c, LZ4F_compressBound(0, &c->lz4_prefs))) return "no memory";
        size_t k = LZ4F_compressEnd(c->lz4, c->out.data + c->out_len, c->out.size - c->out_len, NULL);
        if (LZ4F_isError(k)) return LZ4F_getErrorName(k);
        c->out_len += k;
        c->begun = 0;
    }
    return NULL;
}

static int get_stream(ErlNifEnv *env, ERL_NIF_TERM t, chunk_stream **c)
{
    return enif_get_resource(env, t, CHUNK_STREAM, (void **)c);
}

/* chunk_add(Stream, IoData) -> ok */
static ERL_NIF_TERM nif_chunk_add(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    chunk_stream *c;
    ErlNifBinary in;
    if (!get_stream(env, argv[0], &c) || !enif_inspect_iolist_as_binary(env, argv[1], &in))
        return enif_make_badarg(env);
    enif_mutex_lock(c->lock);
    /* zstd's CRC is taken at the chunk's end, with its compression */
    if (c->algorithm != ALG_ZSTD) c->crc = crc32(c->crc, in.data, (uInt)in.size);
    c->size += in.size;
    const char *failed = stream_in(c, in.data, in.size, 0);
    enif_mutex_unlock(c->lock);
    if (failed) return raise(env, failed);
    return enif_make_atom(env, "ok");
}

/* chunk_finish(Stream) -> {Compressed, Crc32, UncompressedSize}; the
 * stream is then empty, ready for the next chunk */
static ERL_NIF_TERM nif_chunk_finish(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    chunk_stream *c;
    if (!get_stream(env, argv[0], &c)) return enif_make_badarg(env);
    enif_mutex_lock(c->lock);
    if (c->algorithm == ALG_ZSTD && c->raw_len > 0) c->crc = crc32(c->crc, c->raw, (uInt)c->raw_len);
    const char *failed = stream_in(c, NULL, 0, 1);
    if (failed) {
        enif_mutex_unlock(c->lock);
        return raise(env, failed);
    }
    ERL_NIF_TERM bin;
    if (c->has_out) {
        if (!enif_realloc_binary(&c->out, c->out_len)) {
            enif_mutex_unlock(c->lock);
            return raise(env, "no memory");
        }
        bin = enif_make_binary(env, &c->out);
        c->has_out = 0;
    } else {
        enif_make_new_binary(env, 0, &bin);
    }
    ERL_NIF_TERM result =
        enif_make_tuple3(env, bin, enif_make_uint(env, (unsigned)c->crc), enif_make_uint64(env, c->size));
    c->out_len = 0;
    c->crc = crc32(0L, Z_NULL, 0);
    c->size = 0;
    enif_mutex_unlock(c->lock);
    return result;
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
    {"chunk_finish", 1, nif_chunk_finish, ERL_NIF_DIRTY_JOB_CPU_BOUND},
};

ERL_NIF_INIT(Elixir.ThinkingCap.MCAP.Compression, funcs, load, NULL, upgrade, NULL)
