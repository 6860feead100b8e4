/*
 * tc_plan: A* and D* Lite on a byte grid, for the grid NIF (tc_grid.c;
 * ThinkingCap.Navigation.AStar and ThinkingCap.Navigation.DStarLite wrap
 * them). The cost model is ThinkingCap.Navigation.Core.Cost's, in the
 * same exact integer units: 8-connected, a straight step 2^36, a diagonal
 * round(sqrt(2) 2^36), no corner cutting (a diagonal step needs both
 * orthogonal cells passable), octile heuristic. Cells: row-major from the
 * bottom row, 0 passable, 1 blocked, 2..255 passable at a cost: a step
 * between cells a and b costs its length times 1 + (p(a) + p(b)) / 16,
 * p(v) = v for v >= 2, else 0 (a cost band round the obstacles). The
 * octile heuristic stays a lower bound, so the plans stay optimal.
 *
 * A* keeps its scratch per thread between calls, stamped with the search
 * it belongs to, so a search costs only the cells it touches. D* Lite (Koenig & Likhachev,
 * the optimized version of their figure 4) is a resource holding its own
 * copy of the grid, each vertex's g and rhs side by side (as INF - value,
 * so zeroed memory is infinite), and its queue: an indexed 4-ary heap
 * that holds each inconsistent vertex once and changes keys in place.
 * A plan walks its path again only from the start to the first cell of
 * the last path it meets, while nothing near that path changed.
 */
#include "tc_plan.h"
#include "tc_nif.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#define INF (1LL << 58)
/* vertices a plan processes on the calling scheduler before it goes on
 * on a dirty one (well under a millisecond), and changes an update makes
 * there */
#define PLAN_BUDGET 4000
#define SMALL_UPDATE 2000
#define STRAIGHT (1LL << 36)
#define BLOCKED 1
/* a cell's cost byte as the step costs count it */
#define PENALTY(v) ((v) >= 2 ? (int64_t)(v) : 0)

/* the CPU time (ns) the calling thread has used: what a search costs,
 * without the time the OS gave to other threads meanwhile */
static inline int64_t cpu_now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (int64_t)t.tv_sec * 1000000000 + t.tv_nsec;
}

static int64_t DIAGONAL;
static ErlNifResourceType *DSL_TYPE;
static ERL_NIF_TERM A_OK, A_ERROR, A_NO_PATH, A_NONE;

typedef struct {
    int64_t k1, k2;
    int32_t u;
} Entry;

typedef struct {
    Entry *e;
    size_t n, cap;
} Heap;

static int less(const Entry *a, const Entry *b)
{
    return a->k1 < b->k1 || (a->k1 == b->k1 && a->k2 < b->k2);
}

static int heap_push(Heap *h, int64_t k1, int64_t k2, int32_t u)
{
    if (h->n == h->cap) {
        size_t cap = h->cap ? 2 * h->cap : 1024;
        Entry *e = realloc(h->e, cap * sizeof(Entry));
        if (!e) return 0;
        h->e = e;
        h->cap = cap;
    }
    size_t i = h->n++;
    Entry x = {k1, k2, u};
    while (i > 0) {
        size_t p = (i - 1) / 2;
        if (!less(&x, &h->e[p])) break;
        h->e[i] = h->e[p];
        i = p;
    }
    h->e[i] = x;
    return 1;
}

static Entry heap_pop(Heap *h)
{
    Entry top = h->e[0];
    Entry x = h->e[--h->n];
    size_t i = 0;
    for (;;) {
        size_t c = 2 * i + 1;
        if (c >= h->n) break;
        if (c + 1 < h->n && less(&h->e[c + 1], &h->e[c])) c++;
        if (!less(&h->e[c], &x)) break;
        h->e[i] = h->e[c];
        i = c;
    }
    if (h->n > 0) h->e[i] = x;
    return top;
}

static int64_t octile(int c1, int r1, int c2, int r2)
{
    int64_t dx = abs(c1 - c2), dy = abs(r1 - r2);
    return dx > dy ? STRAIGHT * (dx - dy) + DIAGONAL * dy : STRAIGHT * (dy - dx) + DIAGONAL * dx;
}

/* The cost of a step of `base` units between cells of bytes a and b. */
static inline int64_t step_cost(int64_t base, uint8_t a, uint8_t b)
{
    int64_t p = PENALTY(a) + PENALTY(b);
    return p ? base + (base >> 4) * p : base;
}

/* The edges of cell i: up to 8 {neighbour, cost}, none from a blocked
 * cell, in the order left, right, down, up, down-left, down-right,
 * up-left, up-right. */
static int edges(const uint8_t *cells, int w, int h, int32_t i, int32_t *to, int64_t *cost)
{
    uint8_t v = cells[i];
    if (v == BLOCKED) return 0;
    int c = i % w, r = i / w;
#define AT(dc, dr)                                                                              \
    ((c + (dc)) >= 0 && (r + (dr)) >= 0 && (c + (dc)) < w && (r + (dr)) < h                     \
         ? cells[(size_t)(r + (dr)) * w + (c + (dc))]                                           \
         : BLOCKED)
    uint8_t l = AT(-1, 0), rr = AT(1, 0), d = AT(0, -1), u = AT(0, 1);
    uint8_t dl = AT(-1, -1), dr = AT(1, -1), ul = AT(-1, 1), ur = AT(1, 1);
#undef AT
    int bl = l == BLOCKED, br = rr == BLOCKED, bd = d == BLOCKED, bu = u == BLOCKED;
    int n = 0;
    if (!((v | l | rr | d | u | dl | dr | ul | ur) & 0xFE)) {
        /* no costly cell round i: the steps' lengths */
        if (!bl) to[n] = i - 1, cost[n++] = STRAIGHT;
        if (!br) to[n] = i + 1, cost[n++] = STRAIGHT;
        if (!bd) to[n] = i - w, cost[n++] = STRAIGHT;
        if (!bu) to[n] = i + w, cost[n++] = STRAIGHT;
        if (!(bl | bd | dl)) to[n] = i - w - 1, cost[n++] = DIAGONAL;
        if (!(br | bd | dr)) to[n] = i - w + 1, cost[n++] = DIAGONAL;
        if (!(bl | bu | ul)) to[n] = i + w - 1, cost[n++] = DIAGONAL;
        if (!(br | bu | ur)) to[n] = i + w + 1, cost[n++] = DIAGONAL;
        return n;
    }
    if (!bl) to[n] = i - 1, cost[n++] = step_cost(STRAIGHT, v, l);
    if (!br) to[n] = i + 1, cost[n++] = step_cost(STRAIGHT, v, rr);
    if (!bd) to[n] = i - w, cost[n++] = step_cost(STRAIGHT, v, d);
    if (!bu) to[n] = i + w, cost[n++] = step_cost(STRAIGHT, v, u);
    if (!(bl | bd | (dl == BLOCKED))) to[n] = i - w - 1, cost[n++] = step_cost(DIAGONAL, v, dl);
    if (!(br | bd | (dr == BLOCKED))) to[n] = i - w + 1, cost[n++] = step_cost(DIAGONAL, v, dr);
    if (!(bl | bu | (ul == BLOCKED))) to[n] = i + w - 1, cost[n++] = step_cost(DIAGONAL, v, ul);
    if (!(br | bu | (ur == BLOCKED))) to[n] = i + w + 1, cost[n++] = step_cost(DIAGONAL, v, ur);
    return n;
}

