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
 * PROTOCOL (integers big-endian)
 *   BEAM -> worker
 *     'A' u16 id, u64 period_ns, u64 deadline_ns, u8 priority, fallback...  add
 *     'R' u16 id                                      remove (applies its fallback)
 *     'C' u16 id, u32 cycle, command...                                    result
 *   worker -> BEAM
 *     'H' u8 sched_fifo_granted, u8 mlockall_granted, text...               hello
 *     'L' u16 id, u32 cycle, u64 scheduled_ns, u64 released_ns              release
 *     'P' u16 id, u32 cycle, u8 kind (0 fresh, 1 fallback, 2 late),
 *         u64 response_ns, command...                                      applied
 *     'E' text...                                                          error
 */
#define _GNU_SOURCE
#include <errno.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#define MAX_ACTIVITIES 64
#define MAX_COMMAND 4096
#define MAX_FRAME (MAX_COMMAND + 64)
#define NS 1000000000ULL

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
} activity;

static activity acts[MAX_ACTIVITIES];
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_mutex_t out_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_t timing_thread;

static uint64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * NS + (uint64_t)ts.tv_nsec;
}

static void put16(uint8_t *p, uint16_t v) { p[0] = v >> 8; p[1] = v; }
static void put32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) p[i] = v >> (24 - 8 * i); }
static void put64(uint8_t *p, uint64_t v) { for (int i = 0; i < 8; i++) p[i] = v >> (56 - 8 * i); }
static uint16_t get16(const uint8_t *p) { return (uint16_t)(p[0] << 8 | p[1]); }
static uint32_t get32(const uint8_t *p) { uint32_t v = 0; for (int i = 0; i < 4; i++) v = v << 8 | p[i]; return v; }
static uint64_t get64(const uint8_t *p) { uint64_t v = 0; for (int i = 0; i < 8; i++) v = v << 8 | p[i]; return v; }

static int write_all(int fd, const uint8_t *buf, size_t len) {
    while (len > 0) {
        ssize_t n = write(fd, buf, len);
        if (n < 0) { if (errno == EINTR) continue; return -1; }
        buf += n; len -= (size_t)n;
    }
    return 0;
}

/* One frame, written whole under out_lock. */
static void send_frame(const uint8_t *payload, uint32_t len) {
    uint8_t buf[MAX_FRAME + 4];
    if (len > MAX_FRAME) return;
    put32(buf, len);
    memcpy(buf + 4, payload, len);
    pthread_mutex_lock(&out_lock);
    write_all(STDOUT_FILENO, buf, len + 4);
    pthread_mutex_unlock(&out_lock);
}

static void send_error(const char *text) {
    uint8_t buf[256];
    size_t n = strlen(text);
    if (n > sizeof buf - 1) n = sizeof buf - 1;
    buf[0] = 'E';
    memcpy(buf + 1, text, n);
    send_frame(buf, (uint32_t)n + 1);
}

static void send_applied(const activity *a, uint8_t kind, uint64_t response, const uint8_t *cmd, uint32_t len) {
    uint8_t buf[MAX_FRAME];
    buf[0] = 'P';
    put16(buf + 1, a->id);
    put32(buf + 3, a->cycle);
    buf[7] = kind;
    put64(buf + 8, response);
    memcpy(buf + 16, cmd, len);
    send_frame(buf, 16 + len);
}

static activity *find(uint16_t id) {
    for (int i = 0; i < MAX_ACTIVITIES; i++)
        if (acts[i].used && acts[i].id == id) return &acts[i];
    return NULL;
}

