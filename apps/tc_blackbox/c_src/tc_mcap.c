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
 */
#include <erl_nif.h>
#include <lz4frame.h>
#include <string.h>
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

static int load(ErlNifEnv *env, void **priv, ERL_NIF_TERM info)
{
    (void)priv;
    (void)info;
    A_OK = enif_make_atom(env, "ok");
    A_ERROR = enif_make_atom(env, "error");
    A_CORRUPT = enif_make_atom(env, "corrupt");
    A_SIZE_MISMATCH = enif_make_atom(env, "size_mismatch");
    A_NO_MEMORY = enif_make_atom(env, "no_memory");
    return 0;
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
};

ERL_NIF_INIT(Elixir.ThinkingCap.MCAP.Compression, funcs, load, NULL, upgrade, NULL)