static ERL_NIF_TERM path_term(ErlNifEnv *env, const int32_t *cells, size_t n, int w)
{
    ERL_NIF_TERM list = enif_make_list(env, 0);
    for (size_t k = n; k > 0; k--) {
        int32_t i = cells[k - 1];
        list = enif_make_list_cell(
            env, enif_make_tuple2(env, enif_make_int(env, i % w), enif_make_int(env, i / w)), list);
    }
    return list;
}

static int get_cell(ErlNifEnv *env, ERL_NIF_TERM t, int w, int h, int32_t *out)
{
    int arity, c, r;
    const ERL_NIF_TERM *e;
    if (!enif_get_tuple(env, t, &arity, &e) || arity != 2 || !enif_get_int(env, e[0], &c) ||
        !enif_get_int(env, e[1], &r) || c < 0 || r < 0 || c >= w || r >= h)
        return 0;
    *out = r * w + c;
    return 1;
}

/* a planning problem's arguments: the grid (cells, w, h) and the start
 * and goal cells on it */
static int get_problem(ErlNifEnv *env, const ERL_NIF_TERM argv[], ErlNifBinary *b, int *w,
                       int *h, int32_t *s, int32_t *g)
{
    return tc_grid_args(env, argv, 1L << 27, b, w, h) && get_cell(env, argv[3], *w, *h, s) &&
           get_cell(env, argv[4], *w, *h, g);
}

/* ---- A* ---- */

/* Each thread (a dirty scheduler) keeps its A* scratch between calls: a
 * cell's g is valid when its stamp is this search's; closed cells have
 * bit 0 of the stamp word set in a second stamp. Nothing is cleared
 * between searches. */
static __thread struct {
    size_t cap;
    int64_t *g;
    uint32_t *seen, *closed;
    uint32_t gen;
} scratch;

static int scratch_for(size_t n)
{
    if (scratch.cap < n) {
        free(scratch.g);
        free(scratch.seen);
        free(scratch.closed);
        scratch.g = malloc(n * sizeof(int64_t));
        scratch.seen = calloc(n, sizeof(uint32_t));
        scratch.closed = calloc(n, sizeof(uint32_t));
        scratch.gen = 0;
        scratch.cap = scratch.g && scratch.seen && scratch.closed ? n : 0;
        if (!scratch.cap) return 0;
    }
    if (++scratch.gen == 0) {
        memset(scratch.seen, 0, scratch.cap * sizeof(uint32_t));
        memset(scratch.closed, 0, scratch.cap * sizeof(uint32_t));
        scratch.gen = 1;
    }
    return 1;
}

static inline int seen(int32_t i) { return scratch.seen[i] == scratch.gen; }
static inline int is_closed(int32_t i) { return scratch.closed[i] == scratch.gen; }
static inline void close_cell(int32_t i) { scratch.closed[i] = scratch.gen; }
static inline int64_t get_g(int32_t i) { return scratch.g[i]; }

static inline void set_g(int32_t i, int64_t v)
{
    scratch.g[i] = v;
    scratch.seen[i] = scratch.gen;
}

/* Relaxes the edges of the closed cell u: a neighbour reached cheaper
 * gets its g and is queued, keyed by f = g + octile to (gc, gr) with ties
 * to the larger g (A*), or by g alone when gc < 0 (Dijkstra). 0 when the
 * queue could not grow. */
static int relax(const uint8_t *cells, int w, int h, int32_t u, Heap *heap, int gc, int gr)
{
    int32_t to[8];
    int64_t cost[8];
    int ok = 1;
    int64_t gu = get_g(u);
    int m = edges(cells, w, h, u, to, cost);
    for (int k = 0; k < m; k++) {
        int32_t v = to[k];
        int64_t gv = gu + cost[k];
        if (!is_closed(v) && (!seen(v) || gv < get_g(v))) {
            set_g(v, gv);
            ok = (gc < 0 ? heap_push(heap, gv, 0, v)
                         : heap_push(heap, gv + octile(v % w, v / w, gc, gr), -gv, v)) &&
                 ok;
        }
    }
    return ok;
}

/* astar(cells, w, h, start, goal) -> {:ok, path, cost_units, expanded} |
 * {:error, :no_path, expanded}; start and goal passable, distinct. Ties on
 * f go to the larger g (the deeper cell). */
