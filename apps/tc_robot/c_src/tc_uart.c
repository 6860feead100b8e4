/*
 * tc_uart: ThinkingCap's serial line worker, one OS process per UART.
 *
 * Opens a tty (a serial port, a USB serial adapter, a pseudo-terminal's
 * slave) or creates a new pseudo-terminal pair and holds its master end,
 * sets the line up with termios (raw; speed, data bits, parity, stop bits,
 * flow control; VMIN = VTIME = 0) and moves bytes both ways: what the line
 * receives goes to the BEAM as it comes, what the BEAM sends is written
 * whole (waiting for the line with poll() when it is full).
 *
 * It talks to the BEAM over stdin/stdout in frames of a 4-byte big-endian
 * length and a payload whose first byte is the frame type (see PROTOCOL
 * below). One thread: poll() over stdin and the tty. While a write waits
 * for room on the line, no further command is read (the BEAM side queues
 * them), but received bytes still flow.
 *
 * When the line goes away (a USB adapter unplugged, the master of a pty
 * closed: read returns 0 or EIO, or poll reports a hangup with nothing to
 * read) the worker says so in an 'L' frame, closes the tty and waits for
 * the next command. A pty MASTER is different: it reads EIO and polls
 * POLLHUP whenever no process has its slave open, which is normal (the
 * program using the slave has not opened it yet, or is reopening it), so
 * the master stays open and the worker looks again every 50 ms instead of
 * spinning on POLLHUP. When stdin closes (the BEAM is gone) the worker
 * closes the line and exits.
 *
 * PROTOCOL (integers big-endian)
 *   BEAM -> worker (each command gets exactly one 'K' or 'E' reply, in order)
 *     'O' settings, path...          open the tty at path
 *     'P' settings                   open a new pty pair, hold its master
 *     'C' settings                   configure the open line
 *     'W' u32 timeout_ms, bytes...   write all bytes (0xFFFFFFFF: no time limit)
 *     'D'                            drain: wait until written bytes are sent
 *     'F' u8 queue                   flush: 0 receive, 1 transmit, 2 both
 *     'G'                            get the line's settings (tcgetattr)
 *     'X'                            close the line
 *   settings: u32 speed, u8 data_bits (5..8), u8 parity (0 none, 1 even,
 *             2 odd), u8 stop_bits (1, 2), u8 flow (0 none, 1 hardware
 *             RTS/CTS, 2 software XON/XOFF)
 *   worker -> BEAM
 *     'H' u32 speed...               hello: the speeds this build supports
 *     'K' bytes...                   ok ('P': the slave's path; 'G': settings)
 *     'E' u8 n, code (n bytes), text...
 *                                    the command failed: code is an errno
 *                                    name ("enoent"), text says what failed
 *     'R' u64 at, bytes...           bytes received on the line; at is
 *                                    CLOCK_MONOTONIC in ns, read right
 *                                    after the read() that got them
 *     'L' code...                    the line went away ("eio", "closed", ...);
 *                                    its fd is closed
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "tc_port.h"

#define MAX_FRAME (64u * 1024u * 1024u)
#define READ_CHUNK 16384
#define HUP_RETRY_MS 50
#define NO_TIMEOUT 0xFFFFFFFFu

typedef struct {
    uint32_t speed;
    uint8_t data_bits, parity, stop_bits, flow;
} settings;

enum { PARITY_NONE = 0, PARITY_EVEN = 1, PARITY_ODD = 2 };
enum { FLOW_NONE = 0, FLOW_HARDWARE = 1, FLOW_SOFTWARE = 2 };

static const struct { uint32_t baud; speed_t code; } speeds[] = {
    {50, B50}, {75, B75}, {110, B110}, {134, B134}, {150, B150}, {200, B200},
    {300, B300}, {600, B600}, {1200, B1200}, {1800, B1800}, {2400, B2400},
    {4800, B4800}, {9600, B9600}, {19200, B19200}, {38400, B38400},
    {57600, B57600}, {115200, B115200}, {230400, B230400},
#ifdef B460800
    {460800, B460800},
#endif
#ifdef B500000
    {500000, B500000},
#endif
#ifdef B576000
    {576000, B576000},
#endif
#ifdef B921600
    {921600, B921600},
#endif
#ifdef B1000000
    {1000000, B1000000},
#endif
#ifdef B1152000
    {1152000, B1152000},
#endif
#ifdef B1500000
    {1500000, B1500000},
#endif
#ifdef B2000000
    {2000000, B2000000},
#endif
#ifdef B2500000
    {2500000, B2500000},
#endif
#ifdef B3000000
    {3000000, B3000000},
#endif
#ifdef B3500000
    {3500000, B3500000},
#endif
#ifdef B4000000
    {4000000, B4000000},
#endif
};
#define NSPEEDS (sizeof speeds / sizeof speeds[0])

/* The open line. */
static int tty = -1;
static int is_master = 0;   /* tty is the master of a pty we created */
static int master_hup = 0;  /* ... and no process has its slave open */
static uint64_t hup_retry_at = 0; /* ms: when to look again */
static char line_path[PATH_MAX];

