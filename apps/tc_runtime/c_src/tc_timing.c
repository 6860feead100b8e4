/*
 * tc_timing: ThinkingCap's timing worker.
 *
 * Releases periodic activities on absolute CLOCK_MONOTONIC deadlines
 * (clock_nanosleep with TIMER_ABSTIME), receives each activity's result
 * (the command to apply), and applies the activity's fallback command in
 * the same cycle when the result misses its deadline, so the robot never
 * runs on a stale command even if the BEAM stalls.
 *
 * It talks to the BEAM over stdin/stdout in frames of a 4-byte big-endian
 * length and a payload whose first byte is the frame type (see PROTOCOL
 * below). Commands are opaque bytes (Erlang external terms, for the BEAM).
 *
 * Two threads: the timing thread sleeps until the next release or deadline
 * and runs at SCHED_FIFO when the OS grants it; the reader thread blocks on
 * stdin and applies a fresh result the moment it arrives. Both write frames
 * under one lock. When stdin closes (the BEAM is gone) the worker applies
 * every activity's fallback and exits.
 *
 * Waking early: a thread's timer wakes it some tens of microseconds late,
 * and now and then hundreds (an interrupt, the hypervisor). With
 * `--wake-early-us N` (default 0) the timing thread sets its timer N us
 * before each release and spins on the clock to the instant: a release
 * goes out on time whenever the wake-up was less than N late. It never
 * goes out early. Deadlines are waited for without it: a fallback does
 * not need the microsecond, and most deadlines find their result in.
 *
 * Wires: an activity may own a device's command path (a serial line, a
 * pty, a FIFO). The worker opens the path write-only and non-blocking (it
 * never touches the line's termios: whoever opened the line set them),
 * writes a fresh result's wire bytes the moment it applies the result,
 * and writes the activity's wire fallback bytes whenever it applies the
 * fallback (deadline missed, activity removed, stdin closed) before it
 * reports: a missed deadline or a dead BEAM puts the stop frame on the
 * line in that same cycle. Writes never block the timing thread: what the
 * line does not take at once is dropped and reported (at most once a
 * second per activity). A line that fails (EIO, ENXIO: unplugged, the pty
 * master gone) is closed, reported once, and reopened on a later write,
 * at most every 100 ms, but only if its path still names the device first
 * opened (its device, inode and, for a character device, its inode's
 * change time: a new pty that got the number /dev/pts/N of a closed one
 * has the same device numbers and inode, not the same change time). A
 * path that names another device now (a replugged adapter, a later pty
 * of the same number, a symlink pointed elsewhere) is not written to and
 * is reported once: that device may be someone else's, and only the
 * activity's owner can tell, by attaching the wire again ('W'). A wire
 * ends when it is detached ('X'), replaced ('W') or its activity removed
 * ('R'), and when the worker exits: the worker never opens its path again.
 *
 * The release boost: the BEAM may name its scheduler (normal and dirty
 * CPU) and poller threads ('B'), each with a SCHED_FIFO priority. While
 * any activity is released and its result not yet in (nor its fallback
 * applied), the worker holds those threads at those priorities; when none
 * is, it puts each back as it found it (unless someone changed it
 * meanwhile: then it leaves it).
 * So the BEAM computes a periodic result above other programs' low
 * real-time threads, and for no longer than the activities' deadlines.
 *
 * PROTOCOL (integers big-endian)
 *   BEAM -> worker
 *     'A' u16 id, u64 period_ns, u64 deadline_ns, u8 priority, fallback...  add
 *     'R' u16 id                                      remove (applies its fallback)
 *     'C' u16 id, u32 cycle, command...                                    result
 *     'D' u16 id, u32 cycle, u16 wire_len, wire bytes, command...
 *                                         result with the bytes for its wire
 *     'W' u16 id, u16 fallback_len, fallback bytes, path...
 *                              attach a wire (open path; replaces an old one)
 *     'X' u16 id                                        detach the wire (close)
 *     'B' (u32 tid, u8 priority)...   the threads to boost while a result is
 *                                     pending (none: no boost)
 *   worker -> BEAM
 *     'H' u8 sched_fifo_granted, u8 mlockall_granted, text...               hello
 *     'L' u16 id, u32 cycle, u64 scheduled_ns, u64 released_ns, u32 timer_late_ns
 *         (how late the timing thread woke after its timer: cyclictest's
 *         measure; with the early wake-up, before it spun)              release
 *     'P' u16 id, u32 cycle, u8 kind (0 fresh, 1 fallback, 2 late: the
 *         cycle is the late result's), u8 wired (1: the command's bytes
 *         went on the wire, whole),
 *         u64 response_ns, command...                                      applied
 *     'V' u16 id, u8 status, text...  wire: 0 the attach failed (text: path
 *         and strerror), 1 attached (the reply to 'W'), 2 reopened by itself
 *     'E' text...                                                          error
 *         (a wire's errors: "wire <id> <path>: ...", with counts)
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "tc_port.h"

#define MAX_ACTIVITIES 256 /* a node hosting a simulated fleet: 2 per robot */
#define MAX_COMMAND 4096
#define MAX_WIRE 4096
#define MAX_PATH 1024
#define MAX_FRAME (MAX_COMMAND + MAX_WIRE + 64)
#define NS 1000000000ULL
#define REOPEN_EVERY (NS / 10)
#define REPORT_EVERY NS