/* The timing thread: releases and deadlines. */
static void *timing_loop(void *arg) {
    (void)arg;
    for (;;) {
        pthread_mutex_lock(&lock);
        uint64_t next = now_ns() + NS / 10; /* idle: look again in 100 ms */
        for (int i = 0; i < MAX_ACTIVITIES; i++) {
            activity *a = &acts[i];
            if (!a->used) continue;
            if (a->next_release < next) next = a->next_release;
            if (a->awaiting && a->due < next) next = a->due;
        }
        pthread_mutex_unlock(&lock);

        struct timespec ts = {.tv_sec = (time_t)(next / NS), .tv_nsec = (long)(next % NS)};
        /* woken early (an activity was added or removed): plan again */
        if (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) continue;

        pthread_mutex_lock(&lock);
        uint64_t now = now_ns();
        /* deadlines first: a missed result gets its fallback in its own cycle */
        for (int i = 0; i < MAX_ACTIVITIES; i++) {
            activity *a = &acts[i];
            if (a->used && a->awaiting && a->due <= now) {
                a->awaiting = 0;
                send_applied(a, FALLBACK, now - a->released_at, a->fallback, a->fallback_len);
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

            uint8_t buf[32];
            buf[0] = 'L';
            put16(buf + 1, best->id);
            put32(buf + 3, best->cycle);
            put64(buf + 7, scheduled);
            put64(buf + 15, released);
            send_frame(buf, 23);
        }
        pthread_mutex_unlock(&lock);
    }
    return NULL;
}

static void on_wake(int sig) { (void)sig; }

/* Interrupts the timing thread's sleep so it plans with the new table. */
static void wake_timing(void) { pthread_kill(timing_thread, SIGUSR1); }

static void handle_frame(const uint8_t *p, uint32_t len) {
    if (len < 1) { send_error("empty frame"); return; }
    pthread_mutex_lock(&lock);
    switch (p[0]) {
    case 'A': {
        if (len < 20 || len - 20 > MAX_COMMAND) { send_error("bad add frame"); break; }
        uint16_t id = get16(p + 1);
        activity *a = find(id);
        for (int i = 0; !a && i < MAX_ACTIVITIES; i++) if (!acts[i].used) a = &acts[i];
        if (!a) { send_error("too many activities"); break; }
        memset(a, 0, sizeof *a);
        a->used = 1;
        a->id = id;
        a->period = get64(p + 3);
        a->deadline = get64(p + 11);
        a->priority = p[19];
        a->fallback_len = len - 20;
        memcpy(a->fallback, p + 20, a->fallback_len);
        if (a->period == 0 || a->deadline == 0) { a->used = 0; send_error("period and deadline must be positive"); break; }
        a->next_release = now_ns() + a->period;
        wake_timing();
        break;
    }
    case 'R': {
        /* a removed activity (its module stopped or crashed) will send no
         * fresh command again: its fallback is the last word */
        activity *a = len >= 3 ? find(get16(p + 1)) : NULL;
        if (a) {
            a->awaiting = 0;
            send_applied(a, FALLBACK, 0, a->fallback, a->fallback_len);
            a->used = 0;
        }
        wake_timing();
        break;
    }
    case 'C': {
        if (len < 7 || len - 7 > MAX_COMMAND) { send_error("bad result frame"); break; }
        activity *a = find(get16(p + 1));
        uint32_t cycle = get32(p + 3);
        if (!a) break;
        uint64_t response = now_ns() - a->released_at;
        if (a->awaiting && cycle == a->cycle) {
            a->awaiting = 0;
            send_applied(a, FRESH, response, p + 7, len - 7);
        } else {
            /* too late: the fallback was applied; the BEAM counts it */
            send_applied(a, LATE, response, p + 7, 0);
        }
        break;
    }
    default:
        send_error("unknown frame type");
    }
    pthread_mutex_unlock(&lock);
}

static int read_all(uint8_t *buf, size_t len) {
    while (len > 0) {
        ssize_t n = read(STDIN_FILENO, buf, len);
        if (n == 0) return -1;
        if (n < 0) { if (errno == EINTR) continue; return -1; }
        buf += n; len -= (size_t)n;
    }
    return 0;
}

int main(void) {
    char text[200];
    /* a write to a BEAM that is gone must fail, not kill the worker */
    signal(SIGPIPE, SIG_IGN);
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

    snprintf(text, sizeof text, "SCHED_FIFO %s; mlockall %s",
             fifo_ok ? "granted (priority 80)" : "refused: running at normal priority",
             mlock_ok ? "granted" : strerror(mlock_errno));
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
        if (read_all(hdr, 4) < 0) break;
        uint32_t len = get32(hdr);
        if (len > MAX_FRAME) {
            /* unrecoverable framing: refuse and stop, the robot stopped below */
            send_error("frame too long");
            break;
        }
        if (read_all(frame, len) < 0) break;
        handle_frame(frame, len);
    }

    /* The BEAM is gone (or the stream broke): nobody will send fresh
     * commands, so every activity's fallback is the last word. */
    pthread_mutex_lock(&lock);
    for (int i = 0; i < MAX_ACTIVITIES; i++)
        if (acts[i].used) send_applied(&acts[i], FALLBACK, 0, acts[i].fallback, acts[i].fallback_len);
    pthread_mutex_unlock(&lock);
    fprintf(stderr, "tc_timing: input closed, fallbacks applied, exiting\n");
    return 0;
}