/* A write waiting for room on the line. */
static uint8_t *wbuf = NULL;
static size_t wlen = 0, woff = 0;
static uint32_t wtimeout = 0;
static uint64_t wdeadline = 0; /* ms, CLOCK_MONOTONIC; 0: none */

static uint64_t now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
}


static const char *errno_name(int e) {
    switch (e) {
    case ENOENT: return "enoent";
    case EACCES: return "eacces";
    case EPERM: return "eperm";
    case EBUSY: return "ebusy";
    case ENXIO: return "enxio";
    case ENODEV: return "enodev";
    case EIO: return "eio";
    case EINVAL: return "einval";
    case ENOTTY: return "enotty";
    case EAGAIN: return "eagain";
    case EISDIR: return "eisdir";
    case ENOTDIR: return "enotdir";
    case ELOOP: return "eloop";
    case ENAMETOOLONG: return "enametoolong";
    case EMFILE: return "emfile";
    case ENFILE: return "enfile";
    case ETIMEDOUT: return "etimedout";
    case EBADF: return "ebadf";
    case EINTR: return "eintr";
    case ENOMEM: return "enomem";
    case EROFS: return "erofs";
    case EPIPE: return "epipe";
    case ENOSPC: return "enospc";
    default: return "eunknown";
    }
}

/* A frame to the BEAM: type byte, then body. */
static void send_frame(uint8_t type, const void *body, size_t len) {
    uint8_t hdr[5];
    tc_put32(hdr, (uint32_t)len + 1);
    hdr[4] = type;
    tc_write_all(STDOUT_FILENO, hdr, 5);
    if (len > 0) tc_write_all(STDOUT_FILENO, body, len);
}

static void reply_ok(const void *body, size_t len) { send_frame('K', body, len); }

/* Received bytes, stamped with the moment they were read: the BEAM may
 * take them milliseconds later on a loaded machine. */
static void send_received(const uint8_t *bytes, size_t len) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    uint64_t ns = (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
    uint8_t hdr[13];
    tc_put32(hdr, (uint32_t)len + 9);
    hdr[4] = 'R';
    for (int i = 0; i < 8; i++) hdr[5 + i] = (uint8_t)(ns >> (56 - 8 * i));
    tc_write_all(STDOUT_FILENO, hdr, sizeof hdr);
    tc_write_all(STDOUT_FILENO, bytes, len);
}