enum { FRESH = 0, FALLBACK = 1, LATE = 2 };

typedef struct {
    int used;
    uint16_t id;
    uint64_t period, deadline;
    uint8_t priority;
    uint8_t fallback[MAX_COMMAND];
    uint32_t fallback_len;
    uint32_t cycle;       /* number of the last release */
    uint64_t next_release;/* absolute, ns */
    uint64_t released_at; /* actual time of the last release */
    uint64_t due;         /* absolute deadline of the last release */
    int awaiting;         /* released, no result and no fallback yet */
    /* the wire: the device this activity's commands are written to */
    struct wire {
        int attached;
        int fd;               /* -1 while the line is down */
        char path[MAX_PATH];
        uint8_t fallback[MAX_WIRE];
        uint32_t fallback_len;
        uint64_t opened_at;   /* last open attempt, for the reopen rate */
        struct stat id;       /* the device first opened: reopened only if the path names it */
        int other_reported;   /* the path names another device: said once */
        uint64_t reported_at; /* last short-write report, for its rate */
        uint32_t short_writes, dropped; /* not reported yet */
    } wire;
} activity;

static activity acts[MAX_ACTIVITIES];

/* the release boost: threads and their priorities while a result is
 * pending (a BEAM's normal and dirty CPU schedulers and its poller: 2n + 1
 * threads on n cores) */
#define MAX_BOOST 512
static struct boost {
    pid_t tid;
    int priority;
    int saved_policy;           /* as found, restored when no result is pending */
    struct sched_param saved;
} boosts[MAX_BOOST];
static int n_boosts, boosted, boost_reported;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_mutex_t out_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_t timing_thread;

static uint64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * NS + (uint64_t)ts.tv_nsec;
}

static void put16(uint8_t *p, uint16_t v) { p[0] = v >> 8; p[1] = v; }
static void put64(uint8_t *p, uint64_t v) { for (int i = 0; i < 8; i++) p[i] = v >> (56 - 8 * i); }
static uint16_t get16(const uint8_t *p) { return (uint16_t)(p[0] << 8 | p[1]); }
static uint64_t get64(const uint8_t *p) { uint64_t v = 0; for (int i = 0; i < 8; i++) v = v << 8 | p[i]; return v; }

/* Frames a thread sends while it holds `lock` wait in its outbox and go
 * out when it lets the lock go (unlock_and_send): a write to the BEAM's
 * pipe may block while the BEAM is busy, and under the lock it held the
 * other thread back (the timing thread's next release). */
#define OUTBOX_BYTES 65536
/* the size asked for the pipe to the BEAM (see main) */
#define OUT_PIPE_BYTES (1 << 20)
static __thread uint8_t outbox[OUTBOX_BYTES];
static __thread uint32_t outbox_len;
static __thread int deferring;