ERL_NIF_TERM tc_nif_astar(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h;
    int32_t s, g;
    if (!get_problem(env, argv, &b, &w, &h, &s, &g)) return enif_make_badarg(env);
    const uint8_t *cells = b.data;
    size_t n = (size_t)w * h;
    if (!scratch_for(n)) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    Heap heap = {0};
    int gc = g % w, gr = g / w;
    set_g(s, 0);
    /* f first, then -g (deeper first) */
    int ok = heap_push(&heap, octile(s % w, s / w, gc, gr), 0, s);
    long expanded = 0;
    int found = 0;
    int32_t to[8];
    int64_t cost[8];
    while (ok && heap.n > 0) {
        Entry e = heap_pop(&heap);
        int32_t u = e.u;
        if (is_closed(u)) continue;
        close_cell(u);
        expanded++;
        if (u == g) {
            found = 1;
            break;
        }
        ok = relax(cells, w, h, u, &heap, gc, gr);
    }
    ERL_NIF_TERM result;
    if (!ok) {
        result = enif_raise_exception(env, enif_make_atom(env, "enomem"));
    } else if (!found) {
        result = enif_make_tuple3(env, A_ERROR, A_NO_PATH, enif_make_long(env, expanded));
    } else {
        /* back from the goal along optimal predecessors (closed, g + cost == g) */
        size_t cap = 1024, len = 0;
        int32_t *path = malloc(cap * sizeof(int32_t));
        int32_t u = g;
        while (path) {
            if (len == cap) {
                int32_t *p = realloc(path, 2 * cap * sizeof(int32_t));
                if (!p) {
                    free(path);
                    path = NULL;
                    break;
                }
                path = p;
                cap *= 2;
            }
            path[len++] = u;
            if (u == s) break;
            int m = edges(cells, w, h, u, to, cost);
            int32_t next = -1;
            for (int k = 0; k < m && next < 0; k++)
                if (is_closed(to[k]) && get_g(to[k]) + cost[k] == get_g(u)) next = to[k];
            if (next < 0) break;
            u = next;
        }
        if (!path) {
            result = enif_raise_exception(env, enif_make_atom(env, "enomem"));
        } else {
            /* reverse into start..goal */
            for (size_t a = 0, z = len - 1; a < z; a++, z--) {
                int32_t t = path[a];
                path[a] = path[z];
                path[z] = t;
            }
            result = enif_make_tuple4(env, A_OK, path_term(env, path, len, w),
                                      enif_make_int64(env, get_g(g)),
                                      enif_make_long(env, expanded));
            free(path);
        }
    }
    free(heap.e);
    return result;
}

/* astar_cpu(cells, w, h, start, goal) -> {cpu_ns, result}: astar's result
 * and the CPU time the search took on its thread */
ERL_NIF_TERM tc_nif_astar_cpu(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    int64_t t0 = cpu_now();
    ERL_NIF_TERM result = tc_nif_astar(env, argc, argv);
    ERL_NIF_TERM exception;
    if (enif_has_pending_exception(env, &exception)) return result;
    return enif_make_tuple2(env, enif_make_int64(env, cpu_now() - t0), result);
}

/* ---- costs to many cells ---- */

/* costs(cells, w, h, start, targets) -> [cost_units | :none], one per
 * target: the cost of the cheapest path from start (Dijkstra, the same
 * steps as A*), :none for a target no path reaches. The search stops when
 * every reachable target is settled. Start passable. */