static void reply_error(const char *code, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void reply_error(const char *code, const char *fmt, ...) {
    uint8_t buf[1024];
    size_t n = strlen(code);
    if (n > 255) n = 255;
    buf[0] = (uint8_t)n;
    memcpy(buf + 1, code, n);
    va_list ap;
    va_start(ap, fmt);
    int t = vsnprintf((char *)buf + 1 + n, sizeof buf - 1 - n, fmt, ap);
    va_end(ap);
    if (t < 0) t = 0;
    if ((size_t)t > sizeof buf - 2 - n) t = (int)(sizeof buf - 2 - n);
    send_frame('E', buf, 1 + n + (size_t)t);
}

/* Closes the line; `gone` names why when it went away by itself. */
static void close_line(const char *gone) {
    if (tty < 0) return;
    close(tty);
    tty = -1;
    is_master = 0;
    master_hup = 0;
    if (wbuf) {
        reply_error(gone ? gone : "ebadf", "write %s: the line went away", line_path);
        free(wbuf);
        wbuf = NULL;
    }
    if (gone) send_frame('L', gone, strlen(gone));
}

static int speed_code(uint32_t baud, speed_t *code) {
    for (size_t i = 0; i < NSPEEDS; i++)
        if (speeds[i].baud == baud) { *code = speeds[i].code; return 0; }
    return -1;
}

static uint32_t speed_baud(speed_t code) {
    for (size_t i = 0; i < NSPEEDS; i++)
        if (speeds[i].code == code) return speeds[i].baud;
    return 0;
}

static void decode_settings(const uint8_t *p, settings *s) {
    s->speed = tc_get32(p);
    s->data_bits = p[4];
    s->parity = p[5];
    s->stop_bits = p[6];
    s->flow = p[7];
}

/* Whether fd is the slave of a Unix 98 pseudo-terminal (settings are
 * always applied through the slave, also for a pty we hold the master of). */
static int is_pty(int fd) {
    struct stat st;
    if (fstat(fd, &st) < 0 || !S_ISCHR(st.st_mode)) return 0;
    unsigned int maj = major(st.st_rdev);
    return maj >= 136 && maj <= 143;
}

/* Sets fd's line up; on failure replies with the error and returns -1. */
static int apply_settings(int fd, const char *what, const settings *s) {
    speed_t code;
    if (speed_code(s->speed, &code) < 0) { reply_error("einval", "unsupported speed %u", s->speed); return -1; }
    if (s->data_bits < 5 || s->data_bits > 8) { reply_error("einval", "unsupported data bits %u", s->data_bits); return -1; }
    if (s->parity > PARITY_ODD) { reply_error("einval", "unsupported parity %u", s->parity); return -1; }
    if (s->stop_bits != 1 && s->stop_bits != 2) { reply_error("einval", "unsupported stop bits %u", s->stop_bits); return -1; }
    if (s->flow > FLOW_SOFTWARE) { reply_error("einval", "unsupported flow control %u", s->flow); return -1; }

    struct termios t;
    if (tcgetattr(fd, &t) < 0) { reply_error(errno_name(errno), "tcgetattr %s: %s", what, strerror(errno)); return -1; }
    cfmakeraw(&t);
    t.c_cflag |= CLOCAL | CREAD;
    t.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | PARODD | CSTOPB | CRTSCTS);
    static const tcflag_t sizes[] = {CS5, CS6, CS7, CS8};
    /* a pty has no bits on a wire: the Linux pty driver forces 8 data bits
     * and no parity (and refuses some other sizes), so a pty takes any
     * data bits and parity and keeps CS8 without parity */
    int pty = is_pty(fd);
    t.c_cflag |= pty ? CS8 : sizes[s->data_bits - 5];
    if (!pty && s->parity != PARITY_NONE) t.c_cflag |= PARENB;
    if (!pty && s->parity == PARITY_ODD) t.c_cflag |= PARODD;
    if (s->stop_bits == 2) t.c_cflag |= CSTOPB;
    t.c_iflag &= ~(tcflag_t)(IXON | IXOFF | IXANY);
    if (s->flow == FLOW_HARDWARE) t.c_cflag |= CRTSCTS;
    if (s->flow == FLOW_SOFTWARE) t.c_iflag |= IXON | IXOFF;
    t.c_cc[VMIN] = 0;
    t.c_cc[VTIME] = 0;
    cfsetispeed(&t, code);
    cfsetospeed(&t, code);
    if (tcsetattr(fd, TCSANOW, &t) < 0) { reply_error(errno_name(errno), "tcsetattr %s: %s", what, strerror(errno)); return -1; }

    /* tcsetattr succeeds if any change was made: check they all were */
    struct termios got;
    if (tcgetattr(fd, &got) < 0) { reply_error(errno_name(errno), "tcgetattr %s: %s", what, strerror(errno)); return -1; }
    const char *refused = NULL;
    if (cfgetospeed(&got) != code) refused = "speed";
    else if ((got.c_cflag & CSTOPB) != (t.c_cflag & CSTOPB)) refused = "stop bits";
    else if ((got.c_cflag & CRTSCTS) != (t.c_cflag & CRTSCTS) ||
             (got.c_iflag & (IXON | IXOFF)) != (t.c_iflag & (IXON | IXOFF))) refused = "flow control";
    else if ((got.c_cflag & CSIZE) != (t.c_cflag & CSIZE)) refused = "data bits";
    else if ((got.c_cflag & (PARENB | PARODD)) != (t.c_cflag & (PARENB | PARODD))) refused = "parity";
    if (refused) {
        reply_error("einval", "tcsetattr %s: the driver refused the %s", what, refused);
        return -1;
    }
    return 0;
}