static void flush_outbox(void) {
    if (outbox_len == 0) return;
    pthread_mutex_lock(&out_lock);
    tc_write_all(STDOUT_FILENO, outbox, outbox_len);
    pthread_mutex_unlock(&out_lock);
    outbox_len = 0;
}

/* `lock`, with what is sent meanwhile held in the outbox. */
static void lock_deferring(void) {
    pthread_mutex_lock(&lock);
    deferring = 1;
}

static void unlock_and_send(void) {
    deferring = 0;
    pthread_mutex_unlock(&lock);
    flush_outbox();
}

/* One frame, written whole under out_lock (after the outbox's, in order). */
static void send_frame(const uint8_t *payload, uint32_t len) {
    uint8_t buf[MAX_FRAME + 4];
    if (len > MAX_FRAME) return;
    if (deferring) {
        /* a full outbox goes out now, under the lock: rare, and in order */
        if (outbox_len + len + 4 > OUTBOX_BYTES) flush_outbox();
        tc_put32(outbox + outbox_len, len);
        memcpy(outbox + outbox_len + 4, payload, len);
        outbox_len += len + 4;
        return;
    }
    tc_put32(buf, len);
    memcpy(buf + 4, payload, len);
    pthread_mutex_lock(&out_lock);
    tc_write_all(STDOUT_FILENO, buf, len + 4);
    pthread_mutex_unlock(&out_lock);
}

static void send_error(const char *text) {
    uint8_t buf[MAX_PATH + 256];
    size_t n = strlen(text);
    if (n > sizeof buf - 1) n = sizeof buf - 1;
    buf[0] = 'E';
    memcpy(buf + 1, text, n);
    send_frame(buf, (uint32_t)n + 1);
}

static void send_applied(const activity *a, uint32_t cycle, uint8_t kind, int wired, uint64_t response, const uint8_t *cmd, uint32_t len) {
    uint8_t buf[MAX_FRAME];
    buf[0] = 'P';
    put16(buf + 1, a->id);
    tc_put32(buf + 3, cycle);
    buf[7] = kind;
    buf[8] = (uint8_t)(wired != 0);
    put64(buf + 9, response);
    memcpy(buf + 17, cmd, len);
    send_frame(buf, 17 + len);
}

static void send_wire_status(uint16_t id, uint8_t status, const char *text) {
    uint8_t buf[MAX_PATH + 256];
    size_t n = strlen(text);
    if (n > sizeof buf - 4) n = sizeof buf - 4;
    buf[0] = 'V';
    put16(buf + 1, id);
    buf[3] = status;
    memcpy(buf + 4, text, n);
    send_frame(buf, (uint32_t)n + 4);
}

/* Opens a wire's path for writing: never blocking, never becoming the
 * controlling terminal, and leaving the line's settings alone. */