ERL_NIF_TERM tc_nif_costs(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h;
    int32_t s;
    unsigned count;
    if (!enif_inspect_binary(env, argv[0], &b) || !enif_get_int(env, argv[1], &w) ||
        !enif_get_int(env, argv[2], &h) || w <= 0 || h <= 0 || (long)w * h > (1L << 27) ||
        b.size != (size_t)w * h || !get_cell(env, argv[3], w, h, &s) ||
        !enif_get_list_length(env, argv[4], &count) || count > 100000)
        return enif_make_badarg(env);
    int32_t *targets = malloc((count ? count : 1) * sizeof(int32_t));
    if (!targets) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    ERL_NIF_TERM list = argv[4], head;
    for (unsigned k = 0; k < count; k++) {
        enif_get_list_cell(env, list, &head, &list);
        if (!get_cell(env, head, w, h, &targets[k])) {
            free(targets);
            return enif_make_badarg(env);
        }
    }
    const uint8_t *cells = b.data;
    if (!scratch_for((size_t)w * h)) {
        free(targets);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    /* a target is waited for only if its cell is passable */
    unsigned left = 0;
    for (unsigned k = 0; k < count; k++) left += cells[targets[k]] != BLOCKED;
    Heap heap = {0};
    set_g(s, 0);
    int ok = heap_push(&heap, 0, 0, s);
    while (ok && heap.n > 0 && left > 0) {
        Entry e = heap_pop(&heap);
        int32_t u = e.u;
        if (is_closed(u)) continue;
        close_cell(u);
        for (unsigned k = 0; k < count; k++) left -= targets[k] == u;
        ok = relax(cells, w, h, u, &heap, -1, -1);
    }
    free(heap.e);
    ERL_NIF_TERM result;
    if (!ok) {
        result = enif_raise_exception(env, enif_make_atom(env, "enomem"));
    } else {
        result = enif_make_list(env, 0);
        for (unsigned k = count; k > 0; k--) {
            int32_t t = targets[k - 1];
            ERL_NIF_TERM c = is_closed(t) ? enif_make_int64(env, get_g(t)) : A_NONE;
            result = enif_make_list_cell(env, c, result);
        }
    }
    free(targets);
    return result;
}

/* ---- D* Lite ---- */

/* A vertex: g and rhs as INF - value, so zeroed memory is infinite; side
 * by side, as the search reads them together. */
typedef struct {
    int64_t g, rhs;
} Vertex;

/* A queued vertex and its key: k1 = min(g, rhs) + h + km, then k2, the
 * order among equal k1: the underconsistent vertices (g < rhs) first, by
 * g from small to large, as in the paper, then the overconsistent ones
 * by rhs from large to small, the deepest (nearest the start) first, as
 * A* breaks ties. The paper breaks every tie by the smaller min(g, rhs):
 * in open space, where the octile distance is exact, that expands every
 * vertex of every shortest path before the start, a parallelogram
 * between the start and the goal. The search may stop while
 * overconsistent vertices tie with the start: a path through one costs
 * at least its k1 - km, the start's cost. It may not stop while an
 * underconsistent one does: the start's cost may rest on its g. */
typedef struct {
    int64_t k1, k2;
    int32_t u;
} Queued;

typedef struct {
    ErlNifMutex *lock;
    int w, h;
    uint8_t *cells;
    Vertex *v;
    /* the queue: a 4-ary heap holding each inconsistent vertex at least
     * once with its key, and stale entries (q_stale) */
    Queued *q;
    size_t qn, qcap;
    /* a bit per vertex: looked at by the update being applied (small, so
     * it stays in cache; cleared after each update) */
    uint64_t *seen;
    /* the last path (plen cells, start to goal) and a bit per cell of
     * it (on). While no g-value and no cell within one cell of it has
     * changed (valid), the walk from any of its cells to the goal is the
     * rest of it. The vertices whose g or cell changed since it was
     * walked are listed (touched, tn of them; past TOUCHED the path is
     * walked again whole) and checked when the next path is walked. */
    int32_t *path, *spare;
    size_t plen, pcap, scap;
    uint64_t *on;
    int32_t *touched;
    size_t tn;
    int valid;
    int64_t km;
    /* the CPU time (ns) the calls on this search have taken */
    int64_t cpu_ns;
    int32_t start, goal;
    int sc, sr; /* the start's column and row */
} Dsl;

#define G(d, i) (INF - (d)->v[i].g)
#define RHS(d, i) (INF - (d)->v[i].rhs)
#define SET_RHS(d, i, x) ((d)->v[i].rhs = INF - (x))
#define BIT(map, i) (((map)[(i) >> 6] >> ((i)&63)) & 1)
#define TOUCHED 4096

/* u's g-value or cell changes */
static inline void touch(Dsl *d, int32_t u)
{
    if (!d->valid) return;
    if (d->tn < TOUCHED)
        d->touched[d->tn++] = u;
    else
        d->valid = 0;
}

static inline void dsl_set_g(Dsl *d, int32_t u, int64_t x)
{
    touch(d, u);
    d->v[u].g = INF - x;
}

/* Zeroed memory for a per-vertex array, in huge pages where the kernel
 * gives them: a big grid's arrays in 4 KB pages cost a page fault on
 * each page a search first reaches and a TLB miss on most reads of a
 * walk, whose rows lie pages apart. */
static void *big_zeroed(size_t size)
{
    void *p = mmap(NULL, size, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) return NULL;
#ifdef MADV_HUGEPAGE
    madvise(p, size, MADV_HUGEPAGE);
#endif
    return p;
}

static void big_free(void *p, size_t size)
{
    if (p) munmap(p, size);
}

static void dsl_free(ErlNifEnv *env, void *obj)
{
    (void)env;
    Dsl *d = obj;
    size_t n = (size_t)d->w * d->h;
    free(d->cells);
    big_free(d->v, n * sizeof(Vertex));
    free(d->q);
    free(d->seen);
    free(d->path);
    free(d->spare);
    free(d->on);
    free(d->touched);
    if (d->lock) enif_mutex_destroy(d->lock);
}

int tc_plan_load(ErlNifEnv *env)
{
    DIAGONAL = (int64_t)llround(sqrt(2.0) * (double)STRAIGHT);
    DSL_TYPE = enif_open_resource_type(env, NULL, "tc_plan_dsl", dsl_free,
                                       ERL_NIF_RT_CREATE | ERL_NIF_RT_TAKEOVER, NULL);
    A_OK = enif_make_atom(env, "ok");
    A_ERROR = enif_make_atom(env, "error");
    A_NO_PATH = enif_make_atom(env, "no_path");
    A_NONE = enif_make_atom(env, "none");
    return DSL_TYPE == NULL;
}

#define UNDER (1LL << 60)

/* k2 of a vertex inconsistent with these g and rhs */
static inline int64_t order(int64_t g, int64_t rhs)
{
    return g < rhs ? g - UNDER : -rhs;
}

/* min(g, rhs) back from k2 */
static inline int64_t k2_min(int64_t k2)
{
    return k2 < -(UNDER >> 1) ? k2 + UNDER : -k2;
}

static inline int qless(const Queued *a, const Queued *b)
{
    return a->k1 < b->k1 || (a->k1 == b->k1 && a->k2 < b->k2);
}

static void q_up(Dsl *d, size_t i, Queued x)
{
    while (i > 0) {
        size_t p = (i - 1) / 4;
        if (!qless(&x, &d->q[p])) break;
        d->q[i] = d->q[p];
        i = p;
    }
    d->q[i] = x;
}

static void q_down(Dsl *d, size_t i, Queued x)
{
    size_t n = d->qn;
    for (;;) {
        size_t c = 4 * i + 1;
        if (c >= n) break;
        size_t best = c, end = c + 4 < n ? c + 4 : n;
        for (size_t j = c + 1; j < end; j++)
            if (qless(&d->q[j], &d->q[best])) best = j;
        if (!qless(&d->q[best], &x)) break;
        d->q[i] = d->q[best];
        i = best;
    }
    d->q[i] = x;
}

static inline int q_stale(const Dsl *d, const Queued *e);

/* the stale entries dropped and the heap made again (Floyd's) */
static void q_compact(Dsl *d)
{
    size_t n = 0;
    for (size_t i = 0; i < d->qn; i++)
        if (!q_stale(d, &d->q[i])) d->q[n++] = d->q[i];
    d->qn = n;
    for (size_t i = n > 1 ? (n - 2) / 4 + 1 : 0; i-- > 0;) q_down(d, i, d->q[i]);
}

/* queues u with this key; an entry of u queued before with another key
 * is left in the queue, stale (see q_stale). A full queue is first
 * rid of its stale entries, and grows only if that leaves it more than
 * half full: stale entries that never reach the top (behind the robot)
 * do not pile up over a long run. */
static int q_set(Dsl *d, int32_t u, int64_t k1, int64_t k2)
{
    Queued x = {k1, k2, u};
    if (d->qn == d->qcap) {
        if (d->qcap) q_compact(d);
        if (d->qcap == 0 || d->qn > d->qcap / 2) {
            size_t cap = d->qcap ? 2 * d->qcap : 1024;
            Queued *q = realloc(d->q, cap * sizeof(Queued));
            if (!q) return 0;
            d->q = q;
            d->qcap = cap;
        }
    }
    q_up(d, d->qn++, x);
    return 1;
}

/* the top of the queue taken out */
static void q_pop(Dsl *d)
{
    Queued last = d->q[--d->qn];
    if (d->qn > 0) q_down(d, 0, last);
}

/* An entry no longer says what its vertex is: the vertex is consistent,
 * or was queued again with another order (k2 holds min(g, rhs) and
 * whether g < rhs). A vertex is queued again, not moved in the queue,
 * when its key changes: the heap then needs no index of where each
 * vertex stands, whose updates on every move of an entry were most of a
 * repair's cost (each a read of memory far from the last). */
static inline int q_stale(const Dsl *d, const Queued *e)
{
    int64_t g = G(d, e->u), rhs = RHS(d, e->u);
    return g == rhs || e->k2 != order(g, rhs);
}

/* UpdateVertex: queued with its key if inconsistent, out of the queue if
 * not; 0 when the queue could not grow */
static int update_vertex(Dsl *d, int32_t u)
{
    int64_t g = G(d, u), rhs = RHS(d, u);
    if (g != rhs) {
        int64_t k = g < rhs ? g : rhs;
        return q_set(d, u, k + octile(d->sc, d->sr, u % d->w, u / d->w) + d->km, order(g, rhs));
    }
    /* consistent: its entries, if any, are stale */
    return 1;
}

static int64_t best_rhs(Dsl *d, int32_t u)
{
    int32_t to[8];
    int64_t cost[8];
    int m = edges(d->cells, d->w, d->h, u, to, cost);
    int64_t best = INF;
    for (int k = 0; k < m; k++) {
        int64_t gv = G(d, to[k]);
        if (gv < INF && cost[k] + gv < best) best = cost[k] + gv;
    }
    return best;
}

/* dsl_new(cells, w, h, start, goal) */
ERL_NIF_TERM tc_nif_dsl_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    ErlNifBinary b;
    int w, h;
    int32_t s, g;
    int64_t t0 = cpu_now();
    if (!get_problem(env, argv, &b, &w, &h, &s, &g)) return enif_make_badarg(env);
    size_t n = (size_t)w * h;
    Dsl *d = enif_alloc_resource(DSL_TYPE, sizeof(Dsl));
    memset(d, 0, sizeof(Dsl));
    d->w = w;
    d->h = h;
    d->cells = malloc(n);
    d->v = big_zeroed(n * sizeof(Vertex));
    d->seen = calloc(n / 64 + 1, sizeof(uint64_t));
    d->on = calloc(n / 64 + 1, sizeof(uint64_t));
    d->touched = malloc(TOUCHED * sizeof(int32_t));
    d->lock = enif_mutex_create("tc_plan_dsl");
    d->start = s;
    d->sc = s % w;
    d->sr = s / w;
    d->goal = g;
    if (!d->cells || !d->v || !d->seen || !d->on || !d->touched || !d->lock) {
        enif_release_resource(d);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    memcpy(d->cells, b.data, n);
    SET_RHS(d, g, 0);
    if (!update_vertex(d, g)) {
        enif_release_resource(d);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    d->cpu_ns = cpu_now() - t0;
    ERL_NIF_TERM t = enif_make_resource(env, d);
    enif_release_resource(d);
    return t;
}

/* Sets cell i's byte (0 free, 1 blocked, 2..255 a cost); returns 1 if
 * that changed it. */
static int set_cell(Dsl *d, int32_t i, uint8_t v)
{
    if (d->cells[i] == v) return 0;
    touch(d, i);
    d->cells[i] = v;
    return 1;
}

/* After cells changed (their new values already in d->cells, so every
 * rhs below sees the new grid): the rhs of each changed cell and of its
 * 8 neighbours (the vertices whose outgoing edges changed) is computed
 * again, once per vertex however many changed cells it touches, and the
 * vertex queued if that made it inconsistent. A vertex whose rhs is
 * infinite (unexplored) next to cells that were only blocked is left
 * alone: its rhs cannot fall. (A cell made dearer counts as freed: its
 * old cost is not kept.) Returns the number of vertices looked at,
 * or -1 out of memory. */
static long repair_rhs(Dsl *d, const int32_t *changed, size_t m)
{
    long looked = 0;
    int w = d->w, h = d->h, ok = 1;
    uint64_t *seen = d->seen;
    for (size_t k = 0; k < m && ok; k++) {
        int32_t i = changed[k];
        int freed = d->cells[i] != BLOCKED;
        int c = i % w, r = i / w;
        for (int rr = r - 1; rr <= r + 1; rr++) {
            if (rr < 0 || rr >= h) continue;
            for (int cc = c - 1; cc <= c + 1; cc++) {
                if (cc < 0 || cc >= w) continue;
                int32_t u = rr * w + cc;
                uint64_t bit = 1ULL << (u & 63);
                if (u == d->goal || (seen[u >> 6] & bit)) continue;
                int64_t old = RHS(d, u);
                if (!freed && old >= INF) continue;
                seen[u >> 6] |= bit;
                looked++;
                int64_t v = best_rhs(d, u);
                if (v != old) {
                    SET_RHS(d, u, v);
                    ok = ok && update_vertex(d, u);
                }
            }
        }
    }
    /* clear the bits set above: the words of the changed cells' rows */
    for (size_t k = 0; k < m; k++) {
        int32_t i = changed[k];
        int c = i % w, r = i / w;
        for (int rr = r - 1; rr <= r + 1; rr++) {
            if (rr < 0 || rr >= h) continue;
            int32_t a = rr * w + (c > 0 ? c - 1 : 0), z = rr * w + (c + 1 < w ? c + 1 : c);
            seen[a >> 6] = 0;
            seen[z >> 6] = 0;
        }
    }
    return ok ? looked : -1;
}

/* dsl_update(dsl, changes): changes is a list of {{col, row}, blocked?}
 * (cells outside the grid and cells already so are skipped; a later
 * change of a cell wins). Returns {applied, cells}: the number of
 * changes that changed a cell and, if any did, a copy of the search's
 * grid as it is now (nil if none did). A malformed list changes nothing. */
static ERL_NIF_TERM dsl_update_now(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Dsl *d;
    unsigned len;
    int64_t t0 = cpu_now();
    if (!enif_get_resource(env, argv[0], DSL_TYPE, (void **)&d) ||
        !enif_get_list_length(env, argv[1], &len))
        return enif_make_badarg(env);
    /* read and check the whole list before anything changes */
    int32_t *index = malloc(((size_t)len + 1) * sizeof(int32_t));
    uint8_t *value = malloc((size_t)len + 1);
    if (!index || !value) {
        free(index);
        free(value);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    size_t k = 0;
    ERL_NIF_TERM list = argv[1], head;
    while (enif_get_list_cell(env, list, &head, &list)) {
        int arity, arity2, c, r;
        const ERL_NIF_TERM *e, *cell;
        char atom[6];
        if (!enif_get_tuple(env, head, &arity, &e) || arity != 2 ||
            !enif_get_tuple(env, e[0], &arity2, &cell) || arity2 != 2 ||
            !enif_get_int(env, cell[0], &c) || !enif_get_int(env, cell[1], &r) ||
            !enif_get_atom(env, e[1], atom, sizeof(atom), ERL_NIF_LATIN1) ||
            (strcmp(atom, "true") && strcmp(atom, "false"))) {
            free(index);
            free(value);
            return enif_make_badarg(env);
        }
        if (c < 0 || r < 0 || c >= d->w || r >= d->h) continue;
        index[k] = r * d->w + c;
        value[k++] = atom[0] == 't';
    }
    enif_mutex_lock(d->lock);
    /* the cells first, so every rhs repaired sees the new grid */
    size_t m = 0;
    for (size_t j = 0; j < k; j++)
        if (set_cell(d, index[j], value[j])) index[m++] = index[j];
    long looked = repair_rhs(d, index, m);
    ERL_NIF_TERM result;
    if (looked < 0) {
        result = enif_raise_exception(env, enif_make_atom(env, "enomem"));
    } else if (m == 0) {
        result = enif_make_tuple2(env, enif_make_long(env, 0), enif_make_atom(env, "nil"));
    } else {
        ERL_NIF_TERM cells;
        size_t n = (size_t)d->w * d->h;
        unsigned char *p = enif_make_new_binary(env, n, &cells);
        memcpy(p, d->cells, n);
        result = enif_make_tuple2(env, enif_make_long(env, (long)m), cells);
    }
    d->cpu_ns += cpu_now() - t0;
    enif_mutex_unlock(d->lock);
    free(index);
    free(value);
    return result;
}

/* small updates run on the calling scheduler; big ones on a dirty one */
ERL_NIF_TERM tc_nif_dsl_update(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    unsigned len;
    if (argc == 2 && enif_get_list_length(env, argv[1], &len) && len > SMALL_UPDATE)
        return enif_schedule_nif(env, "dsl_update", ERL_NIF_DIRTY_JOB_CPU_BOUND, dsl_update_now,
                                 argc, argv);
    return dsl_update_now(env, argc, argv);
}

/* grids are compared in blocks: memcmp skips equal ones at memory speed */
#define BLOCK 256

/* appends j to the changed cells; 0 out of memory */
static int push_changed(int32_t **changed, size_t *m, size_t *cap, int32_t j)
{
    if (*m == *cap) {
        int32_t *more = realloc(*changed, 2 * *cap * sizeof(int32_t));
        if (!more) return 0;
        *changed = more;
        *cap *= 2;
    }
    (*changed)[(*m)++] = j;
    return 1;
}

/* dsl_sync(dsl, cells, max) -> {:ok, changed} | {:too_many, changed}:
 * the search's grid made `cells` (same size), the changed cells repaired
 * as dsl_update does; more than max changed cells leave the search as it
 * was (a new search is then cheaper), `changed` counting up to max + 1.
 * One pass over the grids lists the differing cells, then they are set
 * and repaired. dsl_sync(dsl, cells, max, hint): the same, where only
 * the cells listed in hint (native 32-bit indices, repeats allowed; the
 * cost map's builder lists them as it writes the grid) may differ, so
 * no pass over the grid is needed. */
static ERL_NIF_TERM dsl_sync_now(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    Dsl *d;
    ErlNifBinary b, hint;
    long max;
    int64_t t0 = cpu_now();
    if (!enif_get_resource(env, argv[0], DSL_TYPE, (void **)&d) ||
        !enif_inspect_binary(env, argv[1], &b) || !enif_get_long(env, argv[2], &max) || max < 0)
        return enif_make_badarg(env);
    size_t n = (size_t)d->w * d->h;
    if (b.size != n) return enif_make_badarg(env);
    int hinted = argc == 4;
    if (hinted && (!enif_inspect_binary(env, argv[3], &hint) || hint.size % sizeof(int32_t)))
        return enif_make_badarg(env);
    const int32_t *hints = hinted ? (const int32_t *)hint.data : NULL;
    size_t nh = hinted ? hint.size / sizeof(int32_t) : 0;
    for (size_t k = 0; k < nh; k++)
        if (hints[k] < 0 || (size_t)hints[k] >= n) return enif_make_badarg(env);
    size_t cap = 256, m = 0;
    int32_t *changed = malloc(cap * sizeof(int32_t));
    if (!changed) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    enif_mutex_lock(d->lock);
    int ok = 1;
    if (hinted) {
        /* a cell listed twice is taken once: its bit in seen */
        uint64_t *seen = d->seen;
        for (size_t k = 0; k < nh && m <= (size_t)max && ok; k++) {
            int32_t j = hints[k];
            uint64_t bit = 1ULL << (j & 63);
            if (d->cells[j] == b.data[j] || (seen[j >> 6] & bit)) continue;
            seen[j >> 6] |= bit;
            ok = push_changed(&changed, &m, &cap, j);
        }
        for (size_t k = 0; k < m; k++) seen[changed[k] >> 6] = 0;
    } else {
        for (size_t i = 0; i < n && m <= (size_t)max && ok; i += BLOCK) {
            size_t len = n - i < BLOCK ? n - i : BLOCK;
            if (!memcmp(d->cells + i, b.data + i, len)) continue;
            for (size_t j = i; j < i + len && m <= (size_t)max && ok; j++)
                if (d->cells[j] != b.data[j])
                    ok = push_changed(&changed, &m, &cap, (int32_t)j);
        }
    }
    if (!ok) {
        enif_mutex_unlock(d->lock);
        free(changed);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    if (m > (size_t)max) {
        d->cpu_ns += cpu_now() - t0;
        enif_mutex_unlock(d->lock);
        free(changed);
        return enif_make_tuple2(env, enif_make_atom(env, "too_many"), enif_make_long(env, (long)m));
    }
    /* the cells first, so every rhs repaired sees the new grid */
    for (size_t k = 0; k < m; k++) set_cell(d, changed[k], b.data[changed[k]]);
    long looked = repair_rhs(d, changed, m);
    d->cpu_ns += cpu_now() - t0;
    enif_mutex_unlock(d->lock);
    free(changed);
    if (looked < 0) return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    return enif_make_tuple2(env, A_OK, enif_make_long(env, (long)m));
}

/* a scan of a big grid, or many changes, runs on a dirty scheduler */
ERL_NIF_TERM tc_nif_dsl_sync(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    ErlNifBinary b;
    if (argc == 3 && enif_inspect_binary(env, argv[1], &b) && b.size > (1u << 22))
        return enif_schedule_nif(env, "dsl_sync", ERL_NIF_DIRTY_JOB_CPU_BOUND, dsl_sync_now,
                                 argc, argv);
    return dsl_sync_now(env, argc, argv);
}

/* dsl_move_start(dsl, cell) */
ERL_NIF_TERM tc_nif_dsl_move_start(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Dsl *d;
    int32_t s;
    int64_t t0 = cpu_now();
    if (!enif_get_resource(env, argv[0], DSL_TYPE, (void **)&d) ||
        !get_cell(env, argv[1], d->w, d->h, &s))
        return enif_make_badarg(env);
    enif_mutex_lock(d->lock);
    d->km += octile(d->sc, d->sr, s % d->w, s / d->w);
    d->start = s;
    d->sc = s % d->w;
    d->sr = s / d->w;
    d->cpu_ns += cpu_now() - t0;
    enif_mutex_unlock(d->lock);
    return A_OK;
}


/* dsl_forget_path(dsl): the next plan walks its path from the start to
 * the goal whole (for tests: a walk that joins the last path must give
 * the same path) */
ERL_NIF_TERM tc_nif_dsl_forget_path(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Dsl *d;
    if (!enif_get_resource(env, argv[0], DSL_TYPE, (void **)&d)) return enif_make_badarg(env);
    enif_mutex_lock(d->lock);
    d->valid = 0;
    enif_mutex_unlock(d->lock);
    return A_OK;
}

/* dsl_cpu_ns(dsl): the CPU time (ns) the calls on this search have
 * taken, on whichever threads they ran */
ERL_NIF_TERM tc_nif_dsl_cpu_ns(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Dsl *d;
    if (!enif_get_resource(env, argv[0], DSL_TYPE, (void **)&d)) return enif_make_badarg(env);
    enif_mutex_lock(d->lock);
    int64_t ns = d->cpu_ns;
    enif_mutex_unlock(d->lock);
    return enif_make_int64(env, ns);
}

/* dsl_queued(dsl): the entries in the queue, stale ones included */
ERL_NIF_TERM tc_nif_dsl_queued(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    Dsl *d;
    if (!enif_get_resource(env, argv[0], DSL_TYPE, (void **)&d)) return enif_make_badarg(env);
    enif_mutex_lock(d->lock);
    size_t n = d->qn;
    enif_mutex_unlock(d->lock);
    return enif_make_uint64(env, n);
}

/* ComputeShortestPath, processing at most `budget` vertices (0: no
 * limit); returns the vertices processed, -1 out of memory, and sets
 * *done when the start is consistent (or nothing is left to do). A
 * vertex whose key was a lower bound (queued before the robot moved) is
 * moved to its key and looked at again, as in the paper. */
static long compute(Dsl *d, long budget, int *done)
{
    int w = d->w;
    long processed = 0;
    int32_t to[8];
    int64_t cost[8];
    *done = 1;
    while (d->qn > 0) {
        if (budget && processed >= budget) {
            *done = 0;
            break;
        }
        Queued e = d->q[0];
        int32_t u = e.u;
        if (q_stale(d, &e)) {
            q_pop(d);
            continue;
        }
        int64_t gs = G(d, d->start), rs = RHS(d, d->start);
        int64_t ms = gs < rs ? gs : rs;
        if (!(e.k1 < ms + d->km || (e.k1 == ms + d->km && e.k2 < -(UNDER >> 1)) || rs > gs))
            break;
        int64_t gu = G(d, u), ru = RHS(d, u);
        int64_t k1 = k2_min(e.k2) + octile(d->sc, d->sr, u % w, u / w) + d->km;
        if (e.k1 < k1) {
            e.k1 = k1;
            q_down(d, 0, e);
            continue;
        }
        processed++;
        q_pop(d);
        int m = edges(d->cells, w, d->h, u, to, cost);
        if (gu > ru) {
            /* overconsistent: settle it, offer the new g to its predecessors */
            dsl_set_g(d, u, ru);
            for (int k = 0; k < m; k++) {
                int32_t s = to[k];
                if (s == d->goal) continue;
                int64_t v = cost[k] + ru;
                if (v < RHS(d, s)) {
                    SET_RHS(d, s, v);
                    if (!update_vertex(d, s)) return -1;
                }
            }
        } else {
            /* underconsistent: forget its g; predecessors that relied on it look again */
            dsl_set_g(d, u, INF);
            for (int k = 0; k < m; k++) {
                int32_t s = to[k];
                if (s == d->goal) continue;
                if (RHS(d, s) == cost[k] + gu) {
                    SET_RHS(d, s, best_rhs(d, s));
                    if (!update_vertex(d, s)) return -1;
                }
            }
            if (!update_vertex(d, u)) return -1;
        }
    }
    return processed;
}

/* sets (on) or clears the bits of cells */
static void mark(uint64_t *map, const int32_t *cells, size_t n, int on)
{
    for (size_t k = 0; k < n; k++) {
        int32_t i = cells[k];
        if (on)
            map[i >> 6] |= 1ULL << (i & 63);
        else
            map[i >> 6] &= ~(1ULL << (i & 63));
    }
}

/* whether u or a cell next to it has its bit set */
static int near_bit(const Dsl *d, const uint64_t *map, int32_t u)
{
    int w = d->w, c = u % w, r = u / w;
    for (int rr = r > 0 ? r - 1 : 0; rr <= r + 1 && rr < d->h; rr++)
        for (int cc = c > 0 ? c - 1 : 0; cc <= c + 1 && cc < w; cc++)
            if (BIT(map, rr * w + cc)) return 1;
    return 0;
}

/* The index in the last path after which none of its cells lies within
 * one cell of a vertex touched since it was walked: from there on, each
 * cell's neighbours have the g-values and cells they had, so the walk
 * from it is the rest of the last path. */
static size_t unchanged_from(Dsl *d)
{
    uint64_t *seen = d->seen;
    size_t keep = 0;
    for (size_t k = 0; k < d->tn; k++) seen[d->touched[k] >> 6] |= 1ULL << (d->touched[k] & 63);
    for (size_t i = d->plen; i-- > 0;)
        if (near_bit(d, seen, d->path[i])) {
            keep = i + 1;
            break;
        }
    for (size_t k = 0; k < d->tn; k++) seen[d->touched[k] >> 6] = 0;
    return keep;
}

static void forget_path(Dsl *d)
{
    mark(d->on, d->path, d->plen, 0);
    d->plen = 0;
    d->valid = 0;
    d->tn = 0;
}

/* The path from the start: from each cell to the successor minimising
 * c + g, until the goal. The walk stops at the first cell it meets of
 * the last path's unchanged end (see unchanged_from; none if the touched
 * vertices were too many to list) and the rest is copied: a change near
 * the robot walks only the path up to it. Returns 1 with the path in
 * d->path, 0 if the walk does not reach the goal, -1 out of memory. */
static int walk(Dsl *d)
{
    size_t keep = d->plen;
    if (d->valid) {
        keep = unchanged_from(d);
        /* the cells before it can no longer be joined */
        mark(d->on, d->path, keep, 0);
    }
    d->tn = 0;
    size_t n = (size_t)d->w * d->h, len = 0, cap = d->scap;
    int32_t *next_path = d->spare, to[8];
    int64_t cost[8];
    int32_t u = d->start;
    size_t from = d->plen; /* where the last path is joined */
    for (;;) {
        if (d->valid && BIT(d->on, u)) {
            for (from = keep; d->path[from] != u; from++)
                ;
            break;
        }
        if (len == cap) {
            cap = cap ? 2 * cap : 1024;
            int32_t *p = realloc(next_path, cap * sizeof(int32_t));
            if (!p) return -1;
            d->spare = next_path = p;
            d->scap = cap;
        }
        next_path[len++] = u;
        if (u == d->goal || len > n) break;
        int m = edges(d->cells, d->w, d->h, u, to, cost);
        int64_t best = INF;
        int32_t next = -1;
        for (int k = 0; k < m; k++) {
            int64_t gv = G(d, to[k]);
            if (gv < INF && cost[k] + gv < best) best = cost[k] + gv, next = to[k];
        }
        if (next < 0) break;
        u = next;
    }
    size_t rest = d->plen - from;
    if (len + rest > cap) {
        cap = len + rest;
        int32_t *p = realloc(next_path, cap * sizeof(int32_t));
        if (!p) return -1;
        d->spare = next_path = p;
        d->scap = cap;
    }
    memcpy(next_path + len, d->path + from, rest * sizeof(int32_t));
    /* the cells of the last path left out lose their bit, the walked
     * ones get one (the walk met no cell of the last path before it
     * joined it) */
    mark(d->on, d->path, from, 0);
    size_t walked = len;
    len += rest;
    d->spare = d->path;
    d->scap = d->pcap;
    d->path = next_path;
    d->pcap = cap;
    d->plen = len;
    if (next_path[len - 1] != d->goal) {
        mark(d->on, next_path + walked, rest, 0);
        d->plen = 0;
        d->valid = 0;
        return 0;
    }
    mark(d->on, next_path, walked, 1);
    d->valid = 1;
    return 1;
}

/* dsl_plan(dsl) -> {:ok, path, expanded} | {:error, :no_path, expanded}.
 * It starts on the calling scheduler with a budget of vertices (a repair
 * is usually small) and goes on on a dirty scheduler if that runs out. */
static ERL_NIF_TERM dsl_plan_run(ErlNifEnv *env, const ERL_NIF_TERM argv[], long budget,
                                 long before);

static ERL_NIF_TERM dsl_plan_dirty(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    long before;
    if (!enif_get_long(env, argv[1], &before)) return enif_make_badarg(env);
    return dsl_plan_run(env, argv, 0, before);
}

ERL_NIF_TERM tc_nif_dsl_plan(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[])
{
    (void)argc;
    return dsl_plan_run(env, argv, PLAN_BUDGET, 0);
}

static ERL_NIF_TERM dsl_plan_run(ErlNifEnv *env, const ERL_NIF_TERM argv[], long budget,
                                 long before)
{
    Dsl *d;
    int64_t t0 = cpu_now();
    if (!enif_get_resource(env, argv[0], DSL_TYPE, (void **)&d)) return enif_make_badarg(env);
    enif_mutex_lock(d->lock);
    if (d->cells[d->start] == BLOCKED || d->cells[d->goal] == BLOCKED) {
        enif_mutex_unlock(d->lock);
        return enif_make_tuple3(env, A_ERROR, A_NO_PATH, enif_make_long(env, 0));
    }
    int done;
    long processed = compute(d, budget, &done);
    if (processed < 0) {
        enif_mutex_unlock(d->lock);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    if (!done) {
        d->cpu_ns += cpu_now() - t0;
        enif_mutex_unlock(d->lock);
        ERL_NIF_TERM args[2] = {argv[0], enif_make_long(env, before + processed)};
        return enif_schedule_nif(env, "dsl_plan", ERL_NIF_DIRTY_JOB_CPU_BOUND, dsl_plan_dirty, 2,
                                 args);
    }
    processed += before;
    ERL_NIF_TERM result;
    if (RHS(d, d->start) >= INF) {
        forget_path(d);
        result = enif_make_tuple3(env, A_ERROR, A_NO_PATH, enif_make_long(env, processed));
    } else {
        int ok = walk(d);
        if (ok < 0) {
            enif_mutex_unlock(d->lock);
            return enif_raise_exception(env, enif_make_atom(env, "enomem"));
        }
        result = ok ? enif_make_tuple3(env, A_OK, path_term(env, d->path, d->plen, d->w),
                                       enif_make_long(env, processed))
                    : enif_make_tuple3(env, A_ERROR, A_NO_PATH, enif_make_long(env, processed));
    }
    d->cpu_ns += cpu_now() - t0;
    enif_mutex_unlock(d->lock);
    return result;
}