static void cmd_open(const uint8_t *p, uint32_t len) {
    if (len < 10) { reply_error("einval", "bad open frame"); return; }
    settings s;
    decode_settings(p + 1, &s);
    size_t plen = len - 9;
    if (plen >= sizeof line_path) { reply_error("enametoolong", "open: path too long"); return; }
    char path[PATH_MAX];
    memcpy(path, p + 9, plen);
    path[plen] = '\0';
    if (strlen(path) != plen) { reply_error("einval", "open: path contains a NUL byte"); return; }
    close_line(NULL);

    int fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0) { reply_error(errno_name(errno), "open %s: %s", path, strerror(errno)); return; }
    if (!isatty(fd)) { close(fd); reply_error("enotty", "open %s: not a terminal", path); return; }
    if (apply_settings(fd, path, &s) < 0) { close(fd); return; }
    tty = fd;
    is_master = 0;
    master_hup = 0;
    memcpy(line_path, path, plen + 1);
    reply_ok(NULL, 0);
}

static void cmd_open_pty(const uint8_t *p, uint32_t len) {
    if (len != 9) { reply_error("einval", "bad open_pty frame"); return; }
    settings s;
    decode_settings(p + 1, &s);
    close_line(NULL);

    int fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (fd < 0) { reply_error(errno_name(errno), "posix_openpt: %s", strerror(errno)); return; }
    if (grantpt(fd) < 0) { reply_error(errno_name(errno), "grantpt: %s", strerror(errno)); close(fd); return; }
    if (unlockpt(fd) < 0) { reply_error(errno_name(errno), "unlockpt: %s", strerror(errno)); close(fd); return; }
    char *name = ptsname(fd);
    if (!name) { reply_error(errno_name(errno), "ptsname: %s", strerror(errno)); close(fd); return; }
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s", name);
    int fl = fcntl(fd, F_GETFL);
    if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0) {
        reply_error(errno_name(errno), "fcntl O_NONBLOCK %s: %s", path, strerror(errno));
        close(fd);
        return;
    }
    /* the slave raw too, so that bytes pass unchanged whoever opens it */
    int slave = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (slave < 0) { reply_error(errno_name(errno), "open %s: %s", path, strerror(errno)); close(fd); return; }
    int bad = apply_settings(slave, path, &s) < 0;
    close(slave);
    if (bad) { close(fd); return; }

    tty = fd;
    is_master = 1;
    master_hup = 0;
    snprintf(line_path, sizeof line_path, "%s", path);
    reply_ok(path, strlen(path));
}

static void cmd_configure(const uint8_t *p, uint32_t len) {
    if (len != 9) { reply_error("einval", "bad configure frame"); return; }
    if (tty < 0) { reply_error("ebadf", "configure: no line is open"); return; }
    settings s;
    decode_settings(p + 1, &s);
    int fd = tty, slave = -1;
    if (is_master) {
        /* a pty's line settings are the slave's */
        slave = open(line_path, O_RDWR | O_NOCTTY | O_NONBLOCK);
        if (slave < 0) { reply_error(errno_name(errno), "open %s: %s", line_path, strerror(errno)); return; }
        fd = slave;
    }
    int ok = apply_settings(fd, line_path, &s) == 0;
    if (slave >= 0) close(slave);
    if (ok) reply_ok(NULL, 0);
}