static int open_wire(const char *path) {
    int fd;
    do fd = open(path, O_WRONLY | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    while (fd < 0 && errno == EINTR);
    return fd;
}

/* Whether two stats are the same device node: the same file, and for a
 * character device the same inode's life (devpts gives a new pty of a
 * reused number the same device numbers and inode; its change time is
 * when it was made). FIFOs and files change their change time as they
 * are written, so only their identity counts. */
static int same_device(const struct stat *a, const struct stat *b) {
    if (a->st_dev != b->st_dev || a->st_ino != b->st_ino || a->st_rdev != b->st_rdev ||
        (a->st_mode & S_IFMT) != (b->st_mode & S_IFMT))
        return 0;
    if (S_ISCHR(a->st_mode))
        return a->st_ctim.tv_sec == b->st_ctim.tv_sec && a->st_ctim.tv_nsec == b->st_ctim.tv_nsec;
    return 1;
}

/* Says once that a wire's path names another device now. */
static void report_other_device(activity *a) {
    char text[MAX_PATH + 200];
    if (a->wire.other_reported) return;
    snprintf(text, sizeof text,
             "wire %u %s: the path names another device now; not reopened "
             "(its owner must attach it again)",
             a->id, a->wire.path);
    send_error(text);
    a->wire.other_reported = 1;
}

/* Reopens a wire's path if it still names the device first opened;
 * otherwise says so, once, and leaves the line closed (-1). */
static int reopen_wire(activity *a) {
    struct wire *w = &a->wire;
    struct stat st;
    /* not there (yet): tried again later */
    if (stat(w->path, &st) < 0) return -1;
    /* looked at before opening: another owner's device is not even opened */
    if (!same_device(&w->id, &st)) {
        report_other_device(a);
        return -1;
    }
    int fd = open_wire(w->path);
    if (fd < 0) return -1;
    /* what was opened, not what the path named a moment before */
    if (fstat(fd, &st) < 0 || !same_device(&w->id, &st)) {
        close(fd);
        report_other_device(a);
        return -1;
    }
    w->other_reported = 0;
    return fd;
}

static void close_wire(activity *a) {
    if (a->wire.attached && a->wire.fd >= 0) close(a->wire.fd);
    a->wire.fd = -1;
    a->wire.attached = 0;
}

/* Puts bytes on an activity's wire, never blocking; called under `lock`.
 * Returns whether all of them were written (1), or 0 (no wire, the line
 * is down, or it did not take them all: the rest is dropped). */
static int wire_write(activity *a, const uint8_t *bytes, uint32_t len) {
    struct wire *w = &a->wire;
    char text[MAX_PATH + 160];
    if (!w->attached) return 0;
    uint64_t now = now_ns();
    if (w->fd < 0) {
        /* the line went away: try it again now and then, if its path
         * still names the same device (a tty hung up, a FIFO's reader
         * back); a new device there is its owner's to attach */
        if (now - w->opened_at < REOPEN_EVERY) return 0;
        w->opened_at = now;
        w->fd = reopen_wire(a);
        if (w->fd < 0) return 0;
        snprintf(text, sizeof text, "reopened %s", w->path);
        send_wire_status(a->id, 2, text);
    }
    if (len == 0) return 1;
    ssize_t n;
    do n = write(w->fd, bytes, len);
    while (n < 0 && errno == EINTR);
    if (n == (ssize_t)len) return 1;
    if (n >= 0 || errno == EAGAIN || errno == EWOULDBLOCK) {
        /* the line is full: drop the rest, never wait for it */
        w->short_writes++;
        w->dropped += len - (uint32_t)(n > 0 ? n : 0);
        if (now - w->reported_at >= REPORT_EVERY) {
            snprintf(text, sizeof text,
                     "wire %u %s: the line did not take %u bytes of %u writes (dropped)",
                     a->id, w->path, w->dropped, w->short_writes);
            send_error(text);
            w->reported_at = now;
            w->short_writes = w->dropped = 0;
        }
        return 0;
    }
    /* EIO, ENXIO, EPIPE, EBADF...: the line is gone */
    snprintf(text, sizeof text, "wire %u %s: write: %s; closed, reopening every 100 ms",
             a->id, w->path, strerror(errno));
    send_error(text);
    close(w->fd);
    w->fd = -1;
    w->opened_at = now;
    return 0;
}

/* The fallback of an activity, on its wire first, then reported. */
static void apply_fallback(activity *a, uint64_t response) {
    int wired = a->wire.attached ? wire_write(a, a->wire.fallback, a->wire.fallback_len) : 0;
    send_applied(a, a->cycle, FALLBACK, wired, response, a->fallback, a->fallback_len);
}

static activity *find(uint16_t id) {
    for (int i = 0; i < MAX_ACTIVITIES; i++)
        if (acts[i].used && acts[i].id == id) return &acts[i];
    return NULL;
}

/* Boosts the threads (saving how they were) or puts them back; under `lock`. */
static void apply_boost(int on) {
    if (on == boosted) return;
    for (int i = 0; i < n_boosts; i++) {
        struct boost *b = &boosts[i];
        struct sched_param sp = {.sched_priority = b->priority};
        if (on) {
            b->saved_policy = sched_getscheduler(b->tid);
            if (b->saved_policy < 0 || sched_getparam(b->tid, &b->saved) < 0) {
                b->saved_policy = -1;
                continue;
            }
            if (sched_setscheduler(b->tid, SCHED_FIFO, &sp) < 0) {
                b->saved_policy = -1;
                if (!boost_reported) {
                    char text[160];
                    snprintf(text, sizeof text, "boost: thread %d: %s", (int)b->tid, strerror(errno));
                    send_error(text);
                    boost_reported = 1;
                }
            }
        } else if (b->saved_policy >= 0) {
            /* only what the boost set is undone: a thread someone else
             * rescheduled meanwhile is left as they left it */
            struct sched_param now;
            if (sched_getscheduler(b->tid) == SCHED_FIFO && sched_getparam(b->tid, &now) == 0 &&
                now.sched_priority == b->priority)
                sched_setscheduler(b->tid, b->saved_policy, &b->saved);
            b->saved_policy = -1;
        }
    }
    boosted = on;
}

/* The boost follows the results pending; under `lock`. */
static void update_boost(void) {
    int pending = 0;
    for (int i = 0; i < MAX_ACTIVITIES && !pending; i++) pending = acts[i].used && acts[i].awaiting;
    apply_boost(pending);
}

/* 'B': the threads to boost; a boost under way is undone first. */
static void set_boost(const uint8_t *p, uint32_t len) {
    if ((len - 1) % 5 != 0 || (len - 1) / 5 > MAX_BOOST) { send_error("bad boost frame"); return; }
    apply_boost(0);
    n_boosts = (int)((len - 1) / 5);
    for (int i = 0; i < n_boosts; i++) {
        boosts[i].tid = (pid_t)tc_get32(p + 1 + 5 * i);
        boosts[i].priority = p[5 + 5 * i];
        boosts[i].saved_policy = -1;
    }
    boost_reported = 0;
    update_boost();
}

static uint64_t wake_early_ns; /* --wake-early-us */
#define MAX_WAKE_EARLY_US 2000

static inline void spin_pause(void) {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#elif defined(__aarch64__)
    __asm__ __volatile__("yield");
#endif
}

/* The next instant something is due: a release or a pending deadline
 * (100 ms ahead when nothing is); *release says whether a release is due
 * then. */
static uint64_t next_instant(int *release) {
    pthread_mutex_lock(&lock);
    uint64_t next = now_ns() + NS / 10, first_release = UINT64_MAX;
    for (int i = 0; i < MAX_ACTIVITIES; i++) {
        activity *a = &acts[i];
        if (!a->used) continue;
        if (a->next_release < first_release) first_release = a->next_release;
        if (a->awaiting && a->due < next) next = a->due;
    }
    pthread_mutex_unlock(&lock);
    *release = first_release <= next;
    return *release ? first_release : next;
}

/* The timing thread: releases and deadlines. */
static void *timing_loop(void *arg) {
    (void)arg;
    for (;;) {
        int release;
        uint64_t next = next_instant(&release);
        /* early for a release only: a deadline's fallback does not need
         * the microsecond, and most deadlines find their result in */
        uint64_t early = release ? wake_early_ns : 0;
        uint64_t wake = next > early ? next - early : 0;
        uint64_t timer_late = 0;
        if (wake > now_ns()) {
            struct timespec ts = {.tv_sec = (time_t)(wake / NS), .tv_nsec = (long)(wake % NS)};
            /* woken before the timer (an activity was added or removed): plan again */
            if (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) continue;
            uint64_t woke = now_ns();
            timer_late = woke > wake ? woke - wake : 0;
        }
        if (early) {
            /* up ahead of time: an activity removed meanwhile may have
             * left nothing due so soon; otherwise spin to the instant */
            next = next_instant(&release);
            if (next > now_ns() + early) continue;
            while (now_ns() < next) spin_pause();
        }

        lock_deferring();
        uint64_t now = now_ns();
        /* deadlines first: a missed result gets its fallback in its own cycle */
        for (int i = 0; i < MAX_ACTIVITIES; i++) {
            activity *a = &acts[i];
            if (a->used && a->awaiting && a->due <= now) {
                a->awaiting = 0;
                apply_fallback(a, now - a->released_at);
            }
        }
        /* then releases, highest priority first */
        for (;;) {
            activity *best = NULL;
            for (int i = 0; i < MAX_ACTIVITIES; i++) {
                activity *a = &acts[i];
                if (a->used && a->next_release <= now && (!best || a->priority > best->priority)) best = a;
            }
            if (!best) break;
            uint64_t scheduled = best->next_release;
            uint64_t released = now_ns();
            best->cycle++;
            best->released_at = released;
            best->due = scheduled + best->deadline;
            best->awaiting = 1;
            /* skip releases already missed entirely (the BEAM side counts them) */
            best->next_release = scheduled + best->period;
            while (best->next_release <= released) best->next_release += best->period;
            /* the BEAM's threads up before the release reaches them */
            apply_boost(n_boosts > 0);

            uint8_t buf[32];
            buf[0] = 'L';
            put16(buf + 1, best->id);
            tc_put32(buf + 3, best->cycle);
            put64(buf + 7, scheduled);
            put64(buf + 15, released);
            tc_put32(buf + 23, timer_late > UINT32_MAX ? UINT32_MAX : (uint32_t)timer_late);
            send_frame(buf, 27);
        }
        update_boost();
        unlock_and_send();
    }
    return NULL;
}

static void on_wake(int sig) { (void)sig; }

/* Interrupts the timing thread's sleep so it plans with the new table. */
static void wake_timing(void) { pthread_kill(timing_thread, SIGUSR1); }

/* A fresh result (with the bytes for its wire, if any), or a late one. */
static void result(activity *a, uint32_t cycle, const uint8_t *wire, uint32_t wire_len, const uint8_t *cmd, uint32_t len) {
    uint64_t response = now_ns() - a->released_at;
    if (a->awaiting && cycle == a->cycle) {
        a->awaiting = 0;
        int wired = wire ? wire_write(a, wire, wire_len) : 0;
        send_applied(a, cycle, FRESH, wired, response, cmd, len);
    } else {
        /* too late: the fallback was applied; the BEAM counts it (the
         * result's own cycle: the activity may be cycles further on) */
        send_applied(a, cycle, LATE, 0, response, cmd, 0);
    }
}

/* 'W': opens the path outside the lock (an open may take a while; the
 * timing thread must not wait for it), then attaches it. */
static void attach_wire(const uint8_t *p, uint32_t len) {
    char path[MAX_PATH], text[MAX_PATH + 160];
    if (len < 5) { send_error("bad wire frame"); return; }
    uint16_t id = get16(p + 1);
    uint32_t fallback_len = get16(p + 3);
    if (fallback_len > MAX_WIRE || 5 + fallback_len > len) { send_wire_status(id, 0, "bad wire frame: fallback longer than the frame"); return; }
    uint32_t path_len = len - 5 - fallback_len;
    if (path_len == 0 || path_len >= MAX_PATH || memchr(p + 5 + fallback_len, 0, path_len)) {
        send_wire_status(id, 0, "bad wire frame: the path is empty, too long or holds a NUL byte");
        return;
    }
    memcpy(path, p + 5 + fallback_len, path_len);
    path[path_len] = 0;

    int fd = open_wire(path);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) < 0) {
        snprintf(text, sizeof text, "open %s: %s", path, strerror(errno));
        if (fd >= 0) close(fd);
        send_wire_status(id, 0, text);
        return;
    }
    lock_deferring();
    activity *a = find(id);
    if (!a) {
        unlock_and_send();
        close(fd);
        snprintf(text, sizeof text, "%s: no activity %u to attach it to", path, id);
        send_wire_status(id, 0, text);
        return;
    }
    close_wire(a);
    struct wire *w = &a->wire;
    w->attached = 1;
    w->fd = fd;
    memcpy(w->path, path, path_len + 1);
    memcpy(w->fallback, p + 5, fallback_len);
    w->fallback_len = fallback_len;
    w->opened_at = now_ns();
    w->id = st;
    w->other_reported = 0;
    w->reported_at = 0;
    w->short_writes = w->dropped = 0;
    snprintf(text, sizeof text, "attached %s", path);
    send_wire_status(id, 1, text);
    unlock_and_send();
}

