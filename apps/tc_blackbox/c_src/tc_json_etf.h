/*
 * tc_json_etf.h: Core.JSON's rules in C for the recorder's Foxglove
 * messages, written from a tuple's external term (term_to_binary/1)
 * without decoding it: the buffer they are written into, the numbers'
 * and strings' formats, the external format's reader and the messages
 * of each kind (messages_into/5). Static functions, included by the
 * JSON NIF (tc_json.c) and by the chunk streams' NIF (tc_mcap.c), which
 * writes a tuple's messages straight into its chunk (chunk_held/4).
 * json_etf_load/1 makes the kinds' atoms, once, when a library loads.
 *
 * Floats to N decimals as Erlang's float_to_binary(F, [{decimals, N},
 * compact]) writes them: the integer part, and the fraction times 10^N
 * rounded (half away from zero), carried into the integer part when it
 * rounds up to 10^N; a sign when the sign bit is set.
 */
#ifndef TC_JSON_ETF_H
#define TC_JSON_ETF_H

#include <erl_nif.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_DEPTH 64

typedef struct {
    unsigned char *data;
    size_t len, cap;
    unsigned char local[4096];
} buf;

static void buf_init(buf *b)
{
    b->data = b->local;
    b->len = 0;
    b->cap = sizeof(b->local);
}

static void buf_free(buf *b)
{
    if (b->data != b->local) enif_free(b->data);
}

static int room(buf *b, size_t more)
{
    if (b->len + more <= b->cap) return 1;
    size_t cap = b->cap * 2;
    while (cap < b->len + more) cap *= 2;
    unsigned char *d = enif_alloc(cap);
    if (d == NULL) return 0;
    memcpy(d, b->data, b->len);
    buf_free(b);
    b->data = d;
    b->cap = cap;
    return 1;
}

static int put(buf *b, const char *s, size_t n)
{
    if (!room(b, n)) return 0;
    memcpy(b->data + b->len, s, n);
    b->len += n;
    return 1;
}

static int put_c(buf *b, char c)
{
    if (!room(b, 1)) return 0;
    b->data[b->len++] = (unsigned char)c;
    return 1;
}

static const double pow10s[] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9};

/* an unsigned integer's decimal digits into `out` (20 bytes at most);
 * their count */