static void cmd_get(void) {
    if (tty < 0) { reply_error("ebadf", "settings: no line is open"); return; }
    struct termios t;
    int fd = tty, slave = -1;
    if (is_master) {
        slave = open(line_path, O_RDWR | O_NOCTTY | O_NONBLOCK);
        if (slave < 0) { reply_error(errno_name(errno), "open %s: %s", line_path, strerror(errno)); return; }
        fd = slave;
    }
    int r = tcgetattr(fd, &t);
    int e = errno;
    if (slave >= 0) close(slave);
    if (r < 0) { reply_error(errno_name(e), "tcgetattr %s: %s", line_path, strerror(e)); return; }
    uint8_t out[8];
    tc_put32(out, speed_baud(cfgetospeed(&t)));
    switch (t.c_cflag & CSIZE) {
    case CS5: out[4] = 5; break;
    case CS6: out[4] = 6; break;
    case CS7: out[4] = 7; break;
    default: out[4] = 8; break;
    }
    out[5] = !(t.c_cflag & PARENB) ? PARITY_NONE : (t.c_cflag & PARODD) ? PARITY_ODD : PARITY_EVEN;
    out[6] = (t.c_cflag & CSTOPB) ? 2 : 1;
    out[7] = (t.c_cflag & CRTSCTS) ? FLOW_HARDWARE : (t.c_iflag & (IXON | IXOFF)) ? FLOW_SOFTWARE : FLOW_NONE;
    reply_ok(out, sizeof out);
}

/* Writes what the line takes now; replies once all is written or on error. */
static void continue_write(void) {
    while (woff < wlen) {
        ssize_t n = write(tty, wbuf + woff, wlen - woff);
        if (n > 0) { woff += (size_t)n; continue; }
        if (n < 0 && errno == EINTR) continue;
        if (n < 0 && errno == EAGAIN) return; /* wait for POLLOUT */
        int e = n < 0 ? errno : EIO;
        reply_error(errno_name(e), "write %s: %s (%zu of %zu bytes written)", line_path, strerror(e), woff, wlen);
        free(wbuf);
        wbuf = NULL;
        return;
    }
    free(wbuf);
    wbuf = NULL;
    reply_ok(NULL, 0);
}

/* Takes over frame (a 'W' frame) as the pending write. */
static void cmd_write(uint8_t *frame, uint32_t len) {
    if (len < 5) { reply_error("einval", "bad write frame"); free(frame); return; }
    if (tty < 0) { reply_error("ebadf", "write: no line is open"); free(frame); return; }
    wtimeout = tc_get32(frame + 1);
    wdeadline = wtimeout == NO_TIMEOUT ? 0 : now_ms() + wtimeout;
    wbuf = frame;
    woff = 5;
    wlen = len;
    continue_write();
}

static void check_write_deadline(void) {
    if (wbuf && wdeadline && now_ms() >= wdeadline) {
        reply_error("etimedout", "write %s: timed out after %u ms (%zu of %zu bytes written)", line_path,
                    wtimeout, woff - 5, wlen - 5);
        free(wbuf);
        wbuf = NULL;
    }
}

static void handle_frame(uint8_t *p, uint32_t len) {
    if (len < 1) { reply_error("einval", "empty frame"); free(p); return; }
    switch (p[0]) {
    case 'W': cmd_write(p, len); return; /* owns p */
    case 'O': cmd_open(p, len); break;
    case 'P': cmd_open_pty(p, len); break;
    case 'C': cmd_configure(p, len); break;
    case 'G': cmd_get(); break;
    case 'D':
        if (tty < 0) reply_error("ebadf", "drain: no line is open");
        else if (tcdrain(tty) < 0) reply_error(errno_name(errno), "tcdrain %s: %s", line_path, strerror(errno));
        else reply_ok(NULL, 0);
        break;
    case 'F': {
        static const int queues[] = {TCIFLUSH, TCOFLUSH, TCIOFLUSH};
        if (len != 2 || p[1] > 2) reply_error("einval", "bad flush frame");
        else if (tty < 0) reply_error("ebadf", "flush: no line is open");
        else if (tcflush(tty, queues[p[1]]) < 0) reply_error(errno_name(errno), "tcflush %s: %s", line_path, strerror(errno));
        else reply_ok(NULL, 0);
        break;
    }
    case 'X':
        close_line(NULL);
        reply_ok(NULL, 0);
        break;
    default:
        reply_error("einval", "unknown frame type %u", p[0]);
    }
    free(p);
}