static void handle_frame(const uint8_t *p, uint32_t len) {
    if (len < 1) { send_error("empty frame"); return; }
    if (p[0] == 'W') { attach_wire(p, len); return; }
    lock_deferring();
    switch (p[0]) {
    case 'A': {
        if (len < 20 || len - 20 > MAX_COMMAND) { send_error("bad add frame"); break; }
        uint16_t id = get16(p + 1);
        activity *a = find(id);
        for (int i = 0; !a && i < MAX_ACTIVITIES; i++) if (!acts[i].used) a = &acts[i];
        if (!a) { send_error("too many activities"); break; }
        uint64_t period = get64(p + 3), deadline = get64(p + 11);
        if (period == 0 || deadline == 0) { send_error("period and deadline must be positive"); break; }
        /* an activity added again keeps its wire */
        struct wire w;
        if (a->used) w = a->wire; else { memset(&w, 0, sizeof w); w.fd = -1; }
        memset(a, 0, sizeof *a);
        a->used = 1;
        a->id = id;
        a->period = period;
        a->deadline = deadline;
        a->priority = p[19];
        a->fallback_len = len - 20;
        memcpy(a->fallback, p + 20, a->fallback_len);
        a->wire = w;
        a->next_release = now_ns() + a->period;
        wake_timing();
        break;
    }
    case 'R': {
        /* a removed activity (its module stopped or crashed) will send no
         * fresh command again: its fallback is the last word, on its wire
         * too, and then the wire is closed */
        activity *a = len >= 3 ? find(get16(p + 1)) : NULL;
        if (a) {
            a->awaiting = 0;
            apply_fallback(a, 0);
            close_wire(a);
            a->used = 0;
        }
        wake_timing();
        break;
    }
    case 'X': {
        activity *a = len >= 3 ? find(get16(p + 1)) : NULL;
        if (len < 3) send_error("bad detach frame");
        else if (a) close_wire(a);
        break;
    }
    case 'C': {
        if (len < 7 || len - 7 > MAX_COMMAND) { send_error("bad result frame"); break; }
        activity *a = find(get16(p + 1));
        if (a) result(a, tc_get32(p + 3), NULL, 0, p + 7, len - 7);
        break;
    }
    case 'D': {
        uint32_t wire_len = len >= 9 ? get16(p + 7) : 0;
        if (len < 9 || wire_len > MAX_WIRE || 9 + wire_len > len || len - 9 - wire_len > MAX_COMMAND) {
            send_error("bad wire result frame");
            break;
        }
        activity *a = find(get16(p + 1));
        if (a) result(a, tc_get32(p + 3), p + 9, wire_len, p + 9 + wire_len, len - 9 - wire_len);
        break;
    }
    case 'B':
        set_boost(p, len);
        break;
    default:
        send_error("unknown frame type");
    }
    /* a result in, an activity removed or added again: the boost follows */
    update_boost();
    unlock_and_send();
}