static int utoa(char *out, unsigned long long v)
{
    char tmp[20];
    int n = 0;
    do {
        tmp[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    for (int i = 0; i < n; i++) out[i] = tmp[n - 1 - i];
    return n;
}

/* a float to `decimals` decimals (1..9), trailing zeros dropped but one */
static int put_fixed(buf *b, double f, int decimals)
{
    char tmp[400];
    int neg = signbit(f) ? 1 : 0;
    double af = fabs(f);
    int n;
    if (af > 9007199254740992.0) {
        /* past 2^53: printf's digits, as Erlang does there */
        n = snprintf(tmp, sizeof(tmp), "%.*f", decimals, f);
        if (n <= 0 || n >= (int)sizeof(tmp)) return 0;
        /* trailing zeros, keeping one digit after the point */
        char *dot = strchr(tmp, '.');
        if (dot != NULL) {
            while (n > (dot - tmp) + 2 && tmp[n - 1] == '0') n--;
        }
        return put(b, tmp, (size_t)n);
    }
    /* the integer part, and the fraction times 10^decimals rounded, carried
     * into the integer part when it rounds up to 10^decimals; written by
     * hand (snprintf cost a scan's ranges most of their time) */
    double int_f = floor(af);
    double frac_f = round((af - int_f) * pow10s[decimals]);
    unsigned long long ip = (unsigned long long)int_f;
    unsigned long long fp = (unsigned long long)frac_f;
    if (frac_f >= pow10s[decimals]) {
        ip++;
        fp = 0;
    }
    n = 0;
    if (neg) tmp[n++] = '-';
    n += utoa(tmp + n, ip);
    tmp[n++] = '.';
    /* the fraction's digits less its trailing zeros, one digit at least */
    int digits = decimals;
    while (digits > 1 && fp % 10 == 0) {
        fp /= 10;
        digits--;
    }
    for (int i = digits - 1; i >= 0; i--) {
        tmp[n + i] = (char)('0' + fp % 10);
        fp /= 10;
    }
    n += digits;
    return put(b, tmp, (size_t)n);
}

/* A float's shortest digits that read back the same, written as
 * float_to_binary(F, [short]) does: plain (`0.0012`, `120.0`) or with an
 * exponent (`1.2e-5`, `1.0e15`), whichever is shorter, plain on a tie;
 * from 2^53 always with its exponent. */
static int put_short(buf *b, double f)
{
    char sci[40], digits[24], out[400];
    int prec, n = 0, e = 0;
    for (prec = 0; prec < 17; prec++) {
        snprintf(sci, sizeof(sci), "%.*e", prec, f);
        if (strtod(sci, NULL) == f) break;
    }
    /* sci: [-]d[.ddd]e[+-]xx */
    const char *p = sci;
    int neg = 0;
    if (*p == '-') {
        neg = 1;
        p++;
    }
    for (; *p && *p != 'e'; p++)
        if (*p != '.') digits[n++] = *p;
    if (*p == 'e') e = atoi(p + 1);
    while (n > 1 && digits[n - 1] == '0') n--;
    digits[n] = '\0';

    /* with an exponent */
    char expo[64];
    int el = snprintf(expo, sizeof(expo), "%s%c.%se%d", neg ? "-" : "", digits[0], n > 1 ? digits + 1 : "0", e);
    /* plain */
    int ol = 0;
    if (neg) out[ol++] = '-';
    if (e >= 0) {
        if (e > 300) return put(b, expo, (size_t)el);
        for (int i = 0; i <= e; i++) out[ol++] = i < n ? digits[i] : '0';
        out[ol++] = '.';
        if (n > e + 1)
            for (int i = e + 1; i < n; i++) out[ol++] = digits[i];
        else
            out[ol++] = '0';
    } else {
        if (-e > 300) return put(b, expo, (size_t)el);
        out[ol++] = '0';
        out[ol++] = '.';
        for (int i = 0; i < -e - 1; i++) out[ol++] = '0';
        for (int i = 0; i < n; i++) out[ol++] = digits[i];
    }
    /* from 2^53 (integers a double may skip), Erlang writes the exponent */
    if (fabs(f) >= 9007199254740992.0) return put(b, expo, (size_t)el);
    return ol <= el ? put(b, out, (size_t)ol) : put(b, expo, (size_t)el);
}

/* Core.JSON's number for a float: to the millionth from 0.01 up (below
 * 1e15), else its shortest form */
static int put_float(buf *b, double f)
{
    double af = fabs(f);
    if (af >= 0.01 && af < 1.0e15) return put_fixed(b, f, 6);
    if (f == 0.0) return signbit(f) ? put(b, "-0.0", 4) : put(b, "0.0", 3);
    return put_short(b, f);
}

static int put_int(buf *b, ErlNifSInt64 i)
{
    char tmp[24];
    int n = 0;
    unsigned long long u = (unsigned long long)i;
    if (i < 0) {
        tmp[n++] = '-';
        u = 0ULL - u;
    }
    n += utoa(tmp + n, u);
    return put(b, tmp, (size_t)n);
}

/* a quoted string of ASCII bytes, escaped where JSON needs it (as
 * Core.JSON.string/1); 0 for a byte from 0x80 */
static int put_string(buf *b, const unsigned char *s, size_t n)
{
    if (!room(b, n + 2) || !put_c(b, '"')) return 0;
    for (size_t i = 0; i < n; i++) {
        unsigned char c = s[i];
        if (c >= 0x80) return 0;
        if (c >= 0x20 && c != '"' && c != '\\') {
            if (!put_c(b, (char)c)) return 0;
            continue;
        }
        switch (c) {
        case '"': if (!put(b, "\\\"", 2)) return 0; break;
        case '\\': if (!put(b, "\\\\", 2)) return 0; break;
        case '\n': if (!put(b, "\\n", 2)) return 0; break;
        case '\r': if (!put(b, "\\r", 2)) return 0; break;
        case '\t': if (!put(b, "\\t", 2)) return 0; break;
        default: {
            char tmp[8];
            snprintf(tmp, sizeof(tmp), "\\u00%02X", c);
            if (!put(b, tmp, 6)) return 0;
        }
        }
    }
    return put_c(b, '"');
}

/* a module's name after "Elixir." that inspect/1 prints as it is:
 * segments of a capital letter then letters, digits or _, joined by dots */
static int alias(const char *s)
{
    int start = 1;
    for (; *s; s++) {
        char c = *s;
        if (start) {
            if (c < 'A' || c > 'Z') return 0;
            start = 0;
        } else if (c == '.') {
            start = 1;
        } else if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_')) {
            return 0;
        }
    }
    return !start;
}

/* ---- the same JSON from a term's external format ----
 *
 * Erlang's external term format (`term_to_binary/1`) read with the rules
 * of value/1, so that a tuple held as its external term (the recorder's)
 * need not be decoded: the same bytes, or 0 for anything value/1 would
 * not write (or a binary that is not such a term). Maps come in the
 * order value/1 iterates them (a map's internal order), written in
 * reverse, as value/1 writes them. */

typedef struct {
    const unsigned char *p, *end;
} etf;

static int etf_u8(etf *e, unsigned *v)
{
    if (e->p >= e->end) return 0;
    *v = *e->p++;
    return 1;
}

/* passes over `n` bytes, if there are */
static int etf_pass(etf *e, unsigned long long n)
{
    if ((unsigned long long)(e->end - e->p) < n) return 0;
    e->p += n;
    return 1;
}

static int etf_be(etf *e, int bytes, unsigned long long *v)
{
    if (e->end - e->p < bytes) return 0;
    unsigned long long x = 0;
    for (int i = 0; i < bytes; i++) x = (x << 8) | e->p[i];
    e->p += bytes;
    *v = x;
    return 1;
}

/* an integer of the format (small, 32-bit, or a small big that fits int64) */
static int etf_int(etf *e, unsigned tag, ErlNifSInt64 *out)
{
    unsigned long long v;
    if (tag == 97) {
        if (!etf_be(e, 1, &v)) return 0;
        *out = (ErlNifSInt64)v;
        return 1;
    }
    if (tag == 98) {
        if (!etf_be(e, 4, &v)) return 0;
        *out = (ErlNifSInt64)(int32_t)(uint32_t)v;
        return 1;
    }
    /* SMALL_BIG_EXT: n, sign, n bytes little-endian */
    unsigned n, sign;
    if (!etf_u8(e, &n) || !etf_u8(e, &sign) || n > 8 || e->end - e->p < (long)n) return 0;
    unsigned long long m = 0;
    for (unsigned i = 0; i < n; i++) m |= (unsigned long long)e->p[i] << (8 * i);
    e->p += n;
    if (sign == 0) {
        if (m > 9223372036854775807ULL) return 0;
        *out = (ErlNifSInt64)m;
    } else {
        if (m > 9223372036854775808ULL) return 0;
        *out = (ErlNifSInt64)(0ULL - m);
    }
    return 1;
}

static int etf_float(etf *e, double *f)
{
    unsigned long long v;
    if (!etf_be(e, 8, &v)) return 0;
    memcpy(f, &v, sizeof(*f));
    return 1;
}

/* an atom's name (its length after the tag) */
static int etf_atom(etf *e, unsigned tag, const unsigned char **name, size_t *n)
{
    unsigned long long len;
    if (!etf_be(e, (tag == 100 || tag == 118) ? 2 : 1, &len) || (unsigned long long)(e->end - e->p) < len)
        return 0;
    *name = e->p;
    *n = (size_t)len;
    e->p += len;
    return 1;
}

static int is_atom_tag(unsigned tag) { return tag == 100 || tag == 115 || tag == 118 || tag == 119; }

static int same(const unsigned char *a, size_t n, const char *b)
{
    return n == strlen(b) && memcmp(a, b, n) == 0;
}

static int etf_value(etf *e, buf *b, int depth);

/* passes over one term, checking only its structure; 0 when it is not
 * one value/1 writes */
static int etf_skip(etf *e, int depth)
{
    unsigned tag;
    unsigned long long n;
    if (depth > MAX_DEPTH || !etf_u8(e, &tag)) return 0;
    switch (tag) {
    case 97: return etf_pass(e, 1);
    case 98: return etf_pass(e, 4);
    case 70: return etf_pass(e, 8);
    case 106: return 1;
    case 110: {
        unsigned k;
        return etf_u8(e, &k) && etf_pass(e, 1 + (unsigned long long)k);
    }
    case 100: case 118: case 115: case 119: {
        const unsigned char *name;
        size_t len;
        return etf_atom(e, tag, &name, &len);
    }
    case 107: return etf_be(e, 2, &n) && etf_pass(e, n);
    case 109: return etf_be(e, 4, &n) && etf_pass(e, n);
    case 104: case 105:
        if (!etf_be(e, tag == 104 ? 1 : 4, &n)) return 0;
        for (unsigned long long i = 0; i < n; i++)
            if (!etf_skip(e, depth + 1)) return 0;
        return 1;
    case 108:
        if (!etf_be(e, 4, &n)) return 0;
        for (unsigned long long i = 0; i <= n; i++)
            if (!etf_skip(e, depth + 1)) return 0;
        return 1;
    case 116:
        if (!etf_be(e, 4, &n)) return 0;
        for (unsigned long long i = 0; i < 2 * n; i++)
            if (!etf_skip(e, depth + 1)) return 0;
        return 1;
    default: return 0;
    }
}

/* a map's key, as object() writes it */
static int etf_key(etf *e, buf *b)
{
    unsigned tag;
    if (!etf_u8(e, &tag)) return 0;
    if (is_atom_tag(tag)) {
        const unsigned char *name;
        size_t n;
        return etf_atom(e, tag, &name, &n) && put_string(b, name, n);
    }
    if (tag == 97 || tag == 98 || tag == 110) {
        ErlNifSInt64 i;
        return etf_int(e, tag, &i) && put_c(b, '"') && put_int(b, i) && put_c(b, '"');
    }
    if (tag == 70) {
        double f;
        return etf_float(e, &f) && put_c(b, '"') && put_float(b, f) && put_c(b, '"');
    }
    if (tag == 109) {
        unsigned long long n;
        if (!etf_be(e, 4, &n) || (unsigned long long)(e->end - e->p) < n) return 0;
        int ok = put_string(b, e->p, (size_t)n);
        e->p += n;
        return ok;
    }
    return 0;
}

#define MAX_MEMBERS 32

/* a map (after its tag): its members in the reverse of their order here,
 * a struct's name first */
static int etf_map(etf *e, buf *b, int depth)
{
    unsigned long long n;
    if (!etf_be(e, 4, &n) || n > MAX_MEMBERS) return 0;
    const unsigned char *keys[MAX_MEMBERS], *values[MAX_MEMBERS];
    int skip = -1;
    const unsigned char *module = NULL;
    size_t module_len = 0;
    for (unsigned long long i = 0; i < n; i++) {
        keys[i] = e->p;
        unsigned tag;
        if (!etf_u8(e, &tag)) return 0;
        const unsigned char *name;
        size_t len;
        if (is_atom_tag(tag)) {
            if (!etf_atom(e, tag, &name, &len)) return 0;
            if (same(name, len, "__struct__")) {
                /* a struct when its module is an atom */
                etf v = *e;
                unsigned vtag;
                if (etf_u8(&v, &vtag) && is_atom_tag(vtag)) {
                    if (!etf_atom(&v, vtag, &module, &module_len)) return 0;
                    skip = (int)i;
                }
            }
        } else {
            e->p = keys[i];
            if (!etf_skip(e, depth + 1)) return 0;
        }
        values[i] = e->p;
        if (!etf_skip(e, depth + 1)) return 0;
    }
    const unsigned char *after = e->p;
    int members = 0;
    if (skip >= 0) {
        /* as inspect/1 prints an Elixir module's name */
        char name[256];
        if (module_len <= 7 || module_len >= sizeof(name) || memcmp(module, "Elixir.", 7) != 0) return 0;
        memcpy(name, module + 7, module_len - 7);
        name[module_len - 7] = '\0';
        if (!alias(name)) return 0;
        if (!put(b, "{\"__struct__\":", 14) || !put_string(b, module + 7, module_len - 7)) return 0;
        members = 1;
    } else if (!put_c(b, '{')) {
        return 0;
    }
    for (long long i = (long long)n - 1; i >= 0; i--) {
        if (i == skip) continue;
        if (members++ > 0 && !put_c(b, ',')) return 0;
        etf k = {keys[i], values[i]};
        etf v = {values[i], after};
        if (!etf_key(&k, b) || k.p != values[i] || !put_c(b, ':') || !etf_value(&v, b, depth + 1))
            return 0;
    }
    e->p = after;
    return put_c(b, '}');
}

static int etf_value(etf *e, buf *b, int depth)
{
    unsigned tag;
    unsigned long long n;
    if (depth > MAX_DEPTH || !etf_u8(e, &tag)) return 0;
    switch (tag) {
    case 100: case 115: case 118: case 119: {
        const unsigned char *name;
        size_t len;
        if (!etf_atom(e, tag, &name, &len)) return 0;
        if (same(name, len, "nil")) return put(b, "null", 4);
        if (same(name, len, "true")) return put(b, "true", 4);
        if (same(name, len, "false")) return put(b, "false", 5);
        return put_string(b, name, len);
    }
    case 70: {
        double f;
        return etf_float(e, &f) && put_float(b, f);
    }
    case 97: case 98: case 110: {
        ErlNifSInt64 i;
        return etf_int(e, tag, &i) && put_int(b, i);
    }
    case 109: {
        if (!etf_be(e, 4, &n) || (unsigned long long)(e->end - e->p) < n) return 0;
        int ok = put_string(b, e->p, (size_t)n);
        e->p += n;
        return ok;
    }
    case 106: return put(b, "[]", 2);
    case 107: {
        /* a list of bytes */
        if (!etf_be(e, 2, &n) || (unsigned long long)(e->end - e->p) < n || !put_c(b, '[')) return 0;
        for (unsigned long long k = 0; k < n; k++)
            if ((k > 0 && !put_c(b, ',')) || !put_int(b, e->p[k])) return 0;
        e->p += n;
        return put_c(b, ']');
    }
    case 108: {
        unsigned t;
        if (!etf_be(e, 4, &n) || !put_c(b, '[')) return 0;
        for (unsigned long long k = 0; k < n; k++)
            if ((k > 0 && !put_c(b, ',')) || !etf_value(e, b, depth + 1)) return 0;
        /* a proper list's tail */
        return etf_u8(e, &t) && t == 106 && put_c(b, ']');
    }
    case 104: case 105: {
        if (!etf_be(e, tag == 104 ? 1 : 4, &n)) return 0;
        if (n == 0) return put(b, "[]", 2);
        if (!put_c(b, '[')) return 0;
        for (unsigned long long k = 0; k < n; k++)
            if ((k > 0 && !put_c(b, ',')) || !etf_value(e, b, depth + 1)) return 0;
        return put_c(b, ']');
    }
    case 116: return etf_map(e, b, depth);
    default: return 0;
    }
}

/* ---- Foxglove's own messages from the external term ----
 *
 * A scan (foxglove.LaserScan), a pose estimate (foxglove.PoseInFrame and
 * foxglove.FrameTransform) and the simulator's pose (PoseInFrame), as
 * BlackBox.Foxglove writes them, from the tuple's external term; 0 when
 * the tuple is not of the shape Foxglove's clause for it takes. */

/* a string literal */
#define PUTS(b, lit) put((b), (lit), sizeof(lit) - 1)

/* a map's value for an atom key (the map's tag at e->p) */
static int etf_map_get(const etf *map, const char *key, etf *value)
{
    etf e = *map;
    unsigned tag;
    unsigned long long n;
    if (!etf_u8(&e, &tag) || tag != 116 || !etf_be(&e, 4, &n)) return 0;
    for (unsigned long long i = 0; i < n; i++) {
        unsigned ktag;
        const unsigned char *name;
        size_t len;
        etf k = e;
        int found = 0;
        if (etf_u8(&k, &ktag) && is_atom_tag(ktag) && etf_atom(&k, ktag, &name, &len)) found = same(name, len, key);
        if (!etf_skip(&e, 0)) return 0;
        if (found) {
            *value = e;
            return 1;
        }
        if (!etf_skip(&e, 0)) return 0;
    }
    return 0;
}

typedef struct {
    int is_int;
    ErlNifSInt64 i;
    double f;
} number;

/* a number (an integer of int64, or a float) */
static int etf_number(etf *e, number *x)
{
    unsigned tag;
    if (!etf_u8(e, &tag)) return 0;
    if (tag == 70) {
        x->is_int = 0;
        return etf_float(e, &x->f);
    }
    if (tag == 97 || tag == 98 || tag == 110) {
        x->is_int = 1;
        return etf_int(e, tag, &x->i);
    }
    return 0;
}

static double as_double(const number *x) { return x->is_int ? (double)x->i : x->f; }

/* Core.JSON.number/1 */
static int put_number(buf *b, const number *x) { return x->is_int ? put_int(b, x->i) : put_float(b, x->f); }

/* {"sec":S,"nsec":N} */
static int put_time(buf *b, ErlNifUInt64 ns)
{
    return PUTS(b, "{\"sec\":") && put_int(b, (ErlNifSInt64)(ns / 1000000000ULL)) && PUTS(b, ",\"nsec\":") &&
           put_int(b, (ErlNifSInt64)(ns % 1000000000ULL)) && put_c(b, '}');
}

/* "ROBOT/base_link" */
static int put_frame(buf *b, const unsigned char *robot, size_t n)
{
    char frame[300];
    if (n + 10 > sizeof(frame)) return 0;
    memcpy(frame, robot, n);
    memcpy(frame + n, "/base_link", 10);
    return put_string(b, (unsigned char *)frame, n + 10);
}

/* the tuple's elements: tag (passed over), the robot (an atom's name, or
 * NULL when it is not an atom), the payload (its start) */
static int etf_triple(etf *e, const unsigned char **robot, size_t *robot_len, etf *payload)
{
    unsigned version, tag, arity, rtag;
    if (!etf_u8(e, &version) || version != 131 || !etf_u8(e, &tag) || tag != 104 || !etf_u8(e, &arity) ||
        arity != 3 || !etf_skip(e, 0))
        return 0;
    *robot = NULL;
    etf r = *e;
    if (etf_u8(&r, &rtag) && is_atom_tag(rtag) && !etf_atom(&r, rtag, robot, robot_len)) return 0;
    if (!etf_skip(e, 0)) return 0;
    *payload = *e;
    return etf_skip(e, 0) && e->p == e->end;
}

/* a scan's ranges: floats to the millimetre, integers as they are */
static int etf_ranges(etf *e, buf *b)
{
    unsigned tag;
    unsigned long long n;
    if (!etf_u8(e, &tag)) return 0;
    if (tag == 106) return PUTS(b, "[]");
    if (tag == 107) {
        if (!etf_be(e, 2, &n) || (unsigned long long)(e->end - e->p) < n || !put_c(b, '[')) return 0;
        for (unsigned long long k = 0; k < n; k++)
            if ((k > 0 && !put_c(b, ',')) || !put_int(b, e->p[k])) return 0;
        return put_c(b, ']');
    }
    if (tag != 108 || !etf_be(e, 4, &n) || !put_c(b, '[')) return 0;
    for (unsigned long long k = 0; k < n; k++) {
        number x;
        if ((k > 0 && !put_c(b, ',')) || !etf_number(e, &x)) return 0;
        if (!(x.is_int ? put_int(b, x.i) : put_fixed(b, x.f, 3))) return 0;
    }
    unsigned t;
    return etf_u8(e, &t) && t == 106 && put_c(b, ']');
}

#define IDENTITY "{\"position\":{\"x\":0.0,\"y\":0.0,\"z\":0.0},\"orientation\":{\"x\":0,\"y\":0,\"z\":0,\"w\":1}}"

static int scan_json(etf *e, ErlNifUInt64 ns, buf *b)
{
    const unsigned char *robot;
    size_t robot_len;
    etf payload, ranges, a0e, a1e;
    number a0, a1;
    if (!etf_triple(e, &robot, &robot_len, &payload) || robot == NULL ||
        !etf_map_get(&payload, "ranges", &ranges) || !etf_map_get(&payload, "angle_min", &a0e) ||
        !etf_map_get(&payload, "angle_max", &a1e) || !etf_number(&a0e, &a0) || !etf_number(&a1e, &a1))
        return 0;
    return PUTS(b, "{\"timestamp\":") && put_time(b, ns) && PUTS(b, ",\"frame_id\":") &&
           put_frame(b, robot, robot_len) && PUTS(b, ",\"pose\":") && PUTS(b, IDENTITY) &&
           PUTS(b, ",\"start_angle\":") && put_number(b, &a0) && PUTS(b, ",\"end_angle\":") &&
           put_number(b, &a1) && PUTS(b, ",\"ranges\":") && etf_ranges(&ranges, b) &&
           PUTS(b, ",\"intensities\":[]}");
}

/* the payload's `pose: {x, y, theta}`, numbers */
static int etf_pose(const etf *payload, number *x, number *y, number *theta)
{
    etf p;
    unsigned tag, arity;
    return etf_map_get(payload, "pose", &p) && etf_u8(&p, &tag) && tag == 104 && etf_u8(&p, &arity) &&
           arity == 3 && etf_number(&p, x) && etf_number(&p, y) && etf_number(&p, theta);
}

/* {"x":X,"y":Y,"z":0.0} */
static int put_point(buf *b, const number *x, const number *y)
{
    return PUTS(b, "{\"x\":") && put_number(b, x) && PUTS(b, ",\"y\":") && put_number(b, y) &&
           PUTS(b, ",\"z\":0.0}");
}

/* a rotation by theta about z */
static int put_yaw(buf *b, const number *theta)
{
    double half = as_double(theta) / 2;
    return PUTS(b, "{\"x\":0.0,\"y\":0.0,\"z\":") && put_float(b, sin(half)) && PUTS(b, ",\"w\":") &&
           put_float(b, cos(half)) && put_c(b, '}');
}

/* a PoseInFrame in map */
static int pose_json(ErlNifUInt64 ns, const number *x, const number *y, const number *theta, buf *b)
{
    return PUTS(b, "{\"timestamp\":") && put_time(b, ns) &&
           PUTS(b, ",\"frame_id\":\"map\",\"pose\":{\"position\":") && put_point(b, x, y) &&
           PUTS(b, ",\"orientation\":") && put_yaw(b, theta) && PUTS(b, "}}");
}

/* a FrameTransform from map to the robot's frame */
static int transform_json(ErlNifUInt64 ns, const unsigned char *robot, size_t robot_len, const number *x,
                          const number *y, const number *theta, buf *b)
{
    return PUTS(b, "{\"timestamp\":") && put_time(b, ns) &&
           PUTS(b, ",\"parent_frame_id\":\"map\",\"child_frame_id\":") && put_frame(b, robot, robot_len) &&
           PUTS(b, ",\"translation\":") && put_point(b, x, y) && PUTS(b, ",\"rotation\":") &&
           put_yaw(b, theta) && put_c(b, '}');
}

/* a thinkingcap.Tuple message, as tuple/3 writes it */
static int tuple_json(etf *e, buf *b)
{
    unsigned version, tag, arity;
    return etf_u8(e, &version) && version == 131 && etf_u8(e, &tag) && tag == 104 && etf_u8(e, &arity) &&
           arity == 3 && PUTS(b, "{\"tag\":") && etf_value(e, b, 0) && PUTS(b, ",\"robot\":") &&
           etf_value(e, b, 0) && PUTS(b, ",\"payload\":") && etf_value(e, b, 0) && put_c(b, '}') &&
           e->p == e->end;
}

static ERL_NIF_TERM A_GENERIC, A_SCAN, A_POSE, A_SIM_POSE;

/* A tuple's Foxglove messages (Kind generic, scan, pose or sim_pose) from
 * its external term into `b`, one after the other, each one's end in
 * `ends`; their count (2 at most), or 0 when the tuple is not of that
 * kind's shape or holds what value/1 leaves to Erlang (`b` then as it
 * was), or -1 for an unknown kind */
static int messages_into(ERL_NIF_TERM kind, const ErlNifBinary *in, ErlNifUInt64 ns, buf *b, size_t ends[2])
{
    etf e = {in->data, in->data + in->size};
    size_t start = b->len;
    int count = 0;
    if (kind == A_GENERIC) {
        if (tuple_json(&e, b)) ends[count++] = b->len;
    } else if (kind == A_SCAN) {
        if (scan_json(&e, ns, b)) ends[count++] = b->len;
    } else if (kind == A_POSE || kind == A_SIM_POSE) {
        const unsigned char *robot;
        size_t robot_len;
        etf payload;
        number x, y, theta;
        if (etf_triple(&e, &robot, &robot_len, &payload) && etf_pose(&payload, &x, &y, &theta) &&
            (kind == A_SIM_POSE || robot != NULL) && pose_json(ns, &x, &y, &theta, b)) {
            ends[count++] = b->len;
            if (kind == A_POSE) {
                if (transform_json(ns, robot, robot_len, &x, &y, &theta, b)) ends[count++] = b->len;
                else count = 0;
            }
        }
    } else {
        return -1;
    }
    if (count == 0) b->len = start;
    return count;
}

/* the kinds' atoms, made when a library loads (an atom's term is the
 * same in every environment, and an immediate) */
static void json_etf_load(ErlNifEnv *env)
{
    A_GENERIC = enif_make_atom(env, "generic");
    A_SCAN = enif_make_atom(env, "scan");
    A_POSE = enif_make_atom(env, "pose");
    A_SIM_POSE = enif_make_atom(env, "sim_pose");
}

#endif