/* Reads one frame from the BEAM; -1 when stdin is closed. */
static int read_command(void) {
    uint8_t hdr[4];
    if (tc_read_all(STDIN_FILENO, hdr, 4) < 0) return -1;
    uint32_t len = tc_get32(hdr);
    if (len > MAX_FRAME) {
        /* skip it to stay in step with the stream */
        uint8_t junk[4096];
        for (uint32_t left = len; left > 0;) {
            uint32_t n = left < sizeof junk ? left : sizeof junk;
            if (tc_read_all(STDIN_FILENO, junk, n) < 0) return -1;
            left -= n;
        }
        reply_error("einval", "frame too long (%u bytes)", len);
        return 0;
    }
    uint8_t *p = malloc(len ? len : 1);
    if (!p) { reply_error("enomem", "out of memory for a %u byte frame", len); return -1; }
    if (tc_read_all(STDIN_FILENO, p, len) < 0) { free(p); return -1; }
    handle_frame(p, len);
    return 0;
}

/* The tty is readable or hung up. */
static void handle_tty(short revents) {
    static uint8_t buf[READ_CHUNK];
    if (wbuf && (revents & (POLLOUT | POLLHUP | POLLERR))) continue_write();
    if (tty < 0 || !(revents & (POLLIN | POLLHUP | POLLERR))) return;
    ssize_t n = read(tty, buf, sizeof buf);
    if (n > 0) {
        send_received(buf, (size_t)n);
        return;
    }
    if (n < 0 && errno == EINTR) return;
    int again = n < 0 && errno == EAGAIN;
    if (again && !(revents & (POLLHUP | POLLERR))) return;
    if (is_master) {
        /* no process has the slave open: normal, look again later */
        master_hup = 1;
        hup_retry_at = now_ms() + HUP_RETRY_MS;
        return;
    }
    close_line(n == 0 || again ? "closed" : errno_name(errno));
}

int main(void) {
    /* a write to a BEAM that is gone must fail, not kill the worker */
    signal(SIGPIPE, SIG_IGN);

    uint8_t hello[4 * NSPEEDS];
    for (size_t i = 0; i < NSPEEDS; i++) tc_put32(hello + 4 * i, speeds[i].baud);
    send_frame('H', hello, sizeof hello);

    for (;;) {
        struct pollfd fds[2];
        /* no new command while a write waits for the line */
        fds[0].fd = wbuf ? -1 : STDIN_FILENO;
        fds[0].events = POLLIN;
        fds[0].revents = 0;
        fds[1].fd = (tty >= 0 && !master_hup) ? tty : -1;
        fds[1].events = (short)(POLLIN | (wbuf ? POLLOUT : 0));
        fds[1].revents = 0;

        int timeout = -1;
        uint64_t now = now_ms();
        if (tty >= 0 && master_hup) timeout = hup_retry_at > now ? (int)(hup_retry_at - now) : 0;
        if (wbuf && wdeadline) {
            int left = wdeadline > now ? (int)(wdeadline - now) : 0;
            if (timeout < 0 || left < timeout) timeout = left;
        }

        int r = poll(fds, 2, timeout);
        if (r < 0) {
            if (errno == EINTR) continue;
            perror("tc_uart: poll");
            return 1;
        }
        if (tty >= 0 && master_hup && now_ms() >= hup_retry_at) {
            /* look whether a slave is open again; a write waiting is tried then */
            master_hup = 0;
        }
        if (fds[1].fd >= 0 && fds[1].revents) {
            if (fds[1].revents & POLLNVAL) close_line("ebadf");
            else handle_tty(fds[1].revents);
        }
        check_write_deadline();
        if (fds[0].fd >= 0 && (fds[0].revents & (POLLIN | POLLHUP | POLLERR))) {
            if (read_command() < 0) break;
        }
    }

    close_line(NULL);
    return 0;
}