/* --wake-early-us N: 0 to MAX_WAKE_EARLY_US; anything else refused. */
static int parse_args(int argc, char **argv) {
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--wake-early-us") == 0 && i + 1 < argc) {
            char *end;
            errno = 0;
            long us = strtol(argv[++i], &end, 10);
            if (errno || *end || end == argv[i] || us < 0 || us > MAX_WAKE_EARLY_US) {
                fprintf(stderr, "tc_timing: --wake-early-us takes 0 to %d, not %s\n", MAX_WAKE_EARLY_US, argv[i]);
                return -1;
            }
            wake_early_ns = (uint64_t)us * 1000;
        } else {
            fprintf(stderr, "tc_timing: unknown argument %s\n", argv[i]);
            return -1;
        }
    }
    return 0;
}

int main(int argc, char **argv) {
    char text[200];
    if (parse_args(argc, argv) < 0) return 2;
    /* a write to a BEAM that is gone must fail, not kill the worker */
    signal(SIGPIPE, SIG_IGN);
    /* The frames to the BEAM pile up in the pipe while it reads nothing
     * (stopped, swapped out), and the timing thread's write blocks once
     * the pipe is full: no releases, no deadlines, no fallback bytes on
     * the wires. At the default 64 KB that came 11 s into a frozen BEAM
     * (a fault test); at 1 MB it is over two minutes. A pipe kept at its
     * size (F_SETPIPE_SZ refused) only shortens that. */
    (void)fcntl(STDOUT_FILENO, F_SETPIPE_SZ, OUT_PIPE_BYTES);
    /* SIGUSR1 interrupts the timing thread's sleep (no SA_RESTART) */
    struct sigaction wake = {0};
    wake.sa_handler = on_wake;
    sigemptyset(&wake.sa_mask);
    sigaction(SIGUSR1, &wake, NULL);
    int mlock_ok = mlockall(MCL_CURRENT | MCL_FUTURE) == 0;
    int mlock_errno = mlock_ok ? 0 : errno;

    pthread_attr_t attr;
    pthread_attr_init(&attr);
    struct sched_param sp = {.sched_priority = 80};
    int fifo_ok = 0;
    if (pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED) == 0 &&
        pthread_attr_setschedpolicy(&attr, SCHED_FIFO) == 0 &&
        pthread_attr_setschedparam(&attr, &sp) == 0 &&
        pthread_create(&timing_thread, &attr, timing_loop, NULL) == 0) {
        fifo_ok = 1;
    } else if (pthread_create(&timing_thread, NULL, timing_loop, NULL) != 0) {
        perror("tc_timing: pthread_create");
        return 1;
    }

    /* The reader thread (this one) applies fresh results as they arrive:
     * it is on the control path too, just below the timing thread. At
     * normal priority it waited behind the BEAM's real-time schedulers
     * whenever they were busy, and fresh results missed their deadlines. */
    struct sched_param reader_sp = {.sched_priority = 79};
    int reader_ok = fifo_ok && pthread_setschedparam(pthread_self(), SCHED_FIFO, &reader_sp) == 0;

    snprintf(text, sizeof text, "SCHED_FIFO %s; mlockall %s; wakes %d us early",
             reader_ok ? "granted (timing 80, reader 79)"
             : fifo_ok ? "granted (timing 80; reader refused)"
                       : "refused: running at normal priority",
             mlock_ok ? "granted" : strerror(mlock_errno), (int)(wake_early_ns / 1000));
    uint8_t hello[256];
    hello[0] = 'H';
    hello[1] = (uint8_t)fifo_ok;
    hello[2] = (uint8_t)mlock_ok;
    size_t n = strlen(text);
    memcpy(hello + 3, text, n);
    send_frame(hello, (uint32_t)n + 3);

    static uint8_t frame[MAX_FRAME];
    for (;;) {
        uint8_t hdr[4];
        if (tc_read_all(STDIN_FILENO, hdr, 4) < 0) break;
        uint32_t len = tc_get32(hdr);
        if (len > MAX_FRAME) {
            /* unrecoverable framing: refuse and stop, the robot stopped below */
            send_error("frame too long");
            break;
        }
        if (tc_read_all(STDIN_FILENO, frame, len) < 0) break;
        handle_frame(frame, len);
    }

    /* The BEAM is gone (or the stream broke): nobody will send fresh
     * commands, so every activity's fallback is the last word. */
    pthread_mutex_lock(&lock);
    for (int i = 0; i < MAX_ACTIVITIES; i++) {
        if (!acts[i].used) continue;
        apply_fallback(&acts[i], 0);
        close_wire(&acts[i]);
        acts[i].awaiting = 0;
    }
    apply_boost(0);
    pthread_mutex_unlock(&lock);
    fprintf(stderr, "tc_timing: input closed, fallbacks applied, exiting\n");
    return 0;
}